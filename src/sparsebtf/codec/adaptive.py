"""Encode with adaptive patch sizes (beyond the paper: its §5's future work): a quadtree per
material, chosen by rate and distortion.

The rule (``docs/format.md`` §3, "Adaptive patch sizes", says it for users):

1. **Every node coded.** The material is cut into blocks of the model's largest size P; every
   block, and every block of every smaller size s inside it, is coded as a data point of its
   size on the model's ensemble for s (the paper's rule with ε = 0: the least-error dictionary
   at the cap τ_s = ⌈τ·(s/P)²⌉, τ per point of size P, so every size gets the same
   coefficients per texel). Cost: the encode of the material once per size.
2. **Each node's code at a multiplier λ.** A node keeps its k coefficients whose squares
   exceed λ·b (b = 5 bytes per coefficient, Table 4), at least one: the k minimising
   D(k) + λ·R(k), with D(k) the squared error (standardised log-YUV, the coder's error, summed
   over the node's values and Y, U, V) and R(k) = b·k + 2 bytes (membership and count).
3. **The tree at λ.** Bottom-up, a block keeps its split when the sum of its children's best
   D + λR is lower than its own D + λR.
4. **λ by bisection** (60 halvings of log λ) to the smallest λ whose tree's Table 4 bytes —
   coefficients, memberships, counts and one bit per split flag of the tree — are at most the
   budget: ``target_bytes`` or raw / ``target_ratio`` (Table 4 bytes of the material); with a
   plain τ, the Table 4 bytes of the material coded at (τ, ε) at the fixed size P (the same
   projections), so the adaptive code spends at most the fixed code's bytes.

Each bisection step is a pass over the kept coefficients (no projection): the coding of step 1
dominates.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..data.btf import BTF
from ..errors import BTFInputError, UnreachableTargetError
from ..execution import Execution
from ..learning.codes import RELEASE_EPS, RELEASE_TAU, count_and_error
from ..learning.coding import SparseCodes, sparse_code_levels
from ..learning.cost import POINT_BYTES, VALUE_BYTES, location_width, raw_bytes
from ..model import CHANNELS, Model, TauSpec, model_text, parse_tau
from ..patch_tree import (
    AdaptiveCodedBTF,
    PatchTree,
    coefficient_indices,
    expand_points,
    node_taus,
    select_points,
)
from ..points.grid import PatchGrid, stream_points
from ..points.preprocessing import Preprocessor, Standardization
from .encode import _check_levels, coded_btf, plan_candidates, rule_params
from .jobs import Header, run_plan
from .options import EncodeOptions

__all__ = ["AdaptivePlan", "encode_adaptive", "node_taus"]

#: Halvings of log λ in the bisection (far below one coefficient's bytes at the end).
BISECTIONS = 60


@dataclass(frozen=True)
class AdaptivePlan:
    """The encoding plan (:mod:`.jobs`) of adaptive patch sizes: every node of every size
    coded by point ranges of the largest blocks, the tree chosen in :meth:`finish`."""

    tau: Any = RELEASE_TAU
    target_bytes: int | None = None
    target_ratio: float | None = None
    level: tuple[tuple[str, int], ...] = ()
    eps: float = RELEASE_EPS
    dtype: str = "float32"
    candidates: int | None = None
    desc: str = "encode (adaptive)"

    rule: ClassVar[str] = "rate-distortion quadtree, lambda by bisection"
    #: what :func:`~.jobs.run_plan` checks the option ``adaptive_patches`` against
    adaptive: ClassVar[bool] = True

    @property
    def kind(self) -> str:
        return ("ratio" if self.target_ratio is not None
                else "size" if self.target_bytes is not None else "tau")  # fmt: skip

    def bind(self, model: Model, options: EncodeOptions) -> AdaptivePlan:
        if len(model.patch_sizes) < 2:
            raise BTFInputError(
                f"adaptive patch sizes need a model with several patch sizes; "
                f"{model_text(model.content_hash, model.file)} has {model.patch}x{model.patch} "
                "patches only (train one with: sparsebtf train ... --patch 20,10,5)"
            )
        if model.patch != model.patch_sizes[0]:
            raise BTFInputError(f"adaptive patch sizes: the model's patch {model.patch} must be "
                                f"its largest size {model.patch_sizes[0]}")  # fmt: skip
        if options.objective != "log":
            raise BTFInputError(f"adaptive patch sizes choose the tree by the log objective; "
                                f"objective {options.objective!r} is not supported with them")
        if set(model.channels) != set(CHANNELS):
            raise BTFInputError(f"adaptive patch sizes need a Y, U, V model, this one has "
                                f"{model.channels}")  # fmt: skip
        release = dict(zip(CHANNELS, RELEASE_TAU, strict=True))
        level = parse_tau(self.tau, model.channels, nominal=release)
        _check_levels([level], model, options.allow_below_training)
        return AdaptivePlan(self.tau, self.target_bytes, self.target_ratio,
                            tuple(level.items()), options.eps, options.dtype,
                            plan_candidates(options.candidates, model))  # fmt: skip

    def prepare(self, header: Header, model: Model) -> int | None:
        """The material's budget of Table 4 bytes for a target (None: the τ rule's)."""
        PatchGrid(header.height, header.width, model.patch)  # one line for a bad size
        if self.target_ratio is not None:
            return int(raw_bytes(header.n_values) // self.target_ratio)
        return self.target_bytes

    def code_range(
        self, btf: BTF, model: Model, stats: Standardization, lo: int, hi: int, extra: Any,
        batch_size: int, tick: Callable[[int], object] | None = None,
    ) -> list[tuple[int, np.ndarray, dict[str, SparseCodes]]]:  # fmt: skip
        """Every node of every size inside blocks ``[lo, hi)`` of the largest size:
        (size, point numbers on that size's grid, codes per channel at the node's cap)."""
        big = model.patch_sizes[0]
        roots = PatchGrid(btf.height, btf.width, big)
        pre = Preprocessor(stats)
        dt = np.dtype(self.dtype).type
        tau = dict(self.level)
        out = []
        for size in model.patch_sizes:
            grid = PatchGrid(btf.height, btf.width, size)
            k = big // size
            rb, cb = roots.blocks(np.arange(lo, hi))
            sub = np.arange(k)
            rows = (rb[:, None, None] * k + sub[None, :, None]).repeat(k, axis=2)
            cols = (cb[:, None, None] * k + sub[None, None, :]).repeat(k, axis=1)
            points = np.sort(np.asarray(grid.index(rows, cols)).ravel())
            one = model.for_patch(size)
            caps = node_taus(tau, model, size)
            parts: dict[str, list[SparseCodes]] = {ch: [] for ch in model.channels}
            for _, x in stream_points(btf, pre, size, points, batch_size, True):
                for c, ch in enumerate(model.channels):
                    (sc,) = sparse_code_levels(x[c], one.dictionaries[ch], [caps[ch]], 0.0,
                                               dt, self.candidates)  # fmt: skip
                    parts[ch].append(sc)
            out.append((size, points, {ch: SparseCodes.concatenate(p)
                                       for ch, p in parts.items()}))  # fmt: skip
        if tick is not None:
            tick(hi - lo)
        return out

    def finish(
        self, header: Header, model: Model, stats: Standardization, parts: list[Any],
        extra: int | None,
    ) -> list[AdaptiveCodedBTF]:  # fmt: skip
        nodes = {}
        for size in model.patch_sizes:
            pts = np.concatenate([pts for p in parts for s, pts, _ in p if s == size])
            order = np.argsort(pts, kind="stable")
            codes = {ch: select_points(SparseCodes.concatenate(
                [c[ch] for p in parts for s, _, c in p if s == size]), order)
                for ch in model.channels}  # fmt: skip
            nodes[size] = _NodeCurves(codes, header.height, header.width, size)
        tau = dict(self.level)
        budget = extra if extra is not None else self._tau_budget(nodes[model.patch], tau)
        lam, tree, total = _bisect(nodes, model.patch_sizes, budget, header.label)
        layers = {}
        for size in model.patch_sizes:
            pts = tree.points(size)
            codes = {ch: expand_points(nodes[size].prefix(ch, pts, lam), pts,
                                       nodes[size].n_points)
                     for ch in model.channels}  # fmt: skip
            params = {"tau": tau, "eps": self.eps, "dtype": self.dtype,
                      **rule_params(self.candidates),
                      "adaptive": {"rule": self.rule, "lambda": lam, "budget_bytes": int(budget),
                                   "budget": "tau" if extra is None else self.kind,
                                   "bytes_table4": int(total)}}  # fmt: skip
            layers[size] = coded_btf(header, model.for_patch(size), codes, stats, params)
        return [AdaptiveCodedBTF(tree, layers, model)]

    def _tau_budget(self, top: _NodeCurves, tau: dict[str, int]) -> int:
        """Table 4 bytes of the material coded at (τ, ε) in blocks of the largest size."""
        total = 0
        for ch, c in top.codes.items():
            size = int(np.prod(c.mode_sizes))
            o = c.offsets
            for i in range(c.n_points):
                sq = c.values[o[i]:o[i + 1]].astype(np.float64) ** 2
                energy = float(c.errors[i]) * size + float(sq.sum())
                n, _ = count_and_error(sq, energy, size, tau[ch], self.eps)
                total += top.coef_bytes[ch] * n + POINT_BYTES
        return total


class _NodeCurves:
    """The nodes of one size, every point of its grid: each node's error and bytes at a
    multiplier λ, from its coefficients (by decreasing magnitude) and its residual."""

    def __init__(self, codes: dict[str, SparseCodes], height: int, width: int, size: int
                 ) -> None:  # fmt: skip
        self.codes = codes
        self.grid = PatchGrid(height, width, size)
        self.n_points = self.grid.n_points
        self.coef_bytes = {ch: VALUE_BYTES + location_width(c.mode_sizes)
                           for ch, c in codes.items()}  # fmt: skip
        self._sq = {ch: c.values.astype(np.float64) ** 2 for ch, c in codes.items()}
        self._cum = {ch: np.concatenate([[0.0], np.cumsum(sq)]) for ch, sq in self._sq.items()}
        self._owner = {ch: np.repeat(np.arange(c.n_points), c.counts) for ch, c in codes.items()}
        self._base = {ch: c.errors.astype(np.float64) * float(np.prod(c.mode_sizes))
                      for ch, c in codes.items()}  # fmt: skip

    def kept(self, ch: str, lam: float) -> np.ndarray:
        """Coefficients each node keeps at λ: those whose square exceeds λ·b, at least one."""
        c = self.codes[ch]
        above = np.bincount(self._owner[ch], self._sq[ch] > lam * self.coef_bytes[ch],
                            minlength=c.n_points).astype(np.int64)  # fmt: skip
        return np.clip(above, 1, c.counts)

    def cost(self, lam: float) -> tuple[np.ndarray, np.ndarray]:
        """(D, R) of every node at λ, on the grid as (row blocks, column blocks)."""
        d = np.zeros(self.n_points)
        r = np.zeros(self.n_points)
        for ch, c in self.codes.items():
            k = self.kept(ch, lam)
            o = c.offsets
            d += self._base[ch] + (self._cum[ch][o[1:]] - self._cum[ch][o[:-1] + k])
            r += self.coef_bytes[ch] * k + POINT_BYTES
        return self._on_grid(d), self._on_grid(r)

    def _on_grid(self, a: np.ndarray) -> np.ndarray:
        # point = rb + n_rb·cb: (cb, rb) → (rb, cb)
        return a.reshape(self.grid.n_col_blocks, self.grid.n_row_blocks).T

    def prefix(self, ch: str, points: np.ndarray, lam: float) -> SparseCodes:
        """The codes of ``points`` cut to what each keeps at λ (errors: the residual)."""
        c = self.codes[ch]
        k = self.kept(ch, lam)[points]
        sel = select_points(c, points)
        o = sel.offsets
        take = coefficient_indices(o[:-1], k)
        size = float(np.prod(c.mode_sizes))
        d = self._base[ch][points] + (self._cum[ch][c.offsets[points + 1]]
                                      - self._cum[ch][c.offsets[points] + k])  # fmt: skip
        return SparseCodes(c.mode_sizes, sel.membership, k, sel.values[take],
                           sel.locations[take], d / size)  # fmt: skip


def _tree_at(nodes: dict[int, _NodeCurves], sizes: tuple[int, ...], lam: float
             ) -> tuple[PatchTree, int]:  # fmt: skip
    """The tree of least D + λR (bottom-up), and its Table 4 bytes with its split flags."""
    best_j = best_r = None
    split: dict[int, np.ndarray] = {}
    costs = {}
    for size in reversed(sizes):  # smallest first
        d, r = nodes[size].cost(lam)
        costs[size] = r
        j = d + lam * r
        if best_j is None:
            split[size] = np.zeros(j.shape, dtype=bool)
            best_j, best_r = j, r
            prev = size
            continue
        k = size // prev
        h, w = j.shape
        cj = best_j.reshape(h, k, w, k).sum(axis=(1, 3))
        cr = best_r.reshape(h, k, w, k).sum(axis=(1, 3))
        split[size] = cj < j
        best_j = np.where(split[size], cj, j)
        best_r = np.where(split[size], cr, r)
        prev = size
    rows = []
    active = np.ones(split[sizes[0]].shape, dtype=bool)
    for i, size in enumerate(sizes):
        leaf = active & ~split[size]
        rb, cb = np.nonzero(leaf)
        rows.append(np.stack([rb * size, cb * size, np.full(rb.size, size)], axis=1))
        if i + 1 < len(sizes):
            k = size // sizes[i + 1]
            active = np.repeat(np.repeat(active & split[size], k, axis=0), k, axis=1)
    first = nodes[sizes[0]].grid
    tree = PatchTree.from_nodes(first.height, first.width, sizes, np.concatenate(rows))
    total = int(best_r.sum()) + tree.tree_bytes()  # type: ignore[union-attr]
    return tree, total


def _bisect(nodes: dict[int, _NodeCurves], sizes: tuple[int, ...], budget: int, label: str
            ) -> tuple[float, PatchTree, int]:  # fmt: skip
    """The smallest λ (to :data:`BISECTIONS` halvings of log λ) whose tree fits ``budget``."""
    energy = sum(float(c._base[ch].sum() + c._sq[ch].sum())
                 for c in nodes.values() for ch in c.codes)  # fmt: skip
    lo, hi = 1e-12, 10.0 * energy + 1.0  # at hi one byte outweighs every error
    tree, total = _tree_at(nodes, sizes, lo)
    if total <= budget:
        return lo, tree, total
    tree, total = _tree_at(nodes, sizes, hi)
    if total > budget:
        raise UnreachableTargetError(
            f"{label}: a budget of {budget:,} Table 4 bytes is below the smallest adaptive "
            f"code of this material ({total:,} bytes: one coefficient per block of the largest "
            "size); give a larger target"
        )
    for _ in range(BISECTIONS):
        mid = math.sqrt(lo * hi)
        t, n = _tree_at(nodes, sizes, mid)
        if n <= budget:
            hi, tree, total = mid, t, n
        else:
            lo = mid
    return hi, tree, total


def encode_adaptive(
    btf: BTF,
    model: Model,
    tau: TauSpec = RELEASE_TAU,
    *,
    target_bytes: int | None = None,
    target_ratio: float | None = None,
    options: EncodeOptions | None = None,
    execution: Execution | None = None,
    **keywords: Any,
) -> AdaptiveCodedBTF:
    """One BTF coded with adaptive patch sizes on a model of several sizes (the module's rule):
    at most ``target_bytes`` Table 4 bytes (or raw / ``target_ratio``), else at most the bytes
    of the fixed code at (τ, ``eps``) in blocks of the largest size. ``tau`` caps the
    coefficients per point of the largest size (scaled to each node's texels)."""
    if target_bytes is not None and target_ratio is not None:
        raise BTFInputError("give one of target_bytes and target_ratio")
    plan = AdaptivePlan(tau, target_bytes, target_ratio)
    (coded,) = run_plan([btf], model, plan, options, execution, **keywords)
    return coded[0]
