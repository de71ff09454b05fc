"""The benchmark's method interface: what every compared method (SparseBTF, PCA, [MHU19], the
neural encodings, a user's own) provides to ``sparsebtf bench quality``.

A method is fitted once (:meth:`Method.fit`: on the benchmark's training materials for a
method with a shared part, a no-op for one fitted per material), then codes each test
material at a list of :class:`Budget` (:meth:`Method.code`) and returns one :class:`Coding`
per budget. A coding's ``reconstruction`` is a :class:`~sparsebtf.data.btf.BTF`: it decodes
values at (texel, light, view) queries through ``read(rows, cols, lights, views)``, so the
runner scores every method with the same streamed metrics.

Storage is counted the paper's way (binary16 values, Table 4): ``material_bytes`` is what
this material alone needs (its codes, latents, textures; a per-material decoder's weights);
``shared_bytes`` serves every material (dictionaries, a shared decoder) and is reported
apart. Encoders are never counted: rendering does not need them.

Two ways to match storage (both are budgets here; every table names which):

* ``matching="paper"``: SparseBTF(L) against L binary16 values per texel
  (:data:`PAPER` — exact when the dictionaries are spread over a 400×400 material);
* ``matching="per_material"``: the per-material bytes of SparseBTF(L) on this material,
  shared parts excluded on both sides (:data:`PER_MATERIAL`).

A user's own method is a subclass registered by name (:func:`register_method`) or named on the
command line as ``--method package.module:Class``; ``docs/benchmarks.md`` has a minimal one.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

from ...data.btf import BTF
from ...points.grid import RELEASE_PATCH

__all__ = [
    "MATCHINGS",
    "PAPER",
    "PER_MATERIAL",
    "Budget",
    "Coding",
    "FitContext",
    "Method",
]

#: SparseBTF(L) ↔ L binary16 values per texel (the paper's Table 3 matching).
PAPER = "paper"
#: SparseBTF(L)'s per-material bytes on this material, shared parts excluded on both sides.
PER_MATERIAL = "per_material"
MATCHINGS = (PAPER, PER_MATERIAL)


@dataclass(frozen=True)
class Budget:
    """How many bytes one material may spend at one storage level.

    ``material_bytes`` is the per-material budget in bytes (shared parts excluded): under
    ``matching="paper"`` it is ``2 · level · H · W`` (L binary16 values per texel), under
    ``"per_material"`` SparseBTF(level)'s per-material bytes on this material. ``factor`` is
    the multiple of the reference budget (Table 5 codes PCA at 1× and 2×).
    """

    level: int | None
    material_bytes: int
    matching: str = PER_MATERIAL
    factor: float = 1.0

    def __post_init__(self) -> None:
        if self.matching not in MATCHINGS:
            raise ValueError(f"matching must be one of {MATCHINGS}, got {self.matching!r}")
        if self.material_bytes < 0:
            raise ValueError(f"material_bytes must be >= 0, got {self.material_bytes}")


@dataclass
class Coding:
    """One material coded by one method at one budget.

    ``reconstruction`` is None when nothing fits in the budget (the row then records
    ``note``). ``info`` holds the method's own row fields (τ, ranks, latent size, ...), all
    JSON-serialisable; they land in ``results.json`` beside the metrics.

    A reconstruction may also answer point queries, ``query(rows, cols, lights, views)`` with
    four equal-length integer arrays → (n, 3) float32 linear RGB: the decode-speed
    measurement (Table 1's "fast local reconstruction") times it at batch 1 and at a large
    batch. Without it, the measurement falls back to ``read`` per query.
    """

    reconstruction: BTF | None
    material_bytes: int
    shared_bytes: int = 0
    info: dict[str, Any] = field(default_factory=dict)
    note: str | None = None


@dataclass(frozen=True)
class FitContext:
    """What the runner tells a method when fitting it.

    ``levels`` are the storage levels the run codes at; ``level_bytes_per_texel`` maps each
    level to SparseBTF(level)'s per-material bytes per texel (fixed τ spends the same bytes on
    every data point, so this holds for every material size), which lets a method with one
    model per budget (RGJW20: one network per latent size) train only the sizes it will need.
    ``executor`` is the run's :class:`~sparsebtf.execution.Executor` (in process or Dask).
    """

    levels: tuple[int, ...]
    level_bytes_per_texel: Mapping[int, float]
    patch: int = RELEASE_PATCH
    seed: int = 0
    progress: bool | None = None
    executor: Any = None
    #: the run's configuration (:class:`~sparsebtf.evaluation.benchmark_set.BenchConfig`)
    config: Any = None
    #: the fitted reference method (SparseBTF) when fitting any other: a variant of it (rate
    #: control) codes with its model instead of training its own
    reference: Any = None
    #: the run's folder: pictures a method draws go under it (None: it draws none)
    out: Any = None

    def __getstate__(self) -> dict[str, Any]:
        # a live cluster connection does not survive a pickle (a checkpoint, a task): the
        # copy runs in process until the runner binds its own executor (``with_executor``)
        return {**self.__dict__, "executor": None}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)


class Method(abc.ABC):
    """A compression method compared by the benchmark.

    Class attributes: ``name`` (registry key, the ``--methods`` spelling), ``label`` (how
    tables name it), ``scope`` (``"shared"``: learns from the training materials once;
    ``"per_material"``: everything is fitted per material), ``matchings`` (the storage
    matchings it is coded under: a method whose storage is continuous in the budget, like a
    latent size, is coded under both; SparseBTF defines the budgets and is coded once),
    ``sets``, ``factors`` and ``grid`` (which materials, budget multiples and image grids).

    The estimator convention of scikit-learn: ``__init__`` stores parameters, :meth:`fit`
    learns and stores learned state in attributes ending in ``_``; :meth:`code` uses them.
    """

    name: ClassVar[str] = ""
    label: ClassVar[str] = ""
    scope: ClassVar[str] = "per_material"
    matchings: ClassVar[tuple[str, ...]] = (PER_MATERIAL,)
    #: the material sets it codes: ``"test"`` (Tables 2 and 3) and/or ``"table5"`` (the
    #: 100×100 materials of Table 5)
    sets: ClassVar[tuple[str, ...]] = ("test",)
    #: multiples of the reference budget it is coded at (Table 5 codes PCA at 1× and 2×)
    factors: ClassVar[tuple[float, ...]] = (1.0,)
    #: whether its reconstructions at the grid levels go into the image grids
    grid: ClassVar[bool] = False

    @classmethod
    def from_config(cls, config: Any) -> Method:
        """The method as the benchmark configuration ``config`` (a
        :class:`~sparsebtf.evaluation.benchmark_set.BenchConfig`) wants it; the runner builds
        every method this way. Default: ``cls()``. A method whose cost must follow the run's
        size (training iterations of a neural method in ``--quick``) overrides it."""
        return cls()

    def fit(self, train: Sequence[BTF], context: FitContext) -> Method:
        """Learn the shared part from the training materials (default: nothing to learn)."""
        return self

    @abc.abstractmethod
    def code(self, btf: BTF, budgets: Sequence[Budget]) -> list[Coding]:
        """Code ``btf`` at every budget (one :class:`Coding` each, in order)."""

    def cost_log(self) -> list[Any]:
        """What :meth:`code` added to the method's own accounting (training seconds, efforts),
        entry by entry. When the benchmark codes a material on a cluster, the task codes with a
        copy of the method and hands back the entries it added; :meth:`replay` adds them to the
        method here, so ``training_budget`` counts every material. Default: nothing kept."""
        return []

    def replay(self, entries: Sequence[Any]) -> None:  # noqa: B027 - default: nothing kept
        """Add ``entries`` of another copy's :meth:`cost_log` to this method's accounting."""

    def shared_bytes(self) -> int:
        """Bytes shared by every material (dictionaries, a shared decoder); 0 if none."""
        return 0

    def training_budget(self) -> dict[str, Any]:
        """What fitting cost: at least ``seconds``; neural methods add ``queries_per_texel``
        (training queries seen per texel) and their iterations. Reported with every result."""
        return {}

    def describe(self) -> dict[str, Any]:
        """The method's parameters for ``results.json`` (default: its public attributes)."""
        return {k: v for k, v in vars(self).items()
                if not k.startswith("_") and not k.endswith("_")}
