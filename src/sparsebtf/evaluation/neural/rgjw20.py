"""[RGJW20] "Unified Neural Encoding of BTFs" (Rainer, Ghosh, Jakob, Weyrich, CGF 39(2) 2020),
rebuilt small: one encoder and one decoder shared by every material.

Verified from the publication: one network trained once on many materials projects every
texel into a shared latent space; the decoder plays the role of an analytic BRDF of the light
and view directions; the encoder places no requirement on the number or positions of the
angular samples; encoding a new material is one network evaluation per texel. The encoder's
internals are not published in what we could read: ours is a set encoder (a per-sample MLP,
a mean over the texel's samples, an MLP to the latents), our reading of "any number, any
position". Everything we chose is in :class:`RGJW20Recipe`; docs/neural-baselines.md says why.

Storage: the material's latents (H·W·L binary16) per material; the decoder's weights are
shared (reported apart, like SparseBTF's dictionaries); the encoder is not stored. One model
per latent size L: the paper's matching codes SparseBTF(level) against L = level, the
per-material matching against L = ⌊per-material bytes per texel / 2⌋ (with the decoder
shared, only the latents count). :meth:`RGJW20Method.fit` trains every size the run's levels
need.

:class:`RGJW20FineTunedMethod` is an extension, not [RGJW20]: the same networks, then each
material's latents optimised with the decoder frozen. It is its own row.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from ...data.btf import BTF
from ...errors import BTFInputError
from ..methods.base import MATCHINGS, PAPER, Budget, Coding, FitContext
from ._base import NeuralMethod
from ._convergence import StopRule, train_to_convergence
from ._torch import (
    CPU,
    HeldOut,
    Layers,
    NeuralBTF,
    SamplePool,
    activate,
    as_f32,
    binary16,
    decode_latents,
    direction_terms,
    direction_xy,
    flat,
    init_mlp,
    mlp_params,
    read_pool,
    seed_generator,
    step_generator,
    tail,
    to_device,
    torch_threads,
)

__all__ = ["FINETUNE_CAP", "QUICK_CAP", "RECIPE", "STOP", "RGJW20FineTunedMethod", "RGJW20Method",
           "RGJW20Recipe"]


@dataclass(frozen=True)
class RGJW20Recipe:
    """Our build of [RGJW20] ([R] recalled, [P] our proposal; nothing here is verified).

    * ``sample_hidden`` — [P] the set encoder's per-sample MLP: [log1p RGB, ω_i.xy, ω_o.xy]
      (7 values) → these widths (LeakyReLU), then the mean over the texel's samples.
    * ``pooled_hidden`` — [P] widths from the pooled feature to the L latents.
    * ``decoder_hidden`` — [P] widths of the shared decoder [z, ω_i.xy, ω_o.xy] → … → RGB
      (log1p). Shared, so its size costs no material bytes, only time: every scored value
      is one decoder query.
    * ``slope`` — [R] LeakyReLU slope. Loss — [R] MSE of log1p(RGB).
    * ``lr`` — [P] Adam, geometric decay; ``finetune_lr`` the same for latent fine-tuning.
    """

    sample_hidden: tuple[int, ...] = (64, 64)
    pooled_hidden: tuple[int, ...] = (128,)
    decoder_hidden: tuple[int, ...] = (64, 64, 64)
    slope: float = 0.01
    lr: tuple[float, float] = (3e-3, 1e-4)
    finetune_lr: tuple[float, float] = (1e-2, 1e-3)

    def sample_sizes(self) -> list[int]:
        return [7, *self.sample_hidden]

    def pooled_sizes(self, latents: int) -> list[int]:
        return [self.sample_hidden[-1], *self.pooled_hidden, latents]

    def decoder_sizes(self, latents: int) -> list[int]:
        return [latents + 4, *self.decoder_hidden, 3]


#: The recipe every RGJW20 model uses (one place; docs/neural-baselines.md).
RECIPE = RGJW20Recipe()
#: When RGJW20's shared training stops: a plateau of its held-out loss, tested from the 850
#: training queries per training texel it had before (3,000 steps), capped at 30,000
#: training queries per training texel (35x the 3,000 steps it had before: about 100,000
#: steps, 10 to 15 CPU-minutes per latent size, so the run's sizes together get more than
#: SparseBTF's ensemble training).
STOP = StopRule(max_queries_per_texel=30_000, eval_every=250, min_queries_per_texel=850)
#: The cap of the quick configuration.
QUICK_CAP = 6_000
#: The cap of a material's latent fine-tuning (RGJW20 + fine-tuning), in queries per texel.
FINETUNE_CAP = 20_000


@dataclass
class _Model:
    """One trained size: the encoder's layers (float32), the decoder as stored (binary16) and
    how it was trained."""

    latents: int
    sample: Layers
    pooled: Layers
    decoder16: list[tuple[np.ndarray, np.ndarray]]
    info: dict[str, Any] = field(default_factory=dict)


#: Trained models by (training set, recipe, effort, seed, L): RGJW20 and RGJW20 + fine-tuning
#: of one run share them instead of training twice (same inputs, same networks).
_TRAINED: dict[tuple[Any, ...], _Model] = {}


def _fingerprint(train: Sequence[BTF]) -> tuple[Any, ...]:
    """What identifies a training set: each material's label, shape and first texel's first
    values (a cheap read)."""
    return tuple((b.label, b.shape, b.read([0], [0], slice(0, 4), [0]).tobytes())
                 for b in train)  # fmt: skip


def encode(model: _Model, values: torch.Tensor, li: torch.Tensor, vi: torch.Tensor,
           lights: torch.Tensor, views: torch.Tensor, slope: float) -> torch.Tensor:  # fmt: skip
    """Latents (B, L) of B texels from their samples: ``values`` (B, E, 3) log1p RGB at the
    light and view indices ``li``, ``vi`` (B, E) into the tables ``lights``, ``views``."""
    w0, b0 = model.sample[0]
    a_l, a_v = direction_terms(w0, 3, lights, views)
    pre = values @ w0[:, :3].T + b0 + a_l[li] + a_v[vi]
    feature = activate(tail(pre, model.sample, slope), slope).mean(dim=1)
    return tail(F.linear(feature, *model.pooled[0]), model.pooled, slope)


class RGJW20Method(NeuralMethod):
    """[RGJW20]: trained once on the training materials, one model per latent size.

    Effort: iterations of ``texels_per_step`` texels, each giving ``encoder_samples`` of its
    pooled samples to the encoder and ``loss_samples`` others to the loss (random subsets
    teach the invariance to the samples' number and positions); ``train_texels`` random
    texels per training material, ``pool`` samples each. Training runs until the loss on
    ``heldout`` held-out queries on each of ``heldout_texels`` training texels (pairs outside
    their pools, encoded from their first ``encoder_samples`` pooled samples) plateaus
    (:data:`STOP`), at most ``max_queries_per_texel`` training queries per training texel.
    Coding a material: one encoder pass per texel over ``code_samples`` random samples.
    """

    name = "rgjw20"
    label = "RGJW20"
    scope = "shared"
    matchings = MATCHINGS
    recipe = RECIPE

    def __init__(
        self,
        max_queries_per_texel: float = STOP.max_queries_per_texel,
        eval_every: float = STOP.eval_every,
        tolerance: float = STOP.tolerance,
        texels_per_step: int = 16,
        encoder_samples: int = 128,
        loss_samples: int = 128,
        train_texels: int = 400,
        pool: int = 1024,
        code_samples: int = 2048,
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
        self.heldout = int(heldout)
        self.heldout_texels = int(heldout_texels)
        if self.heldout < 1 or self.heldout_texels < 1:
            raise ValueError(f"heldout and heldout_texels must be >= 1 (the stop rule is judged "
                             f"on held-out queries), got {heldout} and {heldout_texels}")
        self.texels_per_step = int(texels_per_step)
        self.encoder_samples = int(encoder_samples)
        self.loss_samples = int(loss_samples)
        self.train_texels = int(train_texels)
        self.pool = int(pool)
        self.code_samples = int(code_samples)
        self.models_: dict[int, _Model] = {}

    @classmethod
    def from_config(cls, config: Any) -> RGJW20Method:
        device = cls.config_device(config)
        if getattr(config, "name", "full") == "quick":
            return cls(max_queries_per_texel=QUICK_CAP, eval_every=QUICK_CAP / 40, device=device)
        return cls(device=device)

    @property
    def rule(self) -> StopRule:
        return replace(STOP, max_queries_per_texel=self.max_queries_per_texel,
                       eval_every=self.eval_every, tolerance=self.tolerance,
                       min_queries_per_texel=min(STOP.min_queries_per_texel,
                                                 self.max_queries_per_texel))  # fmt: skip

    # -- sizes ------------------------------------------------------------------------------
    def sizes_for(self, context: FitContext) -> list[int]:
        """Latent sizes the run needs: L = level (paper matching) and ⌊bytes per texel / 2⌋
        (per-material matching) for every level."""
        sizes = set()
        for level in context.levels:
            for matching in self.matchings:
                if matching == PAPER:
                    sizes.add(int(level))
                else:
                    sizes.add(int(context.level_bytes_per_texel[level] // 2))
        return sorted(s for s in sizes if s >= 1)

    def _effort(self) -> tuple[int, ...]:
        return (self.rule, self.texels_per_step, self.encoder_samples, self.loss_samples,
                self.train_texels, self.pool, self.heldout, self.heldout_texels)  # fmt: skip

    # -- fitting ----------------------------------------------------------------------------
    def fit(self, train: Sequence[BTF], context: FitContext) -> RGJW20Method:
        super().fit(train, context)
        if not train:
            raise BTFInputError(f"{self.label}: fit needs at least one training material")
        dev = self.device_
        base = (_fingerprint(train), self.recipe, self._effort(), self.seed_, str(dev))
        sizes = self.sizes_for(context)
        missing = [s for s in sizes if (*base, s) not in _TRAINED]
        if missing:
            with torch_threads(self.threads):
                pool, lxy, vxy = self._training_pool(train, dev)
                for size in missing:
                    _TRAINED[(*base, size)] = self._train(pool, lxy, vxy, size)
        self.models_ = {s: _TRAINED[(*base, s)] for s in sizes}
        return self

    def _training_pool(self, train: Sequence[BTF], device: torch.device
                       ) -> tuple[SamplePool, torch.Tensor, torch.Tensor]:  # fmt: skip
        """Up to ``train_texels`` random texels of every training material, ``pool`` samples
        each, in one pool whose direction indices point into the concatenated tables (read on
        the CPU, returned on ``device``)."""
        gen = seed_generator(self.seed_, "rgjw20-data")
        parts, lights, views = [], [], []
        offset_l = offset_v = 0
        for btf in train:
            hw = btf.height * btf.width
            texels = torch.randperm(hw, generator=gen, device="cpu")[: self.train_texels].numpy()
            p = read_pool(btf, self.pool, gen, texels=texels, progress=self.progress,
                          heldout=self.heldout, heldout_texels=self.heldout_texels)
            p.lights += offset_l
            p.views += offset_v
            parts.append(p)
            lights.append(direction_xy(btf.lights))
            views.append(direction_xy(btf.views))
            offset_l += len(btf.lights)
            offset_v += len(btf.views)
        rows = np.cumsum([0] + [p.values.shape[0] for p in parts])
        held = HeldOut(*(torch.cat(x) for x in zip(*[
            (p.heldout.rows + int(r), p.heldout.values, p.heldout.lights + int(dl),
             p.heldout.views + int(dv)) for p, r, dl, dv in zip(
                parts, rows, np.cumsum([0] + [len(b.lights) for b in train]),
                np.cumsum([0] + [len(b.views) for b in train]), strict=False)], strict=True)))
        pool = SamplePool(torch.cat([p.values for p in parts]),
                          torch.cat([p.lights for p in parts]),
                          torch.cat([p.views for p in parts]),
                          np.concatenate([p.texels for p in parts]), heldout=held)  # fmt: skip
        return pool.to(device), torch.cat(lights).to(device), torch.cat(views).to(device)

    def _train(self, pool: SamplePool, lxy: torch.Tensor, vxy: torch.Tensor,
               size: int) -> _Model:  # fmt: skip
        t0 = time.perf_counter()
        r = self.recipe
        dev = pool.values.device  # everything runs on the pool's device
        gen = seed_generator(self.seed_, "rgjw20", size)
        model = _Model(size, init_mlp(r.sample_sizes(), gen, dev),
                       init_mlp(r.pooled_sizes(size), gen, dev), [])  # fmt: skip
        dec = init_mlp(r.decoder_sizes(size), gen, dev)
        step = step_generator(gen, dev, self.seed_, "rgjw20", size)
        n, s = pool.values.shape[:2]
        b = min(self.texels_per_step, n)
        e = max(1, min(self.encoder_samples, s - 1))
        q = max(1, min(self.loss_samples, s - e))

        def loss_at(_: int, __: float) -> torch.Tensor:
            rows = torch.randint(0, n, (b, 1), generator=step, device=dev)
            order = torch.rand(b, s, generator=step, device=dev).argsort(dim=1)
            z = encode(model, *pool.take(rows, order[:, :e]), lxy, vxy, r.slope)
            y, li, vi = pool.take(rows, order[:, e:e + q])
            return F.mse_loss(decode_latents(dec, z, li, vi, lxy, vxy, r.slope), y)

        ho = pool.heldout
        ho_texels, ho_index = torch.unique(ho.rows, return_inverse=True)

        def heldout() -> float:
            z = encode(model, *pool.take(ho_texels[:, None], torch.arange(e, device=dev)), lxy,
                       vxy, r.slope)  # fmt: skip
            pred = decode_latents(dec, z[ho_index], ho.lights[:, None], ho.views[:, None],
                                  lxy, vxy, r.slope)[:, 0]  # fmt: skip
            return float(F.mse_loss(pred, ho.values))

        params = flat(model.sample) + flat(model.pooled) + flat(dec)
        fit = train_to_convergence(params, loss_at, heldout, b * q / n, r.lr, self.rule,
                                   f"rgjw20 L={size}", self.progress)  # fmt: skip
        for layers in (model.sample, model.pooled):
            for wb in layers:
                for t in wb:
                    t.requires_grad_(False)
        # kept on the CPU (a checkpoint, a Dask task): coding moves them to its device
        model.sample, model.pooled = to_device(model.sample, CPU), to_device(model.pooled, CPU)
        model.decoder16 = [(binary16(w), binary16(bb)) for w, bb in dec]
        seconds = time.perf_counter() - t0
        self.record(seconds, fit)
        model.info = {"train_seconds": round(seconds, 3), "train_texels": n,
                      "texel_visits": fit["iterations"] * b,
                      "heldout_queries": int(ho.rows.numel()),
                      "encoder_params": mlp_params(r.sample_sizes())
                      + mlp_params(r.pooled_sizes(size)), **fit}  # fmt: skip
        return model

    def shared_bytes(self) -> int:
        """Every trained decoder's binary16 weights (one per latent size)."""
        return sum(2 * sum(w.size + b.size for w, b in m.decoder16)
                   for m in self.models_.values())  # fmt: skip

    def training_budget(self) -> dict[str, Any]:
        infos = [m.info for m in self.models_.values()]
        efforts = [i["queries_per_texel"] for i in infos]
        return {
            "seconds": round(sum(i.get("train_seconds", 0.0) for i in infos), 3),
            "cpu_seconds": round(sum(i.get("cpu_seconds", 0.0) for i in infos), 3),
            "trainings": len(infos),
            "converged": f"{sum(bool(i.get('converged')) for i in infos)}/{len(infos)}",
            "latent_sizes": sorted(self.models_),
            "iterations": "until the held-out loss plateaus, at most "
                          f"{self.max_queries_per_texel:g} queries per training texel",
            "texels_per_step": self.texels_per_step,
            "queries_per_texel": round(max(efforts), 1) if efforts else 0,
            "queries_per_texel_min": round(min(efforts), 1) if efforts else 0,
            "cap_queries_per_texel": self.max_queries_per_texel,
            "stop_rule": self.rule.describe(),
            "encoder_samples": self.encoder_samples,
            "code_samples": self.code_samples,
            "scope": "one shared model per latent size, trained once",
        }

    # -- coding -----------------------------------------------------------------------------
    def code(self, btf: BTF, budgets: Sequence[Budget]) -> list[Coding]:
        if not self.models_:
            raise BTFInputError(f"{self.label}: fit() must train the shared models before "
                                f"coding {btf.label}")  # fmt: skip
        hw = btf.height * btf.width
        gen = seed_generator(self.seed_, "rgjw20-code", btf.name)
        out: list[Coding] = []
        done: dict[int, tuple[NeuralBTF, dict[str, Any]]] = {}
        dev = self.device_
        with torch_threads(self.threads):
            pool = read_pool(btf, self.code_samples, gen, progress=self.progress,
                             heldout=self.coding_heldout, heldout_texels=self.heldout_texels
                             ).to(dev)  # fmt: skip
            lxy, vxy = direction_xy(btf.lights, dev), direction_xy(btf.views, dev)
            for budget in budgets:
                want = budget.material_bytes // (2 * hw)
                fits = [s for s in self.models_ if s <= want]
                if not fits:
                    out.append(self.nothing_fits(
                        budget, f"{self.label}: {budget.material_bytes} B hold {want} binary16 "
                        f"values per texel, fewer than the smallest trained latent size "
                        f"(trained: {sorted(self.models_)})"))  # fmt: skip
                    continue
                size = max(fits)
                if size not in done:
                    done[size] = self._code_size(btf, pool, lxy, vxy, self.models_[size])
                rec, info = done[size]
                extra = {} if size == want else {"wanted_latent_size": int(want)}
                out.append(self.coding(rec, budget, True, {**info, **extra}))
        return out

    def _code_size(self, btf: BTF, pool: SamplePool, lxy: torch.Tensor, vxy: torch.Tensor,
                   model: _Model) -> tuple[NeuralBTF, dict[str, Any]]:  # fmt: skip
        r = self.recipe
        n = pool.values.shape[0]
        dev = pool.values.device  # everything runs on the pool's device
        enc = replace(model, sample=to_device(model.sample, dev),
                      pooled=to_device(model.pooled, dev))  # fmt: skip
        with torch.no_grad():
            chunk = max(1, (1 << 17) // pool.values.shape[1])  # samples per encoder pass
            cols = torch.arange(pool.values.shape[1], device=dev)
            z = torch.cat([encode(enc, *pool.take(torch.arange(i, min(i + chunk, n),
                                                               device=dev)[:, None], cols),
                                  lxy, vxy, r.slope) for i in range(0, n, chunk)])  # fmt: skip
        z, refine = self._refine(btf, pool, lxy, vxy, model, z)
        latents = binary16(z).reshape(btf.height, btf.width, model.latents)
        rec = NeuralBTF(latents, model.decoder16, btf.lights, btf.views, head="log1p",
                        slope=r.slope, name=f"{self.name}-{btf.name}-L{model.latents}",
                        threads=self.threads, device=dev)  # fmt: skip
        shared = model.info
        info = {"latent_size": model.latents, "code_samples": pool.values.shape[1],
                "converged": bool(shared["converged"]) and refine.get("converged", True),
                "loss_curve": shared["loss_curve"],
                "cpu_seconds": round(shared["cpu_seconds"] + refine.get("cpu_seconds", 0.0), 3),
                "training": {k: v for k, v in shared.items() if k != "loss_curve"},
                **refine}  # fmt: skip
        return rec, info

    def _refine(self, btf: BTF, pool: SamplePool, lxy: torch.Tensor, vxy: torch.Tensor,
                model: _Model, z: torch.Tensor) -> tuple[torch.Tensor, dict[str, Any]]:  # fmt: skip
        """The latents as stored: [RGJW20] keeps the encoder's (no optimisation)."""
        return z, {}

    @property
    def coding_heldout(self) -> int:
        """Held-out queries per texel read with a material to code (none: RGJW20 does not
        train on it)."""
        return 0


class RGJW20FineTunedMethod(RGJW20Method):
    """RGJW20's networks, then each material's latents fine-tuned with the decoder frozen (as
    stored, binary16): ``finetune_steps`` Adam steps, every texel queried
    ``finetune_queries`` times per step at its pooled samples. An extension, not [RGJW20]."""

    name = "rgjw20+ft"
    label = "RGJW20 + fine-tuning"

    def __init__(self, *args: Any, finetune_max_queries_per_texel: float = FINETUNE_CAP,
                 finetune_queries: int = 16, **kwargs: Any) -> None:  # fmt: skip
        super().__init__(*args, **kwargs)
        self.finetune_max_queries_per_texel = float(finetune_max_queries_per_texel)
        self.finetune_queries = int(finetune_queries)
        self.finetune_seconds_ = 0.0
        self.finetunes_: list[dict[str, Any]] = []

    @property
    def coding_heldout(self) -> int:
        return self.heldout

    @classmethod
    def from_config(cls, config: Any) -> RGJW20FineTunedMethod:
        device = cls.config_device(config)
        if getattr(config, "name", "full") == "quick":
            return cls(max_queries_per_texel=QUICK_CAP, eval_every=QUICK_CAP / 40,
                       finetune_max_queries_per_texel=FINETUNE_CAP / 4,
                       device=device)  # fmt: skip
        return cls(device=device)

    @property
    def finetune_rule(self) -> StopRule:
        cap = self.finetune_max_queries_per_texel
        return StopRule(max_queries_per_texel=cap, eval_every=cap / 40)

    def _count(self, seconds: float, fit: dict[str, Any], kind: str) -> None:
        if kind != "finetune":
            super()._count(seconds, fit, kind)
            return
        self.finetune_seconds_ += seconds
        self.finetunes_.append(fit)

    def training_budget(self) -> dict[str, Any]:
        done = self.finetunes_
        return {**super().training_budget(),
                "finetune_cap_queries_per_texel": self.finetune_max_queries_per_texel,
                "finetune_queries_per_texel": max((f["queries_per_texel"] for f in done),
                                                  default=0),
                "finetune_converged": f"{sum(f['converged'] for f in done)}/{len(done)}",
                "finetune_seconds": round(self.finetune_seconds_, 3)}  # fmt: skip

    def _refine(self, btf: BTF, pool: SamplePool, lxy: torch.Tensor, vxy: torch.Tensor,
                model: _Model, z: torch.Tensor) -> tuple[torch.Tensor, dict[str, Any]]:  # fmt: skip
        t0 = time.perf_counter()
        r = self.recipe
        dev = pool.values.device
        gen = seed_generator(self.seed_, "rgjw20-ft", btf.name, model.latents)
        step = step_generator(gen, dev, self.seed_, "rgjw20-ft", btf.name, model.latents)
        dec = [(as_f32(w, dev), as_f32(b, dev)) for w, b in model.decoder16]
        z = z.clone().requires_grad_()
        n, s = pool.values.shape[:2]
        rows = torch.arange(n, device=dev)[:, None]

        def loss_at(_: int, __: float) -> torch.Tensor:
            cols = torch.randint(0, s, (n, self.finetune_queries), generator=step, device=dev)
            y, li, vi = pool.take(rows, cols)
            return F.mse_loss(decode_latents(dec, z, li, vi, lxy, vxy, r.slope), y)

        ho = pool.heldout

        def heldout() -> float:
            pred = decode_latents(dec, z[ho.rows], ho.lights[:, None], ho.views[:, None], lxy,
                                  vxy, r.slope)[:, 0]  # fmt: skip
            return float(F.mse_loss(pred, ho.values))

        fit = train_to_convergence([z], loss_at, heldout, float(self.finetune_queries),
                                   r.finetune_lr, self.finetune_rule,
                                   f"rgjw20+ft {btf.name} L={model.latents}",
                                   self.progress)  # fmt: skip
        seconds = time.perf_counter() - t0
        curve = fit.pop("loss_curve")
        self.record(seconds, dict(fit), kind="finetune")
        return z.detach(), {"converged": fit["converged"], "cpu_seconds": fit["cpu_seconds"],
                            "finetune": {**fit, "loss_curve": curve,
                                         "seconds": round(seconds, 3)}}  # fmt: skip
