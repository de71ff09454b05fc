"""Synthetic materials as lazy BTFs: :class:`SyntheticMaterial` and :func:`synthesize`.

A material is a pure function of (class, seed, size, direction set): same inputs, bit-identical
values. Rendering is vectorised over texels and lights; one view block (H, W, L, 3) is shaded
at a time after the L shadow maps have been computed once per light set.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...errors import BTFInputError
from ..btf import FunctionBTF
from ..directions import DirectionSet, by_name
from .microgeometry import ALL_CLASSES, build_surface
from .shading import BLACK_PENUMBRA, LightTable, pack, prepare_lights, shade_view
from .surface import SurfaceMaps

__all__ = [
    "GENERATOR_VERSION",
    "MIN_SIZE",
    "SyntheticMaterial",
    "check_material",
    "check_seed",
    "check_size",
    "resolve_directions",
    "synthesize",
]

#: Bump whenever a change alters rendered values: it is part of every cache key.
GENERATOR_VERSION = "1"
MIN_SIZE = 4


def check_material(material: object) -> str:
    """The canonical class name, or :class:`BTFInputError` listing the known classes."""
    name = material.strip().lower() if isinstance(material, str) else None
    if name not in ALL_CLASSES:
        raise BTFInputError(
            f"unknown material class {material!r}; known classes: {', '.join(ALL_CLASSES)}"
        )
    return name


def check_size(size: object) -> tuple[int, int]:
    """(H, W) from an int or a pair of ints, each at least :data:`MIN_SIZE` texels."""
    pair = (size, size) if not isinstance(size, tuple | list) else tuple(size)
    if len(pair) != 2:
        raise BTFInputError(f"size must be an int or a (height, width) pair, got {size!r}")
    out = []
    for s in pair:
        if isinstance(s, bool) or not isinstance(s, numbers.Integral):
            raise BTFInputError(f"size must be whole texels (int), got {size!r}")
        if int(s) < MIN_SIZE:
            raise BTFInputError(f"size must be at least {MIN_SIZE} texels per side, got {size!r}")
        out.append(int(s))
    return out[0], out[1]


def check_seed(seed: object) -> int:
    """A non-negative int seed."""
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or int(seed) < 0:
        raise BTFInputError(f"seed must be a non-negative int, got {seed!r}")
    return int(seed)


def resolve_directions(directions: str | DirectionSet) -> DirectionSet:
    """A :class:`DirectionSet` from itself or from a set name (``ubo2014``, ``tiny13``...)."""
    if isinstance(directions, DirectionSet):
        return directions
    if isinstance(directions, str):
        return by_name(directions)  # raises BTFInputError listing the known sets
    raise BTFInputError(
        f"directions must be a DirectionSet or a set name, got {type(directions).__name__}"
    )


@dataclass(eq=False)
class SyntheticMaterial:
    """A procedural height-field material of one class, renderable at any directions.

    Parameters
    ----------
    material : one of :data:`~sparsebtf.data.synth.ALL_CLASSES` (the seven UBO2014-like
        classes and ``metal``).
    size : tile size in texels, an int (square) or (H, W); at least 4.
    seed : non-negative int; every random choice derives from it.
    relief : scale of the height field (1 = natural; 0 = flat, i.e. a plain SVBRDF without
        shadows, parallax or masking).
    black : the true-black variant: no inter-reflection (shadows are exact zeros), hard
        shadows and no highlight compression (high dynamic range), like a path-traced or a
        measured BTF with deep shadows (see :mod:`~sparsebtf.data.synth.shading`).

    The maps (``height``, ``albedo``...) are built on first access and kept.
    """

    material: str
    size: tuple[int, int] | int = 64
    seed: int = 0
    relief: float = 1.0
    black: bool = False
    _maps: SurfaceMaps | None = field(default=None, init=False, repr=False)
    _lights: tuple[bytes, LightTable, np.ndarray] | None = field(
        default=None, init=False, repr=False
    )

    def __post_init__(self) -> None:
        self.material = check_material(self.material)
        self.size = check_size(self.size)
        self.seed = check_seed(self.seed)
        if not np.isfinite(self.relief) or self.relief < 0:
            raise BTFInputError(f"relief must be finite and >= 0, got {self.relief!r}")
        self.relief = float(self.relief)
        self.black = bool(self.black)

    # -- maps ------------------------------------------------------------------------------
    @property
    def maps(self) -> SurfaceMaps:
        """All per-texel maps (built once)."""
        if self._maps is None:
            self._maps = build_surface(self.material, self.size, self.seed, self.relief)
        return self._maps

    @property
    def height(self) -> np.ndarray:
        """(H, W) height field in texel units, zero mean."""
        return self.maps.height

    @property
    def albedo(self) -> np.ndarray:
        """(H, W, 3) diffuse albedo, linear RGB."""
        return self.maps.albedo

    @property
    def normal(self) -> np.ndarray:
        """(H, W, 3) unit normals of the height field."""
        return self.maps.normal

    # -- rendering ---------------------------------------------------------------------------
    def _light_table(self, lights: DirectionSet) -> tuple[LightTable, np.ndarray]:
        key = np.ascontiguousarray(lights.xyz, dtype=np.float64).tobytes()
        if self._lights is None or self._lights[0] != key:
            penumbra = BLACK_PENUMBRA if self.black else None
            table = prepare_lights(self.maps, lights.xyz, penumbra)
            self._lights = (key, table, pack(self.maps, table))
        return self._lights[1], self._lights[2]

    def shadow_maps(self, lights: DirectionSet) -> np.ndarray:
        """(H, W, L) soft light visibility in [0, 1] of each surface point for each light."""
        return self._light_table(lights)[0].visibility

    def view_block(self, lights: DirectionSet, view_dir: np.ndarray) -> np.ndarray:
        """All texels and lights for one view direction ``view_dir`` (3,): (H, W, L, 3) float32."""
        if not isinstance(lights, DirectionSet):
            raise BTFInputError("lights must be a DirectionSet")
        v = np.asarray(view_dir, dtype=np.float64)
        if v.shape != (3,) or not np.all(np.isfinite(v)) or np.linalg.norm(v) == 0:
            raise BTFInputError(f"view_dir must be a finite non-zero 3-vector, got {view_dir!r}")
        if v[2] < -1e-9:
            raise BTFInputError(f"view_dir points below the surface: {v.tolist()}")
        table, packed = self._light_table(lights)
        return shade_view(self.maps, table, packed, v, black=self.black)

    def render(self, lights: DirectionSet, views: DirectionSet) -> np.ndarray:
        """The whole BTF in memory, (H, W, L, V, 3) float32 — for small sets only."""
        blocks = [self.view_block(lights, v) for v in views.xyz]
        return np.stack(blocks, axis=3)

    def attrs(self, directions: DirectionSet) -> dict[str, Any]:
        """Provenance recorded with a rendered BTF."""
        return {
            "generator": "sparsebtf.data.synth",
            "generator_version": GENERATOR_VERSION,
            "material": self.material,
            "seed": self.seed,
            "size": list(self.size),
            "relief": self.relief,
            "black": self.black,
            "directions": directions.name,
        }


def synthesize(
    material: str,
    size: int | tuple[int, int] = 64,
    directions: str | DirectionSet = "ubo2014",
    seed: int = 0,
    black: bool = False,
) -> FunctionBTF:
    """A lazy synthetic BTF of class ``material``; nothing is rendered until a view is read.

    The same direction set serves as lights and views (as in UBO2014). Each view block is
    rendered on demand by :meth:`SyntheticMaterial.view_block`. ``black`` selects the
    true-black, high-dynamic-range variant (:class:`SyntheticMaterial`).
    """
    mat = SyntheticMaterial(material, size, seed, black=black)
    dirs = resolve_directions(directions)
    h, w = mat.size

    def block(v: int) -> np.ndarray:
        return mat.view_block(dirs, dirs.xyz[v])

    variant = "-black" if mat.black else ""
    name = f"synth-{mat.material}{variant}-{h}x{w}-s{mat.seed}"
    return FunctionBTF((h, w), dirs, dirs, block, name=name, attrs=mat.attrs(dirs))
