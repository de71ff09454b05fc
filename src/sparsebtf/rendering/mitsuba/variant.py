"""Choose the Mitsuba variant and register the plugins for it.

:func:`setup` picks a variant with :func:`sparsebtf.llvm.choose_variant` (which
probes libLLVM in a subprocess and sets ``DRJIT_LIBLLVM_PATH`` before Dr.Jit is loaded), sets it
unless the caller already chose one, and calls :func:`register`. :data:`variant_message` says
why the variant was chosen. ``mitsuba`` is imported only inside these functions, so importing
this module leaves the choice of libLLVM open.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType

from ...errors import BTFInputError
from .materials import DENSE_PLUGIN, PLUGIN

__all__ = ["evaluated", "register", "setup", "variant_message"]

#: Why the current variant was chosen (set by :func:`setup`).
variant_message = ""
# Variants whose plugin registry already holds our classes.
_registered: set[str] = set()


def setup(backend: str = "auto", quiet: bool = False) -> str:
    """Choose and set a Mitsuba variant (unless one is set), register the plugins; the variant.

    ``backend``: "auto" (llvm, else scalar), "llvm", "cuda" (GPU if it works), "scalar".
    With a variant already active and ``backend="auto"`` that variant is kept. Falling back to
    ``scalar_rgb`` when llvm was wanted prints why on stderr, once, unless ``quiet``.
    """
    global variant_message
    from ...llvm import activate_variant

    variant_message = activate_variant(backend, quiet)[1]
    return register()


def _plugins_for(variant: str) -> ModuleType:
    """:mod:`.plugins` built for ``variant``: imported, or reloaded if built for another."""
    from . import plugins

    if plugins.VARIANT != variant:
        plugins = importlib.reload(plugins)
    return plugins


def register() -> str:
    """Register ``sparsebtf`` and ``sparsebtf_dense`` for the active Mitsuba variant (idempotent).

    Returns the variant. Call after ``mi.set_variant`` (:func:`setup` does both); after
    switching variants call it again.
    """
    import mitsuba as mi

    variant = mi.variant()
    if variant is None:
        raise BTFInputError("no Mitsuba variant is set; call mi.set_variant(...) first")
    if variant in _registered:
        return variant
    if "rgb" not in variant:
        raise BTFInputError(
            f"the sparsebtf plugins need an RGB variant (llvm_ad_rgb, cuda_ad_rgb or scalar_rgb); "
            f"the active Mitsuba variant is {variant}"
        )
    plugins = _plugins_for(variant)
    # Bind the classes now: a later reload for another variant replaces the module's names.
    coded_cls, dense_cls = plugins.SparseBTFBSDF, plugins.SparseBTFDenseBSDF
    mi.register_bsdf(PLUGIN, lambda props: coded_cls(props))
    mi.register_bsdf(DENSE_PLUGIN, lambda props: dense_cls(props))
    _registered.add(variant)
    return variant


#: Dr.Jit's flags that record calls and loops symbolically (one megakernel per render).
_SYMBOLIC_FLAGS = ("SymbolicCalls", "SymbolicLoops")


@contextmanager
def evaluated() -> Iterator[None]:
    """Within the block Dr.Jit runs Mitsuba's virtual calls and loops in evaluated (wavefront)
    mode; the flags are restored on leaving.

    A wavefront of queries then reaches the ``sparsebtf`` plugin as arrays it can hand to the
    runtime's compiled lookup (``backend`` auto or numba: texel groups, register sums,
    :meth:`~sparsebtf.runtime.RuntimeBTF.evaluate`) instead of tracing the Dr.Jit kernel into a
    megakernel. Everything else in the scene runs in Dr.Jit's evaluated mode too: a kernel per
    step and bounce instead of one, which costs time of its own (measured against the
    megakernel in ``benchmarks/bench_render.py``).
    """
    import drjit as dr

    flags = [getattr(dr.JitFlag, name) for name in _SYMBOLIC_FLAGS]
    before = [dr.flag(f) for f in flags]
    try:
        for f in flags:
            dr.set_flag(f, False)
        yield
    finally:
        for f, b in zip(flags, before, strict=True):
            dr.set_flag(f, b)
