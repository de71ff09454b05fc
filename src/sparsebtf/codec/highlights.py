"""Spending a level's bytes between coefficients and the highlight store (issue 46).

``encode_levels(..., highlights=True)``: each level's τ fixes its **byte budget** — the Table 4
bytes of τ coefficients in every point (what the level is worth, even where a point's code
stops earlier: ε, or a linear objective that drops what does not lower its error) — and the
coder spends it on a *base* code (one of the
call's τ, or τ/2 … τ/32 of the smallest) plus the nodes of the highlight store
(:mod:`sparsebtf.learning.highlights`) whose correction (an E5M2 scale of the point's tint, or
three E5M2 values untinted) removes the most linear-RGB squared error, whichever pair errs
least. Every level of a call chooses among the same bases,
and a larger budget keeps at least the same entries on each, so the material's linear error
never grows with the level.

One streaming pass over the points (memory: one point and the kept entries): the reference
point and its decode at each base give the residual r = reference − decode at every node; a
node's gain is ‖r‖² − ‖r − q(r)‖², q(r) its correction as the store keeps it (what storing it
removes; the store is compact, :mod:`sparsebtf.learning.entry_code`): E5M2(r), three bytes,
or in a tinted store s·t with t the point's tint (the principal direction of its residuals'
colours) and s = E5M2(r·t/t·t), one byte — a level takes the kind that errs less at its
bytes (tinted where a point's highlights share a colour, as a metal's do). Per base and kind
the largest gains over the whole material are kept (at most what the largest budget can
hold), their cumulative sums give each budget's error, a budget holds the most of them whose
code fits it (the code's bytes grow with each entry, so a bisection finds it), and the level
takes the best base and kind.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from .._limits import ENV as MEMORY_ENV
from .._limits import check_allocation, format_bytes, memory_budget
from .._progress import bar as progress_bar
from ..data.btf import BTF
from ..errors import BTFInputError
from ..learning.cost import channel_storage
from ..learning.entry_code import (
    HEADER_BYTES,
    MIN_ENTRY_BYTES,
    compact_bytes,
    quantise,
    tint,
    tint_scales,
    tinted,
)
from ..learning.highlights import Highlights
from ..learning.lobes import LOBE_BYTES, fit_lobes, lobe_amplitudes16, unit_lobes_at
from ..model import CodedBTF, Model
from ..points.grid import PatchGrid
from ..runtime.dense import DecodedBTF

__all__ = ["BASE_FRACTIONS", "base_taus", "choose_highlights", "level_budget"]

#: Bases below the smallest level's τ, as divisors of it (each channel, at least 1).
BASE_FRACTIONS = (2, 4, 8, 16, 32)


def base_taus(levels: Sequence[dict[str, int]]) -> list[dict[str, int]]:
    """The extra τ coded for the bases: τ/2 … τ/32 of the smallest level (per channel,
    at least 1), those not among ``levels``."""
    low = min(levels, key=lambda t: sum(t.values()))
    out: list[dict[str, int]] = []
    for f in BASE_FRACTIONS:
        t = {ch: max(1, v // f) for ch, v in low.items()}
        if t not in levels and t not in out:
            out.append(t)
    return out


def _material_bytes(coded: CodedBTF, model: Model) -> int:
    """Table 4 bytes of ``coded`` as it is (its codes and store)."""
    from ..storage.accounting import storage_report

    return int(storage_report(coded, model, stored=False)["bytes_table4_material"])


def level_budget(coded: CodedBTF) -> int:
    """Table 4 bytes of ``coded``'s τ in every point (coefficients, membership, counts)."""
    total = 0
    for ch, tau in coded.coded_tau.items():
        if ch not in coded.codes:
            continue
        c = channel_storage(int(tau) * coded.n_points, coded.n_points, 1,
                            coded.codes[ch].mode_sizes)
        total += c["bytes_coefficients"] + c["bytes_membership"] + c["bytes_counts"]
    return total


#: A candidate buffer is cut back to its cap when it grows past this many times the cap.
_GROWTH = 1.25


def _candidate_bytes(cap: int, tinted: bool) -> int:
    """Peak bytes of a :class:`_TopGains` of ``cap``: a full buffer (``_GROWTH`` × cap), its
    concatenation when cut, and the cut; an entry's gain (float32), point, key (4 bytes each)
    and what the store keeps (one byte tinted, six not)."""
    return int((2 * _GROWTH + 1) * cap) * (13 if tinted else 18)


class _TopGains:
    """The ``cap`` largest gains streamed in, with their nodes: a buffer cut back to ``cap``
    when it grows past ``_GROWTH`` × cap. Gains are kept in float32 (they rank the entries and
    add up to a level's error: float32's 6e-8 is far below what decides a choice)."""

    def __init__(self, cap: int) -> None:
        self.cap = cap
        self.parts: list[tuple[np.ndarray, ...]] = []
        self.size = 0
        self.floor = 0.0

    def add(self, gain: np.ndarray, point: int, rgb: np.ndarray) -> None:
        """One point's nodes: ``gain`` (n,) and their corrections ``rgb`` (n, 3), or scales
        (n,), node i's key being i; nodes whose gain is not positive never pay."""
        if not self.cap:
            return
        keep = gain > max(self.floor, 0.0)
        if not keep.any():
            return
        keys = np.flatnonzero(keep)
        g = gain[keys].astype(np.float32)
        self.parts.append((g, np.full(g.size, point, np.int32), keys.astype(np.uint32),
                           rgb[keys]))  # fmt: skip
        self.size += g.size
        if self.size > _GROWTH * self.cap:
            self._cut()

    def _cut(self) -> None:
        g, p, k, v = (np.concatenate(a) for a in zip(*self.parts, strict=True))
        if g.size > self.cap:
            top = np.argpartition(-g, self.cap - 1)[: self.cap]
            g, p, k, v = g[top], p[top], k[top], v[top]
            self.floor = float(g.min())
        self.parts, self.size = [(g, p, k, v)], g.size

    def sorted(self) -> tuple[np.ndarray, ...]:
        """Gains (decreasing), points, keys, corrections (or scales) of the kept entries."""
        if not self.parts:
            return (np.zeros(0, np.float32), np.zeros(0, np.int32), np.zeros(0, np.uint32),
                    np.zeros(0, np.float16))  # fmt: skip
        self._cut()
        g, p, k, v = self.parts[0]
        order = np.lexsort((k, p, -g))
        return g[order], p[order], k[order], v[order]


def _node_gains(ref: np.ndarray, dec: np.ndarray, tinted_store: bool
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, float]:  # fmt: skip
    """Per node of one point ((p, p, L, V, 3) arrays): the gain of storing its correction;
    what the store keeps of it (``tinted_store``: the E5M2 scale (n,) along the point's
    tint; else the E5M2 correction (n, 3)), float16; the tint (3,) or None; and the point's
    squared error."""
    ref64 = ref.astype(np.float64).reshape(-1, 3)
    dec64 = np.asarray(dec, dtype=np.float64).reshape(-1, 3)
    r = ref64 - dec64
    if tinted_store:
        t = tint(r)
        kept = tint_scales(r, t)
        c = tinted(kept, np.broadcast_to(t, r.shape))
    else:
        t, kept = None, quantise(r)
        c = kept
    # the errors the decoders leave: every decoded value is clamped at 0 (a tinted correction
    # can push a channel below it, and the clamp takes that back)
    sq = np.square(ref64 - np.maximum(dec64, 0.0)).sum(axis=1)
    left = np.square(ref64 - np.maximum(dec64 + c.astype(np.float64), 0.0)).sum(axis=1)
    return sq - left, kept, t, float(sq.sum())


def _lobe_pass(ref: np.ndarray, pilot: np.ndarray, wi: np.ndarray, wo: np.ndarray,
               iters: int) -> np.ndarray:
    """The lobes' shapes of one point (p, p, L, V, 3 arrays): fitted to the residual of the
    ``pilot`` decode, (p², 5) float16 (:func:`~sparsebtf.learning.lobes.fit_lobes`)."""
    t = ref.shape[0] * ref.shape[1]
    r = (ref.astype(np.float64) - pilot).reshape(t, -1, 3)
    return fit_lobes(r, wi, wo, iters=iters)[:, :5]


def _with_lobes(ref: np.ndarray, dec: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, ...]:
    """The decode ``dec`` (p, p, L, V, 3) plus the lobes of unit values ``g`` (p², L·V) at
    their best binary16 amplitudes against the residual, and those amplitudes (p², 3)
    float16."""
    t = g.shape[0]
    r = (ref.astype(np.float64) - dec).reshape(t, -1, 3)
    amp = lobe_amplitudes16(g, r)
    lobe = g[..., None] * amp.astype(np.float64)[:, None, :]
    return (dec + lobe.reshape(dec.shape)), amp


def _store_bytes(glob: np.ndarray, n: int, lobes: bool, tints: int) -> int:
    """Bytes of the entries of the first ``n`` global keys ``glob`` (any order) in a compact
    store, tinted in ``tints`` points (none at all when nothing is stored; no tints without
    entries)."""
    if not n:
        return HEADER_BYTES if lobes else 0
    return compact_bytes(np.sort(glob[:n]), tints)


def _most_entries(glob: np.ndarray, room: int, lobes: bool, tints: int) -> int:
    """The most leading entries of ``glob`` whose store fits ``room`` bytes (the code grows
    with each entry: bisection); −1 when not even the store without entries fits."""
    if room < _store_bytes(glob, 0, lobes, tints):
        return -1
    lo, hi = 0, min(glob.size, max(0, room) // MIN_ENTRY_BYTES)
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if _store_bytes(glob, mid, lobes, tints) <= room:
            lo = mid
        else:
            hi = mid - 1
    return lo


def choose_highlights(
    btf: BTF,
    levels: Sequence[CodedBTF],
    bases: Sequence[CodedBTF],
    model: Model,
    progress: bool | None = None,
    lobes: bool = True,
    lobe_iters: int = 20,
    tints: bool = True,
) -> list[CodedBTF]:
    """Each of ``levels`` re-spent at its own bytes on the best of ``levels`` + ``bases`` (all
    coded from ``btf`` in one call) plus highlight entries — three E5M2 values each, or with
    ``tints`` also tinted ones, whichever errs less — and with ``lobes`` per-texel highlight
    lobes where they pay (module docstring; where the tinted candidates alone would pass the
    memory budget, three-value entries only, with a warning). Returns one coded material per
    level: the chosen base's codes with its store; ``params["highlights"]`` records the base
    τ, the entries, whether it has lobes and is tinted, the budget and the squared error the
    choice was judged by."""
    cands = list(levels) + list(bases)
    budgets = [level_budget(c) for c in levels]
    own = [_material_bytes(c, model) for c in cands]
    n_pts = levels[0].n_points
    p = levels[0].patch
    nodes = p * p * len(levels[0].lights) * len(levels[0].views)
    # variants: (candidate, with lobes, tinted); a variant's cap is what the largest budget
    # holds at the fewest bytes an entry costs (1 tinted, 3 not)
    with_lobes = (False, True) if lobes else (False,)
    extra = {False: 0, True: n_pts * p * p * LOBE_BYTES}

    def plan(kinds: tuple[bool, ...]) -> tuple[list[tuple[int, bool, bool]], list[int], int]:
        vs = [(i, v, t) for t in kinds for v in with_lobes for i in range(len(cands))]
        cs = [max(0, (max(budgets) - own[i] - extra[v]) // (MIN_ENTRY_BYTES if t else 3))
              for i, v, t in vs]  # fmt: skip
        return vs, cs, sum(_candidate_bytes(c, t) for c, (_, _, t) in zip(cs, vs, strict=True))

    kinds = (False, True) if tints else (False,)
    variants, caps, mem = plan(kinds)
    budget_bytes = memory_budget()
    if tints and mem > budget_bytes:
        untinted = plan((False,))
        if untinted[2] <= budget_bytes:
            # tinted candidates hold three times the entries: where only they do not fit,
            # the store is coded as before, and the user is told what would allow them
            warnings.warn(f"{btf.label}: tinted highlight entries need {format_bytes(mem)} "
                          f"for their candidates, above the memory budget of "
                          f"{format_bytes(budget_bytes)}; coding three-value entries only "
                          f"(set ${MEMORY_ENV} to allow tinted ones)", stacklevel=2)  # fmt: skip
            kinds, (variants, caps, mem) = (False,), untinted
    check_allocation(mem, f"{btf.label}: the highlight candidates (up to {sum(caps):,d} "
                     "entries)", BTFInputError)  # fmt: skip
    slot = {ivt: j for j, ivt in enumerate(variants)}
    tops = [_TopGains(cap) for cap in caps]
    sse = np.zeros(len(variants))
    decoders = [DecodedBTF(dataclasses.replace(c, highlights=None)) for c in cands]
    pilot = int(np.argmin(own))  # the smallest code: its residual shows the whole highlight
    shapes = np.zeros((n_pts, p * p, 5), np.float16)
    amps = np.zeros((len(cands), n_pts, p * p, 3), np.float16) if lobes else None
    point_tints = np.ones((len(variants), n_pts, 3), np.float16)
    wi = np.repeat(btf.lights.xyz, len(btf.views), axis=0)
    wo = np.tile(btf.views.xyz, (len(btf.lights), 1))
    grid = PatchGrid(btf.height, btf.width, p)
    bar = progress_bar(n_pts, "highlights", unit="point", enabled=progress)
    for point in range(n_pts):
        r0, c0 = grid.origin(point)
        rows, cols = np.arange(r0, r0 + p), np.arange(c0, c0 + p)
        ref = np.asarray(btf.read(rows, cols, slice(None), slice(None)), dtype=np.float32)
        first = decoders[pilot].read(rows, cols, slice(None), slice(None))
        if lobes:
            shapes[point] = _lobe_pass(ref, first, wi, wo, lobe_iters)
            g = unit_lobes_at(shapes[point].astype(np.float64), wi, wo)
        for i, d in enumerate(decoders):
            dec = first if i == pilot else d.read(rows, cols, slice(None), slice(None))
            for v in with_lobes:
                if v:
                    dec, amps[i, point] = _with_lobes(ref, dec.astype(np.float64), g)
                for kind in kinds:
                    j = slot[i, v, kind]
                    gain, kept, t, s_ = _node_gains(ref, dec, kind)
                    if t is not None:
                        point_tints[j, point] = t
                    sse[j] += s_
                    tops[j].add(gain, point, kept)
        bar.update(1)
    bar.close()
    ranked = [t.sorted() for t in tops]
    globs = [pts * np.int64(nodes) + keys for _, pts, keys, _ in ranked]  # the code's keys
    out = []
    for lv, budget in zip(levels, budgets, strict=True):
        best: tuple[float, int, int] | None = None
        for j, ((i, v, t), (g_, *_)) in enumerate(zip(variants, ranked, strict=True)):
            n = _most_entries(globs[j], budget - own[i] - extra[v], v, n_pts if t else 0)
            if n < 0:
                continue
            left = sse[j] - float(g_[:n].sum(dtype=np.float64))
            if best is None or left < best[0]:
                best = (left, j, n)
        assert best is not None  # the level's own codes fit its budget
        left, j, n = best
        i, v, t = variants[j]
        _, pts, keys, kept = ranked[j]
        if t and n:
            store = Highlights.from_tinted(pts[:n], keys[:n], kept[:n], point_tints[j], n_pts)
        else:
            store = Highlights.from_nodes(pts[:n], keys[:n], kept[:n].reshape(n, 3), n_pts)
        if v:
            store = dataclasses.replace(
                store, lobes=np.concatenate([shapes, amps[i]], axis=2))  # type: ignore[index]
        base = cands[i]
        params: dict[str, Any] = {
            **base.params,
            "highlights": {
                "entries": int(n), "lobes": bool(v), "tinted": bool(t and n),
                "budget_bytes": int(budget),
                "base_tau": {ch: int(x) for ch, x in base.coded_tau.items()},
                "level_tau": {ch: int(x) for ch, x in lv.coded_tau.items()},
                "sse": float(left),
            },
        }  # fmt: skip
        out.append(dataclasses.replace(base, params=params,
                                       highlights=None if store.empty_store else store))
    return out
