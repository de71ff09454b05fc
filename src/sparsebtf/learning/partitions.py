"""A training iteration as tasks over fixed-size partitions of the training points.

The points are cut into partitions of a fixed number of points (:data:`PARTITION_POINTS`, not
a share per worker, so the model does not depend on how many workers there are). Each pass of
:class:`~sparsebtf.learning.ensemble.DictionaryEnsemble` is one task per partition on an
executor (:mod:`sparsebtf.execution`):

* coding (:func:`code_partition`): codes, membership and candidate ranking of every point of
  the partition, and its shares of Z⁽ᵇ⁾ and H⁽ᵃ⁾ (:func:`~.steps.code_step`);
* cross products (:func:`cross_partition`): its share of Z⁽ⁿ⁾ for a mode n (Eq. (3) of
  :mod:`.steps`), from the codes of its last coding task.

Within a partition the shares are summed point by point (the same bits however the partition
is cut into batches); over partitions they are summed in the fixed pairwise tree of
:meth:`~sparsebtf.execution.Executor.tree_sum` (in process: :class:`~sparsebtf.execution.
PairwiseSum`, the same pairing one value at a time). So a one-process run and a run on any
cluster give the same dictionaries, bit for bit.

In process a partition is a view of the source (a staged file: memory stays at one batch) and
the tasks run one after the other. On a cluster a partition is the result of a load task
(:func:`load_points`, from the partition's description: BTF sources, point indices,
statistics), held in its worker's memory across iterations; the codes stay beside it. A
partition or codes lost with a worker are recomputed by Dask from their task (lineage). The
client receives per point only membership, error and ranking, and per pass the summed Z's.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._threads import prefetch
from ..errors import BTFInputError
from ..execution import Executor, PairwiseSum
from .codes import SparseCodes
from .steps import BatchCoding, code_step, cross_products, pair_modes, sparse_cross_products

__all__ = [
    "PARTITION_POINTS",
    "ArraySource",
    "Coded",
    "RangeSource",
    "code_partition",
    "coding_pass",
    "cross_partition",
    "cross_pass",
    "load_points",
    "partition_bounds",
    "slice_codes",
]

#: Training points per partition (per task). Paper scale (10×10×151×151 float32 points, 9 MB
#: each): 73 MB per partition, 360 partitions per channel of 2880 points.
PARTITION_POINTS = 8


def partition_bounds(n_points: int, size: int) -> list[tuple[int, int]]:
    """``[lo, hi)`` of each partition of ``size`` points (the last one may be shorter)."""
    return [(lo, min(lo + size, n_points)) for lo in range(0, n_points, size)]


class ArraySource:
    """A :class:`~.ensemble.PointSource` over an in-memory (N, m_1, …, m_N) array."""

    def __init__(self, data: np.ndarray) -> None:
        if data.ndim < 2:
            raise BTFInputError(
                f"data points must be an (N, m_1, ..., m_N) array, got {data.shape}"
            )
        self.data = data

    @property
    def n_points(self) -> int:
        return int(self.data.shape[0])

    @property
    def mode_sizes(self) -> tuple[int, ...]:
        return tuple(int(s) for s in self.data.shape[1:])

    def batches(self, batch_size: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for s, e in partition_bounds(self.n_points, batch_size):
            yield np.arange(s, e), self.data[s:e]  # a view: no copy of the points

    def take(self, indices: np.ndarray) -> np.ndarray:
        return self.data[np.asarray(indices)]

    def part(self, lo: int, hi: int) -> ArraySource:
        return ArraySource(self.data[lo:hi])

    def __sizeof__(self) -> int:
        # Dask's scheduler sizes a value by sys.getsizeof: without the points it took a
        # 36 MB partition for a few bytes and moved it to whichever worker was less busy.
        return object.__sizeof__(self) + int(self.data.nbytes)


class RangeSource:
    """Points ``[lo, hi)`` of a point source, read through its ``take`` (a generic view)."""

    def __init__(self, source: Any, lo: int, hi: int) -> None:
        self.source, self.lo, self.hi = source, lo, hi

    @property
    def n_points(self) -> int:
        return self.hi - self.lo

    @property
    def mode_sizes(self) -> tuple[int, ...]:
        return tuple(self.source.mode_sizes)

    def batches(self, batch_size: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for s, e in partition_bounds(self.n_points, batch_size):
            yield np.arange(s, e), self.source.take(np.arange(self.lo + s, self.lo + e))

    def take(self, indices: np.ndarray) -> np.ndarray:
        return self.source.take(np.asarray(indices) + self.lo)


def part_of(source: Any, lo: int, hi: int) -> Any:
    """Points ``[lo, hi)`` of ``source`` as a point source (its own ``part`` if it has one)."""
    part = getattr(source, "part", None)
    return part(lo, hi) if part is not None else RangeSource(source, lo, hi)


def load_points(part: Any, batch_size: int) -> ArraySource:
    """Task: the points of a partition, read once into memory (float32, as staged)."""
    xs = [np.asarray(x, dtype=np.float32) for _, x in part.batches(batch_size)]
    return ArraySource(np.concatenate(xs))


def code_partition(
    part: Any,
    dictionaries: list[np.ndarray],
    tau: int,
    eps: float,
    dtype: type,
    candidates: np.ndarray | None,
    batch_size: int,
    tick: Any = None,
) -> BatchCoding:
    """Task: :func:`~.steps.code_step` over a partition, batch by batch; Z⁽ᵇ⁾, H⁽ᵃ⁾ summed
    point by point. ``candidates`` (P, c) are the partition's rows (None: all K)."""
    sums: BatchCoding | None = None
    parts = []
    for idx, xb in prefetch(part.batches(batch_size)):
        cand = None if candidates is None else candidates[idx]
        sums = code_step(xb, dictionaries, tau, eps, dtype, cand, sums)
        parts.append(BatchCoding(sums.codes, sums.ranking, None, None))
        if tick is not None:
            tick(len(idx))
    out = BatchCoding.combine(parts)
    assert sums is not None  # a partition is never empty
    out.z_last, out.pair = sums.z_last, sums.pair
    return out


def cross_partition(
    part: Any,
    codes: SparseCodes,
    dictionaries: list[np.ndarray],
    mode: int,
    dtype: type,
    update: str,
    batch_size: int,
    tick: Any = None,
) -> np.ndarray:
    """Task: the partition's share of Z⁽ⁿ'ᵏ⁾ (K, m_n, m_n), summed point by point."""
    step = sparse_cross_products if update == "codes" else cross_products
    z = None
    for idx, xb in prefetch(part.batches(batch_size)):
        z = step(xb, slice_codes(codes, idx), dictionaries, mode, dtype, z)
        if tick is not None:
            tick(len(idx))
    return z


def _codes_of(c: BatchCoding) -> SparseCodes:
    return c.codes


def _summary(c: BatchCoding) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return c.codes.membership, c.codes.errors, c.ranking


def _z_last_of(c: BatchCoding) -> np.ndarray:
    return c.z_last  # type: ignore[return-value]


def _pair_of(c: BatchCoding) -> np.ndarray:
    return c.pair  # type: ignore[return-value]


def _done(_: Any) -> None:
    return None


@dataclass(eq=False)
class Coded:
    """A coding pass as the client sees it.

    ``codes``: one handle per partition on its codes (kept where they were computed);
    ``membership``, ``errors`` (N,), ``ranking`` (N, c) padded with -1; ``z_last``, ``pair``:
    Z⁽ᵇ⁾ and H⁽ᵃ⁾ summed over every point.
    """

    codes: list[Any]
    membership: np.ndarray
    errors: np.ndarray
    ranking: np.ndarray
    z_last: np.ndarray | None
    pair: np.ndarray | None


def _rows(rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> tuple[np.ndarray, ...]:
    width = max(r[2].shape[1] for r in rows)
    ranking = np.concatenate([
        np.pad(r[2], ((0, 0), (0, width - r[2].shape[1])), constant_values=-1) for r in rows
    ])  # fmt: skip
    return np.concatenate([r[0] for r in rows]), np.concatenate([r[1] for r in rows]), ranking


def coding_pass(
    ex: Executor,
    parts: list[Any],
    bounds: list[tuple[int, int]],
    dictionaries: list[np.ndarray],
    tau: int,
    eps: float,
    dtype: type,
    ranking: np.ndarray | None,
    batch_size: int,
    desc: str,
    progress: bool | None,
) -> Coded:
    """Code every partition (all K, or each point's ``ranking`` row) and reduce."""
    d = ex.constant([u.copy() for u in dictionaries])  # later updates must not reach it
    weights = [hi - lo for lo, hi in bounds]
    tasks = (
        ex.submit(code_partition, p, d, tau, eps, dtype,
                  None if ranking is None else ranking[lo:hi], batch_size, ticks=True)
        for p, (lo, hi) in zip(parts, bounds, strict=True)
    )  # fmt: skip
    bar = {"weights": weights, "desc": desc, "unit": "pt", "progress": progress}
    has_pair = pair_modes([u.shape[1] for u in dictionaries])[1] is not None
    if not ex.distributed:
        z, h = PairwiseSum(), PairwiseSum()
        codes, rows = [], []
        for c in ex.results(tasks, **bar):  # each partition's H is dropped once summed
            codes.append(ex.constant(c.codes))
            rows.append(_summary(c))
            z.add(c.z_last)
            if has_pair:
                h.add(c.pair)
        return Coded(codes, *_rows(rows), z.total(), h.total() if has_pair else None)
    coded = list(tasks)
    codes = [ex.submit(_codes_of, c) for c in coded]
    rows_h = [ex.submit(_summary, c) for c in coded]
    sums = [ex.tree_sum([ex.submit(_z_last_of, c) for c in coded])]
    if has_pair:
        sums.append(ex.tree_sum([ex.submit(_pair_of, c) for c in coded]))
    del coded  # the codes stay on the workers; each H is dropped once summed
    rows = list(ex.results(rows_h, **bar))
    del rows_h
    total = ex.gather(sums)
    return Coded(codes, *_rows(rows), total[0], total[1] if has_pair else None)


def cross_pass(
    ex: Executor,
    parts: list[Any],
    bounds: list[tuple[int, int]],
    codes: list[Any],
    dictionaries: list[np.ndarray],
    mode: int,
    dtype: type,
    update: str,
    batch_size: int,
    desc: str,
    progress: bool | None,
) -> np.ndarray:
    """Z⁽ⁿ'ᵏ⁾ (K, m_n, m_n) summed over every partition, for the codes of the last pass."""
    d = ex.constant([u.copy() for u in dictionaries])
    tasks = (
        ex.submit(cross_partition, p, c, d, mode, dtype, update, batch_size, ticks=True)
        for p, c in zip(parts, codes, strict=True)
    )
    bar = {"weights": [hi - lo for lo, hi in bounds], "desc": desc, "unit": "pt",
           "progress": progress}  # fmt: skip
    if not ex.distributed:
        acc = PairwiseSum()
        for z in ex.results(tasks, **bar):
            acc.add(z)
        return acc.total()
    zs = list(tasks)
    total = ex.tree_sum(zs)
    # The bar follows the partitions' tasks; their Z's are summed on the workers.
    for _ in ex.results([ex.submit(_done, z) for z in zs], **bar):
        pass
    del zs
    return ex.gather([total])[0]


def slice_codes(codes: SparseCodes, idx: np.ndarray) -> SparseCodes:
    """Codes of a contiguous run of points (a batch)."""
    lo, hi = int(idx[0]), int(idx[-1]) + 1
    o = codes.offsets
    return SparseCodes(
        codes.mode_sizes,
        codes.membership[lo:hi],
        codes.counts[lo:hi],
        codes.values[o[lo] : o[hi]],
        codes.locations[o[lo] : o[hi]],
        codes.errors[lo:hi],
    )
