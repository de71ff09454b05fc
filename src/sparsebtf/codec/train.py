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
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from .._version import library_version
from ..data.btf import BTF
from ..errors import BTFInputError
from ..execution import Execution, Executor
from ..learning.ensemble import DictionaryEnsemble, PointSource
from ..learning.partitions import load_points
from ..learning.tau_levels import VALIDATION, check_levels
from ..model import CHANNELS, Model
from ..points.grid import check_nested, parse_patches
from ..points.preprocessing import resolve_log_offset
from ..points.sources import BTFPointSource, channel_sources, training_points
from .jobs import Source
from .levels import parse_tau_train
from .options import TrainOptions, train_settings

__all__ = ["join_patch_sizes", "train"]


def _train_channel(
    ch: str, c: int, src: PointSource, tau: int | list[int], options: TrainOptions,
    ex: Executor, partition: Callable[[int, int, int], Any] | None, data_key: str, *,
    learn_tau: bool = False, validation_taus: list[int] | None = None,
) -> tuple[list[np.ndarray], dict[str, Any]]:  # fmt: skip
    """Fit one channel's ensemble; its dictionaries and training diagnostics."""
    o = options
    ens = DictionaryEnsemble(
        n_dictionaries=o.n_dictionaries,
        tau=tau,
        max_iter=o.max_iter,
        tol=o.tol,
        init=o.init,
        candidates=o.candidates,
        full_pass_every=o.full_pass_every,
        batch_size=o.batch_size,
        partition_size=o.partition_size,
        dtype=o.dtype,
        random_state=o.seed + c,
        checkpoint=None if o.checkpoint_dir is None else checkpoint_path(o.checkpoint_dir, ch),
        progress=o.progress,
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
        "candidate_rule": "given" if o.candidates is not None else "auto",
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
    options: TrainOptions | None = None,
    execution: Execution | None = None,
    **keywords: Any,
) -> Model:
    """Learn a model from BTFs (paper §3.2): one ensemble per YUV channel, or one 5D ensemble.

    ``options`` (:class:`~.options.TrainOptions`) say how: K = ``n_dictionaries``, ``tau_train``
    (τ_l per channel; several levels, ``[(64, 8, 8), (256, 32, 32)]`` or ``"64,8,8/256,32,32"``: the
    K dictionaries split evenly over them, each trained at its own; or ``"learn"``: each
    dictionary's τ_l chosen from a grid by the error on a validation split,
    :mod:`sparsebtf.codec.levels`, :mod:`sparsebtf.learning.tau_levels`), ``tau_validation`` (with
    ``"learn"``, the coding τ_t the validation error is measured at; default the grid's levels),
    ``init`` ("points", "random" or "preclustered", :mod:`sparsebtf.learning.init`), ``patch``,
    ``sample`` (the fraction of each BTF's data points used; paper: 10% of 18 BTFs), ``max_iter``,
    ``colour_mode`` (one ensemble on 5D points (p, p, L, V, 3), the paper's Table 6), ``candidates``
    / ``full_pass_every`` (the coding passes between full ones,
    :class:`~sparsebtf.learning.ensemble.DictionaryEnsemble`; the final memberships always come from
    a full pass), ``preprocessing="identity"`` (raw linear R, G, B in the channel slots Y, U, V, the
    [MHU19] baseline of Table 2; encoding with the model then uses the same), ``log_offset`` (the
    rule of each BTF's offset in ln(x + offset): "auto", "release" = 1e-5, or a number;
    :func:`~sparsebtf.points.statistics.choose_log_offset`) … With ``checkpoint_dir`` each channel
    resumes from its last completed iteration; ``stage`` preprocesses the sampled points once into a
    temporary file in ``stage_dir`` (default: when they need at most
    :data:`~sparsebtf.points.sources.STAGE_LIMIT_BYTES` and half the free disk), otherwise every
    pass streams them from the BTFs. ``keywords`` set the options' fields (``n_dictionaries=2``) and
    the execution's (``workers=4``).

    ``btfs`` is a list of BTF objects or sources (paths, ``synth:`` specs; ``crop`` = (rows,
    cols) applies to every one); one BTF or path alone is refused
    (:class:`~sparsebtf.errors.ArgumentTypeError`: give ``[path]``). ``execution``
    (:class:`~sparsebtf.execution.Execution`) runs the training passes in this process
    (default) or on a Dask cluster; the points are cut into tasks of ``partition_size``
    points, and the model does not depend on where they run. On a cluster the workers open
    the sources themselves (give paths on shared storage).
    """
    btfs = _check_inputs(btfs, options, execution)
    o, where = train_settings(options, execution, keywords)
    if not btfs:
        raise BTFInputError("training needs at least one BTF")
    sizes = parse_patches(o.patch)
    if len(sizes) == 1:
        return _train_one(btfs, replace(o, patch=sizes[0]), where)
    if o.colour_mode:
        raise BTFInputError("several patch sizes need the 4D Y, U, V ensembles; the colour "
                            "mode's 5D ensemble takes one --patch")  # fmt: skip
    # One ensemble per size, one after the other, each on its own sample of the same
    # materials (a size's points are cut from the same texels); checkpoints by size.
    models = []
    for p in sizes:
        ck = None if o.checkpoint_dir is None else os.path.join(o.checkpoint_dir, f"patch{p}")
        models.append(_train_one(btfs, replace(o, patch=p, checkpoint_dir=ck), where))
    return join_patch_sizes(models)


def _check_inputs(btfs: Any, options: Any, execution: Any) -> list[Any]:
    """:func:`train`'s arguments of the wrong type, refused in one line each (one BTF or
    path where a list belongs: say so, not iterate the path's characters); the list."""
    from ..constraints import wrong_type
    from ..open import check_btf_list
    if options is not None and not isinstance(options, TrainOptions):
        raise wrong_type("train", "options", "a TrainOptions or None", options)
    if execution is not None and not isinstance(execution, Execution):
        raise wrong_type("train", "execution", "an Execution or None", execution)
    what = "a list of BTFs, paths or synth: specs"
    if isinstance(btfs, BTF | str | os.PathLike):
        one = repr(btfs) if isinstance(btfs, str) else "btf"
        raise wrong_type("train", "btfs", what, btfs, f"for one, give [{one}]")
    return check_btf_list("train", "btfs", btfs, what)


def join_patch_sizes(models: Sequence[Model]) -> Model:
    """One model of several patch sizes from models of one size each, largest first, as
    :func:`train` with several sizes makes it (each size trained alone with the same options
    gives the same model: a size's ensemble does not depend on the others)."""
    first = models[0]
    sizes = check_nested([m.patch for m in models], "join_patch_sizes")
    if sizes != tuple(m.patch for m in models) or any(
            m.patches or m.channels != first.channels or not m.lights.equals(first.lights)
            or not m.views.equals(first.views) for m in models):  # fmt: skip
        raise BTFInputError("join_patch_sizes: give models of one patch size each, largest "
                            "first, with the same channels and directions")
    params = {**first.params, "patch": sizes[0], "patch_sizes": list(sizes)}
    # ``training`` is per channel (the largest size's); the other sizes' beside the provenance
    provenance = {**first.provenance,
                  "seconds": sum(m.provenance["seconds"] for m in models),
                  "training_by_patch": {str(m.patch): m.training for m in models[1:]}}
    return Model(first.dictionaries, sizes[0], first.lights, first.views, params, provenance,
                 first.training, patches={m.patch: m.dictionaries for m in models[1:]})


def _train_one(btfs: Sequence[BTF | str | os.PathLike[str]], o: TrainOptions,
               where: Execution) -> Model:  # fmt: skip
    """:func:`train` at one patch size ``o.patch``."""
    rule = resolve_log_offset(o.log_offset)
    channels = ("YUV",) if o.colour_mode else CHANNELS
    taus, learn = parse_tau_train(o.tau_train, channels)
    several = learn or len(next(iter(taus.values()))) > 1
    coding = (None if o.tau_validation is None
              else parse_tau_train(o.tau_validation, channels)[0])  # fmt: skip
    for levels in taus.values():  # before any pass: K a multiple of the levels' number
        check_levels(levels, o.n_dictionaries, learn, VALIDATION)
    t0 = time.perf_counter()
    if o.checkpoint_dir is not None:
        Path(o.checkpoint_dir).mkdir(parents=True, exist_ok=True)
    sources = [Source.of(b, o.crop) for b in btfs]
    opened = [s.open() for s in sources]
    _check_tau_fits(taus, o.patch, opened[0], o.colour_mode)
    points = training_points(opened, o.patch, o.sample, o.seed, o.std_mode, o.preprocessing,
                             o.progress, rule)  # fmt: skip
    dictionaries: dict[str, list[np.ndarray]] = {}
    training: dict[str, dict[str, Any]] = {}
    with (
        where.executor() as ex,
        # On a cluster the workers load the points; here only a few are read (seeds).
        channel_sources(points, channels, False if ex.distributed else o.stage, o.stage_dir,
                        o.batch_size, o.progress) as source,
    ):  # fmt: skip
        for c, ch in enumerate(channels):
            channel = None if o.colour_mode else c
            partition = (_partitions(ex, points, sources, opened, channel, o.batch_size)
                         if ex.distributed else None)  # fmt: skip
            dictionaries[ch], training[ch] = _train_channel(
                ch, c, source(ch), taus[ch] if several else taus[ch][0], o, ex, partition,
                _data_key(points, ch), learn_tau=learn,
                validation_taus=None if coding is None else coding[ch],
            )
    params = {
        "n_dictionaries": o.n_dictionaries,
        # the smallest level: coding below it is refused (encode's allow_below_training)
        "tau_train": {ch: min(ts) for ch, ts in taus.items()},
        "patch": o.patch,
        "sample": o.sample,
        "max_iter": o.max_iter,
        "tol": o.tol,
        "std_mode": o.std_mode,
        "colour_mode": o.colour_mode,
        "init": o.init,
        # what the passes used (the channels share their points, so one value)
        "candidates": max(t["candidates"] for t in training.values()),
        "full_pass_every": o.full_pass_every,
        "partition_size": o.partition_size,
        "seed": o.seed,
        "dtype": o.dtype,
    }
    if several:
        params["tau_train_levels"] = [{ch: ts[i] for ch, ts in taus.items()}
                                      for i in range(len(next(iter(taus.values()))))]
        params["tau_learn"] = learn
        if learn and coding is not None:
            params["tau_validation"] = coding
        params["tau_dictionaries"] = {ch: t["tau_dictionaries"] for ch, t in training.items()}
    if o.preprocessing != "log_yuv":
        params["preprocessing"] = o.preprocessing
    else:
        params["log_offset"] = rule
    provenance = {
        "library": f"sparsebtf {library_version()}",
        "materials": [b.name for b in opened],
        "material_attrs": [b.attrs for b in opened],
        "seconds": time.perf_counter() - t0,
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    return Model(dictionaries, o.patch, opened[0].lights, opened[0].views, params, provenance,
                 training)
