"""Methods the benchmark compares, by name (:mod:`.base` defines the interface).

The registry maps a name to ``"module:Class"`` and imports the class only when it is asked
for, so the neural methods (PyTorch, the optional ``neural`` extra) cost nothing until used
and a machine without PyTorch lists them all the same. ``--method package.module:Class``
names a user's own :class:`~.base.Method` subclass without registering it.
"""

from __future__ import annotations

import importlib

from ...errors import BTFInputError
from .base import MATCHINGS, PAPER, PER_MATERIAL, Budget, Coding, FitContext, Method

__all__ = [
    "GROUPS",
    "MATCHINGS",
    "PAPER",
    "PER_MATERIAL",
    "Budget",
    "Coding",
    "FitContext",
    "Method",
    "available_methods",
    "method_class",
    "register_method",
]

#: name → "module:Class" (relative modules start with '.': this package). The names are the
#: ``method`` of the benchmark's rows; ``--methods`` also takes the groups of :data:`GROUPS`.
_REGISTRY: dict[str, str] = {
    "sparsebtf": ".sparse:SparseBTFMethod",
    "rate": ".sparse:RateControlMethod",
    "per_channel": ".sparse:PerChannelMethod",
    "raw": ".sparse:MHU19Method",
    # beyond the paper (issue 34): training variants, not run by default
    "sparsebtf-multitau": ".beyond:MultiTauMethod",
    "sparsebtf-learntau": ".beyond:LearnTauMethod",
    "sparsebtf-precluster": ".beyond:PreclusterMethod",
    # beyond the paper (issue 35): adaptive patch sizes, not run by default
    "sparsebtf-adaptive": ".adaptive:AdaptiveMethod",
    # beyond the paper (issue 46): each level's bytes on codes and a highlight store
    "sparsebtf-highlights": ".highlights:HighlightsMethod",
    "pca_log": ".pca:PCALogMethod",
    "pca_linear": ".pca:PCALinearMethod",
    "rgjw20": "..neural.rgjw20:RGJW20Method",
    "rgjw20+ft": "..neural.rgjw20:RGJW20FineTunedMethod",
    "rjgw19": "..neural.rjgw19:RJGW19Method",
    "neumip": "..neural.neumip:NeuMIPMethod",
}
#: ``--methods`` spellings that stand for several methods
GROUPS: dict[str, tuple[str, ...]] = {
    "mhu19": ("raw",),
    "pca": ("pca_log", "pca_linear"),
    "training": ("sparsebtf-multitau", "sparsebtf-learntau", "sparsebtf-precluster"),
    "neural": ("rgjw20", "rgjw20+ft", "rjgw19", "neumip"),
}


def register_method(name: str, target: str | type[Method]) -> None:
    """Register a method class (or its ``"module:Class"`` path) under ``name``."""
    if isinstance(target, type):
        if not issubclass(target, Method):
            raise TypeError(f"{target!r} is not a sparsebtf Method subclass")
        target = f"{target.__module__}:{target.__qualname__}"
    _REGISTRY[name] = target


def available_methods() -> list[str]:
    """Every registered name, in registration order."""
    return list(_REGISTRY)


def method_class(spec: str) -> type[Method]:
    """The class of a registered ``name`` or of ``"package.module:Class"`` (one clear line
    naming what was asked for when it cannot be had)."""
    target = _REGISTRY.get(spec, spec)
    if ":" not in target:
        raise BTFInputError(
            f"unknown method {spec!r}: expected one of {', '.join(_REGISTRY)} or "
            "'package.module:Class'"
        )
    mod_name, _, cls_name = target.partition(":")
    try:
        module = importlib.import_module(mod_name, package=__name__)
    except ModuleNotFoundError as e:
        extra = " (install the neural extra: pip install 'sparsebtf[neural]')" if (
            e.name and e.name.split(".")[0] == "torch") else ""
        raise BTFInputError(f"method {spec!r}: cannot import {mod_name}: {e}{extra}") from None
    obj: object = module
    for part in cls_name.split("."):
        obj = getattr(obj, part, None)
        if obj is None:
            raise BTFInputError(f"method {spec!r}: {mod_name} has no {cls_name}")
    if not (isinstance(obj, type) and issubclass(obj, Method)):
        raise BTFInputError(
            f"method {spec!r}: {target} is not a subclass of sparsebtf.evaluation.methods.Method"
        )
    return obj
