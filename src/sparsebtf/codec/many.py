"""Encode many BTFs in one run, at fixed τ or to a size, in process or on a Dask cluster.

>>> for coded in encode_many(["a.btf", "b.h5"], model, workers=4):    # doctest: +SKIP
...     save_coded(coded, f"out/{coded.name}.coded.h5")

Each BTF is checked before any work starts; on a cluster the data points of every BTF are
spread over the workers (:mod:`.jobs`), and each result equals a one-process encode of the
same BTF bit for bit.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from ..data.btf import BTF
from ..errors import BTFInputError
from ..learning.coding import DEFAULT_CANDIDATES
from ..model import CodedBTF, Model, TauSpec
from ..points.preprocessing import LogOffset, StdMode
from .encode import FixedTau
from .jobs import Source, run_plan
from .rate import RateTargets

__all__ = ["encode_many", "output_name"]

#: Suffixes dropped from an input's file name to name its coded file.
_SUFFIXES = (".h5", ".hdf5", ".btf", ".zip")


def encode_many(
    sources: Sequence[str | os.PathLike[str] | BTF],
    model: Model,
    *,
    tau: TauSpec | None = None,
    eps: float = 1e-5,
    target_bytes: int | None = None,
    target_ratio: float | None = None,
    per_material: bool = False,
    budget: str = "paper",
    weighting: str = "rgb",
    std_mode: StdMode | None = None,
    log_offset: LogOffset = "auto",
    batch_size: int = 4,
    dtype: str = "float32",
    allow_below_training: bool = False,
    crop: tuple[slice, slice] | None = None,
    progress: bool | None = None,
    client: Any = None,
    scheduler: str | None = None,
    workers: int | None = None,
    checkpoint_dir: str | os.PathLike[str] | None = None,
    candidates: int | None = DEFAULT_CANDIDATES,
    objective: str = "log",
) -> Iterator[CodedBTF]:
    """Encode every BTF of ``sources`` on ``model``; yield their coded BTFs in order.

    ``sources`` are paths or ``synth:`` specs (opened by whoever runs the task: on a cluster,
    every worker must see the files) or BTF objects. Sparsity: ``tau`` / ``eps`` (see
    :func:`~sparsebtf.codec.encode`, default τ = 885,64,64), or rate control to
    ``target_bytes`` / ``target_ratio`` per BTF, counted as ``budget`` says (see
    :func:`~sparsebtf.codec.encode_to_size`).
    ``crop`` = (rows, cols) applies to every source. ``client`` / ``scheduler`` / ``workers``
    choose the cluster (:func:`sparsebtf.execution.executor`; default: this process).
    Iterate to the end (or close the iterator) to release a cluster it started.
    ``checkpoint_dir`` saves each finished point range there and resumes from the ranges it
    already holds (:mod:`.checkpoint`; the coded BTFs are those of an uninterrupted run).
    ``candidates``: dictionaries projected exactly per point after screening; None: every
    dictionary (the paper's exhaustive rule; see :func:`~sparsebtf.codec.encode`).
    ``objective``: the error coded for, "log" (the paper's), "linear" or "display"
    (:mod:`sparsebtf.learning.objective`), at fixed τ and in rate control alike.
    """
    if not sources:
        raise BTFInputError("nothing to encode: give at least one BTF")
    if target_bytes is not None or target_ratio is not None:
        if tau is not None:
            raise BTFInputError("give a sparsity tau or a target size, not both")
        plan: FixedTau | RateTargets = RateTargets(
            target_bytes=target_bytes, target_ratio=target_ratio, per_material=per_material,
            budget=budget, weighting=weighting, dtype=dtype, candidates=candidates,
            objective=objective,
        ).check(model)  # fmt: skip
    else:
        taus = [tau if tau is not None else (885, 64, 64)]
        plan = FixedTau.for_model(model, taus, eps, dtype, allow_below_training, candidates,
                                  objective)
    for levels in run_plan(
        [Source.of(s, crop) for s in sources], model, plan, std_mode=std_mode,
        log_offset=log_offset,
        batch_size=batch_size, progress=progress, client=client, scheduler=scheduler,
        workers=workers, checkpoint_dir=checkpoint_dir,
    ):  # fmt: skip
        yield levels[0]


def output_name(source: str | os.PathLike[str]) -> str:
    """The coded file name of an input: ``stone.h5`` → ``stone.coded.h5``,
    ``synth:stone:40:1`` → ``synth_stone_40_1.coded.h5``."""
    s = str(source)
    if s.startswith("synth:"):
        stem = s.replace(":", "_")
    else:
        stem = Path(s).name
        for suffix in _SUFFIXES:
            if stem.lower().endswith(suffix):
                stem = stem[: -len(suffix)]
                break
    return f"{stem}.coded.h5"
