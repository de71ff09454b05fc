"""What the preprocessing measures of a BTF before coding (paper §3.1): μ and σ of every
angular image, the bound, the per-material log offset.

Statistics are gathered in one streaming pass over view blocks (:func:`gather_statistics`), or
by view ranges in separate tasks (:func:`statistic_sums`, :func:`combine_statistics`).

One read for the ``auto`` log offset too (:func:`statistics_with_offset`): the sums need the
offset, which needs a sample of the data, so the pass runs on a *provisional* offset (the
sample's first band of rows, :func:`provisional_log_offset`, a few percent of a read) and
histograms the offset's whole sample from the blocks it reads anyway (``sample=True``). When
the sample's offset (:func:`sampled_log_offset`) equals the provisional one — the median of a
material's first rows usually falls in the same 1/64-decade bin — the sums are final, bit for
bit those of reading the offset first; otherwise the sums are read again with it (the cost of
two passes, as before).

True black and high dynamic range. ln(x + 1e-5) turns an exact zero (a hard shadow, a masked
texel) into −11.5 among values near −2: standardisation and the sparse code then chase those
outliers, and the overshoot they cause comes back through exp() as values thousands of times
the material's maximum. Two defences, both recorded with the statistics:

* the **log offset** of ln(x + offset) is chosen per material (:func:`choose_log_offset`,
  ``"auto"``): :data:`LOG_OFFSET_FRACTION` of the median positive value, never below the
  release's 1e-5;
  values far below the offset lose their relative precision, which costs nothing in linear error;
  ``"release"`` keeps 1e-5;
* the **bound**: for every angular image the largest ln(x + offset) over its texels and R, G, B,
  rounded up to a multiple of 1/32. Every decoder clamps its log-RGB values to it
  (interpolated with the angular weights between sampled directions), so no decoded value
  exceeds the brightest value of its angular image by more than 3.2 %:
  :meth:`Standardization.clamp_log_rgb`.
"""

from __future__ import annotations

import itertools
import warnings
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._progress import bar
from ..colour import RGB_TO_YUV_F32
from ..data.btf import BTF
from ..data.validate import check_finite
from ..errors import BTFInputError
from .preprocessing import (
    MAX_LOG_OFFSET,
    RELEASE_LOG_OFFSET,
    TRANSFORMS,
    LogOffset,
    Standardization,
    StdMode,
    Transform,
    check_std_mode,
    resolve_log_offset,
    round_up_bound,
)

__all__ = [
    "LOG_OFFSET_FRACTION",
    "STATS_READ_BYTES",
    "StatisticSums",
    "choose_log_offset",
    "combine_statistics",
    "gather_statistics",
    "offset_of_median",
    "positive_median",
    "provisional_log_offset",
    "sampled_log_offset",
    "statistic_bands",
    "statistic_sums",
    "statistics_with_offset",
    "warn_negatives",
]

#: The per-material log offset: max(:data:`RELEASE_LOG_OFFSET`, this share of the median
#: positive value).
LOG_OFFSET_FRACTION = 0.01
#: Views read to choose the log offset (evenly spaced; all of them up to this many).
_OFFSET_VIEWS = 12
#: Log-spaced histogram of positive values for the median: 64 bins per decade, 1e-12 … 1e12.
_HIST_PER_DECADE, _HIST_LOW, _HIST_DECADES = 64, -12, 24
_N_BINS = _HIST_DECADES * _HIST_PER_DECADE
#: Texels per view block the median is taken over (a regular subsample of larger tiles).
_OFFSET_TEXELS = 10_000


@dataclass(frozen=True, eq=False)
class StatisticSums:
    """Sums over the texels of one BTF's log-YUV values, for the views ``[v0, v1)``.

    Each view's sums are independent of the others, so a BTF's statistics can be gathered
    by view ranges in separate tasks (or machines) and combined by
    :func:`combine_statistics` into exactly what one pass gives. Sums are shifted by the first
    texel (``shift``) to keep Σ(x − μ)² accurate in float32.

    Attributes
    ----------
    views : (v0, v1).
    shift, s1, s2 : (L, v1 − v0, 3) float64: the first texel, Σ(x − shift), Σ(x − shift)².
    top : (L, v1 − v0) float64: the largest ln(x + offset) over texels and R, G, B.
    n_texels : H·W.
    negatives : values clamped to 0.
    counts, seen : with ``sample=True``: the log-spaced histogram of the positive values of
        the ``auto`` log offset's sample (:func:`positive_median`) within these views, and
        the number of sampled values; otherwise None and 0.
    """

    views: tuple[int, int]
    shift: np.ndarray
    s1: np.ndarray
    s2: np.ndarray
    top: np.ndarray
    n_texels: int
    negatives: int
    counts: np.ndarray | None = None
    seen: int = 0


#: Bytes of BTF values one statistics read holds (a band of rows of a few views), per thread,
#: unless one row of the file's chunks is larger: the pass's memory does not grow with the
#: number of views.
STATS_READ_BYTES = 32 * 2**20


def statistic_bands(btf: BTF) -> tuple[int, int]:
    """(rows, views) of one read of the statistics pass: :attr:`BTF.block_hint` views
    (a file's chunk) and as many whole rows (a multiple of the hint's) as fit
    :data:`STATS_READ_BYTES`, at least the hint's. Fixed per BTF, so every view's sums are
    added in the same bands whatever the view ranges of the tasks."""
    h, w, nl, nv, _ = btf.shape
    hint_rows, hint_views = (max(1, int(x)) for x in btf.block_hint)
    views = min(hint_views, nv)
    rows = max(1, STATS_READ_BYTES // max(1, 12 * w * nl * views))
    rows = max(hint_rows, rows - rows % hint_rows) if rows >= hint_rows else hint_rows
    return min(rows, h), views


def statistic_sums(
    btf: BTF,
    views: tuple[int, int] | None = None,
    log_offset: float = RELEASE_LOG_OFFSET,
    tick: Callable[[int], object] | None = None,
    sample: bool = False,
) -> StatisticSums:
    """The :class:`StatisticSums` of ``btf`` over ``views`` (default: all); with ``sample``
    also the ``auto`` log offset's histogram of its sample views in the range, from the same
    reads (:attr:`StatisticSums.counts`).

    Read in bands of rows of a few views (:func:`statistic_bands`; memory: a band per
    thread), the groups of views on the worker threads (:func:`_each_group`), each value
    touched in three passes (:mod:`.kernels`); ``tick(n)`` after each group of n views.
    NaN/Inf abort with their count and first location."""
    h, w, nl, nv, _ = btf.shape
    v0, v1 = views if views is not None else (0, nv)
    if not 0 <= v0 < v1 <= nv:
        raise BTFInputError(f"{btf.label}: view range [{v0}, {v1}) is not inside [0, {nv})")
    n = h * w
    if n < 2:
        raise BTFInputError(f"{btf.label}: standardisation needs at least 2 texels, got {n}")
    rows, step = statistic_bands(btf)
    # groups aligned on the storage's view blocks (absolute indices), cut at [v0, v1)
    edges = sorted({v0, v1, *range(v0 - v0 % step + step, v1, step)})
    groups = list(itertools.pairwise(edges))
    s1 = np.zeros((nl, v1 - v0, 3))
    s2 = np.zeros((nl, v1 - v0, 3))
    shift = np.zeros((nl, v1 - v0, 3))
    top = np.zeros((nl, v1 - v0))
    negatives = 0
    where = _offset_sample(btf) if sample else None
    counts = np.zeros(_N_BINS, dtype=np.int64) if sample else None
    seen = 0

    for (a, b), (sh, g1, g2, gt, neg, gc, gs) in zip(
        groups, _each_group(btf, groups, rows, log_offset, where), strict=True
    ):
        shift[:, a - v0 : b - v0] = sh
        s1[:, a - v0 : b - v0] = g1
        s2[:, a - v0 : b - v0] = g2
        top[:, a - v0 : b - v0] = gt
        negatives += neg
        if counts is not None:
            counts += gc
            seen += gs
        if tick is not None:
            tick(b - a)
    return StatisticSums((v0, v1), shift, s1, s2, top, n, negatives, counts, seen)


def _each_group(
    btf: BTF, groups: list[tuple[int, int]], rows: int, offset: float,
    sample: tuple[np.ndarray, int] | None,
) -> Iterator[tuple[Any, ...]]:  # fmt: skip
    """Each view group's sums (:class:`_GroupAccumulator`), in order: the groups on the
    worker threads (:func:`~sparsebtf._threads.ordered_map`), or, for a BTF whose reads hold
    a lock of the process (:attr:`~sparsebtf.data.btf.BTF.serial_reads`), the bands read one
    after another on a thread of their own while this one adds up the band read before (two
    threads reading side by side waited for each other a fifth of the time). Same sums
    either way."""
    from .._threads import n_workers, ordered_map, prefetch

    def new(g: int) -> _GroupAccumulator:
        return _GroupAccumulator(btf, groups[g], offset, sample)

    if not btf.serial_reads or n_workers() == 1:

        def group_sums(g: int) -> tuple[Any, ...]:
            acc = new(g)
            for r0, block in _bands(btf, groups[g], rows):
                acc.add(r0, block)
            return acc.result()

        yield from ordered_map(group_sums, range(len(groups)))
        return
    bands = ((g, r0, block) for g in range(len(groups))
             for r0, block in _bands(btf, groups[g], rows))  # fmt: skip
    acc: _GroupAccumulator | None = None
    for g, r0, block in prefetch(bands, depth=1):
        if r0 == 0:
            if acc is not None:
                yield acc.result()
            acc = new(g)
        acc.add(r0, block)  # type: ignore[union-attr]
    if acc is not None:
        yield acc.result()


def _bands(btf: BTF, views: tuple[int, int], rows: int) -> Iterator[tuple[int, np.ndarray]]:
    """(first row, linear RGB (rows, W, L, b − a, 3)) of views ``[a, b)``, ``rows`` rows at a
    time from the top."""
    h = btf.shape[0]
    for r0 in range(0, h, rows):
        yield r0, btf.read(slice(r0, min(r0 + rows, h)), slice(None), slice(None),
                           slice(*views))  # fmt: skip


class _GroupAccumulator:
    """Shift, Σd, Σd², top and the negative count of views ``[a, b)`` from their bands of
    rows, added in row order (each view's sums in band order); with ``sample`` = (views,
    step) of :func:`_offset_sample`, also the histogram of those views' subsampled values
    in the range and their number (else None, 0)."""

    def __init__(self, btf: BTF, views: tuple[int, int], offset: float,
                 sample: tuple[np.ndarray, int] | None) -> None:  # fmt: skip
        self.label, self.offset, self.sample = btf.label, offset, sample
        self.nl = btf.shape[2]
        self.a, b = views
        self.nvg = b - self.a
        n = self.nl * self.nvg
        self.shift = np.zeros((n, 3), dtype=np.float32)
        self.s1 = np.zeros((n, 3))
        self.s2 = np.zeros((n, 3))
        self.top = np.full(n, -np.inf)
        self.negatives = 0
        self.mine = [] if sample is None else [int(v) for v in sample[0] if self.a <= v < b]
        self.counts = None if sample is None else np.zeros(_N_BINS, dtype=np.int64)
        self.seen = 0

    def add(self, r0: int, block: np.ndarray) -> None:
        """The band of rows from ``r0``: (rows, W, L, b − a, 3) linear RGB."""
        from .kernels import accumulate_sums, log_offset

        a = self.a
        if self.mine:  # the offset's sample rows (multiples of its step) and columns here
            step = self.sample[1]  # type: ignore[index]
            for v in self.mine:
                sub = block[(-r0) % step :: step, ::step, :, v - a]
                if sub.size:
                    self.counts += _histogram(sub)  # type: ignore[operator]
                    self.seen += sub.size
        # float32 transforms (the release computed its statistics in single precision),
        # float64 accumulators.
        logs, bad, neg = log_offset(block, self.offset)
        if bad:
            check_finite(block, self.label, offset=(r0, 0, 0, a))
        self.negatives += neg
        accumulate_sums(logs.reshape(-1, self.nl * self.nvg, 3), RGB_TO_YUV_F32, self.shift,
                        self.s1, self.s2, self.top, first=r0 == 0)  # fmt: skip

    def result(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int,
                              np.ndarray | None, int]:  # fmt: skip
        nl, nvg = self.nl, self.nvg
        return (
            self.shift.reshape(nl, nvg, 3).astype(np.float64),
            self.s1.reshape(nl, nvg, 3),
            self.s2.reshape(nl, nvg, 3),
            self.top.reshape(nl, nvg),
            self.negatives,
            self.counts,
            self.seen,
        )


def combine_statistics(
    parts: Sequence[StatisticSums], mode: StdMode = "shared",
    log_offset: float = RELEASE_LOG_OFFSET,
) -> Standardization:
    """The :class:`Standardization` from :class:`StatisticSums` of consecutive view ranges
    covering every view (bit for bit the same whatever the ranges)."""
    check_std_mode(mode)
    if not parts or parts[0].views[0] != 0 or any(
        a.views[1] != b.views[0] for a, b in itertools.pairwise(parts)
    ):
        raise BTFInputError("statistic sums must cover consecutive view ranges from view 0")
    n = parts[0].n_texels
    shift, s1, s2, top = (np.concatenate([getattr(p, a) for p in parts], axis=1)
                          for a in ("shift", "s1", "s2", "top"))  # fmt: skip
    # With y = x − K: Σ(x − μ)² = Σy² + 2(K − μ)Σy + n(K − μ)².
    if mode == "shared":
        mean = (shift + s1 / n).mean(axis=2, keepdims=True)
        # per channel, about the shared μ (release convention)
        d = shift - mean
        ss = s2 + 2 * d * s1 + n * d**2
        std = np.sqrt(np.maximum(ss, 0) / (n - 1)).mean(axis=2, keepdims=True)
    else:
        mean = shift + s1 / n
        std = np.sqrt(np.maximum(s2 - s1**2 / n, 0) / (n - 1))
    std = np.where(std > 0, std, 1.0)
    return Standardization(mode=mode, mean=mean, std=std, log_offset=log_offset,
                           bound=round_up_bound(top))


def choose_log_offset(btf: BTF, rule: LogOffset = "auto") -> float:
    """The log offset of ``btf``: a number as given, 1e-5 for "release", and for "auto"
    max(1e-5, :data:`LOG_OFFSET_FRACTION` × the median positive value).

    The median comes from a log-spaced histogram (64 bins per decade) of up to
    :data:`_OFFSET_VIEWS` evenly spaced view blocks, on a regular subsample of about
    :data:`_OFFSET_TEXELS` texels of each (every texel of a tile up to 100×100), so it costs a
    few view reads and memory of one block. A material with a stray-light floor far above 1 %
    of its median keeps values in the same order; one with exact zeros gets a floor that the
    zeros no longer dominate.
    """
    rule = resolve_log_offset(rule)
    if rule == "release":
        return RELEASE_LOG_OFFSET
    if not isinstance(rule, str):
        return float(rule)
    return offset_of_median(positive_median(btf)[0])


def provisional_log_offset(btf: BTF, rule: LogOffset = "auto") -> float:
    """:func:`choose_log_offset`, for "auto" on the sample's rows within the first band of
    :func:`statistic_bands` only (all of it when one band holds every row): the offset a
    statistics pass with ``sample=True`` starts from, checked against
    :func:`sampled_log_offset` when it ends."""
    rule = resolve_log_offset(rule)
    if rule != "auto":
        return choose_log_offset(btf, rule)
    return offset_of_median(positive_median(btf, rows=statistic_bands(btf)[0])[0])


def sampled_log_offset(parts: Sequence[StatisticSums]) -> float:
    """The "auto" log offset from the histograms of :func:`statistic_sums` with
    ``sample=True`` over every view: the same as :func:`choose_log_offset`'s."""
    if any(p.counts is None for p in parts):
        raise BTFInputError("statistic sums without the log offset's sample (sample=True)")
    counts = np.sum([p.counts for p in parts], axis=0)
    return offset_of_median(_median(counts, sum(p.seen for p in parts))[0])


def offset_of_median(median: float | None) -> float:
    """The "auto" rule's offset for a median positive value (None: no positive value)."""
    if median is None:
        return RELEASE_LOG_OFFSET
    # Round to 3 significant digits: the offset is a recorded parameter, not a measurement.
    offset = max(RELEASE_LOG_OFFSET, min(LOG_OFFSET_FRACTION * median, MAX_LOG_OFFSET))
    return float(f"{offset:.3g}")



def _offset_sample(btf: BTF) -> tuple[np.ndarray, int]:
    """(views, step) of the "auto" offset's sample: up to :data:`_OFFSET_VIEWS` evenly spaced
    views, rows and columns that are multiples of ``step``."""
    h, w, _, nv, _ = btf.shape
    views = np.unique(np.linspace(0, nv - 1, min(nv, _OFFSET_VIEWS)).round().astype(int))
    return views, max(1, int(np.sqrt(h * w / _OFFSET_TEXELS)))


def _histogram(block: np.ndarray) -> np.ndarray:
    """Counts of the positive values of ``block`` in the log-spaced bins (order-free: any
    split of the sample sums to the same counts): bin = ⌊64·(log10 x + 12)⌋, no search over
    the edges (:func:`~.kernels.log_histogram`)."""
    from .kernels import log_histogram

    counts = np.zeros(_N_BINS, dtype=np.int64)
    log_histogram(block, _HIST_LOW, _HIST_PER_DECADE, counts)
    return counts


def _median(counts: np.ndarray, seen: int) -> tuple[float | None, float]:
    """(the median bin's geometric centre, share of values <= 0) of a histogram of ``seen``
    values; None when none is positive."""
    total = int(counts.sum())
    zeros = 1.0 - total / seen if seen else 0.0
    if total == 0:
        return None, zeros
    k = int(np.searchsorted(np.cumsum(counts), (total + 1) // 2))
    return float(10.0 ** (_HIST_LOW + (k + 0.5) / _HIST_PER_DECADE)), zeros  # bin centre


def positive_median(btf: BTF, rows: int | None = None) -> tuple[float | None, float]:
    """(median of the positive values, share of values <= 0) of ``btf``, on the sample the
    ``auto`` log offset uses (:func:`choose_log_offset`): up to :data:`_OFFSET_VIEWS` evenly
    spaced view blocks, a regular subsample of about :data:`_OFFSET_TEXELS` texels of each;
    the median is its log-spaced histogram bin's geometric centre (64 bins per decade), None
    when no value is positive. ``rows``: the sample's rows below this one only. NaN/Inf abort
    with their count and a location."""
    from .._threads import ordered_map

    h = btf.shape[0]
    views, step = _offset_sample(btf)
    sub = slice(None, None, step)

    def view_counts(v: int) -> tuple[int, np.ndarray]:
        block = btf.read(slice(0, min(h, rows or h), step), sub, slice(None), [int(v)])
        bad = ~np.isfinite(block)
        if bad.any():  # located in the whole BTF: rows and cols of the subsample × step
            r, c, li, _, ch = (int(i[0]) for i in np.nonzero(bad))
            raise BTFInputError(
                f"{btf.label}: {int(bad.sum())} NaN/Inf values; first at row {r * step}, "
                f"col {c * step}, "
                f"light {li}, view {int(v)}, channel {ch}"
            )
        return block.size, _histogram(block)

    # the views on the worker threads (the first failure in view order is raised); counts
    # are integers, so their sum does not depend on the order
    counts = np.zeros(_N_BINS, dtype=np.int64)
    seen = 0
    for size, c in ordered_map(view_counts, [int(v) for v in views]):
        seen += size
        counts += c
    return _median(counts, seen)


def warn_negatives(name: str, parts: Sequence[StatisticSums]) -> None:
    """One warning with the total count of negative values clamped to 0, if any."""
    negatives = sum(p.negatives for p in parts)
    if negatives:
        warnings.warn(f"{name}: clamped {negatives} negative values to 0", stacklevel=3)


def gather_statistics(
    btf: BTF,
    mode: StdMode = "shared",
    log_offset: float = RELEASE_LOG_OFFSET,
    progress: bool | None = None,
    transform: Transform = "log_yuv",
) -> Standardization:
    """μ and σ of every angular image of ``btf`` in log-YUV, in one pass over view blocks.

    Memory is one view block (H·W·L·3 values). NaN/Inf abort with their count and first
    location; negative values are clamped to 0 with one warning giving the total count.
    ``transform="identity"`` reads nothing and returns μ = 0, σ = 1 (no processing at all).
    The pass is :func:`statistic_sums` + :func:`combine_statistics`.
    """
    check_std_mode(mode)
    if transform not in TRANSFORMS:
        raise BTFInputError(
            f"preprocessing transform must be one of {TRANSFORMS}, got {transform!r}"
        )
    _, _, nl, nv, _ = btf.shape
    if transform == "identity":
        c = 1 if mode == "shared" else 3
        return Standardization(
            mode=mode, mean=np.zeros((nl, nv, c)), std=np.ones((nl, nv, c)),
            log_offset=log_offset,
            transform="identity",
        )
    with bar(nv, "statistics", "view", progress) as pb:
        sums = statistic_sums(btf, log_offset=log_offset, tick=pb.update)
    warn_negatives(btf.label, [sums])
    return combine_statistics([sums], mode, log_offset)


def statistics_with_offset(
    btf: BTF,
    mode: StdMode = "shared",
    rule: LogOffset = "auto",
    progress: bool | None = None,
) -> Standardization:
    """:func:`gather_statistics` at :func:`choose_log_offset`'s offset (log-YUV), the data read
    once when the provisional offset holds (module docstring): the same values as choosing the
    offset first."""
    offset = provisional_log_offset(btf, rule)
    auto = resolve_log_offset(rule) == "auto"
    with bar(btf.shape[3], "statistics", "view", progress) as pb:
        sums = statistic_sums(btf, log_offset=offset, tick=pb.update, sample=auto)
    if auto and (exact := sampled_log_offset([sums])) != offset:
        offset = exact
        with bar(btf.shape[3], "statistics (new log offset)", "view", progress) as pb:
            sums = statistic_sums(btf, log_offset=offset, tick=pb.update)
    warn_negatives(btf.label, [sums])
    return combine_statistics([sums], mode, offset)
