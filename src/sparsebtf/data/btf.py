"""The BTF type: linear RGB reflectance B[row, col, light, view, channel].

A BTF is a 7D function B(x, ω_i, ω_o, λ) (paper §3.1); sampled, it is a 5D array of shape
(H, W, L, V, 3) with a light and a view :class:`~sparsebtf.data.directions.DirectionSet`.
Every backend answers the same accessors, and reads only what is asked for, so a
400×400×151×151 BTF (44 GB in float32) is used without ever being whole in memory:

* :class:`ArrayBTF` — an in-memory (or memory-mapped) array.
* :class:`FunctionBTF` — lazy, generator-backed: a callable renders one view block on demand.
* :class:`FactorBTF` — lazy low-rank factors (spatial × angular per channel), the way UBO2014
  files store their data; any region or angular image is reconstructed on demand.
* :class:`~sparsebtf.data.dense_file.DenseFileBTF` — our chunked HDF5 file.
"""

from __future__ import annotations

import abc
import threading
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from .._limits import check_allocation, format_bytes, memory_budget
from .._threads import thread_buffer
from ..errors import BTFInputError
from .directions import DirectionSet

#: The log offset of BTF dynamic-range reduction: UBO2014 stores ln(x + 1e-5), and §3.1 codes
#: ln(x + 1e-5) (release: ``DataBTF4D.inl``, the shader's exp(·) − 1e-5). Defined once here.
RELEASE_LOG_OFFSET = 1e-5

__all__ = ["BTF", "RELEASE_LOG_OFFSET", "ArrayBTF", "FactorBTF", "FunctionBTF", "as_index",
           "contiguous_slice"]

Index = slice | np.ndarray | list[int]


def as_index(idx: Index | int, n: int, field: str) -> np.ndarray:
    """Normalise a slice / int / sequence into a validated int64 index array into ``range(n)``."""
    if isinstance(idx, slice):
        return np.arange(n)[idx]
    arr = np.atleast_1d(np.asarray(idx))
    if arr.dtype.kind not in "iu":
        raise BTFInputError(f"{field} index must be integers, got dtype {arr.dtype}")
    arr = arr.astype(np.int64).ravel()
    bad = (arr < 0) | (arr >= n)
    if np.any(bad):
        raise BTFInputError(f"{field} index {int(arr[bad][0])} is out of range [0, {n})")
    return arr


def contiguous_slice(idx: np.ndarray) -> slice | None:
    """The slice equal to ``idx`` when it is a contiguous ascending run, else None."""
    if idx.size and np.all(np.diff(idx) == 1):
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return None


class BTF(abc.ABC):
    """Abstract sampled BTF, linear RGB, indexed (row, col, light, view, channel).

    Subclasses implement :meth:`read`; all accessors are built on it.

    Attributes
    ----------
    lights, views : DirectionSet of the sampled light (ω_i) and view (ω_o) directions.
    name : a label for tables and file names.
    attrs : free-form provenance (material class, seed, source file...).
    source : the file it was read from (:func:`sparsebtf.open.open_btf` sets it), or None.
    """

    lights: DirectionSet
    views: DirectionSet
    name: str
    attrs: dict[str, Any]
    #: (rows, views) a scan should read at once to follow the storage (a file's chunks).
    block_hint: tuple[int, int] = (1, 1)
    #: Whether reads hold a lock of the process (h5py's, around every HDF5 call): threads
    #: reading side by side then wait for each other, so a coding loop reads on one thread.
    serial_reads: bool = False
    source: str | None = None

    @property
    def label(self) -> str:
        """How messages name this BTF: its file when it has one, else its name."""
        return self.source or self.name

    def __init__(
        self,
        height: int,
        width: int,
        lights: DirectionSet,
        views: DirectionSet,
        name: str = "btf",
        attrs: dict[str, Any] | None = None,
    ) -> None:
        if not isinstance(lights, DirectionSet) or not isinstance(views, DirectionSet):
            raise BTFInputError("lights and views must be DirectionSet objects")
        if height < 1 or width < 1:
            raise BTFInputError(f"spatial size must be positive, got {height}x{width}")
        self._hw = (int(height), int(width))
        self.lights = lights
        self.views = views
        self.name = name
        self.attrs = dict(attrs or {})

    # -- geometry -------------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int, int, int, int]:
        """(H, W, L, V, 3)."""
        return (*self._hw, len(self.lights), len(self.views), 3)

    @property
    def height(self) -> int:
        return self._hw[0]

    @property
    def width(self) -> int:
        return self._hw[1]

    @property
    def n_values(self) -> int:
        """H·W·L·V·3, the number of stored values of the raw BTF."""
        return int(np.prod(self.shape, dtype=np.int64))

    def __repr__(self) -> str:
        h, w, l, v, _ = self.shape
        return f"{type(self).__name__}(name={self.name!r}, {h}x{w} texels, {l} lights x {v} views)"

    def indices(
        self, rows: Index, cols: Index, lights: Index, views: Index
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Validated int64 index arrays of a read request (errors name the axis)."""
        h, w, nl, nv, _ = self.shape
        out = (
            as_index(rows, h, "row"),
            as_index(cols, w, "col"),
            as_index(lights, nl, "light"),
            as_index(views, nv, "view"),
        )
        # Every read's float32 result must fit the memory budget (sizes may come from a file).
        n = int(np.prod([ix.size for ix in out], dtype=np.int64))
        check_allocation(12 * n, f"{self.label}: reading {'x'.join(str(ix.size) for ix in out)}x3"
                         " values at once", BTFInputError)  # fmt: skip
        return out

    # -- access ----------------------------------------------------------------------------
    @abc.abstractmethod
    def read(self, rows: Index, cols: Index, lights: Index, views: Index) -> np.ndarray:
        """Values at the outer product of the given indices: (h, w, l, v, 3) float32."""

    def angular_image(self, light: int, view: int) -> np.ndarray:
        """One angular image (fixed light and view): (H, W, 3)."""
        return self.read(slice(None), slice(None), [light], [view])[:, :, 0, 0, :]

    def view_block(self, view: int) -> np.ndarray:
        """All lights at one view: (H, W, L, 3). The natural streaming unit of measured data."""
        return self.read(slice(None), slice(None), slice(None), [view])[:, :, :, 0, :]

    def region(self, rows: slice, cols: slice) -> np.ndarray:
        """A spatial region with all directions: (h, w, L, V, 3)."""
        return self.read(rows, cols, slice(None), slice(None))

    def patch(self, row0: int, col0: int, size: int) -> np.ndarray:
        """Patch [row0:row0+size, col0:col0+size] with all directions: (p, p, L, V, 3)."""
        if row0 < 0 or col0 < 0 or row0 + size > self.height or col0 + size > self.width:
            raise BTFInputError(
                f"patch at ({row0}, {col0}) of size {size} leaves the "
                f"{self.height}x{self.width} BTF"
            )
        return self.region(slice(row0, row0 + size), slice(col0, col0 + size))

    def abrdf(self, row: int, col: int) -> np.ndarray:
        """One texel's apparent BRDF: (L, V, 3)."""
        return self.read([row], [col], slice(None), slice(None))[0, 0]

    def iter_view_blocks(self) -> Iterator[tuple[int, np.ndarray]]:
        """Yield (view index, (H, W, L, 3) block) for every view, in order."""
        for v in range(len(self.views)):
            yield v, self.view_block(v)

    def iter_blocks(self, max_bytes: int = 64 * 2**20) -> Iterator[np.ndarray]:
        """Yield the whole BTF as (h, w, L, v, 3) float32 blocks of about ``max_bytes`` (bands
        of rows of a few views, or tiles), following :attr:`block_hint` where it fits: a scan
        whose memory does not grow with the BTF."""
        h, w, nl, nv, _ = self.shape
        hint_rows, vstep = (max(1, int(x)) for x in self.block_hint)
        vstep = min(vstep, nv) if 12 * w * nl * vstep * hint_rows <= max_bytes else 1
        row_bytes = 12 * w * nl * vstep
        rstep = max(1, max_bytes // max(row_bytes, 1))
        if rstep >= hint_rows:
            rstep -= rstep % hint_rows
        cstep = w if row_bytes <= max_bytes else max(1, max_bytes // (12 * nl * vstep))
        for v0 in range(0, nv, vstep):
            for r0 in range(0, h, rstep):
                for c0 in range(0, w, cstep):
                    yield self.read(
                        slice(r0, min(r0 + rstep, h)), slice(c0, min(c0 + cstep, w)),
                        slice(None), slice(v0, min(v0 + vstep, nv)),
                    )  # fmt: skip

    def to_array(self) -> np.ndarray:
        """The whole BTF in memory. Only for small BTFs: refuses above the memory budget
        (2 GiB unless ``$SPARSEBTF_MAX_MEMORY_GB`` says otherwise)."""
        nbytes = self.n_values * 4
        if nbytes > memory_budget():
            raise BTFInputError(
                f"{self.label}: refusing to load {nbytes / 2**30:.1f} GiB into memory (budget "
                f"{format_bytes(memory_budget())}, $SPARSEBTF_MAX_MEMORY_GB); stream it by region "
                "or view block instead"
            )
        return self.read(slice(None), slice(None), slice(None), slice(None))


class ArrayBTF(BTF):
    """A BTF held in an (H, W, L, V, 3) array (or a memory map)."""

    def __init__(
        self,
        data: np.ndarray,
        lights: DirectionSet,
        views: DirectionSet,
        name: str = "btf",
        attrs: dict[str, Any] | None = None,
    ) -> None:
        arr = np.asarray(data)
        if arr.ndim != 5:
            raise BTFInputError(
                "BTF array must have rank 5 (row, col, light, view, channel), "
                f"got shape {arr.shape}"
            )
        if arr.shape[4] != 3:
            raise BTFInputError(f"BTF array must have 3 colour channels, got {arr.shape[4]}")
        if arr.shape[2] != len(lights):
            raise BTFInputError(
                f"BTF array has {arr.shape[2]} lights but the light table has {len(lights)}"
            )
        if arr.shape[3] != len(views):
            raise BTFInputError(
                f"BTF array has {arr.shape[3]} views but the view table has {len(views)}"
            )
        super().__init__(arr.shape[0], arr.shape[1], lights, views, name, attrs)
        self.data = arr

    def read(self, rows: Index, cols: Index, lights: Index, views: Index) -> np.ndarray:
        r, c, li, vi = self.indices(rows, cols, lights, views)
        sel = tuple((contiguous_slice(ix) or ix) for ix in (r, c, li, vi))
        out = self.data
        # Index one axis at a time: outer-product indexing without fancy-index broadcasting.
        for axis, ix in enumerate(sel):
            out = out[(slice(None),) * axis + (ix,)]
        return np.asarray(out, dtype=np.float32)


class FunctionBTF(BTF):
    """A lazy BTF whose values come from ``view_block_fn(view) -> (H, W, L, 3)``.

    Nothing is computed until asked; each call renders whole view blocks and keeps the last
    one, so an angular-image scan over one view is cheap. Region reads render every view.
    """

    def __init__(
        self,
        shape: tuple[int, int],
        lights: DirectionSet,
        views: DirectionSet,
        view_block_fn: Callable[[int], np.ndarray],
        name: str = "btf",
        attrs: dict[str, Any] | None = None,
    ) -> None:
        super().__init__(shape[0], shape[1], lights, views, name, attrs)
        self._fn = view_block_fn
        self._last: tuple[int, np.ndarray] | None = None
        self.block_hint = (shape[0], 1)  # renders whole view blocks: scans read them whole

    def view_block(self, view: int) -> np.ndarray:
        (v,) = as_index([view], len(self.views), "view")
        last = self._last  # read once: another thread may replace it meanwhile
        if last is not None and last[0] == v:
            return last[1]
        block = np.asarray(self._fn(int(v)), dtype=np.float32)
        expected = (self.height, self.width, len(self.lights), 3)
        if block.shape != expected:
            raise BTFInputError(
                f"{self.label}: view block {v} has shape {block.shape}, expected {expected}"
            )
        self._last = (int(v), block)
        return block

    def read(self, rows: Index, cols: Index, lights: Index, views: Index) -> np.ndarray:
        r, c, li, vi = self.indices(rows, cols, lights, views)
        out = np.empty((r.size, c.size, li.size, vi.size, 3), dtype=np.float32)
        for j, v in enumerate(vi):
            out[:, :, :, j, :] = self.view_block(int(v))[np.ix_(r, c, li)]
        return out


class FactorBTF(BTF):
    """A lazy low-rank BTF: per channel c, ``B_c = g(S_c @ A_cᵀ)``.

    ``spatial`` is (3, H·W, R) or (H·W, R) shared; ``angular`` is (3, L·V, R). Pixel index is
    ``row * W + col``; angular index is ``light * V + view``. If ``log_domain`` is true the
    product holds ln(B + log_offset) (UBO2014's dynamic-range reduction) and is mapped back
    with exp(·) − log_offset. Sums run in float32 or wider (float64 when the factors are float64).
    """

    def __init__(
        self,
        spatial: np.ndarray,
        angular: np.ndarray,
        height: int,
        width: int,
        lights: DirectionSet,
        views: DirectionSet,
        log_domain: bool = False,
        log_offset: float = RELEASE_LOG_OFFSET,
        name: str = "btf",
        attrs: dict[str, Any] | None = None,
    ) -> None:
        super().__init__(height, width, lights, views, name, attrs)
        s = np.asarray(spatial)
        a = np.asarray(angular)
        if s.ndim == 2:
            s = s[None]
        if a.ndim == 2:
            a = a[None]
        if s.shape[-2] != height * width:
            raise BTFInputError(
                f"spatial factor has {s.shape[-2]} rows, expected H*W = {height * width}"
            )
        if a.shape[-2] != len(lights) * len(views):
            raise BTFInputError(
                f"angular factor has {a.shape[-2]} rows, expected L*V = {len(lights) * len(views)}"
            )
        if s.shape[-1] != a.shape[-1]:
            raise BTFInputError(f"factor ranks differ: {s.shape[-1]} vs {a.shape[-1]}")
        if s.shape[0] not in (1, 3) or a.shape[0] not in (1, 3):
            raise BTFInputError("factors must be shared (2D) or per channel (3, n, R)")
        self.spatial = s
        self.angular = a
        self.log_domain = log_domain
        self.log_offset = log_offset

    @property
    def rank(self) -> int:
        return int(self.spatial.shape[-1])

    def read(self, rows: Index, cols: Index, lights: Index, views: Index) -> np.ndarray:
        r, c, li, vi = self.indices(rows, cols, lights, views)
        w, nv = self.width, len(self.views)
        pix = (r[:, None] * w + c[None, :]).ravel()
        ang = (li[:, None] * nv + vi[None, :]).ravel()
        dt = np.result_type(self.spatial.dtype, self.angular.dtype, np.float32)
        # contiguous runs (a patch's all directions, a view's lights) as views, not copies
        pix_at, ang_at = contiguous_slice(pix) or pix, contiguous_slice(ang) or ang
        out = np.empty((r.size, c.size, li.size, vi.size, 3), dtype=np.float32)
        # each channel's product into a buffer of this thread (no fresh pages per read), then
        # exp in place and the offset taken off on the way into the interleaved output: one
        # pass less than exp, subtract and copy (30 → 26 ms a 10×10 patch at rank 100)
        local = self.__dict__.setdefault("_local", threading.local())
        val = thread_buffer(local, pix.size * ang.size, dt).reshape(pix.size, ang.size)
        for ch in range(3):
            s = np.asarray(self.spatial[min(ch, self.spatial.shape[0] - 1)][pix_at], dtype=dt)
            a = np.asarray(self.angular[min(ch, self.angular.shape[0] - 1)][ang_at], dtype=dt)
            np.matmul(s, a.T, out=val)
            dest = out[..., ch].reshape(pix.size, ang.size)
            if self.log_domain:
                np.exp(val, out=val)
                np.subtract(val, self.log_offset, out=dest)
            else:
                dest[...] = val
        return out

    def __getstate__(self) -> dict[str, Any]:
        # the threads' buffers stay behind (a thread-local does not pickle)
        return {k: v for k, v in self.__dict__.items() if k != "_local"}
