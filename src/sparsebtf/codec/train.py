"""Train a model once (paper §3.2): one dictionary ensemble per YUV channel, or one 5D ensemble.

The training set is a seeded fraction of the data points of a few BTFs (§3.1,
:mod:`sparsebtf.points.sources`); each channel's ensemble is learned by
:class:`~sparsebtf.learning.ensemble.DictionaryEnsemble` (Eq. 2), in this process or on a Dask
cluster (:mod:`sparsebtf.execution`, :mod:`sparsebtf.learning.partitions`). On a cluster each
partition of the training points is described by its BTF sources (paths or ``synth:`` specs,
opened by the workers: shared storage, ``docs/distributed.md``), point indices and statistics,
and loaded once into a worker's memory (:func:`load_partition`).
"""

from __future__ import annotations

import hashlib
import math
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._version import library_version
from ..data.btf import BTF
from ..errors import BTFInputError
from ..execution import Executor, executor
from ..learning.ensemble import (
    FULL_PASS_EVERY,
    DictionaryEnsemble,
    PointSource,
)
from ..learning.partitions import PARTITION_POINTS, load_points
from ..model import CHANNELS, Model
from ..points.preprocessing import (
    TRANSFORMS,
    LogOffset,
    StdMode,
    Transform,
    resolve_log_offset,
)
from ..points.sources import BTFPointSource, channel_sources, training_points
from .jobs import Source
from .levels import TauTrainSpec, parse_tau_train

__all__ = ["train"]


def _train_channel(
    ch: str,
    c: int,
    src: PointSource,
    tau: int | list[int],
    *,
    learn_tau: bool = False,
    validation_taus: list[int] | None = None,
    n_dictionaries: int,
    max_iter: int,
    tol: float,
    init: str,
    candidates: int | None,
    full_pass_every: int,
    batch_size: int,
    partition_size: int,
    dtype: str,
    seed: int,
    checkpoint_dir: str | None,
    progress: bool | None,
    ex: Executor,
    partition: Callable[[int, int, int], Any] | None,
    data_key: str,
) -> tuple[list[np.ndarray], dict[str, Any]]:
    """Fit one channel's ensemble; its dictionaries and training diagnostics."""
    ens = DictionaryEnsemble(
        n_dictionaries=n_dictionaries,
        tau=tau,
        max_iter=max_iter,
        tol=tol,
        init=init,
        candidates=candidates,
        full_pass_every=full_pass_every,
        batch_size=batch_size,
        partition_size=partition_size,
        dtype=dtype,
        random_state=seed + c,
        checkpoint=None if checkpoint_dir is None else checkpoint_path(checkpoint_dir, ch),
        progress=progress,
        learn_tau=learn_tau,
        validation_taus=validation_taus,
    )
    ens.fit(src, desc=f"train {ch}", executor=ex, partition=partition, data_key=data_key)
    return ens.dictionaries_, {
        "objective": [float(v) for v in ens.objective_],
        # which coding passes tried all K dictionaries; the last one always did
        "passes": list(ens.passes_),
        "membership_counts": [int(v) for v in ens.counts_],
        "n_iter": int(ens.n_iter_),
        "seconds": float(ens.fit_seconds_),
        "n_points": int(src.n_points),
        # dictionaries tried per point between full passes (K: every pass full), and whether
        # the caller chose it or the size rule did (DictionaryEnsemble.candidates_for)
        "candidates": int(ens.candidates_),
        "candidate_rule": "given" if candidates is not None else "auto",
        "iteration_seconds": [float(v) for v in ens.iteration_seconds_],
        # several training sparsities: each dictionary's, each level's fit, the selection
        **({"tau_dictionaries": [int(t) for t in ens.taus_], "levels": ens.levels_,
            "validation": ens.validation_} if learn_tau or np.ndim(tau) else {}),
    }


def checkpoint_path(checkpoint_dir: str | os.PathLike[str], channel: str) -> str:
    """The checkpoint file of one channel's ensemble in ``checkpoint_dir``."""
    return os.path.join(checkpoint_dir, f"train_{channel}.npz")


def load_partition(items: list[tuple[Any, Any, np.ndarray]], patch: int,
                   channel: int | None, batch_size: int) -> Any:  # fmt: skip
    """Task (on a worker): a partition's points in memory, from its description: per BTF its
    :class:`~.jobs.Source` (opened here), :class:`Preprocessor` and point indices."""
    opened = [(s.open() if isinstance(s, Source) else s, pre, idx) for s, pre, idx in items]
    return load_points(BTFPointSource(opened, patch, channel), batch_size)


def _data_key(points: BTFPointSource, channel: str) -> str:
    """A fingerprint of one channel's training points: materials, sizes, sampled point
    indices and statistics (a checkpoint of other data is refused)."""
    h = hashlib.sha256(f"{channel}:{points.patch}".encode())
    for btf, pre, idx in points.items:
        h.update(f"{btf.name}:{btf.shape}:{pre.stats.mode}:{pre.stats.transform}".encode())
        for a in (np.asarray(idx, dtype=np.int64), pre.stats.mean, pre.stats.std):
            h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


def _partitions(ex: Executor, points: BTFPointSource, sources: list[Source],
                btfs: list[BTF], channel: int | None, batch_size: int,
                ) -> Callable[[int, int, int], Any]:  # fmt: skip
    """``(lo, hi, slot) → handle`` on a cluster: a load task per partition, described by sources,
    indices and statistics (each source and statistics sent once, as shared values)."""
    which = [next(b for b, o in enumerate(btfs) if o is btf) for btf, _, _ in points.items]
    src_h = [s if isinstance(s.spec, str) else ex.constant(s) for s in sources]
    pre_h = [ex.constant(pre) for _, pre, _ in points.items]

    def partition(lo: int, hi: int, slot: int) -> Any:
        items = [(src_h[which[j]], pre_h[j], points.items[j][2][a:b])
                 for j, a, b in points.item_ranges(lo, hi)]  # fmt: skip
        return ex.submit(load_partition, items, points.patch, channel, batch_size, place=slot)

    return partition


def _check_tau_fits(taus: dict[str, list[int]], patch: int, btf: BTF, colour_mode: bool
                    ) -> None:  # fmt: skip
    """τ_l can be at most the coefficients of a data point (p·p·L·V, ×3 in colour mode)."""
    sizes = [patch, patch, len(btf.lights), len(btf.views)] + ([3] if colour_mode else [])
    atoms = math.prod(sizes)
    for ch, t in ((ch, t) for ch, ts in taus.items() for t in ts):
        if t > atoms:
            raise BTFInputError(
                f"tau_train {ch} = {t} is more coefficients than a data point has "
                f"({'x'.join(map(str, sizes))} = {atoms:,}); give at most {atoms}"
            )


def train(
    btfs: Sequence[BTF | str | os.PathLike[str]],
    *,
    n_dictionaries: int = 8,
    tau_train: TauTrainSpec = (256, 32, 32),
    tau_validation: TauTrainSpec | None = None,
    patch: int = 10,
    sample: float = 0.1,
    max_iter: int = 10,
    tol: float = 1e-4,
    std_mode: StdMode = "shared",
    colour_mode: bool = False,
    init: str = "points",
    candidates: int | None = None,
    full_pass_every: int = FULL_PASS_EVERY,
    batch_size: int = 4,
    partition_size: int = PARTITION_POINTS,
    dtype: str = "float32",
    seed: int = 0,
    checkpoint_dir: str | None = None,
    stage: bool | None = None,
    stage_dir: str | None = None,
    progress: bool | None = None,
    preprocessing: Transform = "log_yuv",
    log_offset: LogOffset = "auto",
    crop: tuple[slice, slice] | None = None,
    client: Any = None,
    scheduler: str | None = None,
    workers: int | None = None,
) -> Model:
    """Learn a model from BTFs (paper §3.2): one ensemble per YUV channel, or one 5D ensemble.

    ``tau_train``: τ_l per channel; several levels (``[(64, 8, 8), (256, 32, 32)]`` or
    ``"64,8,8/256,32,32"``: the K dictionaries split evenly over them, each trained at its
    own) or ``"learn"`` (each dictionary's τ_l chosen from a grid by the error on a validation
    split): :mod:`sparsebtf.codec.levels`, :mod:`sparsebtf.learning.tau_levels`.
    ``tau_validation``: with ``"learn"``, the coding τ_t (one or several, same spellings) the
    validation error is measured at (default: the grid's levels).
    ``init``: the initial dictionaries, "points", "random" or "preclustered"
    (:mod:`sparsebtf.learning.init`).
    ``sample`` is the fraction of each BTF's data points used (paper: 10% of 18 BTFs).
    ``colour_mode`` trains one ensemble on 5D points (p, p, L, V, 3), the paper's Table 6.
    ``candidates`` and ``full_pass_every`` set the coding passes between full ones
    (:class:`~sparsebtf.learning.ensemble.DictionaryEnsemble`; ``candidates >= n_dictionaries``
    is the exhaustive trainer; None: all K when a full pass projects at most
    :data:`~sparsebtf.learning.ensemble.EXHAUSTIVE_MAX_ENTRIES` tensor entries, else 1); the
    final memberships always come from a full pass.
    With ``checkpoint_dir`` each channel resumes from its last completed iteration.
    ``stage`` preprocesses the sampled points once into a temporary file in ``stage_dir``
    (default: when they need at most :data:`~sparsebtf.points.sources.STAGE_LIMIT_BYTES` and
    half the free disk); otherwise every pass streams them from the BTFs.
    ``preprocessing="identity"`` skips log, YUV and standardisation: the ensembles learn raw
    linear R, G, B (in the channel slots Y, U, V) — the [MHU19] baseline of the paper's Table 2.
    Encoding with the model then uses the same (no) processing. ``log_offset`` is the rule for
    each BTF's ε in ln(x + ε) ("auto", "release" = 1e-5, or a number; see
    :func:`~sparsebtf.points.statistics.choose_log_offset`).

    ``btfs`` are BTF objects or sources (paths, ``synth:`` specs; ``crop`` = (rows, cols)
    applies to every one). ``client`` (a ``dask.distributed.Client``), ``scheduler`` (an
    address) or ``workers`` (a local cluster of that many processes) run the training passes
    on a Dask cluster (:mod:`sparsebtf.execution`; default: this process). The points are cut
    into tasks of ``partition_size`` points; the model does not depend on where they run.
    On a cluster the workers open the sources themselves (give paths on shared storage).
    """
    if not btfs:
        raise BTFInputError("training needs at least one BTF")
    # The ensemble's own parameter checks, before the statistics pass over every BTF.
    channels = ("YUV",) if colour_mode else CHANNELS
    taus, learn = parse_tau_train(tau_train, channels)
    several = learn or len(next(iter(taus.values()))) > 1
    coding = None if tau_validation is None else parse_tau_train(tau_validation, channels)[0]
    DictionaryEnsemble(
        n_dictionaries=n_dictionaries, tau=next(iter(taus.values())), learn_tau=learn,
        init=init, candidates=candidates,
        full_pass_every=full_pass_every, batch_size=batch_size, partition_size=partition_size,
        dtype=dtype,
    )._validate()  # fmt: skip
    if preprocessing not in TRANSFORMS:
        raise BTFInputError(f"preprocessing must be one of {TRANSFORMS}, got {preprocessing!r}")
    rule = resolve_log_offset(log_offset)
    t0 = time.perf_counter()
    if checkpoint_dir is not None:
        Path(checkpoint_dir).mkdir(parents=True, exist_ok=True)
    sources = [Source.of(b, crop) for b in btfs]
    opened = [s.open() for s in sources]
    _check_tau_fits(taus, patch, opened[0], colour_mode)
    points = training_points(opened, patch, sample, seed, std_mode, preprocessing, progress,
                             rule)
    dictionaries: dict[str, list[np.ndarray]] = {}
    training: dict[str, dict[str, Any]] = {}
    with (
        executor(client=client, scheduler=scheduler, workers=workers) as ex,
        # On a cluster the workers load the points; here only a few are read (seeds).
        channel_sources(points, channels, False if ex.distributed else stage, stage_dir,
                        batch_size, progress) as source,
    ):  # fmt: skip
        for c, ch in enumerate(channels):
            channel = None if colour_mode else c
            dictionaries[ch], training[ch] = _train_channel(
                ch,
                c,
                source(ch),
                taus[ch] if several else taus[ch][0],
                learn_tau=learn,
                validation_taus=None if coding is None else coding[ch],
                n_dictionaries=n_dictionaries,
                max_iter=max_iter,
                tol=tol,
                init=init,
                candidates=candidates,
                full_pass_every=full_pass_every,
                batch_size=batch_size,
                partition_size=partition_size,
                dtype=dtype,
                seed=seed,
                checkpoint_dir=checkpoint_dir,
                progress=progress,
                ex=ex,
                partition=_partitions(ex, points, sources, opened, channel, batch_size)
                if ex.distributed else None,
                data_key=_data_key(points, ch),
            )
    params = {
        "n_dictionaries": n_dictionaries,
        # the smallest level: coding below it is refused (encode's allow_below_training)
        "tau_train": {ch: min(ts) for ch, ts in taus.items()},
        "patch": patch,
        "sample": sample,
        "max_iter": max_iter,
        "tol": tol,
        "std_mode": std_mode,
        "colour_mode": colour_mode,
        "init": init,
        # what the passes used (the channels share their points, so one value)
        "candidates": max(t["candidates"] for t in training.values()),
        "full_pass_every": full_pass_every,
        "partition_size": partition_size,
        "seed": seed,
        "dtype": dtype,
    }
    if several:
        params["tau_train_levels"] = [{ch: ts[i] for ch, ts in taus.items()}
                                      for i in range(len(next(iter(taus.values()))))]
        params["tau_learn"] = learn
        if learn and coding is not None:
            params["tau_validation"] = coding
        params["tau_dictionaries"] = {ch: t["tau_dictionaries"] for ch, t in training.items()}
    if preprocessing != "log_yuv":
        params["preprocessing"] = preprocessing
    else:
        params["log_offset"] = rule
    provenance = {
        "library": f"sparsebtf {library_version()}",
        "materials": [b.name for b in opened],
        "material_attrs": [b.attrs for b in opened],
        "seconds": time.perf_counter() - t0,
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    return Model(dictionaries, patch, opened[0].lights, opened[0].views, params, provenance,
                 training)
