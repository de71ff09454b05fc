"""SparseBTF with a highlight store (issue 46), beyond the paper: ``sparsebtf-highlights``.

The reference's ensemble (its own training, the reference's options), each level's fixed τ
turned into that level's bytes and spent on a base code plus exact linear-RGB values at the
nodes where they remove the most error (:mod:`sparsebtf.codec.highlights`, ``encode
--highlights``): the rows are at most the reference's bytes, counted with the store, and
record the entries and the base τ chosen. Not run by default (``bench quality --methods
sparsebtf,sparsebtf-highlights``); its rows read like the reference's in every table.
"""

from __future__ import annotations

from typing import ClassVar

from .sparse import _Ensemble

__all__ = ["HighlightsMethod"]


class HighlightsMethod(_Ensemble):
    """The reference's ensemble, each level's bytes spent on codes and the highlight store."""

    name = "sparsebtf-highlights"
    label = "SparseBTF + highlight store"
    highlights: ClassVar[bool] = True
