"""SparseBTF and its variants as benchmark methods (:mod:`.base` defines the interface).

* :class:`SparseBTFMethod` — the reference: log, YUV, the release's shared standardisation,
  a fixed τ per point at each storage level (ε = 0: every point holds exactly τ coefficients,
  as in the paper's tables) plus the extra τ_t of the Figure 3 curves. Its per-material bytes
  define every other method's budgets.
* :class:`RateControlMethod` — the reference's model, one byte budget over all points and
  channels, at exactly the reference's fixed-τ bytes.
* :class:`PerChannelMethod` — the same ensemble with per-channel standardisation.
* :class:`MHU19Method` — [MHU19]: the ensemble on raw linear R, G, B (no log, no YUV, no
  standardisation), τ split equally over R, G, B.

Bytes are the paper's Table 4 accounting per material: coefficients (2 B value + 3 B location)
+ membership and count (1 B each per point and channel). The shared dictionaries are not in
the per-material bytes; :meth:`~.base.Method.shared_bytes` reports them once per model.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

from ...codec import encode_levels, encode_rate_levels, train
from ...data.btf import BTF
from ...learning.codes import RELEASE_TAU_TRAIN
from ...learning.coding import DEFAULT_CANDIDATES
from ...model import CodedBTF, Model
from ...points.grid import RELEASE_PATCH
from ...runtime import coded_btf_view
from ...storage.accounting import storage_report
from ..benchmark_set import level_tau
from .base import PER_MATERIAL, Budget, Coding, FitContext, Method

__all__ = [
    "OBJECTIVE_METHODS",
    "MHU19Method",
    "PerChannelMethod",
    "RateControlMethod",
    "SparseBTFMethod",
    "coded_row",
    "objective_variant",
]


def coded_row(coded: CodedBTF, model: Model) -> dict[str, Any]:
    """A coded material's row fields: Table 4's per-material bytes (coefficients + membership
    and counts), raw bytes and ratio, the stored bytes of its schema-3 file, the shared
    dictionaries' bytes, nonzeros per channel and coefficients per data point."""
    rep = storage_report(coded, model)
    mat = rep["bytes_table4_material"]  # coefficients, membership, counts, highlight store
    p = coded.n_points
    nnz = rep["nnz"]
    return {
        "material_bytes": int(mat),
        "bytes_raw": int(rep["bytes_raw"]),
        "ratio_per_material": rep["bytes_raw"] / mat,
        # stored bytes of the schema-3 file (None for codes no coded file holds)
        "stored_codes_bytes": rep.get("bytes_stored_codes"),
        "stored_bytes": rep.get("bytes_stored"),
        "ratio_stored": rep.get("compression_ratio_per_material"),
        "bytes_dictionaries_shared": int(rep["bytes_dictionaries"]),
        "nnz": {k: int(v) for k, v in nnz.items()},
        "coefficients_per_point": sum(nnz.values()) / p,
        "n_points": p,
    }


class _Ensemble(Method):
    """An ensemble of sparse 4D dictionaries trained on the benchmark's training materials
    and coded with a fixed τ per point at each level (``ε = 0``)."""

    scope = "shared"
    #: training options of this variant's model (beside the configuration's)
    training_options: ClassVar[dict[str, Any]] = {"std_mode": "shared"}
    #: whether the configured coding objective applies (it weighs log-YUV residuals)
    weighs_objective: ClassVar[bool] = True
    #: whether each level's bytes are spent on codes and a highlight store
    #: (:mod:`sparsebtf.codec.highlights`)
    highlights: ClassVar[bool] = False

    def __init__(
        self,
        *,
        n_dictionaries: int = 8,
        patch: int = RELEASE_PATCH,
        sample: float = 0.8,
        iters: int = 20,
        tol: float = 3e-3,
        tau_train: tuple[int, int, int] = RELEASE_TAU_TRAIN,
        level_ratios: Mapping[int, float] | None = None,
        log_offset: str | float = "auto",
        candidates: int | None = DEFAULT_CANDIDATES,
        objective: str = "log",
    ) -> None:
        self.n_dictionaries = n_dictionaries
        self.patch = patch
        self.sample = sample
        self.iters = iters
        self.tol = tol
        self.tau_train = tuple(tau_train)
        #: per-material compression ratio of each storage level (default: the paper's)
        self.level_ratios = dict(level_ratios or {})
        self.log_offset = log_offset
        self.candidates = candidates
        #: the coding objective of its encodes (:mod:`sparsebtf.learning.objective`)
        self.objective = objective
        #: the method whose model this one codes with (an objective variant), or None
        self.base_: _Ensemble | None = None

    @classmethod
    def from_config(cls, config: Any) -> Method:
        return cls(
            n_dictionaries=config.n_dictionaries, patch=config.patch, sample=config.sample,
            iters=config.iters, tol=config.tol, tau_train=tuple(config.tau_train),
            level_ratios=config.ratios(), log_offset=config.log_offset,
            candidates=config.candidates,
            objective=(tuple(getattr(config, "objectives", ("log",))) or ("log",))[0]
            if cls.weighs_objective else "log",
        )  # fmt: skip

    # -- the model ----------------------------------------------------------------------------
    def train_tau(self) -> tuple[int, int, int]:
        """τ_l of this variant's training."""
        return self.tau_train

    def train_patch(self) -> int | tuple[int, ...]:
        """The patch size (or nested sizes, largest first) of this variant's training."""
        return self.patch

    def fit(self, train_btfs: Sequence[BTF], context: FitContext) -> Method:
        t0 = time.perf_counter()
        self.context_ = context
        if self.base_ is not None:  # an objective variant: the objective changes coding only
            self.model_, self.seconds_ = self.base_.model_, 0.0
            return self
        self.model_ = train(
            list(train_btfs), n_dictionaries=self.n_dictionaries, patch=self.train_patch(),
            sample=self.sample, max_iter=self.iters, tol=self.tol, seed=context.seed,
            progress=context.progress, client=context.executor, tau_train=self.train_tau(),
            **self.training_options,
        )  # fmt: skip
        self.seconds_ = time.perf_counter() - t0
        return self

    def shared_bytes(self) -> int:
        """The model's dictionaries in binary16 (every material shares them)."""
        m = self.model_
        return int(sum(2 * m.dictionary_entries(ch) for ch in m.channels))

    def training_budget(self) -> dict[str, Any]:
        training = self.model_.training
        return {
            "seconds": self.seconds_,
            "iterations": {ch: int(t.get("n_iter", 0)) for ch, t in training.items()},
            "points_per_channel": max((int(t.get("n_points", 0)) for t in training.values()),
                                      default=0),
        }  # fmt: skip

    def model_record(self) -> dict[str, Any] | None:
        """The model's entry in ``results.json``'s ``models`` (hash, parameters, training);
        None for an objective variant (its base's model, recorded there)."""
        if self.base_ is not None:
            return None
        m = self.model_
        return {"content_hash": m.content_hash, "params": m.params, "training": m.training,
                "bytes_dictionaries": self.shared_bytes(), "seconds": self.seconds_}

    # -- coding -------------------------------------------------------------------------------
    def level_point_bytes(self, btf: BTF, level: int) -> float:
        """Bytes per data point of ``btf`` at ``level``: raw binary16 / the level's ratio."""
        n_pts = (btf.height // self.patch) * (btf.width // self.patch)
        return 2 * btf.n_values / self.level_ratios[level] / n_pts

    def level_tau(self, btf: BTF, level: int) -> tuple[int, int, int]:
        """The fixed τ (Y, U, V) of ``level``: its bytes per point, split 885:64:64, chroma at
        least τ_l (:func:`~sparsebtf.evaluation.benchmark_set.level_tau`)."""
        return level_tau(self.level_point_bytes(btf, level), minimum=self.tau_train)

    def encode(
        self, btf: BTF, taus: Sequence[tuple[int, ...]], log_offset: str | float | None = None
    ) -> list[CodedBTF]:
        """``btf`` coded with every fixed τ of ``taus`` (one pass over the material)."""
        ctx = self.context_
        return encode_levels(
            btf, self.model_, list(taus), eps=0.0, allow_below_training=True,
            log_offset=self.log_offset if log_offset is None else log_offset,
            candidates=self.candidates, progress=ctx.progress, client=ctx.executor,
            objective=self.objective, highlights=self.highlights,
        )  # fmt: skip

    def coding(self, coded: CodedBTF, **info: Any) -> Coding:
        """One coded material as a :class:`~.base.Coding` (its view decodes lazily); with a
        highlight store's choice, its entries and base τ."""
        hl = coded.params.get("highlights")
        if hl is not None:
            info = {**info, "highlight_entries": hl["entries"],
                    "base_tau": list(hl["base_tau"].values())}  # fmt: skip
        row = coded_row(coded, self.model_)
        return Coding(coded_btf_view(coded), row["material_bytes"], self.shared_bytes(),
                      info={**info, **row, "log_offset": float(coded.stats.log_offset),
                            "objective": coded.objective})  # fmt: skip

    def code(self, btf: BTF, budgets: Sequence[Budget]) -> list[Coding]:
        taus = [self.level_tau(btf, b.level) for b in budgets]  # type: ignore[arg-type]
        return [self.coding(c, tau=list(t)) for t, c in zip(taus, self.encode(btf, taus),
                                                            strict=True)]

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "training_options": dict(self.training_options),
                "tau_train_used": list(self.train_tau()), "objective": self.objective,
                **({"model_of": self.base_.name} if self.base_ is not None else {})}


#: the methods a further coding objective codes again (``BenchConfig.objectives``)
OBJECTIVE_METHODS = ("sparsebtf", "rate")


def objective_variant(method: _Ensemble, objective: str) -> _Ensemble:
    """``method`` coding under ``objective`` with ``method``'s model (fitted first): rows
    ``<name>-<objective>``, e.g. ``sparsebtf-linear``."""
    v = copy.copy(method)
    v.objective = objective
    v.name = f"{method.name}-{objective}"
    v.label = f"{method.label} [{objective}]"
    v.base_ = method
    return v


class SparseBTFMethod(_Ensemble):
    """SparseBTF: the reference method (log, YUV, the release's shared standardisation).

    :meth:`code` codes each budget's level with the level's fixed τ; with ``curve=True`` it
    also codes the Figure 3 curve's τ_t (those not among the levels' τ) and returns their
    codings after the budgets' (rows with level None). ``log_offset`` overrides the
    configured rule (the true-black comparison codes with the release's 1e-5 too).
    """

    name = "sparsebtf"
    label = "SparseBTF"
    sets = ("test", "table5")
    grid = True

    def __init__(self, *, curve_taus: Sequence[tuple[int, int, int]] = (), **kw: Any) -> None:
        super().__init__(**kw)
        self.curve_taus = [tuple(t) for t in curve_taus]

    @classmethod
    def from_config(cls, config: Any) -> Method:
        m = super().from_config(config)
        assert isinstance(m, SparseBTFMethod)
        m.curve_taus = [tuple(t) for t in config.curve_taus]
        return m

    def level_budgets(self, btf: BTF, levels: Sequence[int]) -> list[Budget]:
        """The reference's budgets: each level's nominal per-material bytes (raw / ratio)."""
        return [Budget(lv, int(2 * btf.n_values / self.level_ratios[lv])) for lv in levels]

    def level_bytes_per_texel(self, levels: Sequence[int], n_values_per_texel: int) -> dict:
        """Per-material bytes per texel of each level (fixed τ spends the same on every point:
        5 B per coefficient + 2 B per point and channel, over patch² texels)."""
        out = {}
        for lv in levels:
            point = 2 * n_values_per_texel * self.patch**2 / self.level_ratios[lv]
            tau = level_tau(point, minimum=self.tau_train)
            out[lv] = (5 * sum(tau) + 2 * len(tau)) / self.patch**2
        return out

    def code(  # type: ignore[override]
        self,
        btf: BTF,
        budgets: Sequence[Budget],
        *,
        curve: bool = False,
        log_offset: str | float | None = None,
    ) -> list[Coding]:
        taus = [self.level_tau(btf, b.level) for b in budgets]  # type: ignore[arg-type]
        extra = [t for t in self.curve_taus if tuple(t) not in taus] if curve else []
        alls = taus + extra
        coded = self.encode(btf, alls, log_offset)
        return [self.coding(c, tau=list(t)) for t, c in zip(alls, coded, strict=True)]


class RateControlMethod(_Ensemble):
    """The reference's model with rate control: one byte budget over all points and channels
    (``encode_rate``), aimed at exactly the reference's fixed-τ bytes on each material."""

    name = "rate"
    label = "SparseBTF + rate control"
    matchings = (PER_MATERIAL,)
    grid = True

    def fit(self, train_btfs: Sequence[BTF], context: FitContext) -> Method:
        # no model of its own: the reference's (rate control is a coding rule)
        ref = context.reference
        if ref is None or not hasattr(ref, "model_"):
            raise ValueError("rate control codes with the fitted reference's model; fit "
                             "SparseBTF first and pass it as FitContext.reference")
        self.context_ = context
        self.model_ = ref.model_
        self.seconds_ = 0.0
        return self

    def model_record(self) -> None:  # type: ignore[override]
        return None  # the reference's model, recorded there

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "uses_reference_model": True}

    def code(self, btf: BTF, budgets: Sequence[Budget]) -> list[Coding]:
        ctx = self.context_
        targets = [b.material_bytes for b in budgets]
        coded = encode_rate_levels(btf, self.model_, targets, progress=ctx.progress,
                                   log_offset=self.log_offset, candidates=self.candidates,
                                   client=ctx.executor, objective=self.objective)  # fmt: skip
        return [self.coding(c, tau=list(c.params["tau"].values()),
                            target_bytes=c.params["rate_control"]["target_material_bytes"])
                for c in coded]  # fmt: skip


class PerChannelMethod(_Ensemble):
    """The same ensemble with per-channel standardisation statistics (a release choice), coded
    at each level's fixed τ like the reference."""

    name = "per_channel"
    label = "SparseBTF, per-channel std"
    training_options: ClassVar[dict[str, Any]] = {"std_mode": "per_channel"}


class MHU19Method(_Ensemble):
    """[MHU19]: the ensemble on raw linear R, G, B (no log, no YUV, no standardisation),
    trained with τ_l = round(Σ τ_l / 3) per channel and coded with each level's bytes split
    equally over R, G, B."""

    name = "raw"
    label = "[MHU19] (raw RGB)"
    grid = True
    # raw linear R, G, B: the paper's rule already minimises the linear-RGB error (Parseval
    # on unstandardised values), and the weighted objectives need log-YUV points
    weighs_objective = False
    training_options: ClassVar[dict[str, Any]] = {"std_mode": "shared", "preprocessing": "identity"}

    def train_tau(self) -> tuple[int, int, int]:
        t = max(1, round(sum(self.tau_train) / 3))
        return (t, t, t)

    def level_tau(self, btf: BTF, level: int) -> tuple[int, int, int]:
        return level_tau(self.level_point_bytes(btf, level), split=(1.0, 1.0, 1.0),
                         minimum=self.train_tau())
