"""Sampled light and view directions of a BTF, and nearest-direction search.

Directions live in the tangent frame of the surface: z is the normal, x and y span the surface.
A :class:`DirectionSet` keeps unit vectors together with their polar angle θ (from the normal)
and azimuth φ, in radians. The measured sets follow the Bonn gantries:

* :func:`ubo2014` — the 151 directions of UBO2014, identical in order and value (to float32
  rounding) to the authors' ``bonn_angles.bin``; rings from
  ``shared/specs/official-release-format.md`` §2.
* :func:`ubo2003` — the 81 directions of UBO2003 (θ ∈ {0, 15, 30, 45, 60, 75}° with
  {1, 6, 12, 18, 20, 24} azimuths, each ring starting at φ = 0).
* :func:`tiny` — small hemispherical sets (7, 13, 19 directions) for tests.

Nearest neighbours use the chord distance ‖a − b‖ of unit vectors, which orders neighbours exactly
as the angular distance does (paper §3.4; the release's shader and ``adjMap.bin``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._numba import HAVE_NUMBA
from .._numba import numba as _nb
from ..errors import BTFInputError

__all__ = [
    "DirectionSet",
    "by_name",
    "from_angles",
    "from_vectors",
    "k_nearest",
    "tiny",
    "ubo2003",
    "ubo2014",
    "unit_vectors",
]


@dataclass(frozen=True, eq=False)
class DirectionSet:
    """An ordered set of unit directions on the upper hemisphere.

    Attributes
    ----------
    xyz : (n, 3) float64 unit vectors in the tangent frame (z = normal).
    theta : (n,) polar angle from the normal, radians.
    phi : (n,) azimuth in [-π, π), radians.
    name : a label ("ubo2014", "ubo2003", "tiny13", "custom", ...).
    """

    xyz: np.ndarray
    theta: np.ndarray = field(repr=False)
    phi: np.ndarray = field(repr=False)
    name: str = "custom"

    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    def __repr__(self) -> str:
        return f"DirectionSet(name={self.name!r}, n={len(self)})"

    @property
    def elevation(self) -> np.ndarray:
        """Elevation above the surface plane (π/2 − θ), the release's ``elev``."""
        return np.pi / 2 - self.theta

    def equals(self, other: DirectionSet, atol: float = 1e-6) -> bool:
        """Same count and same vectors in the same order (within ``atol``)."""
        return len(self) == len(other) and bool(np.allclose(self.xyz, other.xyz, atol=atol))

    def nearest(self, query: np.ndarray, k: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` nearest sampled directions of each query by chord distance.

        Parameters
        ----------
        query : (..., 3) directions (normalised here; need not be unit length).
        k : number of neighbours, 1 <= k <= len(self).

        Returns
        -------
        index : (..., k) int64 indices into this set, nearest first.
        distance : (..., k) float64 chord distances, ascending.
        """
        q = np.asarray(query, dtype=np.float64)
        if q.shape[-1:] != (3,):
            raise BTFInputError(f"query directions must have a last axis of 3, got shape {q.shape}")
        if not 1 <= k <= len(self):
            raise BTFInputError(f"k must be in [1, {len(self)}], got {k}")
        norm = np.linalg.norm(q, axis=-1, keepdims=True)
        if np.any(norm == 0) or not np.all(np.isfinite(norm)):
            raise BTFInputError("query directions must be finite and non-zero")
        idx, d2 = k_nearest(self.xyz, (q / norm).reshape(-1, 3), k)
        shape = (*q.shape[:-1], k)
        return idx.astype(np.int64).reshape(shape), np.sqrt(d2).reshape(shape)


def k_nearest(xyz: np.ndarray, q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(index, squared chord distance) of the ``k`` nearest rows of ``xyz`` for each unit query
    of ``q`` (n, 3), nearest first, ties by lower index: ‖a−b‖² = 2 − 2 a·b for unit vectors.

    Compiled when numba is present: a scan of the N directions with an insertion list of k
    beats argpartition + sort of the (n, N) distance matrix by ~20× for N = 151.
    """
    if HAVE_NUMBA:
        return _knn_nb(np.ascontiguousarray(xyz, dtype=np.float64), np.ascontiguousarray(q), k)
    d2 = np.maximum(2.0 - 2.0 * (q @ xyz.T), 0.0)
    if k < xyz.shape[0]:
        part = np.argpartition(d2, k - 1, axis=1)[:, :k]
    else:
        part = np.broadcast_to(np.arange(xyz.shape[0]), d2.shape).copy()
    pd = np.take_along_axis(d2, part, axis=1)
    # Stable order: by distance, then by index so ties are deterministic.
    order = np.lexsort((part, pd), axis=1)
    return np.take_along_axis(part, order, axis=1), np.take_along_axis(pd, order, axis=1)


if HAVE_NUMBA:

    @_nb.njit(parallel=True, cache=True, nogil=True)
    def _knn_nb(xyz, q, k):
        n = q.shape[0]
        m = xyz.shape[0]
        idx = np.empty((n, k), dtype=np.int32)
        dist = np.empty((n, k), dtype=np.float64)
        for i in _nb.prange(n):
            cnt = 0
            for j in range(m):
                d = 2.0 - 2.0 * (q[i, 0] * xyz[j, 0] + q[i, 1] * xyz[j, 1] + q[i, 2] * xyz[j, 2])
                d = max(d, 0.0)
                if cnt < k:
                    cnt += 1
                elif d >= dist[i, k - 1]:
                    continue
                # insertion: strict comparison keeps the lower index first on ties
                pos = cnt - 1
                while pos > 0 and dist[i, pos - 1] > d:
                    dist[i, pos] = dist[i, pos - 1]
                    idx[i, pos] = idx[i, pos - 1]
                    pos -= 1
                dist[i, pos] = d
                idx[i, pos] = j
        return idx, dist


def unit_vectors(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Unit vectors (n, 3) of polar angles θ (from the normal) and azimuths φ (radians),
    unchecked: :func:`from_angles` checks them first."""
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=1)


def from_angles(theta: np.ndarray, phi: np.ndarray, name: str = "custom") -> DirectionSet:
    """Build a set from polar angle θ (from the normal) and azimuth φ, radians."""
    theta = np.asarray(theta, dtype=np.float64).ravel()
    phi = np.asarray(phi, dtype=np.float64).ravel()
    if theta.shape != phi.shape:
        raise BTFInputError(f"theta and phi differ in length: {theta.size} vs {phi.size}")
    if theta.size == 0:
        raise BTFInputError("a direction set needs at least one direction")
    bad = ~(np.isfinite(theta) & np.isfinite(phi))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise BTFInputError(
            f"direction {i}: angles must be finite, got theta={theta[i]}, phi={phi[i]} (radians)"
        )
    if np.any(np.abs(phi) > 4 * np.pi):
        bad = int(np.flatnonzero(np.abs(phi) > 4 * np.pi)[0])
        raise BTFInputError(
            f"direction {bad}: azimuth {float(phi[bad]):.6g} rad is outside ±4π (±720°); "
            "expected radians"
        )
    if np.any(theta < -1e-12) or np.any(theta > np.pi / 2 + 1e-9):
        bad = int(np.flatnonzero((theta < -1e-12) | (theta > np.pi / 2 + 1e-9))[0])
        raise BTFInputError(
            f"direction {bad}: polar angle {float(theta[bad]) * 180 / np.pi:.3f}° is outside "
            "[0°, 90°]"
        )
    xyz = unit_vectors(theta, phi)
    wrapped = (phi + np.pi) % (2 * np.pi) - np.pi
    return DirectionSet(xyz=xyz, theta=theta, phi=wrapped, name=name)


def from_vectors(xyz: np.ndarray, name: str = "custom") -> DirectionSet:
    """Build a set from (n, 3) vectors in the tangent frame (normalised here)."""
    v = np.asarray(xyz, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise BTFInputError(f"direction vectors must have shape (n, 3), got {v.shape}")
    n = np.linalg.norm(v, axis=1)
    if np.any(~np.isfinite(n)) or np.any(n == 0):
        bad = int(np.flatnonzero(~np.isfinite(n) | (n == 0))[0])
        raise BTFInputError(f"direction {bad} is zero or not finite: {v[bad].tolist()}")
    v = v / n[:, None]
    if np.any(v[:, 2] < -1e-9):
        bad = int(np.flatnonzero(v[:, 2] < -1e-9)[0])
        raise BTFInputError(f"direction {bad} points below the surface (z = {v[bad, 2]:.4f})")
    theta = np.arccos(np.clip(v[:, 2], -1.0, 1.0))
    phi = np.arctan2(v[:, 1], v[:, 0])
    phi = np.where(phi >= np.pi, phi - 2 * np.pi, phi)
    return DirectionSet(xyz=v, theta=theta, phi=phi, name=name)


def _rings(rings: list[tuple[float, int, float]], name: str) -> DirectionSet:
    """Rings of (polar angle °, azimuth count, first azimuth °), counter-clockwise."""
    theta, phi = [], []
    for polar, count, first in rings:
        az = first + 360.0 * np.arange(count) / count
        theta.append(np.full(count, np.radians(polar)))
        phi.append(np.radians(az))
    return from_angles(np.concatenate(theta), np.concatenate(phi), name=name)


# UBO2014 (official-release-format.md §2): polar angle, azimuth count, first azimuth.
_UBO2014_RINGS = [
    (0.0, 1, 0.0),
    (11.0, 6, 15.0),
    (23.5, 12, 0.0),
    (30.0, 12, 15.0),
    (37.5, 12, 0.0),
    (45.0, 18, 0.0),
    (52.5, 18, 7.5),
    (60.0, 24, 0.0),
    (67.5, 24, 7.5),
    (75.0, 24, 0.0),
]

_UBO2003_RINGS = [
    (0.0, 1, 0.0),
    (15.0, 6, 0.0),
    (30.0, 12, 0.0),
    (45.0, 18, 0.0),
    (60.0, 20, 0.0),
    (75.0, 24, 0.0),
]

_TINY_RINGS = {
    7: [(0.0, 1, 0.0), (40.0, 6, 0.0)],
    13: [(0.0, 1, 0.0), (30.0, 6, 0.0), (60.0, 6, 30.0)],
    19: [(0.0, 1, 0.0), (25.0, 6, 0.0), (50.0, 6, 30.0), (70.0, 6, 0.0)],
}


def ubo2014() -> DirectionSet:
    """The 151 directions of UBO2014 in the release's order (``bonn_angles.bin``)."""
    return _rings(_UBO2014_RINGS, "ubo2014")


def ubo2003() -> DirectionSet:
    """The 81 directions of UBO2003 (ring layout of the Bonn 2003 gantry)."""
    return _rings(_UBO2003_RINGS, "ubo2003")


def tiny(n: int = 13) -> DirectionSet:
    """A small hemispherical set of 7, 13 or 19 directions, for tests and quick runs."""
    if n not in _TINY_RINGS:
        raise BTFInputError(f"tiny direction sets have {sorted(_TINY_RINGS)} directions, not {n}")
    return _rings(_TINY_RINGS[n], f"tiny{n}")


_NAMED = {"ubo2014": ubo2014, "ubo2003": ubo2003}


def by_name(name: str) -> DirectionSet:
    """Look up a named set: ``ubo2014``, ``ubo2003``, ``tiny7``, ``tiny13``, ``tiny19``."""
    key = name.strip().lower()
    if key in _NAMED:
        return _NAMED[key]()
    if key.startswith("tiny") and key[4:].isdigit() and int(key[4:]) in _TINY_RINGS:
        return tiny(int(key[4:]))
    known = ", ".join([*_NAMED, *(f"tiny{n}" for n in _TINY_RINGS)])
    raise BTFInputError(f"unknown direction set {name!r}; known sets: {known}")
