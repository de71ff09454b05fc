"""NeuMIP (Kuznetsov et al., TOG 40(4) 2021) without its neural offset, as the paper compares
it: a neural texture of C channels at the material's resolution and a small MLP per material.

From the public code (experiment ``StandardRawLShadowNoOffset``): MLP input [ω_i.xy, ω_o.xy,
texture(C)], three hidden layers of 25 (ReLU), 6 outputs (log-YUV and a shadow term, see
:func:`~._torch.output`), texture initialised N(0, 0.1²), Adam 1e-3, loss
MSE(log1p(clamp(ŷ, −0.1)), log1p(y)) + 0.01·L1(ŷ, y), the texture blurred early in training
with σ(t) = 8·exp(−t·ln 8 / 10,000) texels (floored at 0.1) over 30,000 iterations. We keep
all of that (:class:`NeuMIPRecipe`); what differs: training stops on a plateau of the loss
on held-out queries (at most twice the recipe's effort), a higher starting learning rate
that drops to the recipe's, and one texture level (a single-scale BTF needs no pyramid). A
query at a texel's centre reads that texel exactly (bilinear lookup at the sample point), so
the lookup is an index.

Storage, per material: 2·C·H·W bytes of texture + 2·(MLP parameters, which grow with C).
C is the largest that fits the budget.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import torch
import torch.nn.functional as F

from ...data.btf import BTF
from ..methods.base import MATCHINGS, Budget, Coding
from ._base import NeuralMethod, largest_size
from ._convergence import StopRule, train_to_convergence
from ._torch import (
    NeuralBTF,
    SamplePool,
    binary16,
    direction_terms,
    direction_xy,
    flat,
    init_mlp,
    mlp_params,
    output,
    read_pool,
    seed_generator,
    step_generator,
    tail,
    torch_threads,
)

__all__ = ["QUICK_CAP", "RECIPE", "REFERENCE_QUERIES", "STOP", "NeuMIPMethod", "NeuMIPRecipe",
           "blur_fades_at", "blur_sigma", "circular_blur"]


@dataclass(frozen=True)
class NeuMIPRecipe:
    """NeuMIP without offset ([V] from its public code; [P] our change for the budget).

    * ``hidden`` (25, 25, 25), ReLU, 6 outputs — [V].
    * ``texture_std`` 0.1 — [V] N(0, σ²) initial texture.
    * ``l1_weight`` 0.01, ``clamp_low`` −0.1 — [V] the loss.
    * ``blur_sigma0`` 8, ``blur_floor`` 0.1, ``blur_fall_iterations`` 10,000 of
      ``reference_iterations`` 30,000 — [V] σ(t) = 8·exp(−t·ln 8/10,000); the schedule is
      followed per training query per texel, as the recipe's 4 queries per texel per
      iteration give it (a shorter span only in the quick configuration).
    * ``lr`` — [V] 1e-3 constant in the original; [P] we start 10x higher and drop to it on
      the held-out plateaus (:mod:`._convergence`), so 1e-3 is the floor.
    """

    hidden: tuple[int, ...] = (25, 25, 25)
    outputs: int = 6
    texture_std: float = 0.1
    l1_weight: float = 0.01
    clamp_low: float = -0.1
    blur_sigma0: float = 8.0
    blur_floor: float = 0.1
    blur_fall_iterations: int = 10_000
    reference_iterations: int = 30_000
    lr: tuple[float, float] = (1e-2, 1e-3)

    def mlp_sizes(self, channels: int) -> list[int]:
        return [channels + 4, *self.hidden, self.outputs]


#: The recipe every NeuMIP coding uses (one place; docs/neural-baselines.md).
RECIPE = NeuMIPRecipe()
#: The recipe's effort: 30,000 iterations of 4 images, every texel queried 4 times each.
REFERENCE_QUERIES = 4 * RECIPE.reference_iterations
#: When a NeuMIP training stops: a plateau of its held-out loss once the blur has faded
#: (84,000 queries per texel on the recipe's schedule), capped at twice the recipe's effort.
STOP = StopRule(max_queries_per_texel=2 * REFERENCE_QUERIES, eval_every=2000)
#: The cap of the quick configuration (its blur compressed to half of it).
QUICK_CAP = 20_000


def blur_sigma(queries: float, span: float, recipe: NeuMIPRecipe = RECIPE) -> float:
    """The texture blur σ (texels) after ``queries`` training queries per texel: NeuMIP's
    schedule over its ``reference_iterations``, mapped onto ``span`` queries per texel (the
    recipe's own mapping: 4 queries per texel per iteration, ``span`` = 120,000)."""
    t = queries * recipe.reference_iterations / max(span, 1e-9)
    s = recipe.blur_sigma0 * math.exp(-t * math.log(recipe.blur_sigma0)
                                      / recipe.blur_fall_iterations)  # fmt: skip
    return max(s, recipe.blur_floor)


def blur_fades_at(span: float, recipe: NeuMIPRecipe = RECIPE) -> float:
    """The queries per texel at which :func:`blur_sigma` reaches its floor: before it, the
    loss measures a blurred texture, so the stop rule is not tested."""
    t = (recipe.blur_fall_iterations * math.log(recipe.blur_sigma0 / recipe.blur_floor)
         / math.log(recipe.blur_sigma0))  # fmt: skip
    return t * span / recipe.reference_iterations


def circular_blur(n: int, sigma: float, device: torch.device | str = "cpu") -> torch.Tensor:
    """(n, n) row-normalised Gaussian weights over the wrapped distance (the texture wraps):
    ``blur(T) = G_H · T · G_Wᵀ``, on ``device``."""
    i = torch.arange(n, dtype=torch.float32, device=device)
    d = (i[:, None] - i[None, :]).abs()
    d = torch.minimum(d, n - d)
    g = torch.exp(-0.5 * (d / sigma) ** 2)
    return g / g.sum(1, keepdim=True)


class NeuMIPMethod(NeuralMethod):
    """NeuMIP without neural offset, one texture and MLP per material and budget.

    Effort: every iteration queries every texel ``queries_per_step`` times (NeuMIP: a batch of
    4 full images, each pixel with its own random light and view), from a pool of ``pool``
    random samples per texel; the blur schedule spans ``blur_queries_per_texel`` (the
    recipe's 120,000); training runs until the loss on ``heldout`` held-out queries on each of
    ``heldout_texels`` texels plateaus after the blur has faded (:data:`STOP`), at most
    ``max_queries_per_texel``.
    """

    name = "neumip"
    label = "NeuMIP (no offset)"
    scope = "per_material"
    matchings = MATCHINGS
    recipe = RECIPE

    def __init__(
        self,
        max_queries_per_texel: float = STOP.max_queries_per_texel,
        eval_every: float = STOP.eval_every,
        tolerance: float = STOP.tolerance,
        blur_queries_per_texel: float = REFERENCE_QUERIES,
        queries_per_step: int = 2,
        pool: int = 4000,
        heldout: int = 16,
        heldout_texels: int = 4096,
        seed: int | None = None,
        threads: int | None = None,
        progress: bool | None = None,
        device: str | None = None,
    ) -> None:
        super().__init__(seed, threads, progress, device)
        self.max_queries_per_texel = float(max_queries_per_texel)
        self.eval_every = float(eval_every)
        self.tolerance = float(tolerance)
        self.blur_queries_per_texel = float(blur_queries_per_texel)
        self.queries_per_step = int(queries_per_step)
        self.pool = int(pool)
        self.heldout = int(heldout)
        self.heldout_texels = int(heldout_texels)
        if self.heldout < 1 or self.heldout_texels < 1:
            raise ValueError(f"heldout and heldout_texels must be >= 1 (the stop rule is judged "
                             f"on held-out queries), got {heldout} and {heldout_texels}")

    @classmethod
    def from_config(cls, config: Any) -> NeuMIPMethod:
        device = cls.config_device(config)
        if getattr(config, "name", "full") == "quick":
            return cls(max_queries_per_texel=QUICK_CAP, blur_queries_per_texel=QUICK_CAP / 2,
                       eval_every=QUICK_CAP / 40, pool=3000, device=device)  # fmt: skip
        return cls(device=device)

    @property
    def rule(self) -> StopRule:
        return replace(STOP, max_queries_per_texel=self.max_queries_per_texel,
                       eval_every=self.eval_every, tolerance=self.tolerance,
                       min_queries_per_texel=blur_fades_at(self.blur_queries_per_texel,
                                                           self.recipe))  # fmt: skip

    def channels(self, budget_bytes: int, texels: int) -> int:
        """The largest C with 2·C·H·W + 2·(MLP parameters at C) <= ``budget_bytes``."""
        return largest_size(budget_bytes, texels, self.recipe.mlp_sizes, True)

    def training_budget(self) -> dict[str, Any]:
        return {
            "seconds": round(self.seconds_, 3),
            **self.effort_summary(),
            "cap_queries_per_texel": self.max_queries_per_texel,
            "iterations": f"until the held-out loss plateaus after the blur, at most "
                          f"ceil({self.max_queries_per_texel:g} / {self.queries_per_step})",
            "pool_per_texel": self.pool,
            "reference_queries_per_texel": REFERENCE_QUERIES,
            "stop_rule": self.rule.describe(),
            "scope": "one model per material and channel count",
        }

    def code(self, btf: BTF, budgets: Sequence[Budget]) -> list[Coding]:
        hw = btf.height * btf.width
        sizes = [self.channels(b.material_bytes, hw) for b in budgets]
        if not any(sizes):
            return [self._too_small(b, hw) for b in budgets]
        gen = seed_generator(self.seed_, "neumip", btf.name)
        out: list[Coding] = []
        dev = self.device_
        with torch_threads(self.threads):
            pool = read_pool(btf, self.pool, gen, progress=self.progress, heldout=self.heldout,
                             heldout_texels=self.heldout_texels).to(dev)
            trained: dict[int, tuple[NeuralBTF, dict[str, Any]]] = {}
            for budget, c in zip(budgets, sizes, strict=True):
                if c < 1:
                    out.append(self._too_small(budget, hw))
                    continue
                if c not in trained:
                    trained[c] = self._train(btf, pool, c)
                rec, info = trained[c]
                out.append(self.coding(rec, budget, False, info))
        return out

    def _too_small(self, budget: Budget, texels: int) -> Coding:
        mlp = 2 * mlp_params(self.recipe.mlp_sizes(1))
        return self.nothing_fits(budget, f"NeuMIP: {budget.material_bytes} B cannot hold one "
                                 f"texture channel ({2 * texels} B) and the MLP ({mlp} B)")

    def _train(self, btf: BTF, pool: SamplePool, channels: int
               ) -> tuple[NeuralBTF, dict[str, Any]]:  # fmt: skip
        t0 = time.perf_counter()
        r = self.recipe
        h, w = btf.height, btf.width
        dev = pool.values.device  # everything runs on the pool's device
        gen = seed_generator(self.seed_, "neumip", btf.name, channels)
        texture = (torch.randn(h, w, channels, generator=gen, device="cpu") * r.texture_std
                   ).to(dev).requires_grad_()  # fmt: skip
        mlp = init_mlp(r.mlp_sizes(channels), gen, dev)
        step = step_generator(gen, dev, self.seed_, "neumip", btf.name, channels)
        lxy, vxy = direction_xy(btf.lights, dev), direction_xy(btf.views, dev)
        n, s = pool.values.shape[:2]
        rows = torch.arange(n, device=dev)[:, None]
        span = self.blur_queries_per_texel

        def loss(tex: torch.Tensor, y_log: torch.Tensor, li: torch.Tensor,
                 vi: torch.Tensor) -> torch.Tensor:  # fmt: skip
            w0, b0 = mlp[0]
            a_l, a_v = direction_terms(w0, channels, lxy, vxy)
            pre = (tex @ w0[:, :channels].T + b0)[:, None] + a_l[li] + a_v[vi]
            y_hat = output(tail(pre, mlp, 0.0), "neumip")
            return (F.mse_loss(torch.log1p(y_hat.clamp_min(r.clamp_low)), y_log)
                    + r.l1_weight * F.l1_loss(y_hat, torch.expm1(y_log)))  # fmt: skip

        def loss_at(_: int, queries: float) -> torch.Tensor:
            sigma = blur_sigma(queries, span, r)
            tex = torch.einsum("ih,hwc,jw->ijc", circular_blur(h, sigma, dev), texture,
                               circular_blur(w, sigma, dev)).reshape(n, channels)  # fmt: skip
            cols = torch.randint(0, s, (n, self.queries_per_step), generator=step, device=dev)
            return loss(tex, *pool.take(rows, cols))

        ho = pool.heldout

        def heldout() -> float:  # the texture as it will be stored: unblurred
            tex = texture.reshape(n, channels)[ho.rows]
            return float(loss(tex, ho.values[:, None], ho.lights[:, None], ho.views[:, None]))

        fit = train_to_convergence([texture, *flat(mlp)], loss_at, heldout,
                                   float(self.queries_per_step), r.lr, self.rule,
                                   f"neumip {btf.name} C={channels}", self.progress)  # fmt: skip
        rec = NeuralBTF(binary16(texture), [(binary16(a), binary16(b)) for a, b in mlp],
                        btf.lights, btf.views, head="neumip", slope=0.0,
                        name=f"neumip-{btf.name}-C{channels}", threads=self.threads,
                        device=dev)  # fmt: skip
        seconds = time.perf_counter() - t0
        self.record(seconds, fit)
        info = {"channels": channels, "pool_per_texel": s, "train_seconds": round(seconds, 3),
                "heldout_queries": int(ho.rows.numel()), **fit}  # fmt: skip
        return rec, info
