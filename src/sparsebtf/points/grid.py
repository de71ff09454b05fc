"""4D data points (paper §3.1): non-overlapping p×p spatial patches with all lights and views.

A data point of channel c is the tensor X[i1, i2, light, view] of shape (p, p, L, V): modes
(row-in-patch, col-in-patch, light, view). Patches are numbered as in the release
(``official-release-format.md`` §1)::

    point = row_block + n_row_blocks * col_block,   i1 = row % p,   i2 = col % p

:class:`PatchGrid` holds that geometry; :func:`iter_points` streams standardised log-YUV data
points of a BTF in batches (memory bounded by the batch); :func:`sample_points` draws a seeded
fraction of the data points of several BTFs (the paper trains on 10% of 18 BTFs).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from ..data.btf import BTF
from ..data.validate import check_finite
from ..errors import BTFInputError
from .preprocessing import Preprocessor

__all__ = [
    "MAX_PATCH",
    "RELEASE_PATCH",
    "PatchGrid",
    "assemble",
    "check_nested",
    "extract",
    "iter_points",
    "parse_patches",
    "sample_points",
    "stream_points",
]

#: The release's patch size p (10×10 texels; paper §3.1): the default everywhere.
RELEASE_PATCH = 10
#: The largest patch size any reader accepts (and training takes).
MAX_PATCH = 4096


def check_nested(sizes: Sequence[int], what: str | None = None) -> tuple[int, ...]:
    """Several patch sizes, largest first, checked to nest: each an integer in [1,
    :data:`MAX_PATCH`], no repeats, and each dividing the next larger one (a block of one
    size splits into (big / small)² blocks of the next: four for 20,10,5, the quadtree of
    adaptive patch sizes). One line names what is wrong."""
    given = list(sizes)
    what = what or f"patch sizes {given}"
    if not given or any(isinstance(p, bool) or not isinstance(p, (int, np.integer))
                        for p in given):  # fmt: skip
        raise BTFInputError(f"{what}: expected one or more integers such as 20,10,5")
    out = tuple(sorted((int(p) for p in given), reverse=True))
    if len(set(out)) != len(out) or out[-1] < 1 or out[0] > MAX_PATCH:
        raise BTFInputError(f"{what}: expected distinct integers in [1, {MAX_PATCH}]")
    for big, small in itertools.pairwise(out):
        if big % small:
            raise BTFInputError(
                f"{what}: sizes must nest, each dividing the next larger (a block "
                f"splits into smaller ones), but {small} does not divide {big}; e.g. 20,10,5"
            )
    return out


def parse_patches(value: object) -> tuple[int, ...]:
    """A patch size or several, largest first: an integer, a sequence of integers, or text
    ``"10"`` / ``"20,10,5"`` (several must nest, :func:`check_nested`, and be given largest
    first)."""
    what = f"patch sizes {value!r}"
    if isinstance(value, str):
        parts = [v.strip() for v in value.split(",")]
        if not all(v.isdigit() for v in parts):
            raise BTFInputError(f"{what}: expected integers such as 10 or 20,10,5")
        value = [int(v) for v in parts]
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        value = [int(value)]
    if not isinstance(value, Sequence):
        raise BTFInputError(f"{what}: expected integers such as 10 or 20,10,5")
    out = check_nested(value, what)
    if tuple(int(v) for v in value) != out:  # one order, as every listing shows them
        raise BTFInputError(f"{what}: give the sizes largest first, each dividing the next "
                            f"larger, such as {','.join(map(str, out))}")  # fmt: skip
    return out


@dataclass(frozen=True)
class PatchGrid:
    """Tiling of an H×W texture into p×p patches numbered ``rb + n_row_blocks * cb``."""

    height: int
    width: int
    patch: int = RELEASE_PATCH

    def __post_init__(self) -> None:
        if self.patch < 1:
            raise BTFInputError(f"patch size must be >= 1, got {self.patch}")
        if self.height % self.patch or self.width % self.patch:
            raise BTFInputError(
                f"spatial size {self.height}x{self.width} is not a multiple of the patch size "
                f"{self.patch}; crop it (e.g. --crop 0:{self.height - self.height % self.patch},"
                f"0:{self.width - self.width % self.patch}) or choose another patch size"
            )

    @classmethod
    def for_btf(cls, btf: BTF, patch: int = RELEASE_PATCH) -> PatchGrid:
        return cls(btf.height, btf.width, patch)

    @property
    def n_row_blocks(self) -> int:
        return self.height // self.patch

    @property
    def n_col_blocks(self) -> int:
        return self.width // self.patch

    @property
    def n_points(self) -> int:
        return self.n_row_blocks * self.n_col_blocks

    def index(self, row_block: np.ndarray | int, col_block: np.ndarray | int) -> np.ndarray:
        """Point number of patch (row_block, col_block)."""
        return np.asarray(row_block) + self.n_row_blocks * np.asarray(col_block)

    def blocks(self, point: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
        """(row_block, col_block) of a point number."""
        p = np.asarray(point)
        return p % self.n_row_blocks, p // self.n_row_blocks

    def origin(self, point: int) -> tuple[int, int]:
        """Top-left texel (row, col) of a point."""
        rb, cb = self.blocks(point)
        return int(rb) * self.patch, int(cb) * self.patch

    def locate(self, row: np.ndarray | int, col: np.ndarray | int) -> tuple[np.ndarray, ...]:
        """Texel (row, col) → (point, i1, i2); texture coordinates wrap (tiling)."""
        r = np.asarray(row) % self.height
        c = np.asarray(col) % self.width
        return self.index(r // self.patch, c // self.patch), r % self.patch, c % self.patch


def extract(block: np.ndarray, patch: int) -> np.ndarray:
    """Cut an (h, w, ...) array into (n, p, p, ...) patches in release order (row block fastest)."""
    h, w = block.shape[:2]
    grid = PatchGrid(h, w, patch)
    rest = block.shape[2:]
    x = block.reshape(grid.n_row_blocks, patch, grid.n_col_blocks, patch, *rest)
    # (rb, i1, cb, i2, ...) → (cb, rb, i1, i2, ...): flattening (cb, rb) gives rb + nrb·cb.
    x = np.moveaxis(x, 2, 0)
    return x.reshape(grid.n_points, patch, patch, *rest)


def assemble(points: np.ndarray, height: int, width: int) -> np.ndarray:
    """Inverse of :func:`extract`: (n, p, p, ...) patches → (height, width, ...)."""
    patch = points.shape[1]
    grid = PatchGrid(height, width, patch)
    if points.shape[0] != grid.n_points or points.shape[2] != patch:
        raise BTFInputError(
            f"{points.shape[0]} patches of {points.shape[1]}x{points.shape[2]} do not tile "
            f"{height}x{width}"
        )
    rest = points.shape[3:]
    x = points.reshape(grid.n_col_blocks, grid.n_row_blocks, patch, patch, *rest)
    x = np.moveaxis(x, 0, 2)  # (rb, i1, cb, i2, ...)
    return x.reshape(height, width, *rest)


def iter_points(
    btf: BTF,
    pre: Preprocessor,
    patch: int = RELEASE_PATCH,
    points: Sequence[int] | np.ndarray | None = None,
    batch: int = 4,
    dtype: type = np.float32,
    parallel: bool = False,
    reuse: int = 0,
    channels_first: bool = False,
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Stream standardised log-YUV data points of ``btf`` in batches.

    Yields ``(indices, X)`` with X of shape (b, p, p, L, V, 3), b <= ``batch``, or
    (3, b, p, p, L, V) with ``channels_first`` (each channel's batch one contiguous array, as
    the coding of a channel wants it; same values). Points are
    read one spatial patch at a time (a patch holds every direction), so memory stays at
    ``batch`` data points whatever the BTF size. NaN/Inf raise with their location; negative
    values are clamped to 0 (counted by :func:`~sparsebtf.points.statistics.gather_statistics`).
    ``parallel``: the points of a batch are read on the worker threads
    (:func:`~sparsebtf._threads.parallel_map`), unless the BTF's reads hold a lock of the
    process (:attr:`~sparsebtf.data.btf.BTF.serial_reads`): then on this thread, one after
    another, which leaves the workers to the caller's work instead of waiting for the lock
    (a third of a dense file's reading time was that wait); the values are the same.
    ``reuse = n``: the batches are written into ``n`` arrays in turn (batch k's array again
    holds batch k + n), sparing the fresh pages the kernel zeroes for every new array (tens
    of ms per UBO2014 data point); the caller must be done with a batch ``n`` batches later.
    """
    from .._threads import parallel_map

    grid = PatchGrid.for_btf(btf, patch)
    if (pre.stats.n_lights, pre.stats.n_views) != btf.shape[2:4]:
        raise BTFInputError(
            f"{btf.label}: statistics are for {pre.stats.n_lights}x{pre.stats.n_views} directions "
            f"but the BTF has {btf.shape[2]}x{btf.shape[3]}"
        )
    idx = np.arange(grid.n_points) if points is None else np.asarray(points, dtype=np.int64)
    if idx.size and (idx.min() < 0 or idx.max() >= grid.n_points):
        bad = int(idx[(idx < 0) | (idx >= grid.n_points)][0])
        raise BTFInputError(f"{btf.label}: data point {bad} is out of range [0, {grid.n_points})")
    if batch < 1:
        raise BTFInputError(f"batch must be >= 1, got {batch}")
    _, _, nl, nv, _ = btf.shape

    def shape(n: int) -> tuple[int, ...]:
        return (3, n, patch, patch, nl, nv) if channels_first else (n, patch, patch, nl, nv, 3)

    ring: list[np.ndarray] = []
    for k, start in enumerate(range(0, idx.size, batch)):
        chunk = idx[start : start + batch]
        if reuse and len(ring) < reuse:
            ring.append(np.empty(shape(batch), dtype=dtype))
        if reuse:
            full = ring[k % reuse]
            out = full[:, : chunk.size] if channels_first else full[: chunk.size]
        else:
            out = np.empty(shape(chunk.size), dtype=dtype)

        def fill(j: int, chunk: np.ndarray = chunk, out: np.ndarray = out) -> None:
            r0, c0 = grid.origin(int(chunk[j]))
            rgb = btf.patch(r0, c0, patch)
            dest = out[:, j] if channels_first else out[j]
            if out.dtype == np.float32:
                pre.forward_into(rgb, dest, btf.name, (r0, c0))
                return
            check_finite(rgb, btf.name, offset=(r0, c0))
            np.maximum(rgb, 0, out=rgb)
            y = pre.forward(rgb, dtype=dtype)
            dest[...] = np.moveaxis(y, -1, 0) if channels_first else y

        run = parallel_map if parallel and not btf.serial_reads else map
        for _ in run(fill, range(chunk.size)):
            pass
        yield chunk, out


def stream_points(
    btf: BTF,
    pre: Preprocessor,
    patch: int,
    points: Sequence[int] | np.ndarray,
    batch: int = 4,
    channels_first: bool = False,
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """:func:`iter_points` for a coding loop, keeping every core busy: each batch is read
    on the worker threads while the caller codes the one before (a background thread,
    :func:`~sparsebtf._threads.prefetch`), BLAS single-threaded throughout (both
    the reads and the caller's projections are one GEMM per thread). Memory: three batches
    (coded, ready, being read), three arrays written in turn: use a batch before asking for
    the one after next."""
    from .._threads import prefetch, single_threaded_blas

    # With prefetch one batch ahead, the reader fills batch k + 3 only after the caller has
    # asked for batch k + 2, so after it finished with batch k: three arrays suffice.
    with single_threaded_blas():
        yield from prefetch(
            iter_points(btf, pre, patch, points, batch, parallel=True, reuse=3,
                        channels_first=channels_first),
            depth=1,
        )


def sample_points(
    n_points: Sequence[int], fraction: float, seed: int = 0
) -> list[tuple[int, np.ndarray]]:
    """A seeded random fraction of the data points of several BTFs.

    Parameters
    ----------
    n_points : number of data points of each BTF.
    fraction : in (0, 1]; each BTF contributes max(1, round(fraction · n)) points.

    Returns
    -------
    One (btf index, sorted point indices) pair per BTF.
    """
    if not 0 < fraction <= 1:
        raise BTFInputError(f"sample fraction must be in (0, 1], got {fraction}")
    rng = np.random.default_rng(seed)
    out = []
    for b, n in enumerate(n_points):
        k = max(1, round(fraction * n))
        out.append((b, np.sort(rng.choice(n, size=k, replace=False))))
    return out
