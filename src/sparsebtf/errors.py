"""Exceptions raised for bad input: each says *what* is wrong and *where*."""

from __future__ import annotations


class SparseBTFError(ValueError):
    """Base class of every error this library raises on purpose."""


class BTFInputError(SparseBTFError):
    """A BTF, an array or a parameter given by the user is unusable (shape, rank, values)."""


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
    names the option, what it must be and the value found."""

    def __init__(self, option: str, rest: str) -> None:
        super().__init__(option + rest)
        self.option, self.rest = option, rest

    def renamed(self, name: str) -> OptionError:
        """The same refusal naming the option ``name`` (the command line's flag, ``--batch``)."""
        return OptionError(name, self.rest)
