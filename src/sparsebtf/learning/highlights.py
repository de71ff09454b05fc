"""The highlight store (issue 46): linear-RGB corrections at a few sampled nodes
(texel, light, view) of a coded material, for the values a log-domain code reaches slowly.

On a glossy metal nearly all of the linear-RGB error sits in the few values above 1 (95–99.8 %
on the captured metals of docs/benchmarks.md §17), and the sparse code's error there falls
slowly with τ; storing the largest residuals (to within 12.5 %) buys more error per byte than
more coefficients. A node's correction is added after the decode:

    B̂(x, ω_i, ω_o) = max(decode(x, ω_i, ω_o) + Σ_ab wl_a · wv_b · c(x, l_a, v_b), 0)

with the same angular weights (wl, wv over the neighbour lights l_a and views v_b) as the
interpolation of the coefficients (Eq. 6), and c = 0 at a node without an entry: at a sampled
direction pair, where the weights are one-hot, the decode of a stored node is
decode + c = the reference (within the rounding of c: binary16, or E5M2 in a compact store).

Layout (:class:`Highlights`): entries grouped by data point (release order), per point sorted by
their key ``((i1·p + i2)·L + light)·V + view`` (i1, i2: the texel's row and column in the
point's p×p patch; L lights, V views), so a decoder finds a node by a binary search in its
point's range ``offsets[point] : offsets[point + 1]``. A store whose corrections all lie on
the E5M2 grid is **compact**: coded as :mod:`sparsebtf.learning.entry_code` codes it
(Rice-coded gaps between nodes, one byte a channel; 4.3–5.2 bytes an entry at UBO2014 size).
A **tinted** store (the encoder's) is compact with one E5M2 scale an entry along a tint per
point (:meth:`Highlights.from_tinted`; 2.3–3.2 bytes an entry). Any other store costs
:func:`entry_bytes` an entry by Table 4's rule for a coefficient (``learning/cost.py``): its
key as a location (3 bytes for the p²·L·V ≤ 2^24 nodes of a UBO2014 point, else 4) and three
binary16 values; each point a 32-bit count (:data:`POINT_BYTES`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..errors import BTFInputError
from .cost import VALUE_BYTES, location_width
from .entry_code import compact_bytes, from_e5m2, on_e5m2_grid, tinted, to_e5m2
from .lobes import LOBE_BYTES, LOBE_PARAMS, lobe_values

__all__ = [
    "POINT_BYTES",
    "Highlights",
    "correction",
    "entry_bytes",
    "grid_corrections",
    "lobe_corrections",
    "node_keys",
    "node_values",
    "offsets_from_counts",
    "tinted_corrections",
]

#: Bytes per data point: its entry count (uint32).
POINT_BYTES = 4


def entry_bytes(patch: int, n_lights: int, n_views: int) -> int:
    """Bytes of one stored node, counted as Table 4 counts a coefficient: its key a location
    among the point's p·p·L·V nodes (:func:`~sparsebtf.learning.cost.location_width`: 3 for
    UBO2014's 2,280,100) and R, G, B three binary16 values — 9 bytes at UBO2014 size."""
    return location_width((patch, patch, n_lights, n_views)) + 3 * VALUE_BYTES


def offsets_from_counts(counts: np.ndarray) -> np.ndarray:
    """(P + 1,) int64 :attr:`Highlights.offsets` of the points' entry counts (P,)."""
    return np.concatenate([[0], np.cumsum(counts, dtype=np.int64)]).astype(np.int64)


def tinted_corrections(offsets: np.ndarray, scales: np.ndarray,
                       tints: np.ndarray) -> np.ndarray:  # fmt: skip
    """The corrections (N, 3) float16 of a tinted store: each entry's E5M2 ``scales`` (N,)
    times its point's tint (``tints`` (P, 3); points by ``offsets``, as
    :attr:`Highlights.offsets`), :func:`~sparsebtf.learning.entry_code.tinted`."""
    points = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
    return tinted(scales, np.asarray(tints)[points])


def node_keys(i1: np.ndarray, i2: np.ndarray, light: np.ndarray, view: np.ndarray,
              patch: int, n_lights: int, n_views: int) -> np.ndarray:  # fmt: skip
    """The key of node (texel (i1, i2) of its point, light, view): ``((i1·p + i2)·L + light)·V
    + view``, int64 (any broadcastable shapes)."""
    t = np.asarray(i1, dtype=np.int64) * patch + np.asarray(i2, dtype=np.int64)
    return (t * n_lights + np.asarray(light, dtype=np.int64)) * n_views + np.asarray(
        view, dtype=np.int64
    )


@dataclass(frozen=True)
class Highlights:
    """Exact corrections at sampled nodes, per data point (module docstring).

    Attributes
    ----------
    offsets : (P + 1,) int64, point p's entries are ``offsets[p]:offsets[p + 1]``.
    keys : (N,) uint32, :func:`node_keys`, increasing within each point.
    rgb : (N, 3) float16, the linear-RGB correction (reference − decode) of each node.
    lobes : (P, p², 8) float16 or None, a highlight lobe per texel (texel i1·p + i2 of its
        point; :mod:`sparsebtf.learning.lobes`), added at the query's directions.
    tints : (P, 3) float16 or None, a tinted store's tint per point; then ``rgb`` is
        :func:`~sparsebtf.learning.entry_code.tinted` of ``scales`` (E5M2 values, (N,)
        float16) and each entry's tint (made by :meth:`from_tinted`).
    """

    offsets: np.ndarray
    keys: np.ndarray
    rgb: np.ndarray
    lobes: np.ndarray | None = None
    tints: np.ndarray | None = None
    scales: np.ndarray | None = None

    @cached_property
    def entry_points(self) -> np.ndarray:
        """(N,) int64, the data point of each entry."""
        return np.repeat(np.arange(self.n_points, dtype=np.int64), np.diff(self.offsets))

    @cached_property
    def sorted_nodes(self) -> np.ndarray:
        """(N,) int64 ``point · 2^32 + key``, increasing: one sorted key over the whole store
        (made once; a dense read searches it for every node it decodes)."""
        return (self.entry_points << 32) | self.keys.astype(np.int64)

    @property
    def n_entries(self) -> int:
        return int(self.keys.shape[0])

    @property
    def n_points(self) -> int:
        return int(self.offsets.shape[0]) - 1

    @cached_property
    def compact(self) -> bool:
        """Whether the store is tinted or every correction is an E5M2 value: it is then written
        and counted in the compact code (:mod:`~sparsebtf.learning.entry_code`); binary16
        entries else."""
        return self.tints is not None or on_e5m2_grid(self.rgb)

    def global_keys(self, nodes_per_point: int) -> np.ndarray:
        """(N,) int64 ``point · nodes_per_point + key``, increasing (the compact code's)."""
        return self.entry_points * int(nodes_per_point) + self.keys.astype(np.int64)

    @property
    def empty_store(self) -> bool:
        """No entry and no lobe: it changes no decoded value (stored as none)."""
        return not self.n_entries and self.lobes is None

    def nbytes(self, patch: int, n_lights: int, n_views: int) -> int:
        """Stored bytes in a material of ``patch``² texels per point and ``n_lights`` ×
        ``n_views`` directions: a compact store's code
        (:func:`~sparsebtf.learning.entry_code.compact_bytes`), else :func:`entry_bytes` per
        entry and :data:`POINT_BYTES` per point; the lobes' :data:`LOBE_BYTES` a texel; 0
        for an empty store (nothing is stored then)."""
        if self.empty_store:
            return 0
        lobes = 0 if self.lobes is None else self.n_points * patch * patch * LOBE_BYTES
        if self.compact:
            tints = 0 if self.tints is None else self.n_points
            return compact_bytes(self.global_keys(patch * patch * n_lights * n_views),
                                 tints) + lobes  # fmt: skip
        return (self.n_entries * entry_bytes(patch, n_lights, n_views)
                + self.n_points * POINT_BYTES + lobes)  # fmt: skip

    @classmethod
    def empty(cls, n_points: int) -> Highlights:
        return cls(np.zeros(n_points + 1, dtype=np.int64), np.zeros(0, dtype=np.uint32),
                   np.zeros((0, 3), dtype=np.float16))  # fmt: skip

    @classmethod
    def from_nodes(cls, points: np.ndarray, keys: np.ndarray, rgb: np.ndarray,
                   n_points: int) -> Highlights:  # fmt: skip
        """Entries given in any order as (point, key, rgb); sorted here, checked unique."""
        offsets, k, order = _sorted_entries(points, keys, n_points)
        rgb16 = np.asarray(rgb)[order].astype(np.float16)
        return cls(offsets, k, np.ascontiguousarray(rgb16))

    @classmethod
    def from_tinted(cls, points: np.ndarray, keys: np.ndarray, scales: np.ndarray,
                    tints: np.ndarray, n_points: int) -> Highlights:  # fmt: skip
        """A tinted store of entries given in any order as (point, key, scale) — scales
        rounded to E5M2 — and the points' ``tints`` (P, 3); sorted here, checked unique."""
        offsets, k, order = _sorted_entries(points, keys, n_points)
        s = from_e5m2(to_e5m2(np.asarray(scales)[order]))
        t = np.ascontiguousarray(np.asarray(tints, dtype=np.float16))
        if t.shape != (n_points, 3):
            raise BTFInputError(f"tints has shape {t.shape}, expected ({n_points}, 3)")
        return cls(offsets, k, tinted_corrections(offsets, s, t), tints=t, scales=s)

    def check(self, n_points: int, patch: int, n_lights: int, n_views: int,
              where: str) -> None:  # fmt: skip
        """One line naming ``where`` and the field if the store does not fit a material of
        ``n_points`` points of ``patch``² texels, ``n_lights`` × ``n_views`` directions."""
        self._check_entries(n_points, patch, n_lights, n_views, where)
        if self.tints is not None:
            t, s = self.tints, self.scales
            if t.shape != (n_points, 3) or s is None or s.shape != (self.n_entries,):
                raise BTFInputError(f"{where}: tints {t.shape} and scales "
                                    f"{None if s is None else s.shape} do not match "
                                    f"({n_points}, 3) and ({self.n_entries},)")  # fmt: skip
            if not np.all(np.isfinite(t)):
                i = int(np.flatnonzero(~np.isfinite(t).all(axis=1))[0])
                raise BTFInputError(f"{where}: tint of point {i} is not finite")
        if self.lobes is not None:
            lb = self.lobes
            if lb.shape != (n_points, patch * patch, LOBE_PARAMS):
                raise BTFInputError(f"{where}: lobes has shape {lb.shape}, expected "
                                    f"({n_points}, {patch * patch}, {LOBE_PARAMS})")  # fmt: skip
            bad = ~np.isfinite(lb).all(axis=2) | (lb[..., 5:] < 0).any(axis=2)
            if bad.any():
                pt, tx = (int(x[0]) for x in np.nonzero(bad))
                raise BTFInputError(f"{where}: lobe of point {pt}, texel {tx} is not finite or "
                                    "has a negative amplitude")  # fmt: skip

    def _check_entries(self, n_points: int, patch: int, n_lights: int, n_views: int,
                       where: str) -> None:  # fmt: skip
        o, k, v = self.offsets, self.keys, self.rgb
        if o.ndim != 1 or o.shape[0] != n_points + 1:
            raise BTFInputError(f"{where}: offsets has shape {o.shape}, expected "
                                f"({n_points + 1},) for {n_points} points")  # fmt: skip
        if o[0] != 0 or np.any(np.diff(o) < 0) or o[-1] != k.shape[0]:
            raise BTFInputError(f"{where}: offsets must rise from 0 to the {k.shape[0]} entries")
        if k.ndim != 1 or v.shape != (k.shape[0], 3):
            raise BTFInputError(f"{where}: keys {k.shape} and rgb {v.shape} do not match "
                                "(expected (N,) and (N, 3))")  # fmt: skip
        limit = patch * patch * n_lights * n_views
        if k.size and int(k.max()) >= limit:
            i = int(np.argmax(k))
            raise BTFInputError(f"{where}: key {int(k[i])} at entry {i} is outside the "
                                f"{patch}x{patch} texels x {n_lights} x {n_views} nodes")
        starts = np.zeros(k.shape[0], dtype=bool)
        starts[o[:-1][o[:-1] < k.shape[0]]] = True
        bad = (np.diff(k.astype(np.int64)) <= 0) & ~starts[1:]
        if bad.any():
            i = int(np.flatnonzero(bad)[0]) + 1
            raise BTFInputError(f"{where}: keys must increase within a point (entry {i})")
        if not np.all(np.isfinite(v)):
            i = int(np.flatnonzero(~np.isfinite(v).all(axis=1))[0])
            raise BTFInputError(f"{where}: rgb entry {i} is not finite")


def _sorted_entries(points: np.ndarray, keys: np.ndarray,
                    n_points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Offsets, keys (uint32) and the order of entries given in any order as (point, key),
    sorted by point then key; checked unique and inside the points."""
    points = np.asarray(points, dtype=np.int64)
    keys = np.asarray(keys, dtype=np.int64)
    order = np.lexsort((keys, points))
    points, keys = points[order], keys[order]
    if points.size and (points[0] < 0 or points[-1] >= n_points):
        raise BTFInputError(f"highlight points must lie in [0, {n_points})")
    same = (np.diff(points) == 0) & (np.diff(keys) == 0)
    if same.any():
        i = int(np.flatnonzero(same)[0])
        raise BTFInputError(f"highlight node {keys[i]} of point {points[i]} given twice")
    offsets = offsets_from_counts(np.bincount(points, minlength=n_points))
    return offsets, keys.astype(np.uint32), order


def node_values(h: Highlights, points: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """The corrections at nodes (``points``, ``keys``) of any equal shapes: (..., 3) float32,
    zero where the store has no entry. One binary search per node in its point's range."""
    pts = np.asarray(points, dtype=np.int64)
    k = np.asarray(keys, dtype=np.int64)
    out = np.zeros((*k.shape, 3), dtype=np.float32)
    if not h.n_entries:
        return out
    store = h.sorted_nodes
    want = (pts << 32) | k
    at = np.minimum(np.searchsorted(store, want.ravel()), store.size - 1)
    hit = store[at] == want.ravel()
    out.reshape(-1, 3)[hit] = h.rgb[at[hit]].astype(np.float32)
    return out


def correction(h: Highlights, pts: np.ndarray, i1: np.ndarray, i2: np.ndarray,
               li: np.ndarray, lw: np.ndarray, vi: np.ndarray, vw: np.ndarray, patch: int,
               n_lights: int, n_views: int) -> np.ndarray:  # fmt: skip
    """The interpolated correction Σ_ab wl_a · wv_b · c(x, l_a, v_b) of each query: (n, 3)
    float64, from its point ``pts`` (n,), texel (i1, i2) in the point, neighbour lights ``li``
    (n, kl) with weights ``lw`` and views ``vi`` (n, kv) with ``vw`` — the reference the
    compiled decoders are tested against."""
    keys = node_keys(np.asarray(i1)[:, None, None], np.asarray(i2)[:, None, None],
                     li[:, :, None], vi[:, None, :], patch, n_lights, n_views)  # fmt: skip
    c = node_values(h, np.broadcast_to(np.asarray(pts)[:, None, None], keys.shape), keys)
    w = np.asarray(lw, dtype=np.float64)[:, :, None] * np.asarray(vw, dtype=np.float64)[:, None, :]
    return np.einsum("nab,nabc->nc", w, c.astype(np.float64))


def lobe_corrections(h: Highlights, pts: np.ndarray, texels: np.ndarray, wi: np.ndarray,
                     wo: np.ndarray) -> np.ndarray:  # fmt: skip
    """The lobes' values at directions ``wi``, ``wo`` (..., 3) of texel ``texels`` (i1·p + i2)
    of point ``pts`` (shapes broadcasting with ``wi[..., 0]``): (..., 3) float64, 0 without
    lobes — :func:`~sparsebtf.learning.lobes.lobe_values`, the reference."""
    shape = np.broadcast_shapes(np.shape(pts), np.shape(texels), np.shape(wi)[:-1],
                                np.shape(wo)[:-1])  # fmt: skip
    if h.lobes is None:
        return np.zeros((*shape, 3))
    params = h.lobes[np.asarray(pts, dtype=np.int64), np.asarray(texels, dtype=np.int64)]
    return lobe_values(params.astype(np.float64), wi, wo)


def grid_corrections(h: Highlights, rows: np.ndarray, cols: np.ndarray, lights: np.ndarray,
                     views: np.ndarray, patch: int, n_row_blocks: int, n_lights: int,
                     n_views: int, directions: tuple[np.ndarray, np.ndarray]
                     ) -> np.ndarray:  # fmt: skip
    """The corrections at the outer product of texel ``rows`` × ``cols`` × ``lights`` ×
    ``views`` (index arrays, as a dense read takes them): (r, c, l, v, 3) float32, the lobes'
    values included where the store has lobes (``directions``: the material's light and view
    unit vectors, (L, 3) and (V, 3)). Point numbering is the release's:
    ``row_block + n_row_blocks · col_block``."""
    r, c, li, vi = (np.asarray(a, dtype=np.int64) for a in (rows, cols, lights, views))
    p = patch
    pts = (r[:, None] // p) + n_row_blocks * (c[None, :] // p)  # (r, c)
    t = (r[:, None] % p) * p + (c[None, :] % p)
    keys = (t[:, :, None, None] * n_lights + li[None, None, :, None]) * n_views + vi
    out = node_values(h, np.broadcast_to(pts[:, :, None, None], keys.shape), keys)
    if h.lobes is not None:
        wi, wo = directions
        out += lobe_corrections(h, pts[:, :, None, None], t[:, :, None, None],
                                wi[li][None, None, :, None], wo[vi][None, None, None, :]
                                ).astype(np.float32)  # fmt: skip
    return out
