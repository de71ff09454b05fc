"""Built-in Mitsuba 3 scenes for BTF materials: a sphere on a plane, a draped cloth, a sky.

All geometry is generated here as triangle meshes with texture coordinates whose tangent frame
is right-handed: ∂p/∂u, ∂p/∂v and the normal n satisfy (∂p/∂u × ∂p/∂v)·n > 0, so Mitsuba's
shading frame (s = ∂p/∂u, t = n × s) has t along +∂p/∂v and the BTF's azimuth (from +u towards
+v) is oriented as measured. Texels are square on every surface (u and v run at the same rate
per unit length). World space is y-up, as Mitsuba's ``envmap`` expects.

* :func:`sphere_mesh` — a UV sphere; u = 2·longitude/2π (two tiles around), v = latitude
  from the south pole (one tile pole to pole).
* :func:`plane_mesh` — a square floor, ``tiles`` repeats of the texture per side.
* :func:`cloth_mesh` — a square sheet draped over a round support, with radial folds;
  u, v are the flat sheet's coordinates (the cloth is not stretched much, so texels stay
  nearly square).
* :func:`procedural_sky` — a lat-long HDR sky: a zenith-to-horizon gradient, a dark ground
  and a soft sun, as an (H, W, 3) float32 array for ``envmap``.
* :func:`scene_dict` — a complete ``mi.load_dict`` scene with a BSDF dict on the object(s),
  lit by the environment map (``light="sky"``) or by a small bright spherical area light over
  a dimmed environment (``light="emitter"``: the case where direction sampling matters most).
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np

from ..data.meshes import MeshArrays, grid_faces, mesh_object, sphere_mesh
from ..errors import BTFInputError

__all__ = [
    "LIGHTS",
    "SCENES",
    "camera",
    "cloth_mesh",
    "lod_camera",
    "plane_mesh",
    "procedural_sky",
    "scene_dict",
    "sphere_mesh",
    "sun_direction",
]

SCENES = ("sphere", "cloth")
LIGHTS = ("sky", "emitter")


def plane_mesh(size: float = 10.0, tiles: float = 5.0, height: float = 0.0) -> MeshArrays:
    """A square floor at y = ``height`` facing +y; u along +x, v along −z (right-handed)."""
    h = size / 2
    pos = np.array([[-h, height, h], [h, height, h], [h, height, -h], [-h, height, -h]])
    uv = np.array([[0.0, 0.0], [tiles, 0.0], [tiles, tiles], [0.0, tiles]])
    normals = np.tile([0.0, 1.0, 0.0], (4, 1))
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    return pos, normals, uv, faces


def cloth_mesh(
    n: int = 96,
    half_size: float = 1.5,
    support_radius: float = 0.75,
    support_height: float = 1.2,
    folds: int = 7,
    fold_depth: float = 0.16,
    tiles: float = 2.0,
    floor: float = 0.005,
) -> MeshArrays:
    """A square sheet draped over a round table, with ``folds`` radial folds in the overhang.

    The flat sheet has coordinates (a, b) ∈ [−1, 1]²·half_size; a point at radius r keeps its
    azimuth ψ. On the support (r < support_radius) the sheet is a low dome; beyond it the
    sheet hangs down, pulled in towards the support, with a sinusoidal fold pattern that grows
    with the overhang, and rests on the floor (y ≥ ``floor``). Normals are per vertex from the
    mesh (area-weighted). u = (a/half_size + 1)/2·tiles, v likewise from b; x = a-ish, z = −b-ish.
    """
    t = np.linspace(-1.0, 1.0, n + 1)
    bb, aa = np.meshgrid(t, t, indexing="ij")  # rows: v (b), cols: u (a)
    a, b = aa * half_size, bb * half_size
    r = np.hypot(a, b)
    psi = np.arctan2(b, a)
    over = np.maximum(r - support_radius, 0.0)
    dome = support_height + 0.08 * (1.0 - (np.minimum(r, support_radius) / support_radius) ** 2)
    hang = np.tanh(over / 0.35)  # 0 on the table, → 1 far out: how vertical the sheet is
    rho = np.minimum(r, support_radius) + over * (1.0 - 0.8 * hang)
    rho = rho + fold_depth * hang * over * np.sin(folds * psi)
    y = dome - over * (0.3 + 0.7 * hang)
    y = np.maximum(y, floor)
    pos = np.stack([rho * np.cos(psi), y, -rho * np.sin(psi)], -1).reshape(-1, 3)
    uv = np.stack([(aa + 1) / 2 * tiles, (bb + 1) / 2 * tiles], -1).reshape(-1, 2)
    faces = grid_faces(n, n)
    # vertex normals: area-weighted face normals
    p = pos
    fn = np.cross(p[faces[:, 1]] - p[faces[:, 0]], p[faces[:, 2]] - p[faces[:, 0]])
    normals = np.zeros_like(p)
    for j in range(3):
        np.add.at(normals, faces[:, j], fn)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    return pos, normals, uv, faces


def sun_direction(elevation_deg: float = 35.0, azimuth_deg: float = 40.0) -> np.ndarray:
    """Unit vector towards the sun (y-up); azimuth from +z (towards the camera) towards +x."""
    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    return np.array([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])


def procedural_sky(
    width: int = 256,
    height: int = 128,
    sun_elevation: float = 35.0,
    sun_azimuth: float = 40.0,
    sun_strength: float = 25.0,
    sun_size_deg: float = 5.0,
) -> np.ndarray:
    """A lat-long HDR sky (height, width, 3) float32 in Mitsuba ``envmap`` layout (y-up).

    Pixel (row, col) is the direction at θ = (row+½)/H·π from +y and φ = (col+½)/W·2π with
    d = (sin θ sin φ, cos θ, −sin θ cos φ) (Mitsuba's ``envmap`` mapping). Sky: a blue zenith
    fading to a bright horizon; ground: dark grey-brown; sun: a Gaussian lobe of peak
    ``sun_strength`` and width ``sun_size_deg``.
    """
    th = (np.arange(height) + 0.5) / height * np.pi
    ph = (np.arange(width) + 0.5) / width * 2 * np.pi
    t, p = np.meshgrid(th, ph, indexing="ij")
    d = np.stack([np.sin(t) * np.sin(p), np.cos(t), -np.sin(t) * np.cos(p)], -1)
    up = d[..., 1]
    zenith = np.array([0.25, 0.42, 0.85])
    horizon = np.array([1.0, 0.96, 0.9])
    ground = np.array([0.12, 0.11, 0.1])
    s = np.clip(up, 0.0, 1.0)[..., None] ** 0.5
    sky = horizon * (1 - s) + zenith * s
    img = np.where(up[..., None] >= 0, sky, ground * (0.6 + 0.4 * np.exp(up[..., None] * 4)))
    sun = sun_direction(sun_elevation, sun_azimuth)
    cosg = np.clip(d @ sun, -1.0, 1.0)
    gamma = np.arccos(cosg)
    lobe = np.exp(-((gamma / math.radians(sun_size_deg)) ** 2))
    img = img + sun_strength * lobe[..., None] * np.array([1.0, 0.95, 0.85])
    return img.astype(np.float32)


def environment(mi: Any, envmap: str | os.PathLike[str] | None = None, scale: float = 1.0) -> dict:
    """The ``envmap`` emitter dict: the procedural sky (default) or an ``.exr``/``.hdr`` file."""
    if envmap is None or str(envmap) == "sky":
        return {"type": "envmap", "bitmap": mi.Bitmap(procedural_sky()), "scale": scale}
    path = str(envmap)
    if not path.lower().endswith((".exr", ".hdr")):
        raise BTFInputError(f"environment map {path!r}: give an .exr or .hdr file (or 'sky')")
    if not os.path.exists(path):
        raise BTFInputError(f"environment map {path!r} does not exist")
    return {"type": "envmap", "filename": path, "scale": scale}


def scene_dict(
    mi: Any,
    bsdf: dict[str, Any] | Any,
    scene: str = "sphere",
    width: int = 256,
    height: int = 256,
    envmap: str | os.PathLike[str] | None = None,
    max_depth: int = 4,
    floor: str | None = None,
    env_scale: float = 1.0,
    light: str = "sky",
) -> dict[str, Any]:
    """A ``mi.load_dict`` scene with ``bsdf`` (a dict or a loaded BSDF) on the object.

    ``scene``: "sphere" (a unit sphere on a floor; the floor carries the material too, tiled
    5x over 10 units, unless ``floor="diffuse"``) or "cloth" (a draped sheet over a grey floor,
    two-sided shading recommended; ``floor="material"`` puts the material on the floor).
    ``light``: "sky" (the environment map alone) or "emitter" (a sphere light of radius 0.15
    and radiance 400 up and to the right of the camera, giving about the sky's irradiance,
    over the environment at 5 %).
    """
    if scene not in SCENES:
        raise BTFInputError(f"unknown scene {scene!r}; choose one of {', '.join(SCENES)}")
    if light not in LIGHTS:
        raise BTFInputError(f"unknown light {light!r}; choose one of {', '.join(LIGHTS)}")
    floor = floor or ("material" if scene == "sphere" else "diffuse")
    if floor not in ("material", "diffuse"):
        raise BTFInputError(f"floor must be 'material' or 'diffuse', got {floor!r}")
    if isinstance(bsdf, dict):
        bsdf = mi.load_dict(bsdf)  # one instance shared by every shape
    grey = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.35, 0.35, 0.35]}}
    floor_bsdf = bsdf if floor == "material" else grey
    obj = sphere_mesh() if scene == "sphere" else cloth_mesh()
    origin, target, fov = camera(scene)
    shapes = {
        "object": mesh_object(mi, "object", obj, bsdf),
        "floor": mesh_object(mi, "floor", plane_mesh(), floor_bsdf),
    }
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": int(max_depth)},
        "sensor": {
            "type": "perspective",
            "fov": fov,
            "to_world": mi.ScalarTransform4f().look_at(origin=origin, target=target, up=[0, 1, 0]),
            "film": {
                "type": "hdrfilm",
                "width": int(width),
                "height": int(height),
                "rfilter": {"type": "box"},
                "pixel_format": "rgb",
            },
            "sampler": {"type": "independent"},
        },
        "emitter": environment(mi, envmap, env_scale * (0.05 if light == "emitter" else 1.0)),
        **shapes,
        **({"lamp": _lamp()} if light == "emitter" else {}),
    }


def camera(scene: str) -> tuple[list[float], list[float], float]:
    """(origin, target, horizontal field of view in degrees) of a built-in scene's camera."""
    if scene == "sphere":
        return [0.0, 2.3, 5.6], [0.0, 0.8, 0.0], 34.0
    return [0.0, 3.7, 4.4], [0.0, 0.55, 0.0], 38.0


def lod_camera(scene: str, width: int) -> dict[str, Any]:
    """The ``sparsebtf`` plugin's level-of-detail camera parameters for a built-in scene
    rendered ``width`` pixels wide: ``lod_camera`` (the camera's origin) and ``lod_pixel``
    (the angle of one pixel, 2·tan(fov/2)/width radians at the image centre)."""
    origin, _, fov = camera(scene)
    return {
        "lod_camera": ",".join(f"{v:.9g}" for v in origin),
        "lod_pixel": 2.0 * math.tan(math.radians(fov) / 2) / int(width),
    }


def _lamp() -> dict[str, Any]:
    """The small bright emitter of ``light="emitter"``."""
    return {
        "type": "sphere",
        "center": [2.2, 3.6, 2.8],
        "radius": 0.15,
        "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [400.0, 390.0, 370.0]}},
    }
