"""Train a model once (paper §3.2): one dictionary ensemble per YUV channel, or one 5D ensemble.

The training set is a seeded fraction of the data points of a few BTFs (§3.1,
:mod:`sparsebtf.points.sources`); each channel's ensemble is learned by
:class:`~sparsebtf.learning.ensemble.DictionaryEnsemble` (Eq. 2).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from .. import library_version
from ..data.btf import BTF
from ..errors import BTFInputError
from ..learning.ensemble import (
    CANDIDATES,
    FULL_PASS_EVERY,
    DictionaryEnsemble,
    PointSource,
)
from ..model import CHANNELS, Model, TauSpec, parse_tau
from ..points.preprocessing import TRANSFORMS, StdMode, Transform
from ..points.sources import channel_sources, training_points

__all__ = ["train"]


def _train_channel(
    ch: str,
    c: int,
    src: PointSource,
    tau: int,
    *,
    n_dictionaries: int,
    max_iter: int,
    tol: float,
    init: str,
    candidates: int,
    full_pass_every: int,
    batch_size: int,
    dtype: str,
    seed: int,
    checkpoint_dir: str | None,
    progress: bool | None,
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
        dtype=dtype,
        random_state=seed + c,
        checkpoint=None if checkpoint_dir is None else f"{checkpoint_dir}/train_{ch}.npz",
        progress=progress,
    )
    ens.fit(src, desc=f"train {ch}")
    return ens.dictionaries_, {
        "objective": [float(v) for v in ens.objective_],
        # which coding passes tried all K dictionaries; the last one always did
        "passes": list(ens.passes_),
        "membership_counts": [int(v) for v in ens.counts_],
        "n_iter": int(ens.n_iter_),
        "seconds": float(ens.fit_seconds_),
        "n_points": int(src.n_points),
    }


def train(
    btfs: Sequence[BTF],
    *,
    n_dictionaries: int = 8,
    tau_train: TauSpec = (256, 32, 32),
    patch: int = 10,
    sample: float = 0.1,
    max_iter: int = 10,
    tol: float = 1e-4,
    std_mode: StdMode = "shared",
    colour_mode: bool = False,
    init: str = "points",
    candidates: int = CANDIDATES,
    full_pass_every: int = FULL_PASS_EVERY,
    batch_size: int = 4,
    dtype: str = "float32",
    seed: int = 0,
    checkpoint_dir: str | None = None,
    stage: bool | None = None,
    stage_dir: str | None = None,
    progress: bool | None = None,
    preprocessing: Transform = "log_yuv",
) -> Model:
    """Learn a model from BTFs (paper §3.2): one ensemble per YUV channel, or one 5D ensemble.

    ``sample`` is the fraction of each BTF's data points used (paper: 10% of 18 BTFs).
    ``colour_mode`` trains one ensemble on 5D points (p, p, L, V, 3), the paper's Table 6.
    ``candidates`` and ``full_pass_every`` set the coding passes between full ones
    (:class:`~sparsebtf.learning.ensemble.DictionaryEnsemble`; ``candidates >= n_dictionaries``
    is the exhaustive trainer); the final memberships always come from a full pass.
    With ``checkpoint_dir`` each channel resumes from its last completed iteration.
    ``stage`` preprocesses the sampled points once into a temporary file in ``stage_dir``
    (default: when they need at most :data:`~sparsebtf.points.sources.STAGE_LIMIT_BYTES` and
    half the free disk); otherwise every pass streams them from the BTFs.
    ``preprocessing="identity"`` skips log, YUV and standardisation: the ensembles learn raw
    linear R, G, B (in the channel slots Y, U, V) — the [MHU19] baseline of the paper's Table 2.
    Encoding with the model then uses the same (no) processing.
    """
    if not btfs:
        raise BTFInputError("training needs at least one BTF")
    if candidates < 1:
        raise BTFInputError(f"candidates must be >= 1, got {candidates}")
    if full_pass_every < 0:
        raise BTFInputError(f"full_pass_every must be >= 0, got {full_pass_every}")
    if preprocessing not in TRANSFORMS:
        raise BTFInputError(f"preprocessing must be one of {TRANSFORMS}, got {preprocessing!r}")
    channels = ("YUV",) if colour_mode else CHANNELS
    taus = parse_tau(tau_train, channels)
    t0 = time.perf_counter()
    points = training_points(btfs, patch, sample, seed, std_mode, preprocessing, progress)
    dictionaries: dict[str, list[np.ndarray]] = {}
    training: dict[str, dict[str, Any]] = {}
    with channel_sources(points, channels, stage, stage_dir, batch_size, progress) as source:
        for c, ch in enumerate(channels):
            dictionaries[ch], training[ch] = _train_channel(
                ch,
                c,
                source(ch),
                taus[ch],
                n_dictionaries=n_dictionaries,
                max_iter=max_iter,
                tol=tol,
                init=init,
                candidates=candidates,
                full_pass_every=full_pass_every,
                batch_size=batch_size,
                dtype=dtype,
                seed=seed,
                checkpoint_dir=checkpoint_dir,
                progress=progress,
            )
    params = {
        "n_dictionaries": n_dictionaries,
        "tau_train": taus,
        "patch": patch,
        "sample": sample,
        "max_iter": max_iter,
        "tol": tol,
        "std_mode": std_mode,
        "colour_mode": colour_mode,
        "init": init,
        "candidates": min(candidates, n_dictionaries),
        "full_pass_every": full_pass_every,
        "seed": seed,
        "dtype": dtype,
    }
    if preprocessing != "log_yuv":
        params["preprocessing"] = preprocessing
    provenance = {
        "library": f"sparsebtf {library_version()}",
        "materials": [b.name for b in btfs],
        "material_attrs": [b.attrs for b in btfs],
        "seconds": time.perf_counter() - t0,
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    return Model(dictionaries, patch, btfs[0].lights, btfs[0].views, params, provenance, training)
