"""Angular neighbours and interpolation weights for unmeasured directions (paper §3.4).

A renderer asks for light and view directions that were never measured. Each query direction
is matched to its k nearest sampled directions by chord distance d = |q − x| (equivalent to
angular distance on the unit sphere) and given weights summing to one. The weights feed the
coefficient-space interpolation of Eq. 6 (:mod:`sparsebtf.runtime.decoder`), separately for
light and view.

Schemes
-------
``"nearest"``      k = 1, the nearest bin (no interpolation).
``"linear"``       the release shader's 2-nearest weighting: w₀ = ½ + ½ (d₁ − d₀)/d₁, w₁ = 1 − w₀.
``"barycentric"``  3 nearest, barycentric coordinates of q (centrally projected) in their
                   triangle (negative weights clipped and renormalised; a degenerate triangle
                   falls back to linear).
``"gaussian"``     k nearest (default 4), w ∝ exp(−β d²): the kernel the paper recommends against
                   visible bin edges (release: β = 20). It smooths, so it does not return the
                   sample exactly at a sampled direction.

:func:`neighbour_table` precomputes candidate lists over a (φ, elevation) grid, the release's
``adjMap`` idea, for shaders that should not scan every direction (8 per cell, complete in
practice); :func:`candidate_lists` gives, on the same grid, lists of varying length that are
provably complete (the Mitsuba plugin uses them).
"""

from __future__ import annotations

import functools
from typing import Literal

import numpy as np

from .._numba import HAVE_NUMBA
from .._numba import numba as _nb
from ..data.directions import DirectionSet, k_nearest
from ..errors import BTFInputError

__all__ = [
    "DEFAULT_K",
    "SCHEMES",
    "DirectionIndex",
    "Scheme",
    "angular_weights",
    "candidate_lists",
    "cell_of",
    "neighbour_count",
    "neighbour_table",
]

Scheme = Literal["nearest", "linear", "barycentric", "gaussian"]
SCHEMES: tuple[str, ...] = ("nearest", "linear", "barycentric", "gaussian")
DEFAULT_K = {"nearest": 1, "linear": 2, "barycentric": 3, "gaussian": 4}
_CHUNK = 1 << 16
#: Queries per pass of the compiled weights (:meth:`DirectionIndex.weights`).
_BLOCK = 128
_NO_ORDER = np.empty(0, dtype=np.int64)
#: Entries of a cell's list every k <= 2 query scans (UBO2014, k = 2: lists of 2, 3 or 4 for
#: 97 % of queries, 7 at most).
_HEAD = 4
#: Schemes whose weights :meth:`DirectionIndex.weights` computes in the same compiled pass as
#: the search (every one).
_FUSED = {"nearest": 0, "linear": 1, "gaussian": 2, "barycentric": 3}


def _as_xyz(directions: DirectionSet | np.ndarray) -> np.ndarray:
    xyz = directions.xyz if isinstance(directions, DirectionSet) else np.asarray(directions)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise BTFInputError(f"direction table must have shape (N, 3), got {xyz.shape}")
    return np.asarray(xyz, dtype=np.float64)


def _unit_queries(query: np.ndarray, name: str) -> np.ndarray:
    q = np.asarray(query, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 3:
        raise BTFInputError(f"{name} directions must have shape (n, 3), got {q.shape}")
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    bad = ~np.isfinite(norm[:, 0]) | (norm[:, 0] == 0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise BTFInputError(
            f"{name} direction {i} is zero or not finite ({bad.sum()} such directions)"
        )
    return q / norm


def _linear(d: np.ndarray) -> np.ndarray:
    d0, d1 = d[:, 0], d[:, 1]
    safe = np.where(d1 > 0, d1, 1.0)
    w0 = np.where(d1 > 0, 0.5 + 0.5 * (d1 - d0) / safe, 0.5)
    return np.stack([w0, 1.0 - w0], axis=1)


def _barycentric(xyz: np.ndarray, q: np.ndarray, idx: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Barycentric weights of the central projection of q onto the neighbours' triangle.

    Solving [x₀ x₁ x₂] b = q and normalising b to sum 1 places t·q in the triangle's plane
    (gnomonic projection), so a query on the ray through a point of the triangle gets that
    point's planar barycentric coordinates, and a sampled direction gets (1, 0, 0).
    """
    m = np.stack([xyz[idx[:, 0]], xyz[idx[:, 1]], xyz[idx[:, 2]]], axis=2)  # columns x_i
    ok = np.abs(np.linalg.det(m)) > 1e-9
    m = np.where(ok[:, None, None], m, np.eye(3))
    b = np.linalg.solve(m, q[:, :, None])[:, :, 0]
    s = b.sum(axis=1, keepdims=True)
    ok &= s[:, 0] > 0
    w = np.clip(b / np.where(ok[:, None], s, 1.0), 0.0, None)
    t = w.sum(axis=1, keepdims=True)
    ok &= t[:, 0] > 0
    w = w / np.where(t > 0, t, 1.0)
    if not ok.all():  # degenerate (neighbours on a great circle): the release's 2-NN weights
        lin = np.zeros_like(w)
        lin[:, :2] = _linear(d[:, :2])
        w = np.where(ok[:, None], w, lin)
    return w


def angular_weights(
    directions: DirectionSet | np.ndarray,
    query: np.ndarray,
    scheme: Scheme | str = "linear",
    k: int | None = None,
    beta: float = 20.0,
    table: DirectionIndex | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Neighbour indices and weights of query directions (the α of Eq. 6, generalised).

    Parameters
    ----------
    directions : the sampled directions (a :class:`DirectionSet` or an (N, 3) array).
    query : (n, 3) directions in the same local frame (normalised here).
    scheme : "nearest", "linear", "barycentric" or "gaussian" (see the module docstring).
    k : number of neighbours; only "gaussian" accepts a choice (default 4).
    beta : Gaussian sharpness β in exp(−β d²) (release: 20).
    table : a :class:`DirectionIndex` of ``directions`` for this k: the search scans each
        query's grid-cell list instead of every direction (same neighbours, same distances).

    Returns
    -------
    index : (n, k) int32, nearest first. weight : (n, k) float64, rows summing to 1.
    """
    xyz = _as_xyz(directions)
    kk = neighbour_count(scheme, k, beta, xyz.shape[0])
    if (table is not None and table.k == kk and HAVE_NUMBA
            and scheme in _FUSED):  # fmt: skip
        return table.weights(query, scheme, beta)
    q = _unit_queries(query, "query")
    n = q.shape[0]
    index = np.empty((n, kk), dtype=np.int32)
    weight = np.empty((n, kk), dtype=np.float64)
    for s in range(0, n, _CHUNK):
        qs = q[s : s + _CHUNK]
        idx, d2 = table.k_nearest(qs) if table is not None and table.k == kk else (
            k_nearest(xyz, qs, kk))  # fmt: skip
        if scheme == "nearest":
            w = np.ones((qs.shape[0], 1))
        elif scheme == "linear":
            w = _linear(np.sqrt(d2))
        elif scheme == "barycentric":
            w = _barycentric(xyz, qs, idx, np.sqrt(d2))
        else:
            w = np.exp(-beta * (d2 - d2[:, :1]))
            w /= w.sum(axis=1, keepdims=True)
        index[s : s + _CHUNK] = idx
        weight[s : s + _CHUNK] = w
    return index, weight


def neighbour_count(scheme: str, k: int | None, beta: float, n_directions: int) -> int:
    """The k of ``scheme`` (:func:`angular_weights`' rules: only "gaussian" takes a choice,
    1 <= k <= the directions; β finite and >= 0), or one line saying which is wrong."""
    if scheme not in SCHEMES:
        raise BTFInputError(f"unknown interpolation {scheme!r}; choose one of {', '.join(SCHEMES)}")
    kk = DEFAULT_K[scheme]
    if k is not None:
        if scheme != "gaussian" and k != kk:
            raise BTFInputError(f"interpolation {scheme!r} uses k = {kk}, got k = {k}")
        kk = int(k)
    if not 1 <= kk <= n_directions:
        raise BTFInputError(f"k must be in [1, {n_directions}], got {kk}")
    if scheme == "gaussian" and not (np.isfinite(beta) and beta >= 0):
        raise BTFInputError(f"beta must be finite and >= 0, got {beta}")
    return kk


def neighbour_table(
    directions: DirectionSet | np.ndarray,
    k: int = 8,
    n_phi: int = 256,
    n_elevation: int = 64,
) -> np.ndarray:
    """Candidate neighbours over a (elevation, φ) grid of the upper hemisphere.

    Cell (e, a) covers elevation [e, e+1)·(π/2)/n_elevation and φ [a, a+1)·2π/n_phi − π; it
    lists the ``k`` directions nearest to the cell centre, nearest first. A shader looks up the
    cell of its query and ranks these few candidates by exact distance instead of scanning
    every direction; with k = 8 the true 3 nearest are among them (tested).

    Returns (n_elevation, n_phi, k) int16.
    """
    xyz = _as_xyz(directions)
    if not 1 <= k <= xyz.shape[0]:
        raise BTFInputError(f"k must be in [1, {xyz.shape[0]}], got {k}")
    centres = _grid_points(n_elevation, n_phi, 0.5, 0.5)
    idx, _ = k_nearest(xyz, centres.reshape(-1, 3), k)
    return idx.reshape(n_elevation, n_phi, k).astype(np.int16)


def _grid_points(n_elevation: int, n_phi: int, fe: float, fa: float) -> np.ndarray:
    """(n_elevation, n_phi, 3) unit vectors at fraction (fe, fa) ∈ [0, 1]² of each grid cell."""
    el = np.minimum((np.arange(n_elevation) + fe) * (np.pi / 2) / n_elevation, np.pi / 2)
    ph = (np.arange(n_phi) + fa) * (2 * np.pi) / n_phi - np.pi
    e, a = np.meshgrid(el, ph, indexing="ij")
    return np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1)


def cell_of(query: np.ndarray, n_phi: int = 256, n_elevation: int = 64) -> np.ndarray:
    """Grid cell e·n_phi + a of unit directions (n, 3) (the grid of :func:`neighbour_table`;
    directions below the horizon fall in elevation row 0)."""
    q = np.asarray(query, dtype=np.float64)
    el = np.arcsin(np.clip(q[:, 2], 0.0, 1.0))
    az = np.arctan2(q[:, 1], q[:, 0])
    e = np.minimum((el * (2 / np.pi) * n_elevation).astype(np.int64), n_elevation - 1)
    a = np.clip(((az + np.pi) * (0.5 / np.pi) * n_phi).astype(np.int64), 0, n_phi - 1)
    return e * n_phi + a


def candidate_lists(
    directions: DirectionSet | np.ndarray,
    k: int,
    n_phi: int = 256,
    n_elevation: int = 64,
) -> tuple[np.ndarray, np.ndarray]:
    """Per cell of the :func:`neighbour_table` grid, every direction that can be among the ``k``
    nearest of a query in that cell: the k-nearest search of a query scans only its cell's list.

    Complete by the triangle inequality on angles: with c the cell centre, r the cell's angular
    radius (its farthest corner) and x₍ₖ₎ the k-th nearest direction of c, a query q in the cell
    has its k nearest within ∠(c, x₍ₖ₎) + r of q, so no direction with
    ∠(c, x) > ∠(c, x₍ₖ₎) + 2r can be among them. A margin of 1 % of 2r plus 2·10⁻⁵ rad covers
    float32 cell lookups of queries on a cell border. Lists are in increasing index order, so a
    scan of a list breaks ties as a scan of every direction does (lower index first).
    UBO2014 (151 directions), k = 2: 2.7 candidates per cell on average, at most 7.

    Returns (offsets (n_elevation·n_phi + 1,) int32, indices (offsets[-1],) int32); the list
    of cell e·n_phi + a (:func:`cell_of`) is ``indices[offsets[c]:offsets[c + 1]]``.
    """
    xyz = _as_xyz(directions)
    xyz = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
    if not 1 <= k <= xyz.shape[0]:
        raise BTFInputError(f"k must be in [1, {xyz.shape[0]}], got {k}")
    c = _grid_points(n_elevation, n_phi, 0.5, 0.5).reshape(-1, 3)
    r = np.zeros(c.shape[0])
    for fe in (0.0, 1.0):
        for fa in (0.0, 1.0):
            corner = _grid_points(n_elevation, n_phi, fe, fa).reshape(-1, 3)
            r = np.maximum(r, np.arccos(np.clip(np.sum(corner * c, axis=1), -1.0, 1.0)))
    ang = np.arccos(np.clip(c @ xyz.T, -1.0, 1.0))  # (cells, N)
    kth = np.partition(ang, k - 1, axis=1)[:, k - 1]
    keep = ang <= (kth + 2.02 * r + 2e-5)[:, None]
    offsets = np.zeros(c.shape[0] + 1, dtype=np.int64)
    np.cumsum(keep.sum(axis=1), out=offsets[1:])
    indices = np.nonzero(keep)[1]  # row-major: per cell, increasing index
    return offsets.astype(np.int32), indices.astype(np.int32)


@functools.cache
def _atan_poly(degree: int = 8) -> np.ndarray:
    """Coefficients c of atan(t) ≈ t·Σ_i c_i t^(2i) on [0, 1]: a least-squares fit at
    Chebyshev nodes, max error 6e-9 rad at degree 8 (``tests/test_wavefront.py``)."""
    t = 0.5 + 0.5 * np.cos(np.pi * (np.arange(4000) + 0.5) / 4000)
    basis = np.vander(t * t, degree + 1, increasing=True) * t[:, None]
    return np.linalg.lstsq(basis, np.arctan(t), rcond=None)[0]


@functools.cache
def _atan_poly_f32() -> tuple[np.float32, ...]:
    """:func:`_atan_poly`'s 9 coefficients as a float32 tuple (the compiled cell's)."""
    return tuple(np.float32(c) for c in _atan_poly())


class DirectionIndex:
    """The k-nearest search of one direction set, by table: each query scans the
    :func:`candidate_lists` of its grid cell (UBO2014, k = 2: 2.7 candidates on average)
    instead of all N directions. The lists are complete for directions on or above the
    horizon; a query below it is searched among all N. Same neighbours and the same squared
    chord distances as :func:`~sparsebtf.data.directions.k_nearest`, ties to the lower index
    (tested), so it serves every scheme of :func:`angular_weights`.
    """

    def __init__(self, directions: DirectionSet | np.ndarray, k: int,
                 n_phi: int = 256, n_elevation: int = 64) -> None:  # fmt: skip
        self.xyz = np.ascontiguousarray(_as_xyz(directions))
        self.k = int(k)
        self.n_phi, self.n_elevation = int(n_phi), int(n_elevation)
        self.offsets, self.indices = candidate_lists(self.xyz, self.k, n_phi, n_elevation)
        # each list's first _HEAD entries, a short one padded with repeats of its last
        pos = np.minimum(self.offsets[:-1, None] + np.arange(_HEAD),
                         self.offsets[1:, None] - 1)  # fmt: skip
        self.head = np.ascontiguousarray(self.indices[pos].ravel())

    def k_nearest(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(index (n, k) int32, squared chord distance (n, k) float64) of unit queries (n, 3),
        nearest first."""
        q = np.ascontiguousarray(q, dtype=np.float64)
        if not HAVE_NUMBA:
            return k_nearest(self.xyz, q, self.k)
        return _table_knn_nb(self.xyz, self.offsets, self.indices, q, self.k,
                             self.n_phi, self.n_elevation)  # fmt: skip

    def weights(self, query: np.ndarray, scheme: str, beta: float = 20.0,
                order: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """:func:`angular_weights` of raw queries (n, 3) for any scheme (k = this index's k)
        in one compiled pass: normalise, search, weigh — the same neighbours and weights as
        the NumPy steps (tested; barycentric and Gaussian weights to rounding), without
        their passes over the batch. ``order`` (n,) int64, a permutation: row i answers
        query ``order[i]`` (the runtime's group order, read in place). Needs numba."""
        q = np.asarray(query, dtype=np.float64)
        if q.ndim != 2 or q.shape[1] != 3:
            raise BTFInputError(f"query directions must have shape (n, 3), got {q.shape}")
        o = _NO_ORDER if order is None else np.ascontiguousarray(order, dtype=np.int64)
        idx, w, bad = _table_weights_nb(
            self.xyz, self.offsets, self.indices, self.head, np.ascontiguousarray(q), o, self.k,
            self.n_phi, self.n_elevation, _FUSED[scheme], float(beta),
            _atan_poly_f32())  # fmt: skip
        if bad.size:
            raise BTFInputError(
                f"query direction {int(bad.min())} is zero or not finite ({bad.size} such "
                "directions)"
            )
        return idx, w


if HAVE_NUMBA:

    @_nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
    def _atan2f(y, x, p):
        # atan2 in float32 with _atan_poly's polynomial (p: its 9 coefficients, float32),
        # within 5e-7 rad: a query on a cell border may land in its neighbour cell, whose
        # list is complete for it too (candidate_lists' margin, 2e-5 rad, covers float32
        # cells). Branch-free, so a block of queries runs in vector registers; np.arctan2
        # and np.arcsin are library calls that do not.
        ax, ay = abs(x), abs(y)
        hi = max(ax, ay)
        t = min(ax, ay) / hi if hi > 0 else np.float32(0.0)
        u = t * t
        s = ((((((((p[8] * u + p[7]) * u + p[6]) * u + p[5]) * u + p[4]) * u + p[3]) * u
               + p[2]) * u + p[1]) * u + p[0])  # fmt: skip
        a = t * s
        a = np.float32(np.pi / 2) - a if ay > ax else a
        a = np.float32(np.pi) - a if x < 0 else a
        return -a if y < 0 else a

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _barycentric_row(xyz, q, idx, d2, w):
        # _barycentric for one query: Cramer's rule for [x0 x1 x2] b = q (np.linalg.solve's
        # LU gives the same weights to rounding), the same clipping, renormalising and
        # fallback to the release's 2-NN weights on a degenerate triangle.
        a, b, c = xyz[idx[0]], xyz[idx[1]], xyz[idx[2]]
        c0 = b[1] * c[2] - b[2] * c[1]
        c1 = b[2] * c[0] - b[0] * c[2]
        c2 = b[0] * c[1] - b[1] * c[0]
        det = a[0] * c0 + a[1] * c1 + a[2] * c2
        ok = abs(det) > 1e-9
        s = 0.0
        if ok:
            # b_j = det(m with column j replaced by q) / det
            w[0] = (q[0] * c0 + q[1] * c1 + q[2] * c2) / det
            w[1] = (a[0] * (q[1] * c[2] - q[2] * c[1]) + a[1] * (q[2] * c[0] - q[0] * c[2])
                    + a[2] * (q[0] * c[1] - q[1] * c[0])) / det  # fmt: skip
            w[2] = (a[0] * (b[1] * q[2] - b[2] * q[1]) + a[1] * (b[2] * q[0] - b[0] * q[2])
                    + a[2] * (b[0] * q[1] - b[1] * q[0])) / det  # fmt: skip
            s = w[0] + w[1] + w[2]
            ok = s > 0
        t = 0.0
        if ok:
            for j in range(3):
                w[j] = max(w[j] / s, 0.0)
                t += w[j]
            ok = t > 0
        if ok:
            for j in range(3):
                w[j] /= t
            return
        d0 = np.sqrt(d2[0])
        d1 = np.sqrt(d2[1])
        w[0] = 0.5 + 0.5 * (d1 - d0) / d1 if d1 > 0 else 0.5
        w[1] = 1.0 - w[0]
        w[2] = 0.0

    @_nb.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
    def _table_weights_nb(xyz, offsets, indices, head, q, order, k, n_phi, n_elevation,
                          scheme, beta, p):  # fmt: skip
        # _unit_queries, DirectionIndex.k_nearest and the scheme's weights of angular_weights
        # in their order of operations (the same values), a block of _BLOCK queries at a
        # time, one step per loop: the arithmetic steps (normalise, grid cell, linear
        # weights) vectorise; fused with the list scan into one loop per query, none did
        # (measured: twice the time). Indices are unsigned where a loop should vectorise
        # (numba's wraparound test on signed ones stops LLVM).
        n = q.shape[0]
        m = xyz.shape[0]
        ordered = order.shape[0] > 0
        ok = np.empty(n, dtype=np.bool_)
        idx = np.empty((n, k), dtype=np.int32)
        w = np.empty((n, k))
        d2 = np.empty((n, k))
        top_e = np.float32(n_elevation - 1)
        top_a = np.float32(n_phi - 1)
        to_e = np.float32(2 / np.pi * n_elevation)
        to_a = np.float32(0.5 / np.pi * n_phi)
        for blk in _nb.prange((n + _BLOCK - 1) // _BLOCK):
            i0 = np.uint64(blk * _BLOCK)
            um = np.uint64(min(_BLOCK, n - blk * _BLOCK))
            ux = np.empty(_BLOCK)
            uy = np.empty(_BLOCK)
            uz = np.empty(_BLOCK)
            cell = np.empty(_BLOCK, dtype=np.int64)
            for j in range(um):  # q / |q|; a zero or non-finite query is divided by 1
                r = np.uint64(order[i0 + j]) if ordered else i0 + j
                x, y, z = q[r, 0], q[r, 1], q[r, 2]
                norm = np.sqrt(x * x + y * y + z * z)
                good = np.isfinite(norm) and norm != 0.0
                ok[i0 + j] = good
                norm = norm if good else 1.0
                ux[j] = x / norm
                uy[j] = y / norm
                uz[j] = z / norm
            for j in range(um):  # the cell of cell_of's grid; -1: scan every direction
                x, y, z = np.float32(ux[j]), np.float32(uy[j]), np.float32(uz[j])
                fe = _atan2f(z, np.sqrt(x * x + y * y), p) * to_e
                fa = (_atan2f(y, x, p) + np.float32(np.pi)) * to_a
                # clamped by comparisons, so NaN (a bad query) converts to a finite cell
                fe = fe if fe < top_e else top_e
                fe = fe if fe > 0 else np.float32(0.0)
                fa = fa if fa < top_a else top_a
                fa = fa if fa > 0 else np.float32(0.0)
                c = np.int64(fe) * n_phi + np.int64(fa)
                cell[j] = c if uz[j] >= 0.0 and ok[i0 + j] else -1
            for j in range(um):  # the scan of the cell's list (below the horizon: all N)
                i = i0 + j
                c = cell[j]
                lo = np.int64(0) if c < 0 else np.int64(offsets[c])
                hi = np.int64(m) if c < 0 else np.int64(offsets[c + 1])
                if k > 2:
                    _insert_scan(xyz, indices, ux[j], uy[j], uz[j], lo, hi, c < 0, k,
                                 idx[i], d2[i])  # fmt: skip
                    continue
                b0 = np.inf
                b1 = np.inf
                j0 = 0
                j1 = 0
                if c >= 0:
                    # the list's first _HEAD entries, padded with repeats of its last: a scan
                    # of fixed length (no mispredicted loop exit) for 97 % of queries
                    base = np.uint64(c) * np.uint64(_HEAD)
                    for t in range(np.uint64(_HEAD)):
                        b0, j0, b1, j1 = _keep_two(xyz, np.int64(head[base + t]), ux[j],
                                                   uy[j], uz[j], b0, j0, b1, j1)  # fmt: skip
                    lo += _HEAD
                for t in range(lo, hi):
                    b0, j0, b1, j1 = _keep_two(xyz, t if c < 0 else indices[t], ux[j], uy[j],
                                               uz[j], b0, j0, b1, j1)  # fmt: skip
                idx[i, 0] = j0
                d2[i, 0] = b0
                if k == 2:
                    idx[i, 1] = j1
                    d2[i, 1] = b1
            _weigh_block(xyz, ux, uy, uz, idx[i0:i0 + um],
                         d2[i0:i0 + um], w[i0:i0 + um], scheme, beta)  # fmt: skip
        bad = np.flatnonzero(~ok)
        return idx, w, order[bad] if ordered else bad

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _chord2(xyz, j, qx, qy, qz):
        # squared chord distance of unit q to direction j, never below 0
        return max(2.0 - 2.0 * (qx * xyz[j, 0] + qy * xyz[j, 1] + qz * xyz[j, 2]), 0.0)

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _keep_two(xyz, jj, qx, qy, qz, b0, j0, b1, j1):
        # (b0, j0, b1, j1), the two nearest so far, after candidate jj. Strictly less: a tie
        # keeps the lower index first, as the scan does; a repeat (the head's padding) never
        # takes the place it already holds. Selects, not branches.
        d = _chord2(xyz, jj, qx, qy, qz)
        first = d < b0
        second = d < b1 and jj != j0
        return (d if first else b0, jj if first else j0,
                b0 if first else (d if second else b1), j0 if first else (jj if second else j1))

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _insert_scan(xyz, indices, qx, qy, qz, lo, hi, every, k, idx, dist):
        # The k nearest of entries lo..hi of a cell's list (every: of all directions) by
        # insertion, nearest first, ties to the lower index: data.directions._knn_nb's scan.
        cnt = 0
        for t in range(lo, hi):
            j = t if every else indices[t]
            d = _chord2(xyz, j, qx, qy, qz)
            if cnt < k:
                cnt += 1
            elif d >= dist[k - 1]:
                continue
            pos = cnt - 1
            while pos > 0 and dist[pos - 1] > d:
                dist[pos] = dist[pos - 1]
                idx[pos] = idx[pos - 1]
                pos -= 1
            dist[pos] = d
            idx[pos] = j

    @_nb.njit(cache=True, nogil=True, error_model="numpy")
    def _weigh_block(xyz, ux, uy, uz, idx, d2, w, scheme, beta):
        # angular_weights' weights of a block from its neighbours' squared distances d2.
        um = np.uint64(w.shape[0])
        k = w.shape[1]
        if scheme == 0:
            for j in range(um):
                w[j, 0] = 1.0
            return
        if scheme == 1:  # the release's 2-NN weights; sqrt of a max(·, 0): an intrinsic
            lin = np.empty(um)
            for j in range(um):
                d0 = np.sqrt(max(d2[j, 0], 0.0))
                d1 = np.sqrt(max(d2[j, 1], 0.0))
                lin[j] = 0.5 + 0.5 * (d1 - d0) / d1 if d1 > 0 else 0.5
            for j in range(um):
                w[j, 0] = lin[j]
                w[j, 1] = 1.0 - lin[j]
            return
        u = np.empty(3)
        for j in range(um):
            if scheme == 3:
                u[0], u[1], u[2] = ux[j], uy[j], uz[j]
                _barycentric_row(xyz, u, idx[j], d2[j], w[j])
                continue
            t = 0.0
            for a in range(k):
                w[j, a] = np.exp(-beta * (d2[j, a] - d2[j, 0]))
                t += w[j, a]
            for a in range(k):
                w[j, a] /= t

    @_nb.njit(parallel=True, cache=True, nogil=True)
    def _table_knn_nb(xyz, offsets, indices, q, k, n_phi, n_elevation):
        # The scan of data.directions._knn_nb over a candidate list (increasing index, so the
        # same ties), the cell as cell_of computes it.
        n = q.shape[0]
        m = xyz.shape[0]
        idx = np.empty((n, k), dtype=np.int32)
        dist = np.empty((n, k), dtype=np.float64)
        for i in _nb.prange(n):
            qx, qy, qz = q[i, 0], q[i, 1], q[i, 2]
            below = qz < 0.0
            s0 = 0
            s1 = m
            if not below:
                el = np.arcsin(min(qz, 1.0))
                az = np.arctan2(qy, qx)
                e = min(np.int64(el * (2 / np.pi) * n_elevation), n_elevation - 1)
                a = min(max(np.int64((az + np.pi) * (0.5 / np.pi) * n_phi), 0), n_phi - 1)
                c = e * n_phi + a
                s0 = offsets[c]
                s1 = offsets[c + 1]
            _insert_scan(xyz, indices, qx, qy, qz, s0, s1, below, k, idx[i], dist[i])
        return idx, dist
