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

Dr.Jit picks its libLLVM while ``import drjit`` runs. Installed with the ``render`` extra, a
start-up hook sets ``DRJIT_LIBLLVM_PATH`` to the wheel's LLVM 23, so the order of imports does
not matter; without it, import this module **before** ``mitsuba``/``drjit``. If Dr.Jit already
loaded a libLLVM older than 17 (it would abort the process on the first kernel), this import
raises :class:`sparsebtf.llvm.LLVMImportOrderError`: one line naming the library loaded and
the ``DRJIT_LIBLLVM_PATH`` to set (docs/rendering.md, "Import order"). After switching
variants call :func:`register` again.
Parameters and conventions: :mod:`sparsebtf.rendering.mitsuba` (where the plugins live) and
``docs/rendering.md``. ``variant`` is the variant chosen on import; ``variant_message`` says
why the current one was chosen, naming the libLLVM Dr.Jit actually loaded (kept up to date by
:func:`setup`).
"""

from __future__ import annotations

from typing import Any

from .llvm import LLVMImportOrderError
from .rendering.mitsuba import DENSE_PLUGIN, PLUGIN, add_material, evaluated, register, setup
from .rendering.mitsuba import variant as _variant_state

__all__ = [
    "DENSE_PLUGIN", "PLUGIN", "add_material", "evaluated", "register", "setup", "variant_message",
]

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
    except LLVMImportOrderError as e:
        raise LLVMImportOrderError(str(e)) from None  # the one line, not the search's frames
    except ImportError as e:  # pragma: no cover - mitsuba missing
        raise ImportError(
            f"sparsebtf.mitsuba needs mitsuba>=3.9 and drjit>=1.5 ({e}); "
            "pip install mitsuba drjit"
        ) from e


variant = _auto()
