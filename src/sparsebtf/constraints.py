"""One validator for option values, and the option objects built on it.

An option object (:class:`Options`: :class:`~sparsebtf.codec.options.EncodeOptions`,
:class:`~sparsebtf.codec.options.TrainOptions`, :class:`~sparsebtf.execution.Execution`) is a
small frozen dataclass with one declarative table of constraints, in the manner of
scikit-learn's ``_parameter_constraints``: each option maps to a list of what it may be, and
a value is accepted when any of them accepts it::

    constraints = {
        "candidates": [Interval(int, 1, None, unit="dictionaries per data point"), None],
        "objective": [StrOptions(OBJECTIVES, what="coding objective")],
        "progress": [bool, None],
    }

A list holds :class:`Interval` (integers or finite numbers in a range), :class:`StrOptions`
(named choices), :class:`Rule` (a predicate with its description), Python types and None.
:func:`check_option` refuses a value with one :class:`~sparsebtf.errors.OptionError` line
naming the option, what it must be and what it is; the command line gives the same line with
its flag in place of the option's name (:meth:`~sparsebtf.errors.OptionError.renamed`), so the
library and the CLI refuse a bad value alike.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import numbers
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any, ClassVar, Literal, TypeVar

from .errors import ArgumentTypeError, BTFInputError, OptionError

__all__ = [
    "Interval",
    "Options",
    "Rule",
    "StrOptions",
    "check_option",
    "describe",
    "given",
    "is_array",
    "wrong_type",
]

_O = TypeVar("_O", bound="Options")


def _number(x: float) -> str:
    return str(x) if isinstance(x, int) else f"{x:g}"


class Interval:
    """Integers (``kind`` int) or finite real numbers (``kind`` float) between ``left`` and
    ``right`` (None: unbounded), ``closed`` at "both" ends, "left", "right" or "neither";
    ``unit`` follows the range in a refusal ("an integer in [1, 4096] data points per batch")."""

    def __init__(
        self, kind: type, left: float | None, right: float | None, *,
        closed: Literal["both", "left", "right", "neither"] = "both", unit: str = "",
    ) -> None:  # fmt: skip
        if kind not in (int, float):
            raise TypeError(f"Interval kind must be int or float, not {kind!r}")
        self.kind, self.left, self.right, self.closed, self.unit = kind, left, right, closed, unit

    def accepts(self, value: Any) -> bool:
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            return False
        if self.kind is int and not isinstance(value, numbers.Integral):
            return False
        v = float(value) if self.kind is float else value
        if self.kind is float and not math.isfinite(v):
            return False
        lo_open = self.closed in ("right", "neither")
        hi_open = self.closed in ("left", "neither")
        return (self.left is None or (v > self.left if lo_open else v >= self.left)) and (
            self.right is None or (v < self.right if hi_open else v <= self.right))  # fmt: skip

    def __str__(self) -> str:
        lo, hi = self.left, self.right
        lo_open = self.closed in ("right", "neither")
        hi_open = self.closed in ("left", "neither")
        if lo is not None and hi is not None:
            where = (f"in {'(' if lo_open else '['}{_number(lo)}, {_number(hi)}"
                     f"{')' if hi_open else ']'}")  # fmt: skip
        elif lo is not None:
            where = f"{'>' if lo_open else '>='} {_number(lo)}"
        elif hi is not None:
            where = f"{'<' if hi_open else '<='} {_number(hi)}"
        else:
            where = ""
        what = "an integer" if self.kind is int else "a finite number"
        return " ".join(p for p in (what, where, self.unit) if p)


class StrOptions:
    """One of the strings ``options``; ``what`` names them in a refusal ("unknown coding
    objective 'lin'; choose one of log, linear, display"); default: the option's name."""

    def __init__(self, options: Iterable[str], *, what: str = "") -> None:
        self.options = tuple(options)
        self.what = what

    def accepts(self, value: Any) -> bool:
        return isinstance(value, str) and value in self.options

    def __str__(self) -> str:
        return ", ".join(repr(o) for o in self.options)


class Rule:
    """What ``accepts`` (a predicate) takes, described by ``description`` ("a τ: ..."). A
    predicate that refuses with its own :class:`~sparsebtf.errors.BTFInputError` (the rule's
    owner says why: :func:`~sparsebtf.model.parse_tau`) has that reason in the refusal."""

    def __init__(self, accepts: Callable[[Any], bool], description: str) -> None:
        self._accepts, self.description = accepts, description

    def accepts(self, value: Any) -> bool:
        try:
            return bool(self._accepts(value))
        except (TypeError, ValueError) as e:
            if isinstance(e, BTFInputError):
                raise
            return False

    def __str__(self) -> str:
        return self.description


#: How a refusal names a Python type among the constraints.
_TYPE_NAMES = {bool: "True or False", str: "a string", os.PathLike: "a path", tuple: "a tuple",
               list: "a list", dict: "a mapping", Mapping: "a mapping"}  # fmt: skip


def _accepts(constraint: Any, value: Any) -> bool:
    if constraint is None:
        return value is None
    if isinstance(constraint, type):
        if constraint is float:  # a plain number; True is no number
            return isinstance(value, numbers.Real) and not isinstance(value, bool)
        return isinstance(value, constraint)
    return bool(constraint.accepts(value))


def _described(constraint: Any) -> str:
    if constraint is None:
        return "None"
    if isinstance(constraint, type):
        return _TYPE_NAMES.get(constraint, f"a {constraint.__name__}")
    return str(constraint)


def describe(constraints: Sequence[Any]) -> str:
    """What a value under ``constraints`` must be, in words: "an integer >= 1 or None"."""
    parts = [_described(c) for c in constraints]
    return parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " or " + parts[-1]


def _shown(value: Any) -> str:
    """A found value in a refusal: numbers as the user wrote them (1e+09, not 1000000000.0),
    everything on one line and short."""
    if isinstance(value, float) and not isinstance(value, bool):
        short = f"{value:g}"
        text = short if not math.isfinite(value) or float(short) == value else repr(value)
    else:
        text = repr(value)
    text = " ".join(text.split())
    return text if len(text) <= 80 else text[:77] + "..."


def is_array(value: Any) -> bool:
    """Whether ``value`` is an array (NumPy's, or any with a shape and a dtype), as a refusal
    names it."""
    return hasattr(value, "shape") and hasattr(value, "dtype")


def given(value: Any) -> str:
    """What was given, short, for a refusal: an array by its type, shape and dtype (never its
    values), anything else as its (shortened) repr and its type's name."""
    kind = type(value)
    if is_array(value):
        module = kind.__module__.split(".")[0]
        return (f"a {module}.{kind.__name__} of shape {tuple(value.shape)} and dtype "
                f"{value.dtype}")  # fmt: skip
    if value is None:
        return "None"
    return f"{_shown(value)} ({kind.__name__})"


def wrong_type(function: str, argument: str, expected: str, value: Any,
               hint: str = "") -> ArgumentTypeError:  # fmt: skip
    """The refusal of an argument of the wrong type, one line: ``"<function>: <argument>
    must be <expected>, got <what was given>[; <hint>]"`` (raise it; no ``function``: no
    prefix)."""
    text = f"{function + ': ' if function else ''}{argument} must be {expected}, got {given(value)}"
    return ArgumentTypeError(text + (f"; {hint}" if hint else ""))


def check_option(name: str, value: Any, constraints: Sequence[Any]) -> None:
    """Refuse ``value`` for option ``name`` unless one of ``constraints`` accepts it: one
    :class:`~sparsebtf.errors.OptionError` line naming the option, what it must be and the value."""
    reasons = []
    for c in constraints:
        try:
            if _accepts(c, value):
                return
        except BTFInputError as e:  # a rule's owner said why
            reasons.append(str(e))
    if reasons:
        raise OptionError(name, f": {reasons[0]}")
    choices = next((c for c in constraints if isinstance(c, StrOptions)), None)
    if choices is not None and isinstance(value, str):
        others = [_described(c) for c in constraints if c is not choices and c is not None]
        listed = ", ".join(choices.options) + "".join(f" or {o}" for o in others)
        what = choices.what or name.replace("_", " ")
        raise OptionError(name, f": unknown {what} {_shown(value)}; choose one of {listed}")
    raise OptionError(name, f" must be {describe(constraints)}, got {_shown(value)}")


@dataclasses.dataclass(frozen=True, kw_only=True)
class Options:
    """Base of the option objects: a frozen dataclass whose every field has an entry in the
    class's :attr:`constraints`, checked when the object is made (and :meth:`check` then
    holds the rules between fields). Build one from defaults and keywords with :meth:`build`;
    change one with :meth:`replace`."""

    #: option name → what it may be (see the module docstring)
    constraints: ClassVar[dict[str, list[Any]]] = {}
    #: the functions' argument that takes such an object (named in a refusal)
    argument = "options"

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        declared = set(inspect.get_annotations(cls)) - {"constraints"}
        missing = declared - set(cls.constraints)
        if missing:  # a new option without its constraints is a programming error
            raise TypeError(f"{cls.__name__}: no constraints for {sorted(missing)}")

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            check_option(f.name, getattr(self, f.name), self.constraints[f.name])
        self.check()

    def check(self) -> None:
        """The rules between options (none here); one line on a failure."""

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The options, in declaration order."""
        return tuple(f.name for f in dataclasses.fields(cls))

    @classmethod
    def build(cls: type[_O], base: _O | None = None, /, **keywords: Any) -> _O:
        """``base`` (default: every option's default) with ``keywords`` in place; an option
        this object does not have is one line naming the ones it has."""
        unknown = [k for k in keywords if k not in cls.names()]
        if unknown:
            raise BTFInputError(f"unknown option {unknown[0]!r} for {cls.__name__}; options: "
                                + ", ".join(cls.names()))  # fmt: skip
        if base is None:
            return cls(**keywords)
        if not isinstance(base, cls):
            article = "an" if cls.__name__[0] in "AEIOU" else "a"
            raise wrong_type("", cls.argument, f"{article} {cls.__name__} or None", base)
        return dataclasses.replace(base, **keywords) if keywords else base

    def replace(self: _O, **changes: Any) -> _O:
        """A copy with ``changes`` (checked)."""
        return type(self).build(self, **changes)

    def changed(self) -> dict[str, Any]:
        """The options that differ from their defaults."""
        default = type(self)()
        return {n: v for n in self.names() if (v := getattr(self, n)) != getattr(default, n)}
