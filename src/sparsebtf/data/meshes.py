"""Triangle meshes as arrays, and as Mitsuba mesh objects: shared by the built-in render scenes
(:mod:`sparsebtf.rendering.scenes`) and the capture samples (:mod:`sparsebtf.data.capture`).

A mesh is (positions (n, 3), normals (n, 3), uv (n, 2), faces (m, 3)) of NumPy arrays; no
Mitsuba import here, the ``mi`` module is passed in by the caller that has set a variant.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["MeshArrays", "grid_faces", "mesh_object", "sphere_mesh"]

MeshArrays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def grid_faces(nu: int, nv: int) -> np.ndarray:
    """Two counter-clockwise (in uv) triangles per cell of an (nv+1) x (nu+1) vertex grid."""
    i = np.arange(nv)[:, None] * (nu + 1) + np.arange(nu)[None, :]
    a, b, c, d = i, i + 1, i + nu + 2, i + nu + 1  # (u,v), (u+1,v), (u+1,v+1), (u,v+1)
    return np.stack([np.stack([a, b, c], -1), np.stack([a, c, d], -1)], 2).reshape(-1, 3)


def sphere_mesh(
    center: tuple[float, float, float] = (0.0, 1.0, 0.0),
    radius: float = 1.0,
    n_lon: int = 128,
    n_lat: int = 64,
) -> MeshArrays:
    """(positions (n,3), normals (n,3), uv (n,2), faces (m,3)) of a UV sphere, y-up.

    Longitude λ ∈ [0, 2π] runs counter-clockwise seen from above (+y), latitude from the south
    pole up: u = 2λ/2π, v = (latitude + π/2)/π. Seams and poles are duplicated vertices.
    """
    lon = np.linspace(0.0, 2 * np.pi, n_lon + 1)
    lat = np.linspace(-np.pi / 2, np.pi / 2, n_lat + 1)
    la, lo = np.meshgrid(lat, lon, indexing="ij")  # rows: v (latitude), cols: u (longitude)
    # counter-clockwise seen from +y: x = cos λ, z = −sin λ
    n = np.stack([np.cos(la) * np.cos(lo), np.sin(la), -np.cos(la) * np.sin(lo)], -1)
    pos = np.asarray(center)[None, None, :] + radius * n
    uv = np.stack([2.0 * lo / (2 * np.pi), (la + np.pi / 2) / np.pi], -1)
    faces = grid_faces(n_lon, n_lat)
    # drop the degenerate triangles at the poles (zero area)
    p = pos.reshape(-1, 3)
    e1, e2 = p[faces[:, 1]] - p[faces[:, 0]], p[faces[:, 2]] - p[faces[:, 0]]
    area = np.linalg.norm(np.cross(e1, e2), axis=1)
    faces = faces[area > 1e-12 * radius * radius]
    return p, n.reshape(-1, 3), uv.reshape(-1, 2), faces


def mesh_object(mi: Any, name: str, arrays: MeshArrays, bsdf: Any) -> Any:
    """A Mitsuba mesh object built from arrays, with ``bsdf`` attached (via load_dict)."""
    pos, normals, uv, faces = arrays
    mesh = mi.Mesh(
        name,
        vertex_count=pos.shape[0],
        face_count=faces.shape[0],
        has_vertex_normals=True,
        has_vertex_texcoords=True,
        props=_mesh_props(mi, bsdf),
    )
    params = mi.traverse(mesh)
    # the buffers' own types: mi.Float in JIT variants, dr.scalar.ArrayXf in scalar ones
    fl, ui = type(params["vertex_positions"]), type(params["faces"])
    params["vertex_positions"] = fl(np.asarray(pos, dtype=np.float32).ravel())
    params["vertex_normals"] = fl(np.asarray(normals, dtype=np.float32).ravel())
    params["vertex_texcoords"] = fl(np.asarray(uv, dtype=np.float32).ravel())
    params["faces"] = ui(np.asarray(faces, dtype=np.uint32).ravel())
    params.update()
    return mesh


def _mesh_props(mi: Any, bsdf: Any) -> Any:
    props = mi.Properties()
    props["bsdf"] = bsdf if not isinstance(bsdf, dict) else mi.load_dict(bsdf)
    return props
