"""Coding objectives: which error the sparse coder minimises (beyond the paper's §3.3).

``"log"`` (default, the paper's and the release's rule): the squared error of the
standardised log-YUV data point, exact by Parseval (:func:`~.coding.sparse_code_levels`).

``"linear"`` and ``"display"``: the error of what a renderer integrates, linear RGB, or of
the paper's display mapping f(I) = min(a·I^(1/γ), 1) (a = 1.3, γ = 1.8). A standardised
residual δ at entry e = (texel, light, view) of channel c (angular image j) moves
ln(RGB_r + ε) by YUV_TO_RGB[r, c]·σ_{j,c}·δ; the decoder clamps that to the angular image's
bound b_j (:meth:`~sparsebtf.points.preprocessing.Standardization.clamp_log_rgb`). The
channel's error is computed **exactly** from the residual, the other two channels taken as
exact (they are coded apart)::

    E_c = 1/(3n) Σ_e Σ_r ( g(min(y_er + YUV_TO_RGB[r, c]·σ_{j,c}·δ_e, b_j)) − g(y_er) )²
    y = ln(RGB + ε),  g(y) = exp(y) − ε (linear) or f(exp(y) − ε) (display)

(:class:`ChannelError`; n entries per point: the mean over values, R, G, B apart).

Why not a weighted Parseval rule. The first-order weight of δ², σ²·Σ_r YUV_TO_RGB[r, c]²·
(RGB_r + ε)², ranks a glossy metal's coefficients badly: its log residuals reach several
units (a shadowed texel next to a highlight), where e^δ is far from 1 + δ. Measured on a
captured bumpy copper at τ = 885/64/64 (linear-RGB MSE of the decoded BTF; log rule 1.235):
keeping the coefficients of largest weighted energy S_t²·Σ_e W_e u_t(e)², 1.236; by their
first-order gain S_t(2⟨W X, u_t⟩ − S_t Σ W u_t²), 6.06; refitting the kept values by five
conjugate-gradient steps of weighted least squares, 13.9 ("Coding
objectives", docs/benchmarks.md §17).

The rule, in three steps. (1) Per channel (:func:`judged_code_levels`): each candidate
dictionary's coefficients in the log rule's order (decreasing |S_t|, the order a
level-of-detail prefix reads), evaluated by E_c at the prefix lengths τ and ⌈τ/2⌉ of every
level, and with ε > 0 also 1, 2, 4, … (the grid, :func:`prefix_grid`). At each level τ the
code is the (dictionary, prefix length n <= τ) of least E_c; with ε > 0 the smallest n with
E_c <= ε (then least error) when one exists. The log rule's codes come from the same
projections. (2) Per point and level (:func:`joint_choice`): the joint error E of the three
channels' residuals at once (E_c with every channel's δ) of the judged codes against the log
rule's; the lower is kept, and in increasing τ a level keeps a lower level's codes where those
have the lower E. (3) Level of detail (:func:`walk_order`): a renderer truncates a point's
codes to their first k coefficients, and in the magnitude order a prefix's error in these
objectives can rise with k (a highlight overshot before the coefficient that corrects it). So each
(point, dictionary) chosen at some level is walked in the magnitude order, keeping a
coefficient only if it lowers E_c; one that does not is set aside, and after each coefficient
kept the largest set aside is tried again (then all of them, twice at most, once the pool is
spent).
Every level's judged code is the walk's first τ and the log rule's code its first n (those
are the codes (2) compares). The file keeps that order (``rank``, docs/format.md §3). So for
**every point and channel the error E_c of the first k stored coefficients falls with k**,
and no point's joint E at a level is above its E at a lower level of the same call
(:func:`~sparsebtf.codec.encode_levels`; separate calls judge other lengths) nor above the
log rule's code in the walk's order. The log rule's code as it is (magnitude order, every
coefficient) is no longer a candidate, so being below it is measured, not built in: on the
highlight material of tests/test_objective.py no point is above it at any level (a walk that
set coefficients aside for good was up to 3× above it at τ = 64). ``log`` keeps the
magnitude order.

Cost per point and candidate dictionary (10×10 texels × 151 × 151, n = 2.28 M entries): the
log rule's projection (1.47 GFLOP), one sparse reconstruction of τ_max coefficients split at
the grid and per grid length one evaluation of E_c (~20 flops, one exp per value and R, G, B:
~140 M flops and 7 M exp); then per point and chosen dictionary the walk: one rank-1 tensor
and one evaluation of E_c per coefficient tried (τ_max plus the retries: ~50–70 ms each on
a full-size point, so ~1 min per point at τ = 885 and ~5 min at 4483); per point and level
2 × 3 sparse reconstructions and two joint evaluations.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .._semantic import stored_dtype
from .._threads import parallel_map
from ..errors import BTFInputError
from .codes import SparseCodes, rule_keys, topk_abs
from .tensor import project, reconstruct_sparse

__all__ = [
    "DISPLAY_A",
    "DISPLAY_GAMMA",
    "OBJECTIVES",
    "ChannelError",
    "check_objective",
    "joint_choice",
    "judged_code_levels",
    "objective_params",
    "prefix_grid",
    "stored_precision",
    "walk_order",
    "walk_pool",
]

#: One level's codes: membership, counts, values, flat indices, errors.
Codes = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
#: The coding objectives: "log" (the paper's rule, default), "linear", "display".
OBJECTIVES = ("log", "linear", "display")
#: The paper's display mapping a·I^(1/γ) (:func:`sparsebtf.display.tone_map`).
DISPLAY_A, DISPLAY_GAMMA = 1.3, 1.8


def check_objective(objective: object) -> str:
    """The objective's name, or one :class:`BTFInputError` naming the known ones."""
    if not isinstance(objective, str) or objective not in OBJECTIVES:
        raise BTFInputError(
            f"unknown coding objective {objective!r}; choose one of {', '.join(OBJECTIVES)}"
        )
    return objective


def objective_params(objective: str) -> dict[str, str]:
    """The coded file's record of the objective (docs/format.md): ``{"objective": name}``
    for "linear" or "display"; nothing for "log", so that its files stay as before (files
    without the record read as "log")."""
    return {} if objective == "log" else {"objective": objective}


def _display(v: np.ndarray) -> np.ndarray:
    """f(I) = min(a·max(I, 0)^(1/γ), 1), float32."""
    out = np.power(np.maximum(v, 0, dtype=np.float32), np.float32(1 / DISPLAY_GAMMA))
    out *= np.float32(DISPLAY_A)
    return np.minimum(out, 1, out=out)


@dataclass(frozen=True)
class ChannelError:
    """E_c of the module docstring for one channel of a batch of points.

    ``log_rgb`` (B, p, p, L, V, 3) float32: ln(RGB + log_offset) of the points; ``scale``
    (L, V, 3): YUV_TO_RGB[r, c]·σ_{j,c}; ``bound`` (L, V) or None.
    """

    objective: str
    log_rgb: np.ndarray
    scale: np.ndarray
    bound: np.ndarray | None
    log_offset: float

    @classmethod
    def for_batch(cls, objective: str, log_rgb: np.ndarray, std: np.ndarray,
                  bound: np.ndarray | None, log_offset: float, channel: int
                  ) -> ChannelError:  # fmt: skip
        """From the statistics: σ (L, V, 1 or 3) and the channel's index (0: Y, 1: U, 2: V)."""
        from ..colour import YUV_TO_RGB

        sd = np.broadcast_to(std, (*std.shape[:2], 3))[..., channel]
        scale = (sd[..., None] * YUV_TO_RGB[:, channel]).astype(np.float32)
        b = None if bound is None else np.asarray(bound, dtype=np.float32)
        return cls(objective, log_rgb, scale, b, float(log_offset))

    def sum64(self, i: int, delta: np.ndarray, ref: np.ndarray) -> float:
        """:meth:`__call__` summed in float64 (the walk compares errors that differ by
        little; a float32 dot of millions of values is off by ~1e-5 relative)."""
        y = np.multiply(np.asarray(delta, dtype=np.float32)[..., None], self.scale)
        y += self.log_rgb[i]
        if self.bound is not None:
            np.minimum(y, self.bound[..., None], out=y)
        d = self._value(y)
        d -= ref
        return float(np.einsum("i,i->", d.reshape(-1), d.reshape(-1), dtype=np.float64)) / d.size

    def _value(self, y: np.ndarray) -> np.ndarray:
        v = np.exp(y)
        v -= np.float32(self.log_offset)
        return _display(v) if self.objective == "display" else v

    def reference(self, i: int) -> np.ndarray:
        """g(y) of point ``i``: its true linear RGB (or display value)."""
        return self._value(self.log_rgb[i])

    def __call__(self, i: int, delta: np.ndarray, ref: np.ndarray | None = None) -> float:
        """E_c of point ``i`` for the standardised residual ``delta`` (p, p, L, V) of the
        decoded minus the true values; ``ref``: :meth:`reference` of the point, if at hand."""
        y = np.multiply(np.asarray(delta, dtype=np.float32)[..., None], self.scale)
        y += self.log_rgb[i]
        if self.bound is not None:
            np.minimum(y, self.bound[..., None], out=y)
        d = self._value(y)
        d -= self.reference(i) if ref is None else ref
        flat = d.reshape(-1)
        return float(np.dot(flat, flat)) / flat.size


def prefix_grid(levels: Sequence[int], eps: float = 0.0) -> list[int]:
    """The prefix lengths E_c is evaluated at (increasing, distinct): every level τ and its
    half ⌈τ/2⌉; with ε > 0 also 1, 2, 4, … below the largest level (the ε rule looks for the
    fewest coefficients that meet ε)."""
    top = max(levels)
    lengths = {int(t) for t in levels} | {-(-int(t) // 2) for t in levels}
    if eps > 0:
        lengths |= {1 << g for g in range(math.ceil(math.log2(top)) + 1) if 1 << g < top}
    return sorted(lengths)

#: A coefficient joins a point's level-of-detail order only if it lowers the error by at
#: least this fraction: a decoder sums in another order and precision, so a tie must not
#: read as a rise.
WALK_MARGIN = 1e-6
#: Passes of :func:`walk_order` over the coefficients it set aside.
WALK_PASSES = 2
#: After each coefficient kept, :func:`walk_order` retries this many of those set aside
#: (measured on the highlight material of tests/test_objective.py: 1 reaches the codes of 4
#: with 21 % fewer evaluations; 0, no retries, was up to 3.3× above the log rule's code).
WALK_RETRY = 1


def stored_precision(values: np.ndarray) -> np.ndarray:
    """``values`` rounded as a coded file stores them (binary16, or float32 when one
    overflows it: :func:`~sparsebtf._semantic.stored_dtype`), as float32: the walk judges
    the very values the file keeps."""
    v = np.asarray(values, dtype=np.float32)
    return v.astype(stored_dtype(v)).astype(np.float32)


def walk_order(error: ChannelError, i: int, x: np.ndarray, loc: np.ndarray,
               values: np.ndarray, mats: Sequence[np.ndarray], cap: int,
               passes: int = WALK_PASSES) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The level-of-detail order of point ``i``'s coefficients under ``error``.

    ``loc`` (n, N), ``values`` (n,) (stored precision) the candidates in the log rule's
    order (decreasing magnitude), ``x`` the point's standardised values, ``mats`` its
    dictionary (float64). The candidates are walked in that order; each one is kept if
    adding it to those kept before lowers E_c (by :data:`WALK_MARGIN`), else set aside;
    after each one kept the first :data:`WALK_RETRY` set aside are tried again (a highlight
    overshot by one coefficient is often corrected by the next), and when the candidates
    are spent all those set aside, at most ``passes`` times; the walk stops when ``cap`` are
    kept. Returns (positions of the kept
    candidates in their order (a,) int64, E_c after 0, 1, …, a of them (a + 1,) float64):
    decreasing by construction, so every prefix of the kept ones, the order a decoder
    truncates, errs less than a shorter one. Cost: one rank-1 tensor and one evaluation of
    E_c per candidate tried (the point's values: one exp per value and R, G, B).
    """
    ref = error.reference(i)
    delta = -np.asarray(x, dtype=np.float64)
    errs = [error.sum64(i, delta, ref)]
    kept: list[int] = []
    aside: list[int] = []

    def lowers(m: int) -> bool:
        nonlocal delta
        trial = delta + reconstruct_sparse(loc[m : m + 1], values[m : m + 1].astype(np.float64),
                                           mats)  # fmt: skip
        e = error.sum64(i, trial, ref)
        if e > errs[-1] * (1 - WALK_MARGIN):
            return False
        kept.append(m)
        errs.append(e)
        delta = trial
        return True

    def retry(limit: int) -> bool:
        """Retry the first ``limit`` set aside (magnitude order); True if one was kept."""
        for n, m in enumerate(aside[:limit]):
            if lowers(m):
                del aside[n]
                return True
        return False

    for m in range(values.size):
        if len(kept) >= cap:
            break
        if not lowers(m):
            aside.append(m)
            continue
        # what the new coefficient changed may let one set aside in: the largest first
        while len(kept) < cap and retry(WALK_RETRY):
            pass
    for _ in range(passes):  # the pool is spent: every one set aside, again
        if len(kept) >= cap or not retry(len(aside)):
            break
        while len(kept) < cap and retry(len(aside)):
            pass
    return np.asarray(kept, dtype=np.int64), np.asarray(errs)


def walk_pool(error: ChannelError, i: int, x: np.ndarray, idx: np.ndarray, values: np.ndarray,
              mats: Sequence[np.ndarray], cap: int
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """:func:`walk_order` of point ``i``'s candidates given as flat indices ``idx`` into the
    point (by decreasing |value|) and ``values``: (flat indices (a,), values at the file's
    precision (a,) float32, E_c after 0 … a of them (a + 1,)) in the walk's order."""
    vals = stored_precision(values)
    loc = np.stack(np.unravel_index(np.asarray(idx), x.shape), axis=1)
    pos, errs = walk_order(error, i, x, loc, vals, mats, cap)
    return np.asarray(idx)[pos], vals[pos], errs


def judged_code_levels(
    batch: np.ndarray, dictionaries: Sequence[np.ndarray], levels: Sequence[int], eps: float,
    dtype: type, mask: np.ndarray, error: ChannelError, energy: np.ndarray,
) -> tuple[list[Codes], list[Codes]]:  # fmt: skip
    """The rule of the module docstring on a batch (B, m_1, …, m_N) at caps ``levels``
    (clipped to the point size already), on the dictionaries of ``mask`` (B, K) only;
    ``energy`` (B,) the points' ‖X‖².

    Returns (judged, log): per level (membership (B,), counts (B,), values (Σ counts,), flat
    indices (Σ counts,), errors (B,)), each point's coefficients in the order of
    :func:`walk_order` (values at the file's precision), errors E_c; the log rule's codes are
    the paper's choice of dictionary and count from the same projections, in that order.
    """
    x = np.ascontiguousarray(batch, dtype=dtype)
    b = x.shape[0]
    shape = x.shape[1:]
    n_dict = dictionaries[0].shape[0]
    grid = prefix_grid(levels, eps)
    tmax = grid[-1]
    mats = [[np.asarray(d[k], dtype=dtype) for d in dictionaries] for k in range(n_dict)]
    mats64 = [[np.asarray(d[k], dtype=np.float64) for d in dictionaries] for k in range(n_dict)]

    def judge(ik: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(flat indices, values) of the tmax largest |S| and E_c at each grid length."""
        i, k = ik
        s = project(x[i : i + 1], mats[k]).reshape(-1)
        idx = topk_abs(s, tmax)
        vals = s[idx]
        loc = np.stack(np.unravel_index(idx, shape), axis=1)
        ref = error.reference(i)
        delta = -x[i].astype(np.float64)  # decoded − true, decoded built up prefix by prefix
        errs = np.full(len(grid), np.inf)
        start = 0
        for g, n in enumerate(grid):
            n = min(n, idx.size)
            if n > start:
                delta += reconstruct_sparse(loc[start:n], vals[start:n].astype(np.float64),
                                            mats64[k])  # fmt: skip
                start = n
            errs[g] = error(i, delta, ref)
        return idx, vals, errs

    pairs = [(i, k) for k in range(n_dict) for i in range(b) if mask[i, k]]
    found = dict(zip(pairs, parallel_map(judge, pairs), strict=True))
    grid_a = np.asarray(grid)
    size = int(np.prod(shape))
    logs = []
    for tau in levels:  # the paper's rule: sparsest, then least error; ties: lower k
        best_log: list[tuple[tuple[int, float], int] | None] = [None] * b
        for i, k in pairs:
            vals = found[i, k][1]
            n, e = rule_keys((vals.astype(np.float64) ** 2)[None, :], float(energy[i]), size,
                              tau, eps)  # fmt: skip
            key = (int(n[0]), float(e[0]))
            if best_log[i] is None or key < best_log[i][0]:  # type: ignore[index]
                best_log[i] = (key, k)
        logs.append([(c[1], c[0][0], c[0][1]) for c in best_log])  # type: ignore[index]
    out = []
    for tau in levels:
        chosen: list[tuple[int, int, float]] = []
        for i in range(b):
            best: tuple[tuple[int, float, float], tuple[int, int, float]] | None = None
            for k in range(n_dict):
                if not mask[i, k]:
                    continue
                idx, _, errs = found[i, k]
                for g in np.flatnonzero(grid_a <= tau):
                    n = min(int(grid_a[g]), idx.size)
                    e = float(errs[g])
                    # ε met: sparsest first; else (and at ε = 0) least error, then sparsest
                    key = (0, n, e) if e <= eps else (1, e, n)
                    if best is None or key < best[0]:
                        best = (key, (k, n, e))
            chosen.append(best[1])  # type: ignore[index]
        out.append(chosen)
    return _walked(x, error, mats64, found, levels, eps, out, logs)


def _walked(
    x: np.ndarray, error: ChannelError, mats64: list[list[np.ndarray]],
    found: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]],
    levels: Sequence[int], eps: float, judged: list[list[tuple[int, int, float]]],
    logs: list[list[tuple[int, int, float]]],
) -> tuple[list[Codes], list[Codes]]:  # fmt: skip
    """The chosen (dictionary, count) of every level, judged and log, in the level-of-detail
    order of :func:`walk_order` (one walk per point and dictionary chosen at some level):
    a judged code at level τ keeps the walk's first τ (with ε > 0 the fewest whose error
    meets ε, when some do), a log code of n coefficients those of its n that the walk kept;
    each code's error the walk's E_c."""
    need: dict[tuple[int, int], int] = {}  # (i, k) → the most its walk must keep
    for j, tau in enumerate(levels):
        for i, (k, _, _) in enumerate(judged[j]):
            need[i, k] = max(need.get((i, k), 0), int(tau))
        for i, (k, n, _) in enumerate(logs[j]):
            need[i, k] = max(need.get((i, k), 0), int(n))
    def walk(ik: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        i, k = ik
        return walk_pool(error, i, x[i], found[i, k][0], found[i, k][1], mats64[k], need[i, k])

    keys = sorted(need)
    walks = dict(zip(keys, parallel_map(walk, keys), strict=True))

    def assemble(chosen: list[tuple[int, int]]) -> Codes:
        b = len(chosen)
        parts = [(walks[i, k], n) for i, (k, n) in enumerate(chosen)]
        return (
            np.array([c[0] for c in chosen], dtype=np.int64),
            np.array([n for _, n in parts], dtype=np.int64),
            np.concatenate([w[1][:n] for w, n in parts]) if b else np.empty(0, np.float32),
            np.concatenate([w[0][:n] for w, n in parts]) if b else np.empty(0, np.int64),
            np.array([w[2][n] for w, n in parts], dtype=np.float64),
        )

    out, out_log = [], []
    for j, tau in enumerate(levels):
        chosen = []
        for i, (k, _, _) in enumerate(judged[j]):
            errs = walks[i, k][2]
            n = min(int(tau), errs.size - 1)
            met = np.flatnonzero(errs[: n + 1] <= eps) if eps > 0 else ()
            chosen.append((k, int(met[0]) if len(met) else n))
        out.append(assemble(chosen))
        out_log.append(assemble([(k, min(int(n), walks[i, k][2].size - 1))
                                 for i, (k, n, _) in enumerate(logs[j])]))  # fmt: skip
    return out, out_log


def joint_choice(
    x: Sequence[np.ndarray], errors: Sequence[ChannelError],
    judged: Sequence[Sequence[SparseCodes]], log: Sequence[Sequence[SparseCodes]],
    dictionaries: Sequence[Sequence[np.ndarray]], taus: Sequence[Sequence[int]],
) -> list[list[SparseCodes]]:  # fmt: skip
    """The three channels' codes of a batch judged together, level by level.

    ``x[c]`` (B, p, p, L, V): channel c's standardised points; ``errors[c]`` its
    :class:`ChannelError`; ``judged[c][j]``, ``log[c][j]`` its codes at level j by the
    objective's rule and by the paper's (:func:`~.coding.sparse_code_objective`);
    ``taus[c][j]`` its cap. Per point and level the joint error E (the objective's mean
    squared error over values and R, G, B, with all three channels' residuals at once) of
    the judged codes is compared with the log rule's, and the lower kept; then, in
    increasing τ (levels whose every channel's τ is at least the other's), a level whose E
    is above a lower level's keeps that level's codes. So no point's E is above the log
    rule's at its level, nor above its E at a lower level. Returns ``[c][j]`` codes, each
    point's ``errors`` its channel's E_c.
    """
    n_ch, n_lv = len(x), len(taus[0])
    b = x[0].shape[0]
    e0 = errors[0]
    scale = np.stack([e.scale for e in errors])  # (C, L, V, rgb)

    def residual(c: int, j: int, src: int, i: int) -> np.ndarray:
        """Decoded minus true standardised values of point i, channel c (not kept: a batch
        of them at every level would hold hundreds of MB)."""
        codes = (judged if src == 0 else log)[c][j]
        loc, val = codes.point(i)
        k = int(codes.membership[i])
        mats = [np.asarray(d[k], dtype=np.float64) for d in dictionaries[c]]
        return (reconstruct_sparse(loc, val.astype(np.float64), mats)
                - x[c][i].astype(np.float64)).astype(np.float32)  # fmt: skip

    def joint(ji: tuple[int, int, int]) -> float:
        j, src, i = ji
        y = e0.log_rgb[i].copy()
        for c in range(n_ch):
            y += residual(c, j, src, i)[..., None] * scale[c]
        if e0.bound is not None:
            np.minimum(y, e0.bound[..., None], out=y)
        d = e0._value(y)
        d -= e0.reference(i)
        flat = d.reshape(-1)
        return float(np.dot(flat, flat)) / flat.size

    # the log rule's code is the judged one where every channel has its dictionary and count
    # (both are prefixes of the same order): judged once
    same = np.array([[all(judged[c][j].membership[i] == log[c][j].membership[i]
                          and judged[c][j].counts[i] == log[c][j].counts[i] for c in range(n_ch))
                      for i in range(b)] for j in range(n_lv)])  # fmt: skip
    jobs = [(j, src, i) for j in range(n_lv) for src in (0, 1) for i in range(b)
            if src == 0 or not same[j, i]]  # fmt: skip
    err = np.full((n_lv, 2, b), np.inf)
    for (j, src, i), e in zip(jobs, parallel_map(joint, jobs), strict=True):
        err[j, src, i] = e
    # (level, source) chosen per point: 0 judged, 1 log
    pick = [[(j, int(err[j, 1, i] < err[j, 0, i])) for i in range(b)] for j in range(n_lv)]
    best = np.minimum(err[:, 0], err[:, 1])
    order = sorted(range(n_lv), key=lambda j: tuple(t[j] for t in taus))
    for pos, hi in enumerate(order):
        for lo in order[:pos]:
            if not all(t[lo] <= t[hi] for t in taus):
                continue
            for i in np.flatnonzero(best[lo] < best[hi]):
                pick[hi][i] = pick[lo][i]
                best[hi, i] = best[lo, i]

    out: list[list[SparseCodes]] = []
    for c in range(n_ch):
        per_level = []
        for j in range(n_lv):
            parts, errs = [], np.empty(b)
            for i, (lv, src) in enumerate(pick[j]):
                codes = (judged if src == 0 else log)[c][lv]
                parts.append((codes, i))
                errs[i] = (codes.errors[i] if src == 0
                           else errors[c](i, residual(c, lv, src, i)))  # fmt: skip
            per_level.append(_pick_points(parts, errs, SparseCodes))
        out.append(per_level)
    return out


def _pick_points(parts: list[tuple[SparseCodes, int]], errors: np.ndarray,
                 cls: type[SparseCodes]) -> SparseCodes:  # fmt: skip
    """Codes whose point i is point ``parts[i][1]`` of codes ``parts[i][0]``."""
    shape = parts[0][0].mode_sizes
    locs = [c.point(i)[0] for c, i in parts]
    vals = [c.point(i)[1] for c, i in parts]
    return cls(
        shape,
        np.array([c.membership[i] for c, i in parts], dtype=np.int64),
        np.array([c.counts[i] for c, i in parts], dtype=np.int64),
        np.concatenate(vals).astype(np.float32),
        np.concatenate(locs).astype(np.int32).reshape(-1, len(shape)),
        errors,
    )
