"""Decode codes back to data: Eq. 4 (whole data points) and Eq. 5 (a few directions), and the
lazy decoded BTF (paper §3.4).

:func:`decode_points` reconstructs chosen data points of one channel at chosen lights and views
(standardised values); it switches to Eq. 5's sparse sums (:func:`decode_points_eq5`, the
NumPy reference :func:`~sparsebtf.runtime.kernels.gather_terms`) for a few directions.
:class:`DecodedBTF` wraps a coded BTF as a :class:`~sparsebtf.data.btf.BTF` whose every read
decodes what it needs and undoes the preprocessing.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..data.btf import BTF, Index, as_index
from ..errors import BTFInputError
from ..learning.coding import reconstruct_points
from ..learning.highlights import grid_corrections
from ..model import CodedBTF
from ..patch_tree import refuse_adaptive
from ..points.grid import PatchGrid
from ..points.preprocessing import Preprocessor
from .kernels import gather_terms

__all__ = [
    "EQ5_MAX_DIRECTIONS",
    "DecodedBTF",
    "coded_btf_view",
    "decode_points",
    "decode_points_eq5",
]

#: Up to this many (light, view) pairs a read uses Eq. 5 (sparse sums), above it Eq. 4.
EQ5_MAX_DIRECTIONS = 16


def decode_points(
    coded: CodedBTF,
    channel: str,
    points: Sequence[int] | np.ndarray,
    lights: Index = slice(None),
    views: Index = slice(None),
    dtype: type = np.float64,
) -> np.ndarray:
    """Eq. 4 for chosen points of one channel, restricted to chosen lights and views.

    Returns standardised values (n, p, p, l, v) (plus a colour axis for "YUV"). Restricting
    the angular modes multiplies by the needed rows of U3, U4 only; up to
    :data:`EQ5_MAX_DIRECTIONS` (light, view) pairs use Eq. 5 instead.
    """
    model = coded.require_model()
    li = as_index(lights, len(coded.lights), "light")
    vi = as_index(views, len(coded.views), "view")
    idx = np.asarray(points, dtype=np.int64)
    if li.size * vi.size <= EQ5_MAX_DIRECTIONS:
        return decode_points_eq5(coded, channel, idx, li, vi).astype(dtype, copy=False)
    codes = coded.codes[channel]
    rows = [None, None, li, vi] + [None] * (len(codes.mode_sizes) - 4)
    return reconstruct_points(codes, model.dictionaries[channel], idx, dtype, rows)


def decode_points_eq5(
    coded: CodedBTF,
    channel: str,
    points: Sequence[int] | np.ndarray,
    lights: Index = slice(None),
    views: Index = slice(None),
) -> np.ndarray:
    """Eq. 5 for chosen points: Σ_s v_s U1[i1,l1] U2[i2,l2] U3[light,l3] U4[view,l4].

    Sums the sparse coefficients directly (no dense coefficient tensor): the cost is
    p²·l·v·τ per point, so this is the path for a few directions.
    """
    model = coded.require_model()
    codes = coded.codes[channel]
    li = as_index(lights, len(coded.lights), "light")
    vi = as_index(views, len(coded.views), "view")
    idx = np.asarray(points, dtype=np.int64)
    sizes = codes.mode_sizes
    rows = [np.arange(sizes[0]), np.arange(sizes[1]), li, vi, *map(np.arange, sizes[4:])]
    val, factors = gather_terms(
        codes.values, codes.locations, codes.offsets, codes.membership,
        model.dictionaries[channel], idx, None, rows,
    )  # fmt: skip
    modes = "abcde"[: len(factors)]
    spec = "nw," + ",".join(f"nw{m}" for m in modes) + "->n" + modes
    return np.einsum(spec, val, *factors, optimize=True)


class DecodedBTF(BTF):
    """A coded BTF seen as a lazy :class:`BTF`: every read decodes what it needs (Eq. 4).

    Reads decode the data points that cover the requested texels, only at the requested
    directions, then undo the standardisation, YUV and log (linear RGB, float32).
    """

    def __init__(self, coded: CodedBTF) -> None:
        refuse_adaptive(coded, "DecodedBTF")
        coded.require_model()
        if "YUV" not in coded.channels and len(coded.channels) < 3:
            raise BTFInputError(
                f"{coded.label}: only channels {coded.channels} are coded; RGB needs Y, U and V"
            )
        super().__init__(
            coded.height, coded.width, coded.lights, coded.views, coded.name, dict(coded.attrs)
        )
        self.source = coded.source
        self.coded = coded
        self.grid = PatchGrid(coded.height, coded.width, coded.patch)
        self.pre = Preprocessor(coded.stats)

    def read(self, rows: Index, cols: Index, lights: Index, views: Index) -> np.ndarray:
        r, c, li, vi = self.indices(rows, cols, lights, views)
        z = self.read_standardised(rows, cols, lights, views)
        out = self.pre.inverse(z, li, vi).astype(np.float32, copy=False)
        h = self.coded.highlight_store
        if h is not None:
            # the store's corrections at these nodes, then the clamp every decoder applies
            out += grid_corrections(h, r, c, li, vi, self.coded.patch, self.grid.n_row_blocks,
                                    len(self.lights), len(self.views),
                                    (self.lights.xyz, self.views.xyz))  # fmt: skip
            np.maximum(out, 0, out=out)
        return out

    def read_standardised(
        self, rows: Index, cols: Index, lights: Index, views: Index
    ) -> np.ndarray:
        """The decoded values before the preprocessing is undone: (rows, cols, l, v, 3)
        standardised log-YUV (or, for an "identity" model, linear RGB), float32."""
        r, c, li, vi = self.indices(rows, cols, lights, views)
        p = self.coded.patch
        rb = np.unique(r // p)
        cb = np.unique(c // p)
        pts = self.grid.index(rb[:, None], cb[None, :]).T.ravel()  # col-block major order
        z = np.empty((rb.size * p, cb.size * p, li.size, vi.size, 3), dtype=np.float32)
        for ch_i, ch in enumerate(self.coded.channels):
            # float32 decoding: its rounding (~1e-7) is far below any coding error.
            vals = decode_points(self.coded, ch, pts, li, vi, dtype=np.float32)
            # (cb, rb, i1, i2, ...) → (rb, i1, cb, i2, ...)
            vals = vals.reshape(cb.size, rb.size, p, p, li.size, vi.size, *vals.shape[5:])
            vals = np.moveaxis(vals, 0, 2).reshape(
                rb.size * p, cb.size * p, li.size, vi.size, *vals.shape[6:]
            )
            if ch == "YUV":
                z[...] = vals
            else:
                z[..., ch_i] = vals
        # Map requested rows/cols into the decoded block.
        row_pos = np.searchsorted(rb, r // p) * p + r % p
        col_pos = np.searchsorted(cb, c // p) * p + c % p
        if not np.array_equal(row_pos, np.arange(z.shape[0])):
            z = z[row_pos]
        if not np.array_equal(col_pos, np.arange(z.shape[1])):
            z = z[:, col_pos]
        return z


def coded_btf_view(coded: CodedBTF) -> DecodedBTF:
    """The decoded BTF of ``coded`` as a lazy :class:`BTF` (needs the model attached)."""
    return DecodedBTF(coded)
