"""Per-material PCA (Table 5's baseline) as benchmark methods.

Each material's texel × (light, view) matrix per colour channel is factorised by a streamed
randomised SVD (:func:`~sparsebtf.evaluation.baselines.fit_pca_domains`) in the log domain
(``ln(RGB + 1e-5)``, like UBO2014's own files: :class:`PCALogMethod`) or on the linear values
(:class:`PCALinearMethod`). At a budget of B bytes the total rank is the largest whose binary16
factors fit, ``2 · r · (T + A) <= B`` (T texels, A = L·V directions), shared over R, G, B by
singular value. Table 5 codes it at 1× and 2× SparseBTF's per-material bytes.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

from ...data.btf import BTF
from ..baselines import (
    PCAFit,
    allocate_ranks,
    fit_pca_domains,
    pca_bytes,
    pca_rank_for_budget,
    pca_reconstruction,
)
from .base import Budget, Coding, FitContext, Method

__all__ = ["PCALinearMethod", "PCALogMethod"]

# The last joint fit: both domains come from the same passes over a material (one read each,
# the same random sketch as a joint fit), so the second PCA method of a run reuses the first's.
_LAST: dict[str, Any] = {}


def _joint_fit(btf: BTF, max_rank: int, domains: tuple[str, ...], seed: int,
               progress: bool | None) -> dict[str, PCAFit]:  # fmt: skip
    key = (max_rank, domains, seed)
    if _LAST.get("btf") is not btf or _LAST.get("key") != key:
        fits = fit_pca_domains(btf, max_rank, domains=domains, power_iters=1,  # type: ignore
                               seed=seed, progress=progress)  # fmt: skip
        _LAST.clear()
        _LAST.update(btf=btf, key=key, fits=dict(zip(domains, fits, strict=True)))
    return _LAST["fits"]


class _PCA(Method):
    scope = "per_material"
    sets = ("table5",)
    factors = (1, 2)
    domain: ClassVar[str] = "log"

    def __init__(self, *, domains: Sequence[str] = ("log", "linear")) -> None:
        #: the domains fitted together (the run's configured ones; this one among them)
        self.domains = tuple(domains) if self.domain in domains else (self.domain,)

    @classmethod
    def from_config(cls, config: Any) -> Method:
        return cls(domains=tuple(config.pca_domains))

    def fit(self, train: Sequence[BTF], context: FitContext) -> Method:
        self.seed_ = context.seed
        self.progress_ = context.progress
        return self

    def code(self, btf: BTF, budgets: Sequence[Budget]) -> list[Coding]:
        n_tex = btf.height * btf.width
        n_ang = len(btf.lights) * len(btf.views)
        max_rank = max(1, pca_rank_for_budget(max(b.material_bytes for b in budgets),
                                              n_tex, n_ang))  # fmt: skip
        fit = _joint_fit(btf, max_rank, self.domains, getattr(self, "seed_", 0),
                         getattr(self, "progress_", None))[self.domain]  # fmt: skip
        out = []
        for b in budgets:
            ranks = allocate_ranks(fit, pca_rank_for_budget(b.material_bytes, n_tex, n_ang))
            nbytes = pca_bytes(ranks, n_tex, n_ang)
            info = {"ranks": list(ranks), "bytes_raw": 2 * btf.n_values,
                    "ratio_per_material": (2 * btf.n_values / nbytes) if nbytes else None,
                    "bytes_dictionaries_shared": 0}  # fmt: skip
            if sum(ranks) == 0:
                out.append(Coding(None, nbytes, info=info,
                                  note="no component fits in the budget"))
                continue
            out.append(Coding(pca_reconstruction(fit, ranks, btf), nbytes, info=info))
        return out


class PCALogMethod(_PCA):
    """Per-material PCA of ``ln(RGB + 1e-5)`` (UBO2014's own representation)."""

    name = "pca_log"
    label = "PCA (log)"
    domain = "log"
    grid = True


class PCALinearMethod(_PCA):
    """Per-material PCA of the linear RGB values."""

    name = "pca_linear"
    label = "PCA (linear)"
    domain = "linear"
