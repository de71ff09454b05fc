"""[RJGW19] "Neural BTF Compression and Interpolation" (Rainer, Jakob, Ghosh, Weyrich, CGF
38(2) 2019), rebuilt small: one autoencoder per material.

Verified from the publication: an encoder compresses each texel's apparent BRDF to a small
latent vector; a decoder takes the latent and a light and a view direction and returns one
RGB value, so it is queried continuously. Everything else (widths, activation, loss,
optimiser) is our choice, collected in :class:`RJGW19Recipe`; docs/neural-baselines.md says
why. Storage: the material's latents (H·W·L binary16) **and** its decoder's weights
(binary16), both per material; the encoder is not stored (rendering does not need it).

The latent size follows the budget: the largest L with 2·H·W·L + 2·(decoder parameters at L)
<= budget (the decoder's first layer takes the L latents).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
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
    decode_latents,
    direction_xy,
    flat,
    init_mlp,
    mlp_params,
    read_pool,
    seed_generator,
    step_generator,
    tail,
    torch_threads,
)

__all__ = ["QUICK_CAP", "RECIPE", "STOP", "RJGW19Method", "RJGW19Recipe"]


@dataclass(frozen=True)
class RJGW19Recipe:
    """Our build of [RJGW19] ([R] recalled, [P] our proposal; nothing here is verified).

    * ``encoder_pairs`` — [P] the encoder sees the texel's log1p ABRDF at this many fixed
      (light, view) pairs (the same for every texel of the material), not all 22,801: a
      random angular subsample instead of the full 68,403-value input, which costs 35 M
      first-layer weights.
    * ``encoder_hidden`` — [P] fully connected widths between that input and the L latents.
    * ``decoder_hidden`` — [P] widths of the decoder [z, ω_i.xy, ω_o.xy] → … → RGB; small
      because its weights are stored per material (at 20×20 texels, L = 16 takes 12.8 KB: a
      3 × 64 decoder alone is 18 KB, a 3 × 32 one 5.8 KB).
    * ``slope`` — [R] LeakyReLU slope.
    * ``lr`` — [P] Adam, decaying geometrically from the first to the second value.
    * loss — [R] MSE of log1p(RGB) (the network predicts log1p; decoding is expm1).
    """

    encoder_pairs: int = 256
    encoder_hidden: tuple[int, ...] = (256, 128)
    decoder_hidden: tuple[int, ...] = (32, 32, 32)
    slope: float = 0.01
    lr: tuple[float, float] = (3e-3, 1e-4)

    def decoder_sizes(self, latents: int) -> list[int]:
        return [latents + 4, *self.decoder_hidden, 3]

    def encoder_sizes(self, latents: int, pairs: int) -> list[int]:
        """Widths for ``pairs`` input pairs (``encoder_pairs``, or all of a smaller grid)."""
        return [3 * pairs, *self.encoder_hidden, latents]


#: The recipe every RJGW19 coding uses (one place; docs/neural-baselines.md).
RECIPE = RJGW19Recipe()
#: When an RJGW19 training stops: a plateau of its held-out loss, tested from the fixed
#: effort it had before (2,000 queries per texel, which left it unconverged: at 10x, its
#: error at 128 latents fell 25-fold on felt12; an early stall is no plateau), capped at 50x
#: that, about 120 CPU-s per model at 30x30 texels.
STOP = StopRule(max_queries_per_texel=100_000, eval_every=500, min_queries_per_texel=2000)
#: The cap of the quick configuration (its rows say whether they converged under it).
QUICK_CAP = 20_000


class RJGW19Method(NeuralMethod):
    """One autoencoder per material and budget ([RJGW19]).

    Effort: each step draws ``texels_per_step`` texels × ``queries_per_step`` of their pooled
    samples, from a pool of ``pool`` random (light, view) samples per texel read once per
    material; training runs until the loss on ``heldout`` held-out queries on each of
    ``heldout_texels`` texels (pairs outside the pool) plateaus (:data:`STOP`,
    :mod:`._convergence`), at most ``max_queries_per_texel`` training queries per texel.
    """

    name = "rjgw19"
    label = "RJGW19"
    scope = "per_material"
    matchings = MATCHINGS
    recipe = RECIPE

    def __init__(
        self,
        max_queries_per_texel: float = STOP.max_queries_per_texel,
        eval_every: float = STOP.eval_every,
        tolerance: float = STOP.tolerance,
        texels_per_step: int = 32,
        queries_per_step: int = 32,
        pool: int = 4000,
        heldout: int = 16,
        heldout_texels: int = 2048,
        seed: int | None = None,
        threads: int | None = None,
        progress: bool | None = None,
        device: str | None = None,
    ) -> None:
        super().__init__(seed, threads, progress, device)
        self.max_queries_per_texel = float(max_queries_per_texel)
        self.eval_every = float(eval_every)
        self.tolerance = float(tolerance)
        self.texels_per_step = int(texels_per_step)
        self.queries_per_step = int(queries_per_step)
        self.pool = int(pool)
        self.heldout = int(heldout)
        self.heldout_texels = int(heldout_texels)
        if self.heldout < 1 or self.heldout_texels < 1:
            raise ValueError(f"heldout and heldout_texels must be >= 1 (the stop rule is judged "
                             f"on held-out queries), got {heldout} and {heldout_texels}")

    @classmethod
    def from_config(cls, config: Any) -> RJGW19Method:
        device = cls.config_device(config)
        if getattr(config, "name", "full") == "quick":
            return cls(max_queries_per_texel=QUICK_CAP, pool=3000, device=device)
        return cls(device=device)

    @property
    def rule(self) -> StopRule:
        return replace(STOP, max_queries_per_texel=self.max_queries_per_texel,
                       eval_every=self.eval_every, tolerance=self.tolerance,
                       min_queries_per_texel=min(STOP.min_queries_per_texel,
                                                 self.max_queries_per_texel))  # fmt: skip

    def latent_size(self, budget_bytes: int, texels: int) -> int:
        """The largest L whose latents and decoder fit ``budget_bytes`` (0: none)."""
        return largest_size(budget_bytes, texels, self.recipe.decoder_sizes, True)

    def training_budget(self) -> dict[str, Any]:
        return {
            "seconds": round(self.seconds_, 3),
            **self.effort_summary(),
            "cap_queries_per_texel": self.max_queries_per_texel,
            "pool_per_texel": self.pool,
            "iterations": f"until the held-out loss plateaus, at most "
                          f"ceil({self.max_queries_per_texel:g}·H·W / "
                          f"({self.texels_per_step}·{self.queries_per_step})) per model",
            "stop_rule": self.rule.describe(),
            "scope": "one model per material and latent size",
        }  # fmt: skip

    def code(self, btf: BTF, budgets: Sequence[Budget]) -> list[Coding]:
        hw = btf.height * btf.width
        sizes = [self.latent_size(b.material_bytes, hw) for b in budgets]
        out: list[Coding] = []
        if not any(sizes):
            return [self._too_small(b, hw) for b in budgets]
        nl, nv = len(btf.lights), len(btf.views)
        gen = seed_generator(self.seed_, "rjgw19", btf.name)
        probes = np.sort(torch.randperm(nl * nv, generator=gen, device="cpu")
                         [: self.recipe.encoder_pairs].numpy())  # fmt: skip
        dev = self.device_
        with torch_threads(self.threads):
            pool = read_pool(btf, self.pool, gen, shared_pairs=probes, progress=self.progress,
                             heldout=self.heldout, heldout_texels=self.heldout_texels).to(dev)
            trained: dict[int, tuple[NeuralBTF, dict[str, Any]]] = {}
            for budget, size in zip(budgets, sizes, strict=True):
                if size < 1:
                    out.append(self._too_small(budget, hw))
                    continue
                if size not in trained:  # both matchings may ask for the same L
                    trained[size] = self._train(btf, pool, size)
                rec, info = trained[size]
                out.append(self.coding(rec, budget, False, info))
        return out

    def _too_small(self, budget: Budget, texels: int) -> Coding:
        dec = 2 * mlp_params(self.recipe.decoder_sizes(1))
        return self.nothing_fits(budget, f"RJGW19: {budget.material_bytes} B cannot hold one "
                                 f"latent per texel ({2 * texels} B) and the per-material "
                                 f"decoder ({dec} B at L = 1)")  # fmt: skip

    def _train(self, btf: BTF, pool: SamplePool, size: int) -> tuple[NeuralBTF, dict[str, Any]]:
        """Train the encoder and decoder of latent size ``size`` on ``pool``; the coding's
        reconstruction from the binary16 latents and weights. Everything runs on the pool's
        device."""
        t0 = time.perf_counter()
        r = self.recipe
        dev = pool.values.device
        gen = seed_generator(self.seed_, "rjgw19", btf.name, size)
        pairs = pool.shared.shape[1]
        enc = init_mlp(r.encoder_sizes(size, pairs), gen, dev)
        dec = init_mlp(r.decoder_sizes(size), gen, dev)
        step = step_generator(gen, dev, self.seed_, "rjgw19", btf.name, size)
        x = pool.shared.reshape(pool.shared.shape[0], -1)  # (texels, 3·pairs)
        lxy, vxy = direction_xy(btf.lights, dev), direction_xy(btf.views, dev)
        n, s = pool.values.shape[:2]
        b = min(self.texels_per_step, n)

        def encode(xb: torch.Tensor) -> torch.Tensor:
            return tail(F.linear(xb, *enc[0]), enc, r.slope)

        def loss_at(_: int, __: float) -> torch.Tensor:
            rows = torch.randint(0, n, (b,), generator=step, device=dev)
            cols = torch.randint(0, s, (b, self.queries_per_step), generator=step, device=dev)
            y, li, vi = pool.take(rows[:, None], cols)
            return F.mse_loss(decode_latents(dec, encode(x[rows]), li, vi, lxy, vxy, r.slope), y)

        ho = pool.heldout
        ho_texels, ho_index = torch.unique(ho.rows, return_inverse=True)

        def heldout() -> float:
            z = encode(x[ho_texels])
            pred = decode_latents(dec, z[ho_index], ho.lights[:, None],
                                  ho.views[:, None], lxy, vxy, r.slope)[:, 0]  # fmt: skip
            return float(F.mse_loss(pred, ho.values))

        fit = train_to_convergence(flat(enc) + flat(dec), loss_at, heldout,
                                   b * self.queries_per_step / n, r.lr, self.rule,
                                   f"rjgw19 {btf.name} L={size}", self.progress)  # fmt: skip
        with torch.no_grad():
            z = encode(x)
        latents = binary16(z).reshape(btf.height, btf.width, size)
        rec = NeuralBTF(latents, [(binary16(w), binary16(bb)) for w, bb in dec], btf.lights,
                        btf.views, head="log1p", slope=r.slope, name=f"rjgw19-{btf.name}-L{size}",
                        threads=self.threads, device=dev)  # fmt: skip
        seconds = time.perf_counter() - t0
        self.record(seconds, fit)
        info = {"latent_size": size, "encoder_params": mlp_params(r.encoder_sizes(size, pairs)),
                "encoder_pairs": pairs, "pool_per_texel": s, "train_seconds": round(seconds, 3),
                "heldout_queries": int(ho.rows.numel()), **fit}  # fmt: skip
        return rec, info
