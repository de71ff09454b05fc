"""Which methods a ``bench quality`` run compares: ``--methods`` names and groups,
``--method package.module:Class``, the defaults, and the configuration's ``with_*`` flags.

The reference method (SparseBTF, :data:`REFERENCE`) is always run: its per-material bytes
define every other method's budgets.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from ...errors import BTFInputError
from . import GROUPS, available_methods, method_class
from .base import Method

__all__ = [
    "BASELINE_METHODS",
    "NEURAL_METHODS",
    "REFERENCE",
    "default_methods",
    "parse_methods",
    "resolve_methods",
    "torch_available",
]

#: the method whose bytes define the budgets (always run, coded first)
REFERENCE = "sparsebtf"
#: the default methods that need nothing beyond the core install
BASELINE_METHODS = ("sparsebtf", "rate", "per_channel", "raw", "pca_log", "pca_linear")
#: the neural encodings (PyTorch: the ``neural`` extra), run by default when it imports
NEURAL_METHODS = GROUPS["neural"]
NEURAL_NOTE = ("the neural methods ({}) were left out: PyTorch is not installed "
               '(pip install -e ".[neural]")')  # fmt: skip


def torch_available() -> bool:
    """Whether ``import torch`` works (a broken install counts as absent)."""
    if importlib.util.find_spec("torch") is None:
        return False
    try:
        import torch  # noqa: F401
    except Exception:  # a broken install: the neural methods could not run either
        return False
    return True


def default_methods(note: Callable[[str], None] | None = None) -> list[str]:
    """Today's methods, plus the neural ones when PyTorch is there (else ``note`` hears why
    they were left out)."""
    if torch_available():
        if _neural_present():
            return [*BASELINE_METHODS, *NEURAL_METHODS]
        if note is not None:
            note(f"the neural methods ({', '.join(NEURAL_METHODS)}) were left out: this "
                 "installation has no sparsebtf.evaluation.neural")
        return list(BASELINE_METHODS)
    if note is not None:
        note(NEURAL_NOTE.format(", ".join(NEURAL_METHODS)))
    return list(BASELINE_METHODS)


def _neural_present() -> bool:
    try:
        return importlib.util.find_spec("sparsebtf.evaluation.neural") is not None
    except ImportError:
        return False


def parse_methods(text: str) -> list[str]:
    """``--methods a,b,…``: registry names or groups (:data:`~.GROUPS`), in order, each once;
    an unknown one is one error line listing the choices."""
    names: list[str] = []
    choices = [*available_methods(), *GROUPS]
    for raw in text.split(","):
        item = raw.strip()
        if not item:
            continue
        if item in GROUPS:
            expanded: Iterable[str] = GROUPS[item]
        elif item in available_methods():
            expanded = (item,)
        else:
            raise BTFInputError(f"--methods: unknown method {item!r}; choose from "
                                f"{', '.join(choices)} (or --method package.module:Class)")
        names += [n for n in expanded if n not in names]
    if not names:
        raise BTFInputError(f"--methods: no method named; choose from {', '.join(choices)}")
    return names


def _dropped(config: Any) -> set[str]:
    """Methods the configuration's flags leave out (``with_raw=False`` drops [MHU19], ...)."""
    out = set()
    if not getattr(config, "with_raw", True):
        out.add("raw")
    if not getattr(config, "with_per_channel", True):
        out.add("per_channel")
    if not getattr(config, "with_rate_control", True):
        out.add("rate")
    domains = tuple(getattr(config, "pca_domains", ("log", "linear")))
    out |= {f"pca_{d}" for d in ("log", "linear") if d not in domains}
    return out


def resolve_methods(
    methods: Sequence[str | type[Method]] | None, config: Any,
    note: Callable[[str], None] | None = None,
) -> list[type[Method]]:  # fmt: skip
    """The classes a run compares, the reference first: ``methods`` (registry names, groups,
    ``"package.module:Class"`` or classes; None: :func:`default_methods`) less what the
    configuration's flags drop, each once."""
    if methods is None:
        specs: list[str | type[Method]] = list(default_methods(note))
    else:
        specs = []
        for s in methods:
            specs += list(GROUPS[s]) if isinstance(s, str) and s in GROUPS else [s]
    dropped = _dropped(config)
    classes: list[type[Method]] = [method_class(REFERENCE)]
    for s in specs:
        if isinstance(s, str) and s in dropped:
            continue
        cls = s if isinstance(s, type) else method_class(s)
        if not (isinstance(cls, type) and issubclass(cls, Method)):
            raise BTFInputError(f"method {s!r} is not a sparsebtf Method subclass")
        if cls.name in dropped:
            continue
        if not cls.name:
            raise BTFInputError(f"method {s!r}: its class sets no 'name' (the rows' key)")
        if all(c.name != cls.name for c in classes):
            classes.append(cls)
        elif not any(c is cls for c in classes):
            raise BTFInputError(f"method {s!r}: the name {cls.name!r} is taken by another "
                                "method of this run")
    return classes
