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

The rule, in two steps. (1) Per channel (:func:`judged_code_levels`): each candidate
dictionary's coefficients in the log rule's order (decreasing |S_t|, the order a
level-of-detail prefix reads), evaluated by E_c at the prefix lengths τ and ⌈τ/2⌉ of every
level, and with ε > 0 also 1, 2, 4, … (the grid, :func:`prefix_grid`) — the coefficients of the
point itself and of its **floored** copies (:meth:`ChannelError.floored`: every linear value
below a floor raised to it; the floors f, 4f and 16f, :data:`FLOOR_STEPS`, f the automatic log
offset's rule on the point, 1 % of its median positive value), those above the log offset ε. At
each level τ the code is the (dictionary, target, prefix length n <= τ) of least E_c; with ε >
0 the smallest n with E_c <= ε (then least error) when one exists. The log rule's codes come
from the same projections (of the point itself). (2) Per point and level
(:func:`joint_choice`): the joint error E of the three channels' residuals at once (E_c with
every channel's δ) of the judged codes against the log rule's; the lower is kept, and in
increasing τ a level keeps a lower level's codes where those have the lower E. So **no point's
error in the objective is above the log rule's** at its level, **nor above its error at a lower
level** of the same call (:func:`~sparsebtf.codec.encode_levels`). The stored codes are then
put in their level-of-detail order (:func:`~.lod_order.lod_orders`), which nests the levels
again, per channel as well as jointly (issue 46): in increasing τ no point's joint E nor any
channel's E_c is above a lower level's of the call (a level that would be keeps the best mix of
its own and the lower level's channel codes). Separate calls are not nested: each judges the
prefix lengths of its own levels, and a screened call ranks its candidates for its own τ.

Why floored copies. Under a small ε (the release's 1e-5) a noisy dark value spans ln ε …
ln(dark) in the log domain, several units, and that noise is in every coefficient's projection,
the highlight's included: more coefficients buy little linear error. A value below a floor f
costs at most f² in linear RGB if decoded at f, so projecting a floored copy gives up little
and frees the coefficients for what a renderer sees; which floor leaves the least error is
judged per point and channel, always against the true values. Measured on a captured bumpy
copper at ε = 1e-5 (40×40, 4 spp, τ = 308 … 4,483; docs/benchmarks.md §17, "Floored targets"):
the codes' linear MSE 0.147 → 0.121 at level 16 and 0.127 → 0.077 at level 128 (at the
automatic offset, before them: 0.120 and 0.078).

Cost per point and candidate dictionary (10×10 texels × 151 × 151, n = 2.28 M entries), per
target (up to four: the point and its floored copies above ε): the log rule's projection (1.47
GFLOP), one sparse reconstruction of τ_max coefficients split at the grid (at most a dense 1.47
GFLOP, a few percent of it at τ = 885), and per grid length one evaluation of E_c (~20 flops,
one exp per value and R, G, B: ~140 M flops and 7 M exp; 2 lengths per level at ε = 0); per
point and level 2 × 3 sparse reconstructions and two joint evaluations. Measured: 5–8× the log
rule's encode time per point with the point alone; the floored copies took the benchmark's
glossy encodes to 1.0–2.6× that (docs/benchmarks.md §17).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .._semantic import stored_dtype
from .._threads import parallel_map
from ..colour import RGB_TO_YUV_F32
from ..errors import BTFInputError
from ..points.statistics import offset_of_median
from .codes import SparseCodes, rule_keys, topk_abs
from .tensor import project, reconstruct_sparse

__all__ = [
    "DISPLAY_A",
    "DISPLAY_GAMMA",
    "FLOOR_STEPS",
    "OBJECTIVES",
    "ChannelError",
    "check_objective",
    "joint_choice",
    "joint_error",
    "joint_sum64",
    "judged_code_levels",
    "objective_params",
    "prefix_grid",
    "stored_precision",
]

#: One level's codes: membership, counts, values, flat indices, errors.
Codes = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
#: The floored copies a point is also judged by: its floor (:meth:`ChannelError.floor`) times
#: each (measured on a captured rough copper at ε = 1e-5, level 128's codes: 0.1269 without,
#: 0.0907 with (1,), 0.0799 with (1, 8), 0.0774 with these; docs/benchmarks.md §17).
FLOOR_STEPS = (1.0, 4.0, 16.0)
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
    #: the channel (0: Y, 1: U, 2: V) and its σ (L, V): what :meth:`floored` needs
    channel: int = 0
    std: np.ndarray | None = None

    @classmethod
    def for_batch(cls, objective: str, log_rgb: np.ndarray, std: np.ndarray,
                  bound: np.ndarray | None, log_offset: float, channel: int
                  ) -> ChannelError:  # fmt: skip
        """From the statistics: σ (L, V, 1 or 3) and the channel's index (0: Y, 1: U, 2: V)."""
        from ..colour import YUV_TO_RGB

        sd = np.broadcast_to(std, (*std.shape[:2], 3))[..., channel]
        scale = (sd[..., None] * YUV_TO_RGB[:, channel]).astype(np.float32)
        b = None if bound is None else np.asarray(bound, dtype=np.float32)
        return cls(objective, log_rgb, scale, b, float(log_offset), int(channel),
                   np.ascontiguousarray(sd, dtype=np.float32))  # fmt: skip

    def floor(self, i: int) -> float:
        """Point ``i``'s floor f: the automatic log offset's rule on the point's own values,
        1 % of its median positive linear value
        (:func:`~sparsebtf.points.statistics.offset_of_median`; ε where it has none)."""
        v = np.exp(self.log_rgb[i])
        v -= np.float32(self.log_offset)
        pos = v[v > 0]
        return offset_of_median(float(np.median(pos)) if pos.size else None)

    def floored(self, i: int, x: np.ndarray, f: float | None = None) -> np.ndarray | None:
        """Point ``i``'s standardised values ``x`` (p, p, L, V) with every linear value below
        f (default its :meth:`floor`) raised to it (R, G, B apart), in this channel::

            x + RGB_TO_YUV[c] · (ln(max(RGB, f) + ε) − ln(RGB + ε)) / σ_c

        None where f is not above ε (nothing would change) or σ is not at hand."""
        f = self.floor(i) if f is None else f
        if self.std is None or f <= self.log_offset:
            return None
        lr = self.log_rgb[i]
        lift = np.maximum(lr, np.float32(math.log(f + self.log_offset)))
        lift -= lr
        dy = lift @ RGB_TO_YUV_F32[self.channel]
        dy /= self.std
        dy += x
        return dy.astype(x.dtype, copy=False)

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

    def sum64(self, i: int, delta: np.ndarray, ref: np.ndarray) -> float:
        """:meth:`__call__` as the level-of-detail walk needs it: :func:`joint_sum64` with
        this channel's residual alone."""
        return joint_sum64([self], i, [delta], ref)


#: Texels per chunk of :func:`joint_sum64` (4 × 151 × 151 × 3 float32: 1 MB).
_SUM_TEXELS = 4


def joint_sum64(errors: Sequence[ChannelError], i: int, residuals: Sequence[np.ndarray],
                ref: np.ndarray) -> float:  # fmt: skip
    """:func:`joint_error` of point ``i`` (``ref`` its :meth:`ChannelError.reference`)
    texel by texel, a few at a time so the temporaries stay in cache (half the time of the
    whole point at once), each chunk's float32 sum added in float64: the walk compares
    errors that differ by little, and one float32 dot of millions of values is off by
    ~1e-5 relative."""
    e0 = errors[0]
    t = e0.log_rgb.shape[1] * e0.log_rgb.shape[2]
    lr = e0.log_rgb[i].reshape(t, *e0.log_rgb.shape[3:])
    rf = ref.reshape(lr.shape)
    res = [np.asarray(r, dtype=np.float32).reshape(t, *lr.shape[1:-1]) for r in residuals]
    total = 0.0
    for a in range(0, t, _SUM_TEXELS):
        y = lr[a : a + _SUM_TEXELS].copy()
        for err, r in zip(errors, res, strict=True):
            y += r[a : a + _SUM_TEXELS, ..., None] * err.scale
        if e0.bound is not None:
            np.minimum(y, e0.bound[..., None], out=y)
        v = e0._value(y)
        v -= rf[a : a + _SUM_TEXELS]
        f = v.reshape(-1)
        total += float(np.dot(f, f))
    return total / (t * lr[0].size)


def joint_error(errors: Sequence[ChannelError], i: int, residuals: Sequence[np.ndarray]
                ) -> float:  # fmt: skip
    """The joint error E of point ``i``: the objective's mean squared error over values and
    R, G, B with every channel's standardised residual (decoded − true, (p, p, L, V)) at
    once, clamped to the bound like every decoder."""
    e0 = errors[0]
    y = e0.log_rgb[i].copy()
    for err, r in zip(errors, residuals, strict=True):
        y += np.asarray(r, dtype=np.float32)[..., None] * err.scale
    if e0.bound is not None:
        np.minimum(y, e0.bound[..., None], out=y)
    d = e0._value(y)
    d -= e0.reference(i)
    flat = d.reshape(-1)
    return float(np.dot(flat, flat)) / flat.size


def stored_precision(values: np.ndarray) -> np.ndarray:
    """``values`` rounded as a coded file stores them (binary16, or float32 when one
    overflows it: :func:`~sparsebtf._semantic.stored_dtype`), as float32: the joint choice
    and the level-of-detail walk judge the very values the file keeps."""
    v = np.asarray(values, dtype=np.float32)
    return v.astype(stored_dtype(v)).astype(np.float32)


def prefix_grid(levels: Sequence[int], eps: float = 0.0) -> list[int]:
    """The prefix lengths E_c is evaluated at (increasing, distinct): every level τ and its
    half ⌈τ/2⌉; with ε > 0 also 1, 2, 4, … below the largest level (the ε rule looks for the
    fewest coefficients that meet ε)."""
    top = max(levels)
    lengths = {int(t) for t in levels} | {-(-int(t) // 2) for t in levels}
    if eps > 0:
        lengths |= {1 << g for g in range(math.ceil(math.log2(top)) + 1) if 1 << g < top}
    return sorted(lengths)


def judged_code_levels(
    batch: np.ndarray, dictionaries: Sequence[np.ndarray], levels: Sequence[int], eps: float,
    dtype: type, mask: np.ndarray, error: ChannelError, energy: np.ndarray,
) -> tuple[list[Codes], list[Codes]]:  # fmt: skip
    """The rule of the module docstring on a batch (B, m_1, …, m_N) at caps ``levels``
    (clipped to the point size already), on the dictionaries of ``mask`` (B, K) only;
    ``energy`` (B,) the points' ‖X‖².

    Returns (judged, log): per level (membership (B,), counts (B,), values (Σ counts,), flat
    indices (Σ counts,), errors (B,)), each point's coefficients by decreasing |value|; the
    judged codes' errors are E_c, the log rule's (from the same projections, its codes bit
    for bit) its mean squared standardised residual.
    """
    x = np.ascontiguousarray(batch, dtype=dtype)
    b = x.shape[0]
    shape = x.shape[1:]
    n_dict = dictionaries[0].shape[0]
    grid = prefix_grid(levels, eps)
    tmax = grid[-1]
    mats = [[np.asarray(d[k], dtype=dtype) for d in dictionaries] for k in range(n_dict)]
    mats64 = [[np.asarray(d[k], dtype=np.float64) for d in dictionaries] for k in range(n_dict)]

    def judge(ik: tuple[int, int]) -> list[Judged]:
        """Per target (the point, then its floored copies above ε): (flat indices, values)
        of the tmax largest |S| and E_c at each grid length."""
        i, k = ik
        ref = error.reference(i)
        out = []
        lifted = (error.floored(i, x[i], floors[i] * m) for m in FLOOR_STEPS)
        for target in (x[i], *lifted):
            if target is None:
                continue
            s = project(target[None], mats[k]).reshape(-1)
            idx = topk_abs(s, tmax)
            vals = s[idx]
            loc = np.stack(np.unravel_index(idx, shape), axis=1)
            delta = -x[i].astype(np.float64)  # decoded − true, built up prefix by prefix
            errs = np.full(len(grid), np.inf)
            start = 0
            for g, n in enumerate(grid):
                n = min(n, idx.size)
                if n > start:
                    delta += reconstruct_sparse(loc[start:n], vals[start:n].astype(np.float64),
                                                mats64[k])  # fmt: skip
                    start = n
                errs[g] = error(i, delta, ref)
            out.append((idx, vals, errs))
        return out

    floors = list(parallel_map(error.floor, range(b)))
    pairs = [(i, k) for k in range(n_dict) for i in range(b) if mask[i, k]]
    found = dict(zip(pairs, parallel_map(judge, pairs), strict=True))
    grid_a = np.asarray(grid)
    size = int(np.prod(shape))
    logs = []
    for tau in levels:  # the paper's rule: sparsest, then least error; ties: lower k
        best_log: list[tuple[tuple[int, float], int] | None] = [None] * b
        for i, k in pairs:
            vals = found[i, k][0][1]
            n, e = rule_keys((vals.astype(np.float64) ** 2)[None, :], float(energy[i]), size,
                              tau, eps)  # fmt: skip
            key = (int(n[0]), float(e[0]))
            if best_log[i] is None or key < best_log[i][0]:  # type: ignore[index]
                best_log[i] = (key, k)
        chosen_log = [(c[1], 0, c[0][0], c[0][1]) for c in best_log]  # type: ignore[index]
        logs.append(_assemble(found, chosen_log))
    out = []
    for tau in levels:
        chosen: list[tuple[int, int, int, float]] = []
        for i in range(b):
            best: tuple[tuple[int, float, float], tuple[int, int, int, float]] | None = None
            for k in range(n_dict):
                if not mask[i, k]:
                    continue
                for t, (idx, _, errs) in enumerate(found[i, k]):
                    for g in np.flatnonzero(grid_a <= tau):
                        n = min(int(grid_a[g]), idx.size)
                        e = float(errs[g])
                        # ε met: sparsest first; else (and at ε = 0) least error, then sparsest
                        key = (0, n, e) if e <= eps else (1, e, n)
                        if best is None or key < best[0]:
                            best = (key, (k, t, n, e))
            chosen.append(best[1])  # type: ignore[index]
        out.append(_assemble(found, chosen))
    return out, logs


#: Per target of a (point, dictionary): flat indices, values, E_c at each grid length.
Judged = tuple[np.ndarray, np.ndarray, np.ndarray]


def _assemble(found: dict[tuple[int, int], list[Judged]],
              chosen: list[tuple[int, int, int, float]]) -> Codes:  # fmt: skip
    """Codes of the points' chosen (dictionary, target, count, error), point i the i-th."""
    b = len(chosen)
    idx = [found[i, k][t][0][:n] for i, (k, t, n, _) in enumerate(chosen)]
    vals = [found[i, k][t][1][:n] for i, (k, t, n, _) in enumerate(chosen)]
    return (
        np.array([c[0] for c in chosen], dtype=np.int64),
        np.array([c[2] for c in chosen], dtype=np.int64),
        np.concatenate(vals).astype(np.float32) if b else np.empty(0, np.float32),
        np.concatenate(idx).astype(np.int64) if b else np.empty(0, np.int64),
        np.array([c[3] for c in chosen], dtype=np.float64),
    )


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
    squared error over values and R, G, B, with all three channels' residuals at once, the
    values at the file's precision) of the judged codes is compared with the log rule's, and
    the lower kept; then, in
    increasing τ (levels whose every channel's τ is at least the other's), a level whose E
    is above a lower level's keeps that level's codes. So no point's E is above the log
    rule's at its level, nor above its E at a lower level. Returns ``[c][j]`` codes, each
    point's ``errors`` its channel's E_c.
    """
    n_ch, n_lv = len(x), len(taus[0])
    b = x[0].shape[0]

    def residual(c: int, j: int, src: int, i: int) -> np.ndarray:
        """Decoded minus true standardised values of point i, channel c (not kept: a batch
        of them at every level would hold hundreds of MB)."""
        codes = (judged if src == 0 else log)[c][j]
        loc, val = codes.point(i)
        k = int(codes.membership[i])
        mats = [np.asarray(d[k], dtype=np.float64) for d in dictionaries[c]]
        # at the file's precision: a floored copy's code can win by less than its rounding
        return (reconstruct_sparse(loc, stored_precision(val).astype(np.float64), mats)
                - x[c][i].astype(np.float64)).astype(np.float32)  # fmt: skip

    def joint(ji: tuple[int, int, int]) -> float:
        j, src, i = ji
        return joint_error(errors, i, [residual(c, j, src, i) for c in range(n_ch)])

    # the log rule's code is the judged one where every channel has its dictionary, count
    # and values (a floored copy's prefix has its own values): judged once
    def same_code(j: int, i: int) -> bool:
        return all(judged[c][j].membership[i] == log[c][j].membership[i]
                   and all(np.array_equal(a, g) for a, g in zip(judged[c][j].point(i),
                                                                log[c][j].point(i), strict=True))
                   for c in range(n_ch))  # fmt: skip

    same = np.array([[same_code(j, i) for i in range(b)] for j in range(n_lv)])
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
