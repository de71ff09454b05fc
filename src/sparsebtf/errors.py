"""Exceptions raised for bad input: each says *what* is wrong and *where*."""

from __future__ import annotations


class SparseBTFError(ValueError):
    """Base class of every error this library raises on purpose."""


class BTFInputError(SparseBTFError):
    """A BTF, an array or a parameter given by the user is unusable (shape, rank, values)."""


class ArgumentTypeError(BTFInputError, TypeError):
    """An argument of the wrong type (``sb.load_model(42)``, ``options=5``): one line naming the
    function, the argument, what it must be and what was given
    (:func:`~sparsebtf.constraints.wrong_type`). Both a :class:`TypeError`, Python's rule for a
    wrong type, and a :class:`BTFInputError`, so ``except SparseBTFError`` and the command
    line's one error line catch it too."""


class UnreachableTargetError(BTFInputError):
    """A rate-control target that no coded file of the input meets, found once its points are
    coded: the codes were made for that target alone."""


class FileFormatError(SparseBTFError):
    """A file is not of the expected format, truncated, corrupted, or of an unsupported version."""


class ModelMismatchError(SparseBTFError):
    """A coded file is used with a model (or another coded file) it does not belong with."""


class OutputError(SparseBTFError):
    """An output could not be written (full disk, read-only folder, bad path); the previous
    file at the target, if any, is left as it was."""


class OptionError(BTFInputError):
    """An option's value outside its constraints (:mod:`sparsebtf.constraints`): one line that
    names the option, what it must be and the value found. A rule between options names the
    others it ``mentions`` as ``{name}`` in ``rest``, so the command line can give their flags
    (:meth:`renamed`)."""

    def __init__(self, option: str, rest: str, mentions: tuple[str, ...] = ()) -> None:
        text = rest.format(**{m: m for m in mentions}) if mentions else rest
        super().__init__(option + text)
        self.option, self.rest, self.mentions = option, rest, mentions

    def renamed(self, name: str, flags: dict[str, str] | None = None) -> OptionError:
        """The same refusal naming the option ``name`` (the command line's flag, ``--batch``)
        and each option it mentions by ``flags`` (default: ``--`` and the name, dashed)."""
        if not self.mentions:
            return OptionError(name, self.rest)
        flags = flags or {}
        names = {m: flags.get(m, "--" + m.replace("_", "-")) for m in self.mentions}
        return OptionError(name, self.rest.format(**names))
