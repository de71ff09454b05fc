"""Sparse coding of data points on an ensemble of orthonormal dictionaries (paper §3.3).

For a data point X and each dictionary k, the projection S_k = X ×_1 U1ᵀ … ×_N UNᵀ (Eq. 3) is
exact, so by Parseval the error of keeping a subset T of its entries is ‖X‖² − Σ_{t∈T} s_t²,
with no reconstruction. Coefficients are added by decreasing magnitude until the mean squared
residual (per tensor entry) is <= ε or the count reaches τ (the release's rule, see
``official-release-format.md`` §3 step 4). The **sparsest** dictionary wins; ties and the case
where every dictionary hits the cap go to the **least error**. A point whose energy is already
below ε keeps one coefficient, as in the release.

The same function codes training batches (τ = τ_l, ε = 0: every dictionary is capped, so the
membership is the least-error one, Eq. 2).

**Screening** (``candidates``, beyond the paper): exact projections on all K dictionaries cost
K × 1.47 GFLOP per point at 10×10×151×151, and most points use one or two dictionaries of
their material. :func:`screen_dictionaries` ranks the K dictionaries of each point by the same
rule applied to a *partial* projection — every spatial column, and the angular columns of
each angular mode that carry the most energy of the point's spatial mean, more for a larger τ
and more on the light mode than on the view mode (:func:`screen_columns`) — and only the best
``candidates`` are projected exactly (fewer where the first is ahead by more than
:data:`SCREEN_MARGIN`); the paper's rule then chooses among them. With ``candidates`` >= K
(or None) every dictionary is projected (the exhaustive rule, bit for bit).

**Nested levels** (issue 46). The rule is monotone in τ on a fixed candidate set: a
dictionary's count and error at τ' > τ are at most its own at τ, so the sparsest-then-least-
error choice at τ' errs no more than the one at τ. The levels of one call share one
candidate set (the union of every level's screening), so they are nested; separate calls
are nested with the exhaustive rule only, since the screening ranks the candidates by a
partial projection for the τ it is given and a call at τ' can miss the dictionary that won
at τ (``tests/test_nested_levels.py`` keeps a counterexample).

:class:`~.codes.SparseCodes` stores the result: per point its dictionary (membership m), its
count (z), and its values and multi-index locations **sorted by decreasing magnitude**, so a
renderer can truncate τ by reading a prefix; the count rule is :func:`~.codes.rule_keys`.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence

import numpy as np

from .._threads import parallel_map, thread_buffer
from ..errors import BTFInputError
from .codes import SparseCodes, coding_rule, count_and_error, rule_keys, topk_abs
from .objective import ChannelError, judged_code_levels
from .tensor import project_into, reconstruct_sparse, sum_squares

__all__ = [
    "DEFAULT_CANDIDATES",
    "SCREEN_ASPECT",
    "SCREEN_COLUMNS",
    "SCREEN_DEPTH",
    "SparseCodes",
    "coding_rule",
    "partial_flops",
    "reconstruct_points",
    "screen_columns",
    "screen_dictionaries",
    "sparse_code",
    "sparse_code_batches",
    "sparse_code_levels",
    "sparse_code_objective",
    "topk_abs",
]

#: Dictionaries projected exactly per point and channel after screening, by default (measured
#: in ``benchmarks/bench_screening.py``, docs/benchmarks.md).
DEFAULT_CANDIDATES = 2
#: Fewest angular columns per angular mode in the screening's partial projection, before the
#: light/view split of :data:`SCREEN_ASPECT` (16 missed the exhaustive choice of a felt point
#: at τ = 308, docs/benchmarks.md §14).
SCREEN_COLUMNS = 24
#: The partial projection holds at least this many coefficients per coefficient kept (τ): with
#: fewer (16 columns at τ = 885, 32 at τ = 4483) the ranking missed the exhaustive choice on
#: the benchmark's felt and wood (docs/benchmarks.md §14).
SCREEN_DEPTH = 64
#: Light columns per view column of the partial projection (r·a light, r/a view columns for
#: the r of :func:`screen_columns`: the same count of coefficients). The view mode is
#: contracted first, over the whole point, so its columns set most of the cost: 48 × 12
#: columns cost 0.62x the FLOPs of 24 × 24. On the quality benchmark's 14 unseen materials
#: (``benchmarks/bench_screen_split.py``, docs/benchmarks.md §14) the split kept the exhaustive
#: dictionary about as often: 8 misses of 378 choices at the default τ against 5, 4 of 1,512
#: at four levels coded at once against 0. With the margin below, every material's linear-RGB
#: MSE at each level stayed within +0.13 % of the exhaustive rule's
#: (``bench_screening.py --quality``).
SCREEN_ASPECT = 2.0
#: A candidate after the screening's first is dropped when its partial error is more than this
#: fraction above the first's at the same count. On the same 14 materials it spared 18 % of
#: the exact projections at the default τ (1.63 per point and channel, not 2) and added no
#: miss there, 2 of 1,512 at four levels (docs/benchmarks.md §14).
SCREEN_MARGIN = 0.1


def _partial_squares(x: np.ndarray, mats: Sequence[np.ndarray], columns: tuple[int, int]
                     ) -> np.ndarray:  # fmt: skip
    """(K, p1·p2·r3·r4) squared coefficients of one point x (p1, p2, L, V) on the K
    dictionaries ``mats`` (four stacked (K, m, m)), restricted on the light and view modes to
    the (r3, r4) = ``columns`` columns with the most energy in A_k = U3ᵀ X̄ U4 (X̄: x averaged
    over its texels).

    They are exact entries of S_k (Eq. 3). Cost per dictionary (p = 10, L = V = 151, r3 = 48,
    r4 = 12): 2(L²V + LV²) for A_k, 2p²LV·r4 for ×_4 over the whole point, 2p²L·r3·r4 for ×_3
    and 4p³·r3·r4 for the spatial modes: 88 MFLOP, 6.0 % of the exact 1.47 GFLOP (24 × 24
    columns: 143 MFLOP).
    """
    u1, u2, u3, u4 = mats
    p1, p2, n_l, n_v = x.shape
    k = u1.shape[0]
    r3, r4 = min(columns[0], n_l), min(columns[1], n_v)
    a = np.matmul(np.matmul(u3.transpose(0, 2, 1), x.mean(axis=(0, 1))), u4)  # (K, L, V)
    a *= a
    # stable: ties to the lower column, whatever the platform
    j3 = np.argsort(-a.sum(axis=2), axis=1, kind="stable")[:, :r3]
    j4 = np.argsort(-a.sum(axis=1), axis=1, kind="stable")[:, :r4]
    w3 = np.take_along_axis(u3, j3[:, None, :], axis=2)  # (K, L, r3)
    w4 = np.take_along_axis(u4, j4[:, None, :], axis=2)  # (K, V, r4)
    # ×_4 on every dictionary at once: one (p1·p2·L × V) @ (V × K·r4) GEMM, the bulk of the
    # cost (K stacked GEMMs of r4 columns each ran 1.7x slower)
    y = x.reshape(p1 * p2 * n_l, n_v) @ w4.transpose(1, 0, 2).reshape(n_v, k * r4)
    # ×_3 on the GEMM's output as it lies: each (L, r4) slice is a BLAS operand with leading
    # dimension K·r4, so no transposed copy of it is made (a copy cost twice the ×_3 itself)
    y = np.matmul(w3.transpose(0, 2, 1)[:, None],
                  y.reshape(p1 * p2, n_l, k, r4).transpose(2, 0, 1, 3))  # (K, p1·p2, r3, r4)
    y = np.matmul(u1.transpose(0, 2, 1), y.reshape(k, p1, p2 * r3 * r4))  # ×_1
    y = np.matmul(u2.transpose(0, 2, 1)[:, None], y.reshape(k, p1, p2, r3 * r4))  # ×_2
    return np.square(y.reshape(k, -1), dtype=np.float64)


#: Squares per block of :func:`_top_squares`' pre-filter.
_TOP_BLOCK = 32


def _top_squares(sq: np.ndarray, top: int) -> np.ndarray:
    """(K, top) the ``top`` largest entries of each row of ``sq`` (K, n), by decreasing value:
    what ``-np.sort(-np.partition(sq, n - top)[:, n - top:])`` gives, in about half its time.

    The rows' blocks of :data:`_TOP_BLOCK` entries each have a maximum; the ``top``-th largest
    of these maxima is ``top`` distinct entries' lower bound, so it bounds the row's ``top``-th
    largest entry from below and every entry above it survives the filter. The selection then
    runs on the few survivors (2–4 × ``top``) instead of the whole row (a partition of 8 ×
    57,600 squares took 4 ms, a third of a point's screening)."""
    k, n = sq.shape
    blocks = n // _TOP_BLOCK
    if blocks < top or top >= n:
        return -np.sort(-np.partition(sq, n - top, axis=1)[:, n - top :])
    maxima = sq[:, : blocks * _TOP_BLOCK].reshape(k, blocks, _TOP_BLOCK).max(axis=2)
    floor = np.partition(maxima, blocks - top, axis=1)[:, blocks - top]
    out = np.empty((k, top), dtype=sq.dtype)
    for i in range(k):
        kept = sq[i][sq[i] >= floor[i]]
        out[i] = np.partition(kept, kept.size - top)[kept.size - top :]
    return -np.sort(-out, axis=1)


def _partial_top(x: np.ndarray, mats: Sequence[np.ndarray], columns: tuple[int, int],
                 top: int) -> np.ndarray:  # fmt: skip
    """(K, min(top, n)) the largest squares of :func:`_partial_squares`, decreasing: what the
    screening ranks a point by."""
    sq = _partial_squares(x, mats, columns)
    return _top_squares(sq, min(top, sq.shape[1]))


#: Per worker thread: the two buffers :func:`~.tensor.project_into` writes a projection's
#: modes into and :func:`~.codes.topk_abs`'s scratch (3 × 9 MB at 10×10×151×151 float32),
#: kept from point to point.
_BUFFERS = threading.local()


def _buffers(size: int, dtype: np.dtype) -> list[np.ndarray]:
    return [thread_buffer(_BUFFERS, size, dtype, f"buf{i}") for i in range(3)]


def point_energies(batch: np.ndarray) -> np.ndarray:
    """(B,) float64 ‖X_b‖² of a batch of data points, the points on the worker threads
    (:func:`~sparsebtf.learning.tensor.sum_squares` row by row: the same values)."""
    b = batch.shape[0]
    rows = batch.reshape(b, -1)
    return np.array(list(parallel_map(lambda i: sum_squares(rows[i : i + 1])[0], range(b))),
                    dtype=np.float64).reshape(b)  # fmt: skip


def screen_columns(tau: int, spatial: int, n_light: int | None = None,
                   aspect: float | None = None) -> tuple[int, int]:
    """(light, view) columns (r3, r4) of the screening's partial projection for a cap τ on
    points of ``spatial`` = p1·p2 texels: r the smallest >= :data:`SCREEN_COLUMNS` with
    p1·p2·r² >= :data:`SCREEN_DEPTH` · τ, split r3 = ⌈a·r⌉, r4 = ⌈r/a⌉ by
    ``aspect`` a (default :data:`SCREEN_ASPECT`; 10×10 patches: 48 × 12 up to τ = 900,
    72 × 18 at τ = 2003, 108 × 27 at τ = 4483). With ``n_light`` light columns at most, r4
    grows so that r3·r4 >= r² still holds."""
    a = SCREEN_ASPECT if aspect is None else aspect
    r = max(SCREEN_COLUMNS, math.ceil(math.sqrt(SCREEN_DEPTH * tau / spatial)))
    r3 = math.ceil(a * r)
    if n_light is not None:
        r3 = min(r3, n_light)
    return r3, max(math.ceil(r / a), math.ceil(r * r / r3))


def partial_flops(shape: Sequence[int], columns: tuple[int, int]) -> int:
    """FLOPs of :func:`_partial_squares` per point and dictionary on points of ``shape``
    (p1, p2, L, V) and (r3, r4) = ``columns``: 2(L²V + LV²) + 2p1p2LV·r4 + 2p1p2L·r3·r4 +
    2(p1 + p2)p1p2·r3·r4."""
    p1, p2, n_l, n_v = (int(m) for m in shape)
    r3, r4 = min(columns[0], n_l), min(columns[1], n_v)
    return (2 * (n_l * n_l * n_v + n_l * n_v * n_v) + 2 * p1 * p2 * n_l * n_v * r4
            + 2 * p1 * p2 * n_l * r3 * r4 + 2 * (p1 + p2) * p1 * p2 * r3 * r4)  # fmt: skip


def _kept(sq: np.ndarray, energy: float, size: int, levels: Sequence[int], eps: float,
          candidates: int, margin: float) -> np.ndarray:  # fmt: skip
    """(K,) the dictionaries one point keeps, from its partial squares ``sq`` (K, n) by
    decreasing value (:func:`_top_squares`): at each level, the ``candidates`` best by the
    coding rule, less those whose partial error at the first's count is more than ``margin``
    above the first's."""
    keep = np.zeros(sq.shape[0], dtype=bool)
    for tau in levels:
        n, err = rule_keys(sq, energy, size, tau, eps)
        best = np.lexsort((err, n))[:candidates]
        if math.isinf(margin):
            keep[best] = True
            continue
        # a sparser first, or an error within the margin, leaves the choice open
        close = (n[best] != n[best[0]]) | (err[best] <= (1.0 + margin) * err[best[0]])
        keep[best[close]] = True
    return keep


def screen_dictionaries(
    batch: np.ndarray,
    dictionaries: Sequence[np.ndarray],
    taus: Sequence[int],
    eps: float,
    candidates: int,
    columns: tuple[int, int] | None = None,
    dtype: type = np.float32,
    energy: np.ndarray | None = None,
    margin: float | None = None,
) -> np.ndarray:
    """(B, K) mask of the dictionaries each point is projected on exactly: at every level τ of
    ``taus``, the ``candidates`` best by the coding rule (sparsest, then least error, ties to
    the lower k) applied to the partial projection of :func:`_partial_squares` on ``columns`` =
    (light, view) columns (default :func:`screen_columns` of the largest τ), less those whose
    partial error at the first's count is more than ``margin`` (:data:`SCREEN_MARGIN`) above
    the first's: the first is then kept alone.

    The partial coefficients are a subset of S_k's, so their count and residual bound the
    exact ones from above; the ranking they give is what matters. Only for 4D data points
    (p, p, L, V); other shapes get every dictionary.
    """
    x = np.ascontiguousarray(batch, dtype=dtype)
    b = x.shape[0]
    n_dict = dictionaries[0].shape[0]
    mask = np.zeros((b, n_dict), dtype=bool)
    if not _Screening.applies(x, candidates, n_dict):
        mask[:] = True
        return mask
    if energy is None:
        energy = point_energies(x)
    screen = _Screening(x, dictionaries, taus, eps, candidates, columns, margin)
    for i, keep in enumerate(parallel_map(lambda i: screen.keep(x[i], float(energy[i])),
                                          range(b))):  # fmt: skip
        mask[i] = keep
    return mask


class _Screening:
    """:func:`screen_dictionaries`' rule for the points of one batch ``x`` (B, p1, p2, L, V):
    its levels (the distinct τ clipped to the point size, increasing), the dictionaries in
    x's dtype, the columns (default :func:`screen_columns` of the largest τ) and the margin
    (default :data:`SCREEN_MARGIN`); :meth:`keep` screens one point."""

    def __init__(self, x: np.ndarray, dictionaries: Sequence[np.ndarray], taus: Sequence[int],
                 eps: float, candidates: int, columns: tuple[int, int] | None = None,
                 margin: float | None = None) -> None:  # fmt: skip
        self.size = int(np.prod(x.shape[1:]))
        self.levels = sorted({min(int(t), self.size) for t in taus})
        self.mats = [np.asarray(d, dtype=x.dtype) for d in dictionaries]
        self.columns = (screen_columns(self.levels[-1], x.shape[1] * x.shape[2], x.shape[3])
                        if columns is None else columns)  # fmt: skip
        self.margin = SCREEN_MARGIN if margin is None else margin
        self.eps, self.candidates = eps, candidates

    @staticmethod
    def applies(x: np.ndarray, candidates: int, n_dict: int) -> bool:
        """Screening is for batches of 4D points with fewer candidates than dictionaries."""
        return x.ndim == 5 and candidates < n_dict

    def keep(self, point: np.ndarray, energy: float) -> np.ndarray:
        """(K,) the dictionaries ``point`` (p1, p2, L, V) of energy ‖X‖² is projected on."""
        sq = _partial_top(point, self.mats, self.columns, self.levels[-1])
        return _kept(sq, energy, self.size, self.levels, self.eps, self.candidates,
                     self.margin)  # fmt: skip


def sparse_code(
    batch: np.ndarray,
    dictionaries: Sequence[np.ndarray],
    tau: int,
    eps: float = 0.0,
    dtype: type = np.float32,
    candidates: int | None = None,
    error: ChannelError | None = None,
) -> SparseCodes:
    """Code a batch of data points on an ensemble (Eq. 3 + the §3.3 selection rule).

    Parameters
    ----------
    batch : (B, m_1, …, m_N) data points.
    dictionaries : one array per mode, (K, m_n, m_n), orthonormal.
    tau : the sparsity cap τ (clipped to the tensor size).
    eps : error threshold ε on the mean squared residual per entry (0: always use τ).
    dtype : arithmetic of the projections (float32 is ~2× faster; energies stay float64).
    candidates : dictionaries projected exactly per point after screening
        (:func:`screen_dictionaries`); None or >= K: all of them (the exhaustive rule).
    error : None (the paper's rule on the standardised values), or the batch's error in a
        linear or display objective: the rule of :mod:`.objective` (ε in its units; the
        screening still ranks by the log rule).
    """
    return sparse_code_levels(batch, dictionaries, [tau], eps, dtype, candidates, error)[0]


def _checked(
    batch: np.ndarray, dictionaries: Sequence[np.ndarray], taus: Sequence[int], dtype: type
) -> tuple[np.ndarray, tuple[int, ...], list[int]]:
    """The batch checked against the ensemble and made contiguous in ``dtype``, its point
    shape and the levels clipped to the point size."""
    x = np.asarray(batch)
    shape = tuple(int(s) for s in x.shape[1:])
    if len(dictionaries) != len(shape):
        raise BTFInputError(
            f"data points have {len(shape)} modes but the ensemble has {len(dictionaries)}"
        )
    for n, (d, m) in enumerate(zip(dictionaries, shape, strict=True)):
        if d.ndim != 3 or d.shape[1:] != (m, m):
            raise BTFInputError(f"mode {n + 1}: dictionaries {d.shape} do not fit mode size {m}")
    if not taus or min(taus) < 1:
        raise BTFInputError(f"sparsity tau must be >= 1, got {list(taus)}")
    size = int(np.prod(shape))
    return np.ascontiguousarray(x, dtype=dtype), shape, [min(int(t), size) for t in taus]


def _prepare(
    batch: np.ndarray, dictionaries: Sequence[np.ndarray], taus: Sequence[int], eps: float,
    dtype: type, candidates: int | None,
) -> tuple[np.ndarray, tuple[int, ...], list[int], np.ndarray, np.ndarray]:  # fmt: skip
    """What the objective rules start from (:func:`_checked`), with the (B, K) mask of the
    dictionaries projected exactly (:func:`screen_dictionaries`) and the points' energies
    ‖X‖²."""
    xc, shape, levels = _checked(batch, dictionaries, taus, dtype)
    n_dict = dictionaries[0].shape[0]
    b = xc.shape[0]
    energy = point_energies(xc)
    rule, n_cand = coding_rule(candidates, n_dict)
    if rule == "exhaustive":
        mask = np.ones((b, n_dict), dtype=bool)
    else:
        mask = screen_dictionaries(xc, dictionaries, levels, eps, n_cand, dtype=dtype,
                                   energy=energy)
    return xc, shape, levels, mask, energy


#: One point's exact projections: (dictionary k, the indices of its ``max τ`` largest
#: coefficients by magnitude, their values), k increasing.
Projected = list[tuple[int, np.ndarray, np.ndarray]]


class _PointCoder:
    """Everything one data point of a batch needs on a worker thread, in one task: its
    energy, its screening (:class:`_Screening`) and the exact projections of
    the dictionaries kept, each with its top-τ selection. The values are those of
    :func:`point_energies`, :func:`screen_dictionaries` and the projections made after them,
    bit for bit; one task per point (and channel) leaves one wait per batch instead of three
    per channel (the energies, the screening and the projections each waited for the
    slowest point, behind the reader's tasks)."""

    def __init__(self, x: np.ndarray, dictionaries: Sequence[np.ndarray], levels: list[int],
                 eps: float, candidates: int | None) -> None:  # fmt: skip
        self.x, self.tmax = x, max(levels)
        self.n_dict = dictionaries[0].shape[0]
        rule, n_cand = coding_rule(candidates, self.n_dict)
        self.screen = (_Screening(x, dictionaries, levels, eps, n_cand)
                       if rule != "exhaustive" and _Screening.applies(x, n_cand, self.n_dict)
                       else None)  # fmt: skip
        self.mats_k = [[np.asarray(d[k], dtype=x.dtype) for d in dictionaries]
                       for k in range(self.n_dict)]  # fmt: skip

    def __call__(self, i: int) -> tuple[float, Projected]:
        x = self.x[i]
        energy = float(sum_squares(self.x[i : i + 1].reshape(1, -1))[0])
        keep = (np.arange(self.n_dict) if self.screen is None
                else np.flatnonzero(self.screen.keep(x, energy)))  # fmt: skip
        # :func:`project`'s values, into this thread's buffers: idx and s[idx] are copies
        buf = _buffers(x.size, x.dtype)
        out: Projected = []
        for k in keep:
            s = project_into(x[None], self.mats_k[k], buf[:2]).reshape(-1)
            idx = topk_abs(s, self.tmax, scratch=buf[2])
            out.append((int(k), idx, s[idx]))
        return energy, out


def _select(shape: tuple[int, ...], levels: list[int], eps: float, n_dict: int,
            points: list[tuple[float, Projected]]) -> list[SparseCodes]:  # fmt: skip
    """The paper's rule on each point's exact projections: per level, the sparsest
    dictionary, then the least error (ties to the lower k); dictionaries not projected lose
    every comparison."""
    size = int(np.prod(shape))
    b = len(points)
    nl = len(levels)
    counts = np.full((nl, b, n_dict), np.iinfo(np.int64).max, dtype=np.int64)
    errs = np.full((nl, b, n_dict), np.inf)
    best: list[list[tuple[tuple[int, float], np.ndarray, np.ndarray] | None]] = [
        [None] * b for _ in range(nl)
    ]
    for i, (energy, projected) in enumerate(points):
        for k, idx, vals in projected:
            sq = vals.astype(np.float64) ** 2
            for j, tau in enumerate(levels):
                n, e = count_and_error(sq, energy, size, tau, eps)
                counts[j, i, k], errs[j, i, k] = n, e
                key = (n, e)
                cur = best[j][i]
                # Sparsest first, then least error; strict comparison keeps the first on ties.
                if cur is None or key < cur[0]:
                    best[j][i] = (key, idx[:n], vals[:n])
    out = []
    for j in range(nl):
        member = np.array(
            [int(np.lexsort((errs[j, i], counts[j, i]))[0]) for i in range(b)], dtype=np.int64
        )
        chosen = [best[j][i] for i in range(b)]
        idx_all = (
            np.concatenate([c[1] for c in chosen])  # type: ignore[index]
            if b
            else np.empty(0, dtype=np.int64)
        )
        vals_all = (
            np.concatenate([c[2] for c in chosen]).astype(np.float32)  # type: ignore[index]
            if b
            else np.empty(0, np.float32)
        )
        locs = np.stack(np.unravel_index(idx_all, shape), axis=1).astype(np.int32)
        out.append(SparseCodes(shape, member, counts[j, np.arange(b), member], vals_all, locs,
                               errs[j, np.arange(b), member]))  # fmt: skip
    return out


def sparse_code_batches(
    batches: Sequence[np.ndarray],
    dictionaries: Sequence[Sequence[np.ndarray]],
    taus: Sequence[Sequence[int]],
    eps: float = 0.0,
    dtype: type = np.float32,
    candidates: int | None = None,
) -> list[list[SparseCodes]]:
    """:func:`sparse_code_levels` of several batches at once (a batch's Y, U and V on their
    own ensembles and levels): ``[batch][level]``, the same codes as one call per batch.
    Every point of every batch is one task on the worker threads (:class:`_PointCoder`),
    so the threads wait once for all of them."""
    if not len(batches) == len(dictionaries) == len(taus):
        raise BTFInputError(f"{len(batches)} batches, {len(dictionaries)} ensembles and "
                            f"{len(taus)} lists of levels: give one of each per batch")  # fmt: skip
    checked = [_checked(x, d, t, dtype) for x, d, t in zip(batches, dictionaries, taus,
                                                            strict=True)]  # fmt: skip
    coders = [_PointCoder(xc, d, levels, eps, candidates)
              for (xc, _, levels), d in zip(checked, dictionaries, strict=True)]  # fmt: skip
    work = [(c, i) for c, (xc, _, _) in enumerate(checked) for i in range(xc.shape[0])]
    done = list(parallel_map(lambda ci: coders[ci[0]](ci[1]), work))
    out, at = [], 0
    for (xc, shape, levels), coder in zip(checked, coders, strict=True):
        b = xc.shape[0]
        out.append(_select(shape, levels, eps, coder.n_dict, done[at : at + b]))
        at += b
    return out


def sparse_code_levels(
    batch: np.ndarray,
    dictionaries: Sequence[np.ndarray],
    taus: Sequence[int],
    eps: float = 0.0,
    dtype: type = np.float32,
    candidates: int | None = None,
    error: ChannelError | None = None,
) -> list[SparseCodes]:
    """:func:`sparse_code` at several caps τ from one projection per (point, dictionary).

    The projections do not depend on τ, so a quality–storage curve costs one encoding.
    Returns one :class:`SparseCodes` per τ, identical to separate :func:`sparse_code` calls
    (with screening, a point's candidates are the union of every level's best ``candidates``,
    so they may differ from a single level's). The levels are **nested**: every level
    judges the same candidates, and a larger τ can keep whatever a smaller one chose, so no
    point's error at a larger τ is above its error at a smaller one (under the log rule its
    Parseval error; with ``error`` (:func:`sparse_code`) its error in that objective,
    :func:`~.objective.judged_code_levels`). Separate calls are nested with the exhaustive
    rule (``candidates`` None or >= K) under the log rule, not with screening, whose
    candidates are ranked for the call's own levels (issue 46).
    """
    if error is not None:
        xc, _, levels, mask, energy = _prepare(batch, dictionaries, taus, eps, dtype,
                                               candidates)  # fmt: skip
        return _judged(xc, error, dictionaries, levels, eps, dtype, mask, energy)[0]
    return sparse_code_batches([batch], [dictionaries], [taus], eps, dtype, candidates)[0]


def _judged(x: np.ndarray, error: ChannelError, dictionaries: Sequence[np.ndarray],
            levels: list[int], eps: float, dtype: type, mask: np.ndarray, energy: np.ndarray
            ) -> tuple[list[SparseCodes], list[SparseCodes]]:  # fmt: skip
    """:func:`sparse_code_levels` judged by a linear or display objective (:mod:`.objective`),
    and the log rule's codes from the same projections: (judged, log), one per level."""
    if error.log_rgb.shape[:-1] != x.shape:
        raise BTFInputError(f"the objective's values {error.log_rgb.shape} do not match the "
                            f"batch {x.shape}")  # fmt: skip
    shape = tuple(int(s) for s in x.shape[1:])
    judged, log = judged_code_levels(x, dictionaries, levels, eps, dtype, mask, error, energy)

    def codes(member, counts, vals, idx, errs) -> SparseCodes:  # type: ignore[no-untyped-def]
        locs = np.stack(np.unravel_index(idx, shape), axis=1).astype(np.int32)
        return SparseCodes(shape, member, counts, vals, locs, errs)

    return [codes(*j) for j in judged], [codes(*g) for g in log]


def sparse_code_objective(
    batch: np.ndarray, dictionaries: Sequence[np.ndarray], taus: Sequence[int], eps: float,
    dtype: type, candidates: int | None, error: ChannelError,
) -> tuple[list[SparseCodes], list[SparseCodes]]:  # fmt: skip
    """:func:`sparse_code_levels` with ``error`` (a linear or display objective), together
    with the paper's rule's codes of the same projections (the alternative a caller may
    compare the three channels' joint error against, :func:`~.objective.joint_choice`):
    (judged codes, log-rule codes), one per τ each."""
    xc, _, levels, mask, energy = _prepare(batch, dictionaries, taus, eps, dtype, candidates)
    return _judged(xc, error, dictionaries, levels, eps, dtype, mask, energy)


def reconstruct_points(
    codes: SparseCodes,
    dictionaries: Sequence[np.ndarray],
    points: Sequence[int] | np.ndarray | None = None,
    dtype: type = np.float64,
    rows: Sequence[np.ndarray | None] | None = None,
) -> np.ndarray:
    """Eq. 4 for chosen points: X = Ŝ ×_1 U1 ×_2 U2 … on each point's own dictionary.

    Returns (n, m_1, …, m_N) in the coded domain. ``rows`` restricts modes to some of their
    entries (e.g. a few lights and views: ``[None, None, lights, views]``), multiplying by those
    rows of U_n only; the output then has ``len(rows[n])`` entries on mode n.
    """
    idx = np.arange(codes.n_points) if points is None else np.asarray(points, dtype=np.int64)
    rows = list(rows) if rows is not None else [None] * len(dictionaries)
    sizes = [m if r is None else len(r) for m, r in zip(codes.mode_sizes, rows, strict=True)]
    out = np.empty((idx.size, *sizes), dtype=dtype)

    def task(j: int) -> None:
        i = int(idx[j])
        loc, val = codes.point(i)
        k = int(codes.membership[i])
        mats = [
            np.asarray(d[k] if r is None else d[k][r], dtype=dtype)
            for d, r in zip(dictionaries, rows, strict=True)
        ]
        out[j] = reconstruct_sparse(loc, val.astype(dtype, copy=False), mats)

    for _ in parallel_map(task, range(idx.size)):
        pass
    return out
