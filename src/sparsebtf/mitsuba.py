"""Mitsuba 3 plugins for SparseBTF materials: ``import sparsebtf.mitsuba`` registers them.

>>> import sparsebtf.mitsuba as sbm            # doctest: +SKIP
>>> import mitsuba as mi                       # doctest: +SKIP
>>> bsdf = mi.load_dict({"type": "sparsebtf", "filename": "stone.coded.h5",
...                      "uv_scale": 4.0, "interpolation": "linear"})   # doctest: +SKIP

On import, unless a Mitsuba variant is already set, this module finds a libLLVM that Dr.Jit can
use (probed in a subprocess: LLVM 15/16 abort the whole process, see
:mod:`sparsebtf.llvm`), selects ``llvm_ad_rgb`` — or ``scalar_rgb`` with a message on
stderr when there is none — and registers two BSDF plugins for the active variant:

* ``sparsebtf`` — a coded file evaluated with Eq. 5/6 in Dr.Jit,
* ``sparsebtf_dense`` — a dense BTF table, the uncompressed reference.

Import this module **before** ``mitsuba``/``drjit`` are first used, so that
``DRJIT_LIBLLVM_PATH`` is set in time. After switching variants call :func:`register` again.
Parameters and conventions: :mod:`sparsebtf.rendering.mitsuba` (where the plugins live) and
``docs/rendering.md``. ``variant`` is the variant chosen on import; ``variant_message`` says
why the current one was chosen (kept up to date by :func:`setup`).
"""

from __future__ import annotations

from typing import Any

from .rendering.mitsuba import DENSE_PLUGIN, PLUGIN, add_material, register, setup
from .rendering.mitsuba import variant as _variant_state

__all__ = ["DENSE_PLUGIN", "PLUGIN", "add_material", "register", "setup", "variant_message"]

variant_message: str  # annotation only: the value comes from __getattr__ below


def __getattr__(name: str) -> Any:
    # setup() rebinds variant_message in its own module; read it there so this name stays
    # current after every setup(), not frozen at import.
    if name == "variant_message":
        return _variant_state.variant_message
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), "variant_message"])


def _auto() -> Any:
    try:
        return setup()
    except ImportError as e:  # pragma: no cover - mitsuba missing
        raise ImportError(
            f"sparsebtf.mitsuba needs mitsuba>=3.9 and drjit>=1.5 ({e}); "
            "pip install mitsuba drjit"
        ) from e


variant = _auto()
