"""Level-of-detail order of a linear or display objective's codes (beyond the paper, issue 32).

A renderer's level of detail (:mod:`sparsebtf.runtime.lod`) reads the first τ' = f·τ_c of a
point's stored coefficients, f from 0.1 (path vertices after the first) to 1. In the paper's
magnitude order the log-domain error of a prefix falls with its length (Parseval), but the
error of linear RGB or of the display mapping can rise: a highlight overshot by one
coefficient before the one that corrects it. So under these objectives each channel's code
is stored in an order of its own, found by a **walk** (:func:`walk_order`): the coefficients
in magnitude order, in blocks that bring the kept count to its next **stop**; a block is kept
only if adding it lowers the channel's error E_c (:class:`~.objective.ChannelError`, the
other channels exact), else set aside; after each block kept the largest set aside are tried
again as the next block, and once the pool is spent all of them (twice at most).

* A level's code (:func:`lod_orders`): the walk runs over the code's own coefficients with
  stops at the counts the runtime reads, ⌈f·τ⌉ for f = 0.1, 0.2, …, 1 of the level's τ
  (:data:`LOD_FRACTIONS`; the runtime's 0.1, 0.3 and 0.5 among them). What the walk set
  aside ends the order as one last block when it lowers E_c, and is dropped otherwise (then
  fewer coefficients err less than the code did). So **the stored code errs no more than the
  code chosen at the level, and E_c falls along the stops**; between two stops (the
  runtime's fade from one count to the next) it is not evaluated.
* Nested levels (issue 46, :func:`lod_orders`): in increasing τ a level's stored codes err
  no more than a lower level's of the call, jointly (E) and per channel (E_c); a level that
  would keeps the least-E mix of its channels' codes and a lower level's that errs no more
  (the lower level's codes whole always qualify where the levels are ordered channel by
  channel), walked again at its own fractions.
* Rate control's candidates (:func:`walk_pool`): the walk over a point's candidate pool with
  stops every count up to :data:`WALK_EXACT`, then four per octave (:func:`walk_stops`); the
  error curve at the stops is what the allocation spends on
  (:func:`~sparsebtf.learning.rate_control.hull_gains`).

Why stops, not every count. An evaluation of E_c reads every value of the point (10×10 texels
× 151 × 151 × R, G, B: one exp each, ~20 ms); a walk that judged every coefficient, up to
τ = 4,483 per channel, took over 15 CPU minutes for one full-size point at the benchmark's
four levels. With stops a level's walk costs about ten evaluations per channel (plus the
retries), rate control's ~16 + 4·log2(pool/16).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .._threads import parallel_map
from .codes import SparseCodes
from .objective import ChannelError, joint_sum64, stored_precision
from .tensor import reconstruct_sparse

__all__ = [
    "LOD_FRACTIONS",
    "WALK_EXACT",
    "WALK_MARGIN",
    "WALK_PASSES",
    "WALK_RATIO",
    "joint_walk",
    "lod_orders",
    "lod_stops",
    "walk_order",
    "walk_pool",
    "walk_stops",
]

#: A block joins the order only if it lowers the error by at least this fraction: a decoder
#: sums in another order and precision, so a tie must not read as a rise.
WALK_MARGIN = 1e-6
#: Passes of :func:`walk_order` over the coefficients it set aside.
WALK_PASSES = 2
#: Fractions of a level's τ at which a level's walk stops: the counts the runtime's level of
#: detail reads (:mod:`sparsebtf.runtime.lod`: 0.1 after the first vertex, 0.3 for a sampled
#: direction, 0.5 … 1 by footprint), tenths between.
LOD_FRACTIONS = tuple(round(0.1 * k, 1) for k in range(1, 11))
#: Rate control's walk stops at every count up to this many kept ...
WALK_EXACT = 16
#: ... then at counts growing by this ratio (four per octave).
WALK_RATIO = 2**0.25


def walk_stops(cap: int) -> np.ndarray:
    """Rate control's stops (increasing, ≤ ``cap``): 1 … :data:`WALK_EXACT`, then
    ⌈WALK_EXACT·WALK_RATIO^j⌉, and ``cap``."""
    stops = set(range(1, min(WALK_EXACT, cap) + 1)) | {int(cap)}
    j = 1
    while (n := math.ceil(WALK_EXACT * WALK_RATIO**j - 1e-9)) < cap:
        stops.add(n)
        j += 1
    return np.asarray(sorted(s for s in stops if s > 0), dtype=np.int64)


def lod_stops(count: int, tau: int) -> np.ndarray:
    """A level's stops for a code of ``count`` coefficients at cap ``tau``: ⌈f·τ⌉ for f in
    :data:`LOD_FRACTIONS` below ``count``, and ``count``."""
    stops = {math.ceil(f * tau - 1e-9) for f in LOD_FRACTIONS} | {int(count)}
    return np.asarray(sorted(s for s in stops if 0 < s <= count), dtype=np.int64)


def walk_order(error: ChannelError, i: int, x: np.ndarray, loc: np.ndarray,
               values: np.ndarray, mats: Sequence[np.ndarray], stops: np.ndarray,
               passes: int = WALK_PASSES) -> tuple[np.ndarray, np.ndarray, list[int]]:  # fmt: skip
    """The walk of the module docstring over point ``i``'s coefficients.

    ``loc`` (n, N), ``values`` (n,) (stored precision) in magnitude order, ``x`` the point's
    standardised values (p, p, L, V), ``mats`` its dictionary (float64), ``stops`` the
    increasing kept counts at which E_c is evaluated (the walk ends at the last).
    Returns (positions of the kept coefficients in their order (a,) int64, E_c after 0 … a
    of them (a + 1,) float64, NaN between stops, the positions set aside): E_c falls along
    the stops by construction. Cost: one sparse reconstruction of each block and one
    evaluation of E_c per block tried.
    """
    ref = error.reference(i)
    delta = -np.asarray(x, dtype=np.float64)
    errs = {0: error.sum64(i, delta, ref)}
    kept: list[int] = []
    aside: list[int] = []
    last = errs[0]

    def gap() -> int:
        """Coefficients to the next stop (0: the last stop reached)."""
        j = int(np.searchsorted(stops, len(kept), side="right"))
        return int(stops[j]) - len(kept) if j < stops.size else 0

    def keep(block: list[int]) -> bool:
        nonlocal delta, last
        trial = delta + reconstruct_sparse(loc[block], values[block].astype(np.float64), mats)
        e = error.sum64(i, trial, ref)
        if e > last * (1 - WALK_MARGIN):
            return False
        kept.extend(block)
        errs[len(kept)] = last = e
        delta = trial
        return True

    nxt = 0
    while (m := gap()) and nxt < values.size:
        block = list(range(nxt, min(nxt + m, values.size)))
        nxt += len(block)
        if not keep(block):
            aside.extend(block)
            continue
        # what the new block changed may let those set aside in: the largest first
        while (m := gap()) and aside and keep(aside[:m]):
            del aside[:m]
    for _ in range(passes):  # the pool is spent: every one set aside, again, block by block
        start, moved = 0, False
        while (m := gap()) and start < len(aside):
            if keep(aside[start : start + m]):
                del aside[start : start + m]
                moved = True
            else:
                start += m
        if not moved:
            break
    aside.extend(range(nxt, values.size))  # past the last stop: never tried
    curve = np.full(len(kept) + 1, np.nan)
    for n, e in errs.items():
        curve[n] = e
    return np.asarray(kept, dtype=np.int64), curve, aside


def walk_pool(error: ChannelError, i: int, x: np.ndarray, idx: np.ndarray, values: np.ndarray,
              mats: Sequence[np.ndarray], cap: int,
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Rate control's walk (stops :func:`walk_stops` of ``cap``) of point ``i``'s candidates
    given as flat indices ``idx`` into the point (by decreasing |value|) and ``values``:
    (flat indices (a,), values at the file's precision (a,) float32, E_c after 0 … a of
    them (a + 1,), NaN between stops) in the walk's order; what it set aside is dropped."""
    vals = stored_precision(values)
    loc = np.stack(np.unravel_index(np.asarray(idx), x.shape), axis=1)
    pos, errs, _ = walk_order(error, i, x, loc, vals, mats, walk_stops(cap))
    return np.asarray(idx)[pos], vals[pos], errs


def joint_walk(
    errors: Sequence[ChannelError], i: int, x: Sequence[np.ndarray],
    codes: Sequence[tuple[np.ndarray, np.ndarray, Sequence[np.ndarray]]], taus: Sequence[int],
    passes: int = WALK_PASSES,
) -> tuple[list[np.ndarray], np.ndarray]:  # fmt: skip
    """The three channels of point ``i`` walked together (the module docstring's rule, each
    channel's blocks bringing its kept count to ⌈f·τ_c⌉ for f in :data:`LOD_FRACTIONS`).

    ``x[c]`` the point's standardised values of channel c, ``codes[c]`` its code (locations
    (n_c, N), values at the file's precision in magnitude order, the dictionary's matrices in
    float64), ``taus[c]`` its cap. At each fraction the channels' blocks are tried together,
    then, if together they do not lower the joint error E (:func:`~.objective.joint_sum64`),
    one by one; a block that does not lower E is set aside, and after each step the largest
    set aside of each channel are tried again; then all of them, ``passes`` times at most. A
    channel short of its count at a fraction below 1 with every candidate tried keeps no
    more. Returns (per channel the positions kept, in their order; E after each fraction
    (F + 1,), the first with no coefficient): at each fraction the first ⌈f·τ_c⌉ kept of
    every channel (all of them where fewer) are what was evaluated, so E falls along the
    fractions by construction. What is never kept is dropped.
    """
    n_ch = len(codes)
    ref = errors[0].reference(i)
    deltas = [-np.asarray(xc, dtype=np.float64) for xc in x]
    last = joint_sum64(errors, i, deltas, ref)
    curve = [last]
    kept: list[list[int]] = [[] for _ in range(n_ch)]
    aside: list[list[int]] = [[] for _ in range(n_ch)]
    nxt = [0] * n_ch
    sizes = [int(v.shape[0]) for _, v, _ in codes]

    def keep(blocks: dict[int, list[int]]) -> bool:
        nonlocal last
        trial = list(deltas)
        for c, blk in blocks.items():
            loc, val, mats = codes[c]
            trial[c] = deltas[c] + reconstruct_sparse(loc[blk], val[blk].astype(np.float64),
                                                      mats)  # fmt: skip
        e = joint_sum64(errors, i, trial, ref)
        if e > last * (1 - WALK_MARGIN):
            return False
        for c, blk in blocks.items():
            kept[c].extend(blk)
            deltas[c] = trial[c]
        last = e
        return True

    def retry(target: list[int]) -> None:
        for c in range(n_ch):
            while (m := target[c] - len(kept[c])) > 0 and aside[c] and keep({c: aside[c][:m]}):
                del aside[c][:m]

    for f in LOD_FRACTIONS:
        target = [min(math.ceil(f * t - 1e-9), n) for t, n in zip(taus, sizes, strict=True)]
        while True:
            blocks = {}
            for c in range(n_ch):
                m = target[c] - len(kept[c])
                if m > 0 and nxt[c] < sizes[c]:
                    blocks[c] = list(range(nxt[c], min(nxt[c] + m, sizes[c])))
                    nxt[c] += len(blocks[c])
            if not blocks:
                break
            if not keep(blocks):  # together they raise E: each channel's block alone
                for c, blk in blocks.items():
                    if not keep({c: blk}):
                        aside[c].extend(blk)
            retry(target)
        if f < 1:
            for c in range(n_ch):
                if len(kept[c]) < target[c]:
                    # short of its stop with every candidate tried: what it set aside is
                    # dropped, or keeping one later would put it inside this stop's prefix
                    aside[c].clear()
        curve.append(last)
    for _ in range(passes):  # every one set aside, again, up to each channel's size
        before = [len(k) for k in kept]
        retry(sizes)
        if [len(k) for k in kept] == before:
            break
    curve[-1] = last
    return [np.asarray(k, dtype=np.int64) for k in kept], np.asarray(curve)


def lod_orders(
    x: Sequence[np.ndarray], errors: Sequence[ChannelError], codes: list[list[SparseCodes]],
    dictionaries: Sequence[Sequence[np.ndarray]], taus: Sequence[Sequence[int]],
) -> tuple[list[list[SparseCodes]], int]:  # fmt: skip
    """Every point's codes at every level (``codes[c][j]`` channel c of a batch, ``x[c]`` its
    standardised points, ``taus[c][j]`` its cap) in their level-of-detail order.

    Per point and level the three channels are walked together (:func:`joint_walk`, once per
    distinct code). The walked codes are kept where their joint error E is not above the
    codes as chosen (values at the file's precision); else the chosen codes stay, in
    magnitude order (counted: their level of detail is not judged). Then the levels are
    **nested** (:func:`_nest`, issue 46): in increasing τ, a level whose codes have a joint
    error E or a channel's error E_c above a lower level's (one whose every channel's τ is at
    most its own) takes, of the mixes of its own channels' codes and a lower level's (any
    channel from either), the one of least E that is above no lower level in E nor in any
    E_c; the lower level's codes whole are one of them. The mix is walked again at the
    level's own fractions (its level of detail judged at the counts the runtime reads for
    this level) and kept walked where that stays above no lower level; else as it is
    (counted). Returns (``[c][j]`` codes, each point's ``errors`` its channel's E_c, the
    others exact; the number of (point, level) pairs whose stored order is not judged at
    their level's fractions).
    """
    n_ch, n_lv = len(codes), len(codes[0])
    b = codes[0][0].n_points
    first: dict[tuple, tuple[int, int]] = {}  # the codes of a (level, point) → one walked
    jobs, alias = [], {}
    for j in range(n_lv):
        for i in range(b):
            key = tuple((int(codes[c][j].membership[i]), int(taus[c][j]),
                         *(a.tobytes() for a in codes[c][j].point(i))) for c in range(n_ch))
            if key in first:
                alias[j, i] = first[key]
            else:
                first[key] = (j, i)
                jobs.append((j, i))

    def mats_of(c: int, k: int) -> list[np.ndarray]:
        return [np.asarray(d[k], dtype=np.float64) for d in dictionaries[c]]

    def walk(ji: tuple[int, int]) -> _Stored:
        j, i = ji
        members = [int(codes[c][j].membership[i]) for c in range(n_ch)]
        parts = []
        for c in range(n_ch):
            loc, val = codes[c][j].point(i)
            parts.append((loc, stored_precision(val)))
        xs = [x[c][i] for c in range(n_ch)]
        pc = [(loc, val, mats_of(c, members[c])) for c, (loc, val) in enumerate(parts)]
        pos, curve = joint_walk(errors, i, xs, pc, [int(taus[c][j]) for c in range(n_ch)])
        whole = _Stored.of(errors, i, xs, parts, members, mats_of, walked=False)
        if curve[-1] <= whole.joint:
            chosen = [(loc[p], val[p]) for (loc, val), p in zip(parts, pos, strict=True)]
            return _Stored.of(errors, i, xs, chosen, members, mats_of, walked=True)
        # the walk dropped what the code needs: the whole code, the walk's order first and
        # what it set aside after it, or as it is, where E falls along the fractions so
        level = [int(taus[c][j]) for c in range(n_ch)]
        rest = [np.concatenate([p, np.setdiff1d(np.arange(v.size), p)])
                for (_, v), p in zip(parts, pos, strict=True)]  # fmt: skip
        for order in ([(loc[r], val[r]) for (loc, val), r in zip(parts, rest, strict=True)],
                      parts):  # fmt: skip
            if _falls(errors, i, xs, order, members, mats_of, level):
                return _Stored.of(errors, i, xs, order, members, mats_of, walked=True,
                                  channel=whole.channel)  # fmt: skip
        return whole

    done = dict(zip(jobs, parallel_map(walk, jobs), strict=True))
    for key, src in alias.items():
        done[key] = done[src]
    final = _nest(x, errors, done, taus, b, mats_of)
    unjudged = sum(int(not final[j, i].walked) for j in range(n_lv) for i in range(b))
    out: list[list[SparseCodes]] = []
    for c in range(n_ch):
        per_level = []
        for j in range(n_lv):
            parts = [final[j, i].parts[c] for i in range(b)]
            mode_sizes = codes[c][j].mode_sizes
            per_level.append(SparseCodes(
                mode_sizes,
                np.array([final[j, i].members[c] for i in range(b)], np.int64),
                np.array([p[1].size for p in parts], dtype=np.int64),
                np.concatenate([p[1] for p in parts]).astype(np.float32) if b
                else np.empty(0, np.float32),
                np.concatenate([p[0] for p in parts]).astype(np.int32) if b
                else np.empty((0, len(mode_sizes)), np.int32),
                np.array([final[j, i].channel[c] for i in range(b)], dtype=np.float64),
            ))  # fmt: skip
        out.append(per_level)
    return out, unjudged


@dataclass(frozen=True)
class _Stored:
    """One point's codes at one level as the file will keep them: per channel (locations,
    values at the file's precision) in their stored order and dictionary, per channel E_c
    (the other channels exact), the joint E, and whether the order was judged (walked) at
    the level's fractions."""

    parts: list[tuple[np.ndarray, np.ndarray]]
    members: list[int]
    channel: list[float]
    joint: float
    walked: bool

    @staticmethod
    def residuals(i: int, xs: Sequence[np.ndarray], parts: Sequence[tuple[np.ndarray, np.ndarray]],
                  members: Sequence[int], mats_of) -> list[np.ndarray]:  # type: ignore[no-untyped-def]  # fmt: skip
        return [reconstruct_sparse(loc, val.astype(np.float64), mats_of(c, members[c]))
                - np.asarray(xs[c], dtype=np.float64)
                for c, (loc, val) in enumerate(parts)]  # fmt: skip

    @classmethod
    def of(cls, errors: Sequence[ChannelError], i: int, xs: Sequence[np.ndarray],
           parts: list[tuple[np.ndarray, np.ndarray]], members: list[int], mats_of,  # type: ignore[no-untyped-def]
           walked: bool, channel: Sequence[float | None] | None = None) -> _Stored:  # fmt: skip
        """The codes ``parts`` of point ``i`` with their errors; ``channel[c]`` a channel's E_c
        already known (the same residual gives the same value), else None."""
        res = cls.residuals(i, xs, parts, members, mats_of)
        ref = errors[0].reference(i)
        joint = joint_sum64(errors, i, res, ref)
        known = [None] * len(parts) if channel is None else list(channel)
        per = [errors[c].sum64(i, res[c], errors[c].reference(i)) if known[c] is None
               else float(known[c]) for c in range(len(parts))]  # type: ignore[arg-type]
        return cls(list(parts), list(members), per, float(joint), walked)

    def within(self, lower: Sequence[_Stored]) -> bool:
        """Its E and every E_c at most those of each of ``lower``."""
        return all(self.joint <= lo.joint
                   and all(a <= b for a, b in zip(self.channel, lo.channel, strict=True))
                   for lo in lower)  # fmt: skip


def _nest(x: Sequence[np.ndarray], errors: Sequence[ChannelError],
          done: dict[tuple[int, int], _Stored], taus: Sequence[Sequence[int]], b: int,
          mats_of) -> dict[tuple[int, int], _Stored]:  # type: ignore[no-untyped-def]  # fmt: skip
    """The levels nested point by point (:func:`lod_orders`): ``done[j, i]`` the walked codes
    of level j, point i; returns the codes each (level, point) stores."""
    n_ch, n_lv = len(taus), len(taus[0])
    order = sorted(range(n_lv), key=lambda j: tuple(t[j] for t in taus))
    lowers = {hi: [lo for lo in order[:pos] if all(t[lo] <= t[hi] for t in taus)]
              for pos, hi in enumerate(order)}  # fmt: skip
    final: dict[tuple[int, int], _Stored] = {}

    def nest(i: int) -> list[_Stored]:
        xs = [x[c][i] for c in range(n_ch)]
        mine: dict[int, _Stored] = {}
        for hi in order:
            own = done[hi, i]
            below = [mine[lo] for lo in lowers[hi]]
            if own.within(below):
                mine[hi] = own
                continue
            best: _Stored | None = None
            fallback = own
            for lo_code in reversed(below):  # the largest lower level first
                for mask in itertools.product((False, True), repeat=n_ch):
                    if not any(mask):
                        continue
                    src = [lo_code if m else own for m in mask]
                    if all(mask):
                        cand = lo_code
                    else:
                        cand = _Stored.of(errors, i, xs, [s.parts[c] for c, s in enumerate(src)],
                                          [s.members[c] for c, s in enumerate(src)], mats_of,
                                          walked=False,
                                          channel=[s.channel[c] for c, s in enumerate(src)])
                    if cand.within(below):
                        if best is None or cand.joint < best.joint:
                            best = cand
                    elif cand.joint < fallback.joint:
                        fallback = cand
                if best is not None:  # the largest lower level that gives one: enough
                    break
            # levels ordered channel by channel: a lower level's codes whole are within
            pick = best if best is not None else fallback
            mine[hi] = _rewalk(errors, i, xs, pick, [int(t[hi]) for t in taus], below, mats_of)
        return [mine[j] for j in range(n_lv)]

    for i, per_level in enumerate(parallel_map(nest, range(b))):
        for j, s in enumerate(per_level):
            final[j, i] = s
    return final


def _rewalk(errors: Sequence[ChannelError], i: int, xs: Sequence[np.ndarray], code: _Stored,
            taus: Sequence[int], below: Sequence[_Stored], mats_of  # type: ignore[no-untyped-def]
            ) -> _Stored:  # fmt: skip
    """``code`` (another level's codes, or a mix) walked at the fractions of ``taus``, the
    level that stores it: the walked codes where they stay within ``below``
    (:meth:`_Stored.within`), else ``code`` as it is, not judged at these fractions."""
    pc = [(loc, val, mats_of(c, code.members[c])) for c, (loc, val) in enumerate(code.parts)]
    pos, _ = joint_walk(errors, i, xs, pc, taus)
    parts = [(loc[p], val[p]) for (loc, val), p in zip(code.parts, pos, strict=True)]
    walked = _Stored.of(errors, i, xs, parts, code.members, mats_of, walked=True)
    if walked.within(below) and walked.joint <= code.joint:
        return walked
    judged = _falls(errors, i, xs, code.parts, code.members, mats_of, taus)
    return _Stored(code.parts, code.members, code.channel, code.joint, judged)


def _falls(errors: Sequence[ChannelError], i: int, xs: Sequence[np.ndarray],
           parts: Sequence[tuple[np.ndarray, np.ndarray]], members: Sequence[int],
           mats_of, taus: Sequence[int]) -> bool:  # type: ignore[no-untyped-def]  # fmt: skip
    """Whether the joint E of point ``i``'s codes ``parts`` (in their stored order) does not
    rise from no coefficient to the first ⌈f·τ_c⌉ of every channel, f in
    :data:`LOD_FRACTIONS`, to the next."""
    ref = errors[0].reference(i)
    last = math.inf
    for f in (0.0, *LOD_FRACTIONS):
        res = []
        for c, (loc, val) in enumerate(parts):
            k = math.ceil(f * taus[c] - 1e-9)
            res.append(reconstruct_sparse(loc[:k], val[:k].astype(np.float64),
                                          mats_of(c, members[c]))
                       - np.asarray(xs[c], dtype=np.float64))  # fmt: skip
        e = joint_sum64(errors, i, res, ref)
        if e > last:
            return False
        last = e
    return True
