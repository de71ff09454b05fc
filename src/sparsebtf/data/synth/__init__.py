"""Synthetic BTF materials: seven UBO2014-like classes rendered from height-field microgeometry.

Measured BTFs (Bonn UBO2014) cannot be downloaded here, so demos, tests and benchmarks use
procedural materials with the effects that make a BTF more than an SVBRDF: self-shadowing,
masking, parallax, foreshortening, inter-reflection and (for cloth) sheen. Spatial detail
comes from the photographs bundled with scikit-image mixed with seeded procedural noise.

>>> from sparsebtf.data.synth import synthesize
>>> btf = synthesize("leather", size=32, directions="tiny13", seed=1)   # lazy
>>> btf.view_block(0).shape
(32, 32, 13, 3)
"""

from __future__ import annotations

from .cache import cache_key, cache_path, cached, resolve_cache_dir
from .materials import GENERATOR_VERSION, MIN_SIZE, SyntheticMaterial, synthesize
from .microgeometry import ALL_CLASSES, EXTRA_CLASSES, MATERIAL_CLASSES
from .preview import contact_sheet, tone_map
from .surface import SurfaceMaps

__all__ = [
    "ALL_CLASSES",
    "EXTRA_CLASSES",
    "GENERATOR_VERSION",
    "MATERIAL_CLASSES",
    "MIN_SIZE",
    "SurfaceMaps",
    "SyntheticMaterial",
    "cache_key",
    "cache_path",
    "cached",
    "contact_sheet",
    "resolve_cache_dir",
    "synthesize",
    "tone_map",
]
