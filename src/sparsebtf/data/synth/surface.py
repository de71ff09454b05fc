"""Per-texel maps of a synthetic material: height field and spatially varying reflectance.

Geometry convention (the tangent frame of :mod:`sparsebtf.data.directions`): x runs along
image columns, y runs *up* the image (towards row 0), z is the macroscopic surface normal.
Heights are in texel units, so a slope of 1 is 45°; they are zero-mean, i.e. the reference
plane onto which measured BTF images are rectified lies at the mean height.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["SHEEN_MODELS", "SurfaceMaps", "height_normals"]

#: ``none``: microfacet only; ``fibre``: anisotropic Kajiya–Kay highlight along the fibre
#: direction (woven yarns); ``velvet``: grazing "Charlie" sheen plus a retro-reflective
#: hot spot from the fibre pile (felt, carpet).
SHEEN_MODELS = ("none", "fibre", "velvet")


def height_normals(height: np.ndarray) -> np.ndarray:
    """Unit normals (H, W, 3) of a periodic height field (texel units), central differences."""
    h = np.asarray(height, dtype=np.float64)
    dh_dcol = 0.5 * (np.roll(h, -1, axis=1) - np.roll(h, 1, axis=1))
    dh_drow = 0.5 * (np.roll(h, -1, axis=0) - np.roll(h, 1, axis=0))
    # y points up the image, so ∂h/∂y = −∂h/∂row; n ∝ (−∂h/∂x, −∂h/∂y, 1).
    n = np.stack([-dh_dcol, dh_drow, np.ones_like(h)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return n


@dataclass(frozen=True, eq=False)
class SurfaceMaps:
    """The microgeometry and reflectance parameters of one synthetic material.

    Attributes
    ----------
    height : (H, W) float32, texel units, zero mean.
    albedo : (H, W, 3) float32 diffuse reflectance, linear RGB in [0, 1].
    specular : (H, W, 3) float32 Fresnel reflectance at normal incidence (F0), linear RGB.
    roughness : (H, W) float32 GGX α (0 = mirror, 1 = very rough).
    sheen : (H, W) float32 strength of the cloth/pile sheen lobe (0 where absent).
    fibre_angle : (H, W) float32 fibre direction in the tangent plane, radians from +x.
    sheen_model : one of :data:`SHEEN_MODELS`.
    penumbra : half width (radians) of the soft shadow edge: light-source size plus the
        sub-texel blur of real fibres and grains.
    period : characteristic feature size in texels (thread, tuft, grain, ring spacing).
    mask : (H, W) float32 in [0, 1], the share of each texel that reflects at all (0: a hole
        or a masked texel, exactly black); None: everywhere 1.
    """

    height: np.ndarray
    albedo: np.ndarray
    specular: np.ndarray
    roughness: np.ndarray
    sheen: np.ndarray
    fibre_angle: np.ndarray
    sheen_model: str = "none"
    penumbra: float = 0.12
    period: float = 8.0
    mask: np.ndarray | None = None
    normal: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        h = np.asarray(self.height, dtype=np.float64)
        h = h - h.mean()
        shape = h.shape

        def f32(name: str, a: np.ndarray, tail: tuple[int, ...] = ()) -> np.ndarray:
            arr = np.ascontiguousarray(np.broadcast_to(a, shape + tail), dtype=np.float32)
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"surface map {name!r} has non-finite values")
            arr.setflags(write=False)
            return arr

        object.__setattr__(self, "height", f32("height", h))
        object.__setattr__(self, "albedo", f32("albedo", np.clip(self.albedo, 0.0, 1.0), (3,)))
        object.__setattr__(
            self, "specular", f32("specular", np.clip(self.specular, 0.0, 1.0), (3,))
        )
        object.__setattr__(self, "roughness", f32("roughness", np.clip(self.roughness, 0.03, 1.0)))
        object.__setattr__(self, "sheen", f32("sheen", np.clip(self.sheen, 0.0, None)))
        object.__setattr__(self, "fibre_angle", f32("fibre_angle", self.fibre_angle))
        if self.sheen_model not in SHEEN_MODELS:
            raise ValueError(f"sheen_model must be one of {SHEEN_MODELS}, not {self.sheen_model!r}")
        object.__setattr__(self, "normal", f32("normal", height_normals(h), (3,)))
        if self.mask is not None:
            object.__setattr__(self, "mask", f32("mask", np.clip(self.mask, 0.0, 1.0)))

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W)."""
        return (int(self.height.shape[0]), int(self.height.shape[1]))
