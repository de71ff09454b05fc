"""Encoding as tasks on an executor (:mod:`sparsebtf.execution`): the same steps in one
process and on a Dask cluster.

For every BTF: open it where the task runs (:class:`Source`) and read its header; gather its
statistics by view ranges (:func:`~sparsebtf.points.statistics.statistic_sums`) and
combine them here; code its data points by point ranges (starts on batch boundaries, so every
batch is the one a single pass reads: the codes are bit for bit those of a one-process run);
join the ranges in order. What is computed per range and how the ranges are joined is an
:class:`EncodingPlan` (fixed τ: :mod:`.encode`; rate control: :mod:`.rate`).

On a cluster the workers open the sources themselves: paths must name files on storage
every worker sees (``docs/distributed.md``); BTF objects are sent to the workers.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from ..data.btf import BTF
from ..data.directions import DirectionSet
from ..errors import BTFInputError, FileFormatError, SparseBTFError
from ..execution import Execution, Executor, worker_label
from ..model import Model
from ..points.grid import PatchGrid
from ..points.preprocessing import LogOffset, StdMode, resolve_log_offset
from ..points.statistics import (
    combine_statistics,
    gather_statistics,
    provisional_log_offset,
    sampled_log_offset,
    statistic_sums,
    warn_negatives,
)
from ..storage.coded_streams import binary16_statistics
from .checkpoint import MEASURED, EncodeCheckpoint, range_key, range_layout
from .options import EncodeOptions, encode_settings

__all__ = ["EncodingPlan", "Header", "Source", "run_plan"]

#: Longest point range of one task, in batches: bounds what a lost worker costs, and (the
#: range of every task when checkpointing, :mod:`.checkpoint`) what a stopped encode loses.
RANGE_BATCHES = 8


@dataclass(frozen=True)
class Source:
    """A BTF to encode: a path or ``synth:`` spec (opened where the task runs), or a BTF
    object (sent to the workers), cropped to ``crop`` = (rows, cols) if given."""

    spec: str | BTF
    crop: tuple[slice, slice] | None = None

    @classmethod
    def of(cls, source: str | os.PathLike[str] | BTF, crop: tuple[slice, slice] | None = None
           ) -> Source:  # fmt: skip
        """Paths become absolute here, so that workers in other folders find them."""
        if isinstance(source, BTF):
            return cls(source, crop)
        s = str(source)
        return cls(s if s.startswith("synth:") else str(Path(s).absolute()), crop)

    @property
    def label(self) -> str:
        return self.spec if isinstance(self.spec, str) else self.spec.name

    def open(self) -> BTF:
        """The BTF (paths: opened once per process; errors on a worker name the worker)."""
        if isinstance(self.spec, BTF):
            btf = self.spec
        else:
            try:
                btf = _open_path(self.spec, _stamp(self.spec))
            except (SparseBTFError, OSError) as e:
                where = worker_label()
                if where is None:
                    raise
                raise FileFormatError(
                    f"{where} cannot open {self.spec}: {e} (every worker must see the inputs: "
                    "shared storage, docs/distributed.md)"
                ) from None
        if self.crop is not None:
            from ..data.crop import CroppedBTF

            btf = CroppedBTF(btf, *self.crop)
        return btf


def _stamp(path: str) -> tuple[int, int] | None:
    """Size and modification time: a rewritten file is opened anew."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_size, st.st_mtime_ns


@functools.lru_cache(maxsize=8)
def _open_path(spec: str, stamp: tuple[int, int] | None) -> BTF:
    from ..open import open_btf

    return open_btf(spec)


@dataclass(frozen=True)
class Header:
    """What the client needs of a BTF without reading its values (a worker opened it)."""

    name: str
    height: int
    width: int
    lights: DirectionSet
    views: DirectionSet
    attrs: dict[str, Any] = field(default_factory=dict)
    source: str | None = None

    @classmethod
    def of(cls, btf: BTF) -> Header:
        return cls(btf.name, btf.height, btf.width, btf.lights, btf.views, dict(btf.attrs),
                   btf.source)  # fmt: skip

    @property
    def label(self) -> str:
        """How messages name the BTF: its file when it has one (:attr:`BTF.label`)."""
        return self.source or self.name

    @property
    def shape(self) -> tuple[int, int, int, int, int]:
        return (self.height, self.width, len(self.lights), len(self.views), 3)

    @property
    def n_values(self) -> int:
        return self.height * self.width * len(self.lights) * len(self.views) * 3


class EncodingPlan(Protocol):
    """What an encoding computes per point range and how it joins the ranges of one BTF.

    Made from the target alone (τ levels, byte targets) and bound to a model and the options
    by :meth:`bind`; a plan is pickled to the workers with each task: keep it small
    (parameters only: its fields fingerprint a checkpoint's ranges).
    """

    desc: str

    @property
    def kind(self) -> str:
        """The target, as a refusal names it: "tau", "size" or "ratio"."""
        ...

    def bind(self, model: Model, options: EncodeOptions) -> EncodingPlan:
        """This target with the options it uses, checked against ``model`` (one line)."""
        ...

    def prepare(self, header: Header, model: Model) -> Any:
        """Check one BTF before any work; what its tasks need beyond the model (small)."""
        ...

    def code_range(
        self, btf: BTF, model: Model, stats: Any, lo: int, hi: int, extra: Any, batch_size: int,
        tick: Callable[[int], object] | None = None,
    ) -> Any:  # fmt: skip
        """The work on data points ``[lo, hi)`` (``tick(n)`` after each batch of n points)."""
        ...

    def finish(
        self, header: Header, model: Model, stats: Any, parts: list[Any], extra: Any
    ) -> list[Any]:
        """The coded BTFs (one per level) from the range results, in point order."""
        ...


def _as_btf(x: Source | BTF) -> BTF:
    return x.open() if isinstance(x, Source) else x


def _header(x: Source | BTF) -> Header:
    return Header.of(_as_btf(x))


def _sums(x: Source | BTF, views: tuple[int, int], log_offset: float, sample: bool,
          tick: Any = None) -> Any:  # fmt: skip
    return statistic_sums(_as_btf(x), views, log_offset, tick, sample)


def _log_offset(x: Source | BTF, rule: LogOffset) -> float:
    return provisional_log_offset(_as_btf(x), rule)


def _range(
    plan: EncodingPlan, x: Source | BTF, model: Model, stats: Any, lo: int, hi: int, extra: Any,
    batch_size: int, tick: Any = None,
) -> Any:  # fmt: skip
    return plan.code_range(_as_btf(x), model, stats, lo, hi, extra, batch_size, tick)


def run_plan(
    btfs: Sequence[str | os.PathLike[str] | BTF],
    model: Model,
    plan: EncodingPlan,
    options: EncodeOptions | None = None,
    execution: Execution | None = None,
    /,
    *,
    many: bool = False,
    **keywords: Any,
) -> Iterator[list[Any]]:
    """The one encoder behind every public one: ``btfs`` (paths, ``synth:`` specs or BTF
    objects) coded on ``model`` to the target ``plan`` (fixed τ levels, :class:`~.encode.
    FixedTau`; rate targets, :class:`~.rate.RateTargets`), with ``options`` and ``keywords``
    (:func:`~.options.encode_settings`; ``many``: :func:`~.encode_many`'s keywords apply), on
    ``execution`` (:func:`sparsebtf.execution.executor`); yields each BTF's coded BTFs (one
    per level), in order, as each completes.

    Everything is checked when this is called, before the iterator starts: the options, the
    plan against the model (:meth:`EncodingPlan.bind`). Each BTF is then checked before any
    work. ``options.log_offset`` is the rule for each BTF's log offset
    (:func:`~sparsebtf.points.statistics.choose_log_offset`). With ``options.checkpoint_dir``
    every finished point range is saved there (:mod:`.checkpoint`: ranges of
    :data:`RANGE_BATCHES` batches, in process too) and the ranges already there are read back
    instead of coded: the results equal an uninterrupted run's. The caller removes the folder
    when done.
    """
    opts, where = encode_settings(options, execution, keywords, kind=plan.kind, many=many)
    if not btfs:
        raise BTFInputError("nothing to encode: give at least one BTF")
    if opts.highlights:  # encode_levels and encode_many spend each level's bytes themselves
        raise BTFInputError("option highlights: a fixed tau takes it (sparsebtf.encode, "
                            "encode_levels, encode_many with tau); rate control and adaptive "
                            "patch sizes do not")  # fmt: skip
    if opts.adaptive_patches and not getattr(plan, "adaptive", False):
        raise BTFInputError("option adaptive_patches: this encoder codes one patch size; "
                            "sparsebtf.encode or sparsebtf.codec.adaptive.encode_adaptive "
                            "take it")  # fmt: skip
    bound = plan.bind(model, opts)
    sources = [Source.of(b, opts.crop) for b in btfs]
    ck = None if opts.checkpoint_dir is None else EncodeCheckpoint(opts.checkpoint_dir)

    def runs() -> Iterator[list[Any]]:
        with where.executor() as ex:
            yield from _run(ex, sources, model, bound, opts, ck)

    return runs()


def _run(
    ex: Executor, sources: list[Source], model: Model, plan: EncodingPlan,
    options: EncodeOptions, ck: EncodeCheckpoint | None = None,
) -> Iterator[list[Any]]:  # fmt: skip
    mode = options.std_mode or model.std_mode
    batch_size, progress = options.batch_size, options.progress
    # In process the tasks share one opened BTF. On a cluster each worker opens a path
    # itself; a BTF object travels once, as a shared value, not with every task.
    opened = [
        ex.submit(Source.open, s) if not ex.distributed
        else s if isinstance(s.spec, str) else ex.constant(s)
        for s in sources
    ]  # fmt: skip
    headers: list[Header] = ex.gather([ex.submit(_header, o) for o in opened])
    n_points = []
    for h in headers:
        model.check_directions(h)  # type: ignore[arg-type]
        n_points.append(PatchGrid.for_btf(h, model.patch).n_points)  # type: ignore[arg-type]
    extras = [plan.prepare(h, model) for h in headers]
    at_most = RANGE_BATCHES * batch_size
    if ck is None:
        layout = [ex.chunks(n, batch_size, at_most=at_most, total=sum(n_points))
                  for n in n_points]  # fmt: skip
    else:  # the same ranges wherever they run, so that any run can resume them
        layout = [range_layout(n, at_most) for n in n_points]
        early = [range_key(h, model, plan, None, batch_size, r)
                 for h, r in zip(headers, layout, strict=True)]  # fmt: skip
        found = ck.scan(early, layout, skip=MEASURED)  # refused before the statistics pass
    stats = _statistics(ex, opened, headers, model, mode, options.log_offset, progress)
    done: list[set[tuple[int, int]]] = [set() for _ in headers]
    if ck is not None:
        keys = [range_key(h, model, plan, s, batch_size, r)
                for h, s, r in zip(headers, stats, layout, strict=True)]  # fmt: skip
        done = ck.check(found, keys)
    model_h = ex.constant(model)
    stats_h = [ex.constant(s) for s in stats]
    owner, weights, tasks = [], [], []
    for b, o in enumerate(opened):
        for lo, hi in layout[b]:
            owner.append(b)
            if (lo, hi) in done[b]:
                continue
            tasks.append(ex.submit(
                _range, plan, o, model_h, stats_h[b], lo, hi, extras[b], batch_size, ticks=True
            ))  # fmt: skip
            weights.append(hi - lo)
    what = headers[0].name if len(headers) == 1 else f"{len(headers)} BTFs"
    results = ex.results(
        tasks, weights=weights, desc=f"{plan.desc} {what}", unit="pt", progress=progress
    )
    del tasks  # each range's result is released once read

    def parts() -> Iterator[Any]:
        """Every range's result in order: read back from the checkpoint, or coded (and saved)."""
        for b in range(len(headers)):
            for lo, hi in layout[b]:
                if (lo, hi) in done[b]:
                    yield ck.read(b, lo, hi, keys[b])  # type: ignore[union-attr]
                    continue
                part = next(results)
                if ck is not None:
                    ck.save(b, lo, hi, keys[b], part)
                yield part

    for b, ordered in _by_owner(parts(), owner):
        yield plan.finish(headers[b], model, stats[b], ordered, extras[b])


def _by_owner(results: Iterator[Any], owner: list[int]) -> Iterator[tuple[int, list[Any]]]:
    """Group ordered task results into (input, its results) as soon as an input is complete."""
    parts: list[Any] = []
    for i, part in enumerate(results):
        parts.append(part)
        if i + 1 == len(owner) or owner[i + 1] != owner[i]:
            yield owner[i], parts
            parts = []


def _statistics(
    ex: Executor, opened: list[Any], headers: list[Header], model: Model, mode: StdMode,
    log_offset: LogOffset, progress: bool | None,
) -> list[Any]:  # fmt: skip
    """Each BTF's standardisation in the model's preprocessing, from view-range tasks (after
    one task per BTF that chooses its log offset, provisionally for "auto": the sums tasks
    then check it, :func:`~sparsebtf.points.statistics.statistics_with_offset`); log-YUV
    statistics rounded to binary16
    (:func:`~sparsebtf.storage.coded_streams.binary16_statistics`), the precision the coded
    file keeps."""
    if model.transform != "log_yuv":
        return [
            gather_statistics(h, mode, transform=model.transform)  # type: ignore[arg-type]
            for h in headers
        ]
    # The "auto" offset: sums on a provisional offset that also histogram the offset's
    # sample, read again only for a BTF whose sample gives another offset (statistics.py).
    auto = resolve_log_offset(log_offset) == "auto"
    offsets = ex.gather([ex.submit(_log_offset, o, log_offset) for o in opened])
    sums = _sum_tasks(ex, opened, headers, offsets, range(len(headers)), auto, progress,
                      "statistics")  # fmt: skip
    if auto:
        exact = [sampled_log_offset(p) for p in sums]
        again = [b for b, (x, o) in enumerate(zip(exact, offsets, strict=True)) if x != o]
        offsets = exact
        if again:
            redone = _sum_tasks(ex, opened, headers, offsets, again, False, progress,
                                "statistics (new log offset)")  # fmt: skip
            for b, parts in zip(again, redone, strict=True):
                sums[b] = parts
    out: list[Any] = []
    for b, parts in enumerate(sums):
        warn_negatives(headers[b].label, parts)
        # μ, σ as the coded file stores them (binary16), before any point is coded
        out.append(binary16_statistics(combine_statistics(parts, mode, offsets[b])))
    return out


def _sum_tasks(
    ex: Executor, opened: list[Any], headers: list[Header], offsets: list[float],
    which: Sequence[int], sample: bool, progress: bool | None, desc: str,
) -> list[list[Any]]:  # fmt: skip
    """The view-range :class:`~sparsebtf.points.statistics.StatisticSums` of the BTFs
    ``which``, one list per BTF in view order."""
    owner, weights, tasks = [], [], []
    views = sum(len(headers[b].views) for b in which)
    for b in which:
        for lo, hi in ex.chunks(len(headers[b].views), 1, per_worker=2, total=views):
            tasks.append(ex.submit(_sums, opened[b], (lo, hi), offsets[b], sample, ticks=True))
            owner.append(b)
            weights.append(hi - lo)
    results = ex.results(tasks, weights=weights, desc=desc, unit="view", progress=progress)
    del tasks
    return [parts for _, parts in _by_owner(results, owner)]
