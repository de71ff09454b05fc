"""SparseBTF with a highlight store (issue 46), beyond the paper: ``sparsebtf-highlights``.

The reference's ensemble (its own training, the reference's options), each level's fixed τ
turned into that level's bytes and spent on a base code plus exact linear-RGB values at the
nodes where they remove the most error (:mod:`sparsebtf.codec.highlights`, ``encode
--highlights``): the rows are at most the reference's bytes, counted with the store. Not run
by default (``bench quality --methods sparsebtf,sparsebtf-highlights``); its rows read like
the reference's in every table.
"""

from __future__ import annotations

from collections.abc import Sequence

from ...codec import encode_levels
from ...data.btf import BTF
from ...model import CodedBTF
from .base import Budget, Coding
from .sparse import _Ensemble

__all__ = ["HighlightsMethod"]


class HighlightsMethod(_Ensemble):
    """The reference's ensemble, each level's bytes spent on codes and the highlight store."""

    name = "sparsebtf-highlights"
    label = "SparseBTF + highlight store"

    def encode(self, btf: BTF, taus: Sequence[tuple[int, ...]],
               log_offset: str | float | None = None) -> list[CodedBTF]:  # fmt: skip
        ctx = self.context_
        return encode_levels(
            btf, self.model_, list(taus), eps=0.0, allow_below_training=True,
            log_offset=self.log_offset if log_offset is None else log_offset,
            candidates=self.candidates, progress=ctx.progress, client=ctx.executor,
            objective=self.objective, highlights=True,
        )  # fmt: skip

    def code(self, btf: BTF, budgets: Sequence[Budget]) -> list[Coding]:
        taus = [self.level_tau(btf, b.level) for b in budgets]  # type: ignore[arg-type]
        return [self.coding(c, tau=list(t), highlight_entries=c.params["highlights"]["entries"],
                            base_tau=list(c.params["highlights"]["base_tau"].values()))
                for t, c in zip(taus, self.encode(btf, taus), strict=True)]  # fmt: skip
