"""Each data point's coefficients re-indexed over the dictionary columns it actually uses.

Eq. 6 needs, per query, the factors U1[i1, l1]·U2[i2, l2], the interpolated light row
r3[l3] = Σ_a wl_a U3[L_a, l3] and the view row r4[l4] = Σ_b wv_b U4[V_b, l4], but only at the
columns the point's kept coefficients name. Coded materials use few of them: the bundled
ensembles put a point's energy on a handful of columns (measured on the authors' carpet07 and
felt05 U/V codes at τ = 64: 7–22 light columns, 8–9 view columns and 4–9 (l1, l2) pairs of
the 151, 151 and 100; a captured 40×40 weave's Y at τ = 885: 12 light, 73 view columns, 50
pairs), so building the factors over all 10 + 10 + 151 + 151 columns per query is mostly
wasted work.

:func:`compact_layout` lists, per point, the distinct (l1, l2) pairs, light columns and view
columns **in the order the coefficients first name them** (coefficients are stored by
decreasing magnitude), and recodes each coefficient as compact indices
``e12 | a3 << 16 | b4 << 24``. Because of that order, the columns a level-of-detail prefix of
τ' coefficients needs are a prefix of each list too: ``need[s]`` holds, for the prefix ending
at coefficient s, how many entries of each list it uses (``n12 | n3 << 20 | n4 << 40``). A
lookup then builds ``n12 + kl·n3 + kv·n4`` factor entries instead of
``m1 + m2 + kl·m3 + kv·m4``, and a term is three loads (v·t12[e]·r3[a]·r4[b]) instead of four
(with the coefficients also grouped by (light, view) column pair, one: :class:`CompactLayout`).
Built once per channel, O(nnz log nnz) in NumPy (about 1 s for the Y channel of a 400 × 400
material at τ 885); 18 bytes per coefficient and 8 per (light, view) pair beside the codes.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["DENSE_FRACTION", "CompactLayout", "channel_layout", "compact_layout", "pair_groups"]

#: A point using more than this fraction of a mode's columns keeps the whole mode: a full
#: dictionary row is summed with contiguous vector loads (~16 entries per instruction), a list
#: by one gather per entry, so a list pays only when it is much shorter than the row
#: (``benchmarks/bench_lookup.py``).
DENSE_FRACTION = 0.5


class CompactLayout(NamedTuple):
    """Per channel: ``code`` (nnz,) uint32 compact indices e12 | a3<<16 | b4<<24; ``need``
    (nnz,) uint64 list lengths of each prefix n12 | n3<<20 | n4<<40; per point p the pairs
    ``pair1[o12[p]:o12[p+1]]``, ``pair2[…]`` (l1, l2), the light columns ``col3[o3[p]:o3[p+1]]``
    and view columns ``col4[o4[p]:o4[p+1]]``, each in order of first use; ``widest`` the
    longest lists (n12, n3, n4) of any point (scratch sizes).

    The same coefficients grouped by their (light, view) column pair, for sums over a point's
    whole list: Σ_s v_s·t12[e_s]·r3[a_s]·r4[b_s] = Σ_pairs r3[a]·r4[b]·Σ_{s in pair} v_s·t12[e_s]
    (one table load per coefficient instead of three). Pair r of point p
    (``opair[p] <= r < opair[p+1]``) has compact columns ``pab[r]`` = a | b<<16 and the
    coefficients ``pvalues[pstart[r]:pstart[r+1]]`` with pair indices ``pe12[…]``."""

    code: np.ndarray
    need: np.ndarray
    pvalues: np.ndarray
    pe12: np.ndarray
    pab: np.ndarray
    pstart: np.ndarray
    opair: np.ndarray
    pair1: np.ndarray
    pair2: np.ndarray
    o12: np.ndarray
    col3: np.ndarray
    o3: np.ndarray
    col4: np.ndarray
    o4: np.ndarray
    widest: tuple[int, int, int]

    @property
    def widest_pairs(self) -> int:
        """The most (light, view) column pairs of any point."""
        return int(np.max(np.diff(self.opair), initial=0))

    def mean_sizes(self) -> tuple[float, float, float]:
        """Mean list lengths (n12, n3, n4) over the points: the factor entries of a query."""
        p = max(self.o12.size - 1, 1)
        return self.o12[-1] / p, self.o3[-1] / p, self.o4[-1] / p


def _first_use(point: np.ndarray, column: np.ndarray, span: int, n_points: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Distinct ``column`` values per point in order of first occurrence: (columns (u,),
    offsets (P+1,), local index of every entry (nnz,))."""
    key = point * span + column
    uniq, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    by_first = np.argsort(first, kind="stable")  # entries are sorted by point: points stay apart
    rank = np.empty_like(by_first)
    rank[by_first] = np.arange(by_first.size)
    owner = uniq[by_first] // span
    offsets = np.zeros(n_points + 1, dtype=np.int64)
    np.cumsum(np.bincount(owner, minlength=n_points), out=offsets[1:])
    local = rank[inverse.ravel()] - offsets[point]
    return uniq[by_first] % span, offsets, local


def _prefix_counts(point: np.ndarray, local: np.ndarray) -> np.ndarray:
    """Per entry, 1 + the largest local index so far within its point (the list length a
    prefix ending there needs)."""
    if not local.size:
        return local
    big = np.int64(local.max() + 1)
    return np.maximum.accumulate(point * big + local) - point * big + 1


def _lists(point: np.ndarray, column: np.ndarray, m: int, n_points: int, dense_fraction: float
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Per point, its columns of a mode of size ``m`` in order of first use, or every column
    0 … m−1 in order where it uses more than ``dense_fraction``·m of them (a full row is read
    with contiguous vector loads; a list by gathers). Returns (columns, offsets (P+1,), local
    index of every entry, the list length each prefix needs)."""
    cols, off, local = _first_use(point, column, m, n_points)
    need = _prefix_counts(point, local)
    dense = (np.diff(off) > dense_fraction * m) | (np.diff(off) == m)
    if not dense.any():
        return cols, off, local, need
    count = np.where(dense, m, np.diff(off))
    new_off = np.zeros(n_points + 1, dtype=np.int64)
    np.cumsum(count, out=new_off[1:])
    owner = np.repeat(np.arange(n_points), count)
    new_cols = np.arange(new_off[-1]) - new_off[owner]  # dense lists: 0 … m−1
    old_owner = np.repeat(np.arange(n_points), np.diff(off))
    keep = ~dense[old_owner]
    pos = new_off[old_owner] + np.arange(cols.size) - off[old_owner]
    new_cols[pos[keep]] = cols[keep]
    d = dense[point]
    return new_cols, new_off, np.where(d, column, local), np.where(d, m, need)


def pair_groups(point: np.ndarray, l3: np.ndarray, l4: np.ndarray, n_points: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The coefficients of every point grouped by (light, view) column pair: ``order`` (nnz,)
    sorts them by point, view and light column; pair r holds ``order[pstart[r]:pstart[r+1]]``
    and point p the pairs ``opair[p]:opair[p+1]``; ``first`` (n_pairs,) is each pair's first
    position in ``order``. ``point``, ``l3``, ``l4``: (nnz,) per coefficient, by point."""
    order = np.lexsort((l3, l4, point))
    key = ((point * 256 + l4) * 256 + l3)[order]
    first = np.flatnonzero(np.diff(key, prepend=-1)) if key.size else np.zeros(0, np.int64)
    pstart = np.concatenate((first, [key.size])).astype(np.int64)
    opair = np.zeros(n_points + 1, dtype=np.int64)
    np.cumsum(np.bincount(point[order][first], minlength=n_points), out=opair[1:])
    return order, pstart, opair, first


def compact_layout(offsets: np.ndarray, locations: np.ndarray, values: np.ndarray,
                   sizes: tuple[int, ...],
                   dense_fraction: float | tuple[float, float, float] = DENSE_FRACTION
                   ) -> CompactLayout:  # fmt: skip
    """The :class:`CompactLayout` of one channel from its ``offsets`` (P+1,), packed
    ``locations`` (nnz,) uint32 l1 | l2<<8 | l3<<16 | l4<<24, ``values`` (nnz,) and the four
    mode ``sizes``.
    A point that uses more than ``dense_fraction`` of a mode's columns (of the m1·m2 pairs)
    keeps the whole mode, in order: its list is 0 … m−1, its indices the columns themselves.
    ``dense_fraction``: one for all, or (pairs, light, view).
    """
    f12, f3, f4 = np.broadcast_to(np.asarray(dense_fraction, dtype=np.float64), (3,))
    m1, m2, m3, m4 = (int(m) for m in sizes)
    if max(m1, m2, m3, m4) > 256:
        raise ValueError(f"mode sizes {sizes}: compact indices need every mode <= 256")
    offsets = np.asarray(offsets, dtype=np.int64)
    n_points = offsets.size - 1
    loc = np.asarray(locations, dtype=np.int64)
    point = np.repeat(np.arange(n_points, dtype=np.int64), np.diff(offsets))
    l12 = (loc & 0xFF) * m2 + ((loc >> 8) & 0xFF)
    c12, o12, e12, n12 = _lists(point, l12, m1 * m2, n_points, f12)
    c3, o3, a3, n3 = _lists(point, (loc >> 16) & 0xFF, m3, n_points, f3)
    c4, o4, b4, n4 = _lists(point, loc >> 24, m4, n_points, f4)
    code = (e12 | (a3 << 16) | (b4 << 24)).astype(np.uint32)
    need = (n12 | (n3 << 20) | (n4 << 40)).astype(np.uint64)

    order, pstart, opair, first = pair_groups(point, (loc >> 16) & 0xFF, loc >> 24, n_points)
    pab = (a3[order][first] | (b4[order][first] << 16)).astype(np.uint32)

    def widest(o: np.ndarray) -> int:
        return int(np.max(np.diff(o), initial=0))

    return CompactLayout(
        code, need, np.ascontiguousarray(np.asarray(values)[order]),
        e12[order].astype(np.uint16), pab, pstart.astype(np.int32), opair.astype(np.int32),
        (c12 // m2).astype(np.int32), (c12 % m2).astype(np.int32), o12.astype(np.int32),
        c3.astype(np.int32), o3.astype(np.int32), c4.astype(np.int32), o4.astype(np.int32),
        (widest(o12), widest(o3), widest(o4)),
    )  # fmt: skip


def channel_layout(ch: dict[str, np.ndarray]) -> CompactLayout:
    """:func:`compact_layout` of a runtime channel's arrays (``offsets``, ``locations``,
    ``dict1`` … ``dict4``, as :meth:`~sparsebtf.runtime.RuntimeBTF.arrays` names them)."""
    sizes = tuple(ch[f"dict{i}"].shape[2] for i in range(1, 5))
    return compact_layout(ch["offsets"], ch["locations"], ch["values"], sizes)
