"""SparseBTF: sparse representation learning for Bidirectional Texture Functions (EGSR 2023).

The public API is one import::

    import sparsebtf as sb

    btf = sb.open_btf("synth:stone:20:7")          # a .btf, .zip, dense or coded .h5, synth:
    coded = sb.encode(btf, target="50x")           # the bundled "release" model; or a τ, a size
    sb.save_btf(coded, "stone.coded.h5")
    rgb = sb.decode(coded).angular_image(0, 0)     # (H, W, 3), decoded on demand

* :func:`open_btf` / :func:`save_btf` — read / write any BTF by extension;
* :func:`load_model` — a bundled model (``"release"``) or a model file;
* :func:`train` — a model from BTFs (paper §3.2);
* :func:`encode` — sparse codes at a τ, a size or a ratio, one BTF or many (§3.3);
* :class:`EncodeOptions`, :class:`TrainOptions`, :class:`Execution` — how ``encode`` and
  ``train`` work and where they run (``options=``, ``execution=``, or the same keywords);
* :func:`decode` — a coded BTF as a lazy BTF (Eq. 4);
* :class:`RuntimeBTF` — batches of (uv, ω_i, ω_o) queries and a shader's arrays (Eq. 5/6);
* :func:`blend` — inter-BTF interpolation in coefficient space (Eq. 7–9);
* :func:`capture` — a BTF rendered from a Mitsuba scene (the ``render`` extra).

The names resolve at first use (module ``__getattr__``), so ``import sparsebtf`` loads none
of NumPy's heavier neighbours (PyTorch, Mitsuba, Dask); the subpackages hold the rest.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from ._version import library_version

if TYPE_CHECKING:
    from .api import decode, encode, load_model
    from .codec.options import EncodeOptions, TrainOptions
    from .codec.train import train
    from .data.capture import capture
    from .execution import Execution
    from .open import open_btf
    from .runtime.blend import blend
    from .runtime.decoder import RuntimeBTF
    from .save import save_btf

__all__ = [
    "EncodeOptions",
    "Execution",
    "RuntimeBTF",
    "TrainOptions",
    "blend",
    "capture",
    "decode",
    "encode",
    "library_version",
    "load_model",
    "open_btf",
    "save_btf",
    "train",
]

#: Public name → the module defining it, imported at the name's first use.
_LAZY = {
    "EncodeOptions": "sparsebtf.codec.options",
    "Execution": "sparsebtf.execution",
    "RuntimeBTF": "sparsebtf.runtime.decoder",
    "TrainOptions": "sparsebtf.codec.options",
    "blend": "sparsebtf.runtime.blend",
    "capture": "sparsebtf.data.capture",
    "decode": "sparsebtf.api",
    "encode": "sparsebtf.api",
    "load_model": "sparsebtf.api",
    "open_btf": "sparsebtf.open",
    "save_btf": "sparsebtf.save",
    "train": "sparsebtf.codec.train",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later lookups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted(set(__all__) | {n for n in globals() if n.startswith("__")})

