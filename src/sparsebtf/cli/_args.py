"""Arguments several commands share: opening a BTF (with ``--crop``) and checking ``--tau``."""

from __future__ import annotations

from typing import Any

from ..errors import SparseBTFError

__all__ = ["check_tau", "open_source", "parse_crop"]


def parse_crop(text: str | None) -> tuple[slice, slice] | None:
    """``--crop R0:R1,C0:C1`` → (row slice, column slice), or None."""
    if not text:
        return None
    try:
        r, c = text.split(",")
        r0, r1 = (int(x) for x in r.split(":"))
        c0, c1 = (int(x) for x in c.split(":"))
    except ValueError:
        raise SparseBTFError(f"--crop must look like R0:R1,C0:C1, got {text!r}") from None
    return slice(r0, r1), slice(c0, c1)


def open_source(source: str, model: str | None = None, crop: str | None = None) -> Any:
    """The BTF a command argument names (``sparsebtf.open.open_btf``), cropped if asked."""
    from ..open import open_btf

    btf = open_btf(source, model)
    window = parse_crop(crop)
    if window is not None:
        from ..data.crop import CroppedBTF

        btf = CroppedBTF(btf, *window)
    return btf


def check_tau(text: str | None, flag: str = "--tau") -> str | None:
    """``--tau`` as given, after checking its syntax with the one τ parser
    (:func:`sparsebtf.model.parse_tau`): an error names the flag."""
    if text is None:
        return None
    from ..model import CHANNELS, parse_tau

    ones = dict.fromkeys(CHANNELS, 1)
    try:
        parse_tau(text, CHANNELS, full=ones, nominal=ones)
    except SparseBTFError:
        raise SparseBTFError(
            f"{flag} must be 'Y,U,V' integers (e.g. 885,64,64), one integer for every channel, "
            f"or a fraction in (0, 1) of the coded tau (e.g. 0.25); got {text!r}"
        ) from None
    return text
