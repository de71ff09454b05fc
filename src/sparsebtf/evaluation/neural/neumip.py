"""NeuMIP (Kuznetsov et al., TOG 40(4) 2021) without its neural offset, as the paper compares
it: a neural texture of C channels at the material's resolution and a small MLP per material.

From the public code (experiment ``StandardRawLShadowNoOffset``): MLP input [ω_i.xy, ω_o.xy,
texture(C)], three hidden layers of 25 (ReLU), 6 outputs (log-YUV and a shadow term, see
:func:`~._torch.output`), texture initialised N(0, 0.1²), Adam 1e-3, loss
MSE(log1p(clamp(ŷ, −0.1)), log1p(y)) + 0.01·L1(ŷ, y), the texture blurred early in training
with σ(t) = 8·exp(−t·ln 8 / 10,000) texels (floored at 0.1) over 30,000 iterations. We keep
all of that (:class:`NeuMIPRecipe`); what differs is the budget: far fewer iterations, the
blur schedule compressed to them, a higher starting learning rate, and one texture level
(a single-scale BTF needs no pyramid). A query at a texel's centre reads that texel exactly
(bilinear lookup at the sample point), so the lookup is an index.

Storage, per material: 2·C·H·W bytes of texture + 2·(MLP parameters, which grow with C).
C is the largest that fits the budget.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F

from ...data.btf import BTF
from ..methods.base import MATCHINGS, Budget, Coding
from ._base import NeuralMethod, largest_size
from ._torch import (
    NeuralBTF,
    SamplePool,
    adam_steps,
    binary16,
    direction_terms,
    direction_xy,
    flat,
    init_mlp,
    mlp_params,
    output,
    read_pool,
    seed_generator,
    tail,
    torch_threads,
)

__all__ = ["RECIPE", "NeuMIPMethod", "NeuMIPRecipe", "blur_sigma", "circular_blur"]


@dataclass(frozen=True)
class NeuMIPRecipe:
    """NeuMIP without offset ([V] from its public code; [P] our change for the budget).

    * ``hidden`` (25, 25, 25), ReLU, 6 outputs — [V].
    * ``texture_std`` 0.1 — [V] N(0, σ²) initial texture.
    * ``l1_weight`` 0.01, ``clamp_low`` −0.1 — [V] the loss.
    * ``blur_sigma0`` 8, ``blur_floor`` 0.1, ``blur_fall_iterations`` 10,000 of
      ``reference_iterations`` 30,000 — [V] σ(t) = 8·exp(−t·ln 8/10,000); [P] we map our
      iterations onto the reference's 30,000 so the schedule keeps its shape.
    * ``lr`` — [V] 1e-3 constant in the original over 30,000 iterations; [P] we start higher
      and decay to it, as our budget is a few hundred iterations.
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


def blur_sigma(step: int, steps: int, recipe: NeuMIPRecipe = RECIPE) -> float:
    """The texture blur σ (texels) at ``step`` of ``steps``: NeuMIP's schedule with our steps
    mapped onto its ``reference_iterations``."""
    t = step * recipe.reference_iterations / max(steps, 1)
    s = recipe.blur_sigma0 * math.exp(-t * math.log(recipe.blur_sigma0)
                                      / recipe.blur_fall_iterations)  # fmt: skip
    return max(s, recipe.blur_floor)


def circular_blur(n: int, sigma: float) -> torch.Tensor:
    """(n, n) row-normalised Gaussian weights over the wrapped distance (the texture wraps):
    ``blur(T) = G_H · T · G_Wᵀ``."""
    i = torch.arange(n, dtype=torch.float32)
    d = (i[:, None] - i[None, :]).abs()
    d = torch.minimum(d, n - d)
    g = torch.exp(-0.5 * (d / sigma) ** 2)
    return g / g.sum(1, keepdim=True)


class NeuMIPMethod(NeuralMethod):
    """NeuMIP without neural offset, one texture and MLP per material and budget.

    Effort: ``queries_per_texel`` training queries per texel; every iteration queries every
    texel ``queries_per_step`` times (NeuMIP: a batch of 4 full images, each pixel with its own
    random light and view), from a pool of ``pool`` random samples per texel.
    """

    name = "neumip"
    label = "NeuMIP (no offset)"
    scope = "per_material"
    matchings = MATCHINGS
    recipe = RECIPE

    def __init__(
        self,
        queries_per_texel: int = 2500,
        queries_per_step: int = 2,
        pool: int = 4000,
        seed: int | None = None,
        threads: int | None = None,
        progress: bool | None = None,
    ) -> None:
        super().__init__(seed, threads, progress)
        self.queries_per_texel = int(queries_per_texel)
        self.queries_per_step = int(queries_per_step)
        self.pool = int(pool)

    @classmethod
    def from_config(cls, config: Any) -> NeuMIPMethod:
        if getattr(config, "name", "full") == "quick":
            return cls(queries_per_texel=1200, pool=3000)
        return cls()

    def channels(self, budget_bytes: int, texels: int) -> int:
        """The largest C with 2·C·H·W + 2·(MLP parameters at C) <= ``budget_bytes``."""
        return largest_size(budget_bytes, texels, self.recipe.mlp_sizes, True)

    def steps(self) -> int:
        return max(1, math.ceil(self.queries_per_texel / self.queries_per_step))

    def training_budget(self) -> dict[str, Any]:
        return {
            "seconds": round(self.seconds_, 3),
            "trainings": self.trainings_,
            "queries_per_texel": self.steps() * self.queries_per_step,
            "iterations": self.steps(),
            "pool_per_texel": self.pool,
            "reference_queries_per_texel": self.recipe.reference_iterations * 4,
            "scope": "one model per material and channel count",
        }

    def code(self, btf: BTF, budgets: Sequence[Budget]) -> list[Coding]:
        hw = btf.height * btf.width
        sizes = [self.channels(b.material_bytes, hw) for b in budgets]
        if not any(sizes):
            return [self._too_small(b, hw) for b in budgets]
        gen = seed_generator(self.seed_, "neumip", btf.name)
        out: list[Coding] = []
        with torch_threads(self.threads):
            pool = read_pool(btf, self.pool, gen, progress=self.progress)
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
        gen = seed_generator(self.seed_, "neumip", btf.name, channels)
        texture = (torch.randn(h, w, channels, generator=gen) * r.texture_std).requires_grad_()
        mlp = init_mlp(r.mlp_sizes(channels), gen)
        lxy, vxy = direction_xy(btf.lights), direction_xy(btf.views)
        n, s = pool.values.shape[:2]
        steps = self.steps()
        rows = torch.arange(n)[:, None]

        def loss_at(t: int) -> torch.Tensor:
            sigma = blur_sigma(t, steps, r)
            tex = torch.einsum("ih,hwc,jw->ijc", circular_blur(h, sigma), texture,
                               circular_blur(w, sigma)).reshape(n, channels)  # fmt: skip
            cols = torch.randint(0, s, (n, self.queries_per_step), generator=gen)
            y_log, li, vi = pool.take(rows, cols)
            w0, b0 = mlp[0]
            a_l, a_v = direction_terms(w0, channels, lxy, vxy)
            pre = (tex @ w0[:, :channels].T + b0)[:, None] + a_l[li] + a_v[vi]
            y_hat = output(tail(pre, mlp, 0.0), "neumip")
            return (F.mse_loss(torch.log1p(y_hat.clamp_min(r.clamp_low)), y_log)
                    + r.l1_weight * F.l1_loss(y_hat, torch.expm1(y_log)))  # fmt: skip

        losses = adam_steps([texture, *flat(mlp)], steps, loss_at, r.lr,
                            f"neumip {btf.name} C={channels}", self.progress)  # fmt: skip
        rec = NeuralBTF(binary16(texture), [(binary16(a), binary16(b)) for a, b in mlp],
                        btf.lights, btf.views, head="neumip", slope=0.0,
                        name=f"neumip-{btf.name}-C{channels}", threads=self.threads)  # fmt: skip
        seconds = time.perf_counter() - t0
        self.seconds_ += seconds
        self.trainings_ += 1
        info = {"channels": channels, "iterations": steps,
                "queries_per_texel": steps * self.queries_per_step, "pool_per_texel": s,
                "train_seconds": round(seconds, 3), **losses}  # fmt: skip
        return rec, info
