"""The map and reduce steps of one training iteration (paper §3.2, Eq. 2), free of hidden state.

An iteration of :class:`~sparsebtf.learning.ensemble.DictionaryEnsemble` updates the modes one
at a time (Gauss–Seidel), each by orthogonal Procrustes on

    Z⁽ⁿ'ᵏ⁾ = Σ_{i∈C_k} [P_i]_(n) [Ŝ_i]_(n)ᵀ,   P_i = X_i ×_{q≠n} U_qᵀ          (1)
           = Σ_{i∈C_k} [X_i]_(n) [Ŝ_i ×_{q≠n} U_q]_(n)ᵀ                         (2)

(``shared/specs/training-algorithm.md`` §4: tr(UᵀZ) is the only term of ‖X − Ŝ ×_q U_q‖² that
depends on U = U_n, so U_n = ΓΘᵀ for Z = ΓΣΘᵀ; (1) = (2) by the adjointness of ×_q U_qᵀ and
×_q U_q). Ŝ_i holds τ_l coefficients v_s at multi-indices l(s), so column j of Z only needs
the mode-n fibres of P_i at the τ_l coefficients with l_n(s) = j:

    Z⁽ⁿ⁾[:, j] = Σ_{s: l_n(s)=j} v_s f_s,   f_s = X_i ×_{q≠n} U_q[:, l_q(s)]ᵀ          (3)

which :func:`mode_fibres` builds without forming P_i: the small (spatial) modes are
contracted in full (2·L·m_q FLOP each, m_q = 10), the big (angular) ones one column per
coefficient. For a 10×10×151×151 point that is about 0.1 GFLOP per mode instead of 0.8–1.4
for the dense partial projection (:func:`cross_products`, kept as the reference).

Two modes per iteration cost nothing extra: the coding step projects in
:func:`~sparsebtf.learning.tensor.projection_order` and its last two modes a, b (the spatial
ones) pass through A = X ×_{q∉{a,b}} U_qᵀ and P⁽ᵇ⁾ = A ×_a U_aᵀ. From those the coding step
returns Z⁽ᵇ⁾ by (3) and the pair tensor

    H⁽ᵃ⁾[α, β, j, m] = Σ_{s: l_a(s)=j, l_b(s)=m} v_s A[α, β, l_{q∉{a,b}}(s)]           (4)

from which, once U_b is updated, Z⁽ᵃ⁾[α, j] = Σ_{β,m} U_b[β, m] H⁽ᵃ⁾[α, β, j, m]
(:func:`pair_cross_products`): exactly (1) with the new U_b, so Gauss–Seidel holds.

Map steps (pure functions of one batch of points, the dictionaries and that batch's codes;
they can run on remote workers): :func:`code_step`, :func:`sparse_cross_products`,
:func:`cross_products`. Reduce steps (sums over batches, then small dense algebra):
:meth:`BatchCoding.combine`, :func:`pair_cross_products`, :func:`procrustes`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .._threads import parallel_map
from ..errors import BTFInputError
from .codes import SparseCodes, count_and_error, topk_abs
from .tensor import project, project_modes, projection_order, sum_squares

__all__ = [
    "PAIR_MAX_ENTRIES",
    "BatchCoding",
    "code_step",
    "cross_products",
    "mode_fibres",
    "pair_cross_products",
    "pair_modes",
    "procrustes",
    "sparse_cross_products",
]

#: The pair tensor H⁽ᵃ⁾ of (4) is built when (m_a·m_b)² stays under this many entries.
PAIR_MAX_ENTRIES = 2**20


def procrustes(z: np.ndarray) -> np.ndarray:
    """Orthogonal Procrustes: the orthogonal U maximising tr(UᵀZ), U = ΓΘᵀ for Z = ΓΣΘᵀ."""
    u, _, vt = np.linalg.svd(z)
    return u @ vt


def pair_modes(mode_sizes: Sequence[int]) -> tuple[int, int | None]:
    """(b, a): the last two modes of the projection order. The coding step yields Z⁽ᵇ⁾, and
    H⁽ᵃ⁾ when it is small enough (else a is None and mode a needs its own pass)."""
    order = projection_order(mode_sizes)
    b = order[-1]
    if len(order) < 2:
        return b, None
    a = order[-2]
    small = (int(mode_sizes[a]) * int(mode_sizes[b])) ** 2 <= PAIR_MAX_ENTRIES
    return b, a if small else None


def _coefficient_matrix(cols: np.ndarray, values: np.ndarray, width: int) -> np.ndarray:
    """E (τ, width) with E[s, cols[s]] = v_s: Σ_s v_s f_s e_{cols[s]}ᵀ = Fᵀ E as one GEMM.

    Built by comparison and ``where`` (no in-place scatter: array-API backends have none)."""
    hit = cols[:, None] == np.arange(width)[None, :]
    return np.where(hit, np.asarray(values, dtype=np.float64)[:, None], 0.0)


@dataclass(eq=False)
class BatchCoding:
    """Result of the coding map step on a batch (or, combined, on the whole set).

    Attributes
    ----------
    codes : the codes of the winning dictionary of every point.
    ranking : (P, c) the dictionaries tried for each point, best first by the coding rule
        (fewest coefficients, then least error; ties to the lower index), padded with -1.
    z_last : (K, m_b, m_b) float64, Z⁽ᵇ⁾ of (3) summed over the batch's winners (b: the
        projection's last mode), or None.
    pair : (K, m_a, m_b, m_a, m_b) float64, H⁽ᵃ⁾ of (4), or None.
    """

    codes: SparseCodes
    ranking: np.ndarray
    z_last: np.ndarray | None
    pair: np.ndarray | None

    @staticmethod
    def combine(parts: Sequence[BatchCoding]) -> BatchCoding:
        """Reduce: concatenate codes and rankings of consecutive batches, sum Z⁽ᵇ⁾ and H⁽ᵃ⁾."""
        if not parts:
            raise BTFInputError("nothing to combine")
        width = max(p.ranking.shape[1] for p in parts)
        ranking = np.concatenate([
            np.pad(p.ranking, ((0, 0), (0, width - p.ranking.shape[1])), constant_values=-1)
            for p in parts
        ])  # fmt: skip
        z = None if parts[0].z_last is None else sum(p.z_last for p in parts)  # type: ignore[misc]
        h = None if parts[0].pair is None else sum(p.pair for p in parts)  # type: ignore[misc]
        return BatchCoding(SparseCodes.concatenate([p.codes for p in parts]), ranking, z, h)


def _at_coefficients(t: np.ndarray, loc: np.ndarray, keep: tuple[int, ...]) -> np.ndarray:
    """(τ, m_keep…) float64: t at each coefficient's indices on every mode but ``keep``."""
    rest = tuple(loc[:, q] for q in range(t.ndim) if q not in keep)
    moved = np.moveaxis(t, keep, tuple(range(-len(keep), 0)))
    if not rest:
        return np.broadcast_to(moved, (loc.shape[0], *moved.shape)).astype(np.float64)
    return moved[rest].astype(np.float64)


def code_step(
    batch: np.ndarray,
    dictionaries: Sequence[np.ndarray],
    tau: int,
    eps: float = 0.0,
    dtype: type = np.float32,
    candidates: np.ndarray | None = None,
    sums: BatchCoding | None = None,
) -> BatchCoding:
    """Map step 1: sparse coding and membership of one batch (Eq. 3, hard thresholding).

    ``candidates`` (B, c) lists the dictionaries tried for each point (None: all K, the
    exhaustive step); the point goes to the best of them by the §3.3 rule (with ε = 0: least
    error at τ). The codes equal :func:`~sparsebtf.learning.coding.sparse_code`'s when every
    dictionary is tried (same projections, same rule). Also returns the by-products Z⁽ᵇ⁾ and
    H⁽ᵃ⁾ of the winners (module docstring, (3) and (4)), added point by point to those of
    ``sums`` when given (in place: a stream of batches then sums in one fixed order, however
    it is cut into batches), else to zeros.
    """
    x = np.asarray(batch)
    shape = tuple(int(s) for s in x.shape[1:])
    n_dict = dictionaries[0].shape[0]
    b_count = x.shape[0]
    if candidates is None:
        rows = [np.arange(n_dict)] * b_count
    else:
        cand = np.asarray(candidates, dtype=np.int64)
        if cand.ndim != 2 or cand.shape[0] != b_count or cand.min() < 0 or cand.max() >= n_dict:
            raise BTFInputError(
                f"candidates {cand.shape} must list dictionaries in [0, {n_dict}) per point"
            )
        rows = [np.unique(c) for c in cand]  # sorted: ties go to the lowest index
    size = int(np.prod(shape))
    tau = min(int(tau), size)
    order = projection_order(shape)
    mode_b, mode_a = pair_modes(shape)
    xc = np.ascontiguousarray(x, dtype=dtype)
    energy = sum_squares(xc.reshape(b_count, -1))
    mats_k = [[np.asarray(d[k], dtype=dtype) for d in dictionaries] for k in range(n_dict)]
    m_b = shape[mode_b]
    m_a = shape[mode_a] if mode_a is not None else 0

    def task(ik: tuple[int, int]) -> tuple:
        i, k = ik
        if mode_a is None:
            inner = project_modes(xc[i : i + 1], mats_k[k], order[:-1])[0]
            outer = None
        else:
            outer = project_modes(xc[i : i + 1], mats_k[k], order[:-2])
            inner = project_modes(outer, mats_k[k], [mode_a])[0]
            outer = outer[0]
        s = project_modes(inner[None], mats_k[k], [mode_b]).reshape(-1)
        idx = topk_abs(s, tau)
        vals = s[idx]
        n, err = count_and_error(vals.astype(np.float64) ** 2, energy[i], size, tau, eps)
        idx, vals = idx[:n], vals[:n]
        loc = np.stack(np.unravel_index(idx, shape), axis=1)
        # The values as the codes store them (float32), as the update passes will read them.
        v64 = vals.astype(np.float32).astype(np.float64)
        # (3) for mode b: fibres of P⁽ᵇ⁾ along b at the other indices of each coefficient.
        fib = _at_coefficients(inner, loc, (mode_b,))
        z = fib.T @ _coefficient_matrix(loc[:, mode_b], v64, m_b)
        h = None
        if mode_a is not None and outer is not None:
            # (4): the (m_a, m_b) slices of A at the other indices of each coefficient.
            g = _at_coefficients(outer, loc, (mode_a, mode_b))
            cols = loc[:, mode_a] * m_b + loc[:, mode_b]
            h = g.reshape(n, m_a * m_b).T @ _coefficient_matrix(cols, v64, m_a * m_b)
        return n, err, idx, vals, z, h

    pairs = [(i, int(k)) for i in range(b_count) for k in rows[i]]
    results = dict(zip(pairs, parallel_map(task, pairs), strict=True))
    member = np.empty(b_count, dtype=np.int64)
    ranking = np.full((b_count, max((r.size for r in rows), default=0)), -1, dtype=np.int64)
    counts = np.empty(b_count, dtype=np.int64)
    errors = np.empty(b_count)
    if sums is not None and sums.z_last is not None:
        z_last, pair = sums.z_last, sums.pair
    else:
        z_last = np.zeros((n_dict, m_b, m_b))
        pair = np.zeros((n_dict, m_a, m_b, m_a, m_b)) if mode_a is not None else None
    idx_parts, val_parts = [], []
    for i in range(b_count):
        tried = [results[(i, int(k))] for k in rows[i]]
        rank = np.lexsort(([r[1] for r in tried], [r[0] for r in tried]))
        ranking[i, : rank.size] = rows[i][rank]
        best = tried[rank[0]]
        k = int(ranking[i, 0])
        member[i], counts[i], errors[i] = k, best[0], best[1]
        idx_parts.append(best[2])
        val_parts.append(best[3])
        z_last[k] += best[4]
        if pair is not None:
            pair[k] += best[5].reshape(m_a, m_b, m_a, m_b)
    idx_all = np.concatenate(idx_parts) if idx_parts else np.empty(0, dtype=np.int64)
    vals_all = (
        np.concatenate(val_parts).astype(np.float32) if val_parts else np.empty(0, np.float32)
    )
    locs = np.stack(np.unravel_index(idx_all, shape), axis=1).astype(np.int32)
    codes = SparseCodes(shape, member, counts, vals_all, locs, errors)
    return BatchCoding(codes, ranking, z_last, pair)


def pair_cross_products(pair: np.ndarray, u_b: np.ndarray) -> np.ndarray:
    """Reduce: Z⁽ᵃ⁾[α, j] = Σ_{β,m} U_b[β, m] H⁽ᵃ⁾[α, β, j, m] for the updated U_b (one k)."""
    return np.tensordot(pair, u_b, axes=([1, 3], [0, 1]))


def mode_fibres(
    point: np.ndarray, mats: Sequence[np.ndarray], locations: np.ndarray, mode: int
) -> np.ndarray:
    """F (τ, m_n): F[s] = X ×_{q≠n} U_q[:, l_q(s)]ᵀ, the mode-n fibre of P = X ×_{q≠n} U_qᵀ
    at the other indices of coefficient s ((3) of the module docstring).

    ``point`` is one data point (m_1, …, m_N); ``mats`` its dictionary's bases. Each other mode
    q is contracted with only the columns U_q[:, A_q] its coefficients use (A_q: the distinct
    l_q(s)), the most selective first; then F is a gather. Trained codes concentrate on a few
    angular columns (|A_q| ≈ 10–20 of 151 at τ_l = 256), so this costs about 2·L·|A_q| FLOP
    for the first big mode and little after it.
    """
    loc = np.asarray(locations, dtype=np.int64)
    shape = point.shape
    others = [q for q in range(len(shape)) if q != mode]
    cols, pos = {}, {}
    for q in others:
        cols[q], pos[q] = np.unique(loc[:, q], return_inverse=True)
    sub = [mats[q][:, cols[q]] if q in cols else mats[q] for q in range(len(shape))]
    order = sorted(others, key=lambda q: cols[q].size / shape[q])
    t = np.moveaxis(project_modes(point[None], sub, order)[0], mode, -1)
    if not others:
        return np.broadcast_to(t, (loc.shape[0], shape[mode])).astype(np.float64)
    return t[tuple(pos[q] for q in others)].astype(np.float64)


def _dense_fibres(
    point: np.ndarray, mats: Sequence[np.ndarray], locations: np.ndarray, mode: int
) -> np.ndarray:
    """:func:`mode_fibres` the long way: gathered from the dense partial projection (1)."""
    p = np.moveaxis(project(point[None], mats, skip=mode)[0], mode, -1)
    return p[tuple(locations[:, q] for q in range(locations.shape[1]) if q != mode)].astype(
        np.float64
    )


def _cross_products(
    batch: np.ndarray,
    codes: SparseCodes,
    dictionaries: Sequence[np.ndarray],
    mode: int,
    dtype: type,
    fibres: Callable[[np.ndarray, Sequence[np.ndarray], np.ndarray, int], np.ndarray],
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Σ over the batch of Z⁽ⁿ'ᵏ⁾[:, l_n(s)] += v_s f_s (one GEMM per point), per k, added
    point by point to ``out`` when given (in place), else to zeros."""
    n_dict = dictionaries[0].shape[0]
    m = dictionaries[mode].shape[1]
    z = np.zeros((n_dict, m, m)) if out is None else out
    offsets = codes.offsets

    def task(b: int) -> tuple[int, np.ndarray] | None:
        k = int(codes.membership[b])
        lo, hi = offsets[b], offsets[b + 1]
        if hi == lo:
            return None
        mats = [np.asarray(d[k], dtype=dtype) for d in dictionaries]
        loc = codes.locations[lo:hi]
        f = fibres(np.asarray(batch[b], dtype=dtype), mats, loc, mode)
        e = _coefficient_matrix(loc[:, mode], codes.values[lo:hi].astype(np.float64), m)
        return k, f.T @ e

    for res in parallel_map(task, range(batch.shape[0])):
        if res is not None:
            z[res[0]] += res[1]
    return z


def sparse_cross_products(
    batch: np.ndarray,
    codes: SparseCodes,
    dictionaries: Sequence[np.ndarray],
    mode: int,
    dtype: type = np.float32,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Map step 2: this batch's share of Z⁽ⁿ'ᵏ⁾ for every k, shape (K, m_n, m_n), float64,
    by (3) from each point's τ coefficients (:func:`mode_fibres`; equals :func:`cross_products`).
    ``out``: add to it, point by point, in place.
    """
    return _cross_products(batch, codes, dictionaries, mode, dtype, mode_fibres, out)


def cross_products(
    batch: np.ndarray,
    codes: SparseCodes,
    dictionaries: Sequence[np.ndarray],
    mode: int,
    dtype: type = np.float32,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Map step 2, reference: Z⁽ⁿ'ᵏ⁾ by (1) from the dense partial projection of every point
    (0.8–1.4 GFLOP per 10×10×151×151 point; :func:`sparse_cross_products` gives the same Z
    for about a tenth of that)."""
    return _cross_products(batch, codes, dictionaries, mode, dtype, _dense_fibres, out)
