"""Mitsuba 3 plugins for SparseBTF materials: ``import sparsebtf.mitsuba`` registers them.

>>> import sparsebtf.mitsuba as sbm            # doctest: +SKIP
>>> import mitsuba as mi                       # doctest: +SKIP
>>> bsdf = mi.load_dict({"type": "sparsebtf", "filename": "stone.coded.h5",
...                      "uv_scale": 4.0, "interpolation": "linear"})   # doctest: +SKIP

On import, unless a Mitsuba variant is already set, this module finds a libLLVM that Dr.Jit can
use (probed in a subprocess: LLVM 15/16 abort the whole process, see
:mod:`sparsebtf.rendering.llvm`), selects ``llvm_ad_rgb`` — or ``scalar_rgb`` with a message on
stderr when there is none — and registers two BSDF plugins for the active variant:

* ``sparsebtf`` — a coded file evaluated with Eq. 5/6 in Dr.Jit,
* ``sparsebtf_dense`` — a dense BTF table, the uncompressed reference.

Import this module **before** ``mitsuba``/``drjit`` are first used, so that
``DRJIT_LIBLLVM_PATH`` is set in time. After switching variants call :func:`register` again.
Parameters and conventions: :mod:`sparsebtf.rendering.mitsuba_bsdf` and ``docs/rendering.md``.
"""

from __future__ import annotations

import sys
from typing import Any

from .rendering.mitsuba_bsdf import DENSE_PLUGIN, PLUGIN, add_material
from .rendering.mitsuba_bsdf import register as _register

__all__ = ["DENSE_PLUGIN", "PLUGIN", "add_material", "register", "setup", "variant_message"]

variant_message = ""
_warned: list[str] = []


def setup(backend: str = "auto", quiet: bool = False) -> str:
    """Choose and set a Mitsuba variant (unless one is set), register the plugins; the variant.

    ``backend``: "auto" (llvm, else scalar), "llvm", "cuda" (GPU if it works), "scalar".
    With a variant already active and ``backend="auto"`` that variant is kept.
    """
    global variant_message
    from .rendering.llvm import choose_variant

    variant, why = choose_variant(backend)
    import mitsuba as mi

    current = mi.variant()
    if current is None or backend != "auto":
        if current != variant:
            mi.set_variant(variant)
        variant_message = why
        if variant == "scalar_rgb" and backend != "scalar" and not quiet and not _warned:
            _warned.append(why)
            print(f"sparsebtf.mitsuba: {why}", file=sys.stderr)
    elif current != variant:
        variant_message = f"keeping the active Mitsuba variant {current}"
    else:
        variant_message = why
    return _register()


def register() -> str:
    """Register the plugins for the active variant (after ``mi.set_variant``); the variant."""
    return _register()


def _auto() -> Any:
    try:
        return setup()
    except ImportError as e:  # pragma: no cover - mitsuba missing
        raise ImportError(
            f"sparsebtf.mitsuba needs mitsuba>=3.9 and drjit>=1.5 ({e}); "
            "pip install mitsuba drjit"
        ) from e


variant = _auto()
