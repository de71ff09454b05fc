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
from ..execution import Execution
from ..learning.codes import RELEASE_TAU
from ..model import CodedBTF, Model, TauSpec
from .encode import FixedTau, encode_levels
from .jobs import run_plan
from .options import EncodeOptions, encode_settings
from .rate import RateTargets

__all__ = ["encode_many", "output_name"]

#: Suffixes dropped from an input's file name to name its coded file.
_SUFFIXES = (".h5", ".hdf5", ".btf", ".zip")


def encode_many(
    sources: Sequence[str | os.PathLike[str] | BTF],
    model: Model,
    *,
    tau: TauSpec | None = None,
    options: EncodeOptions | None = None,
    execution: Execution | None = None,
    **keywords: Any,
) -> Iterator[CodedBTF]:
    """Encode every BTF of ``sources`` on ``model``; an iterator of their coded BTFs in order.

    ``sources`` are paths or ``synth:`` specs (opened by whoever runs the task: on a cluster,
    every worker must see the files) or BTF objects. Sparsity: ``tau`` (see
    :func:`~sparsebtf.codec.encode`, default the release's 885,64,64), or rate control to the
    keywords ``target_bytes`` / ``target_ratio`` per BTF, counted as ``budget`` and
    ``per_material`` say (:func:`~sparsebtf.codec.encode_to_size`'s). How and where:
    ``options`` (:class:`~.options.EncodeOptions`; its ``crop`` = (rows, cols) applies to
    every source, its ``checkpoint_dir`` saves each finished point range there and resumes
    from the ranges it already holds: :mod:`.checkpoint`) and ``execution``
    (:class:`~sparsebtf.execution.Execution`; default: this process), or their fields as
    ``keywords``. The options and the target are checked now; the work starts with the
    iteration: iterate to the end (or close the iterator) to release a cluster it started.
    """
    plan: FixedTau | RateTargets | None = RateTargets.take(keywords)
    if plan is not None and tau is not None:
        raise BTFInputError("give a sparsity tau or a target size, not both")
    if plan is None:
        plan = FixedTau((RELEASE_TAU if tau is None else tau,))
        opts, where = encode_settings(options, execution, dict(keywords), kind="tau", many=True)
        if opts.highlights:  # each BTF's budget spent on its own (encode_levels)
            return (encode_levels(s, model, list(plan.taus), options=opts, execution=where)[0]
                    for s in sources)  # fmt: skip
    runs = run_plan(sources, model, plan, options, execution, many=True, **keywords)
    return (levels[0] for levels in runs)


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
