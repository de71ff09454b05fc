"""Angular neighbours and interpolation weights for unmeasured directions (paper §3.4).

A renderer asks for light and view directions that were never measured. Each query direction
is matched to its k nearest sampled directions by chord distance d = |q − x| (equivalent to
angular distance on the unit sphere) and given weights summing to one. The weights feed the
coefficient-space interpolation of Eq. 6 (:mod:`sparsebtf.runtime.decoder`), separately for
light and view.

Schemes
-------
``"nearest"``      k = 1, the nearest bin (no interpolation).
``"linear"``       the release shader's 2-nearest weighting: w₀ = ½ + ½ (d₁ − d₀)/d₁, w₁ = 1 − w₀.
``"barycentric"``  3 nearest, barycentric coordinates of q (centrally projected) in their
                   triangle (negative weights clipped and renormalised; a degenerate triangle
                   falls back to linear).
``"gaussian"``     k nearest (default 4), w ∝ exp(−β d²): the kernel the paper recommends against
                   visible bin edges (release: β = 20). It smooths, so it does not return the
                   sample exactly at a sampled direction.

:func:`neighbour_table` precomputes candidate lists over a (φ, elevation) grid, the release's
``adjMap`` idea, for shaders that should not scan every direction.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from ..data.directions import DirectionSet, k_nearest
from ..errors import BTFInputError

__all__ = ["DEFAULT_K", "SCHEMES", "Scheme", "angular_weights", "neighbour_table"]

Scheme = Literal["nearest", "linear", "barycentric", "gaussian"]
SCHEMES: tuple[str, ...] = ("nearest", "linear", "barycentric", "gaussian")
DEFAULT_K = {"nearest": 1, "linear": 2, "barycentric": 3, "gaussian": 4}
_CHUNK = 1 << 16


def _as_xyz(directions: DirectionSet | np.ndarray) -> np.ndarray:
    xyz = directions.xyz if isinstance(directions, DirectionSet) else np.asarray(directions)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise BTFInputError(f"direction table must have shape (N, 3), got {xyz.shape}")
    return np.asarray(xyz, dtype=np.float64)


def _unit_queries(query: np.ndarray, name: str) -> np.ndarray:
    q = np.asarray(query, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 3:
        raise BTFInputError(f"{name} directions must have shape (n, 3), got {q.shape}")
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    bad = ~np.isfinite(norm[:, 0]) | (norm[:, 0] == 0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise BTFInputError(
            f"{name} direction {i} is zero or not finite ({bad.sum()} such directions)"
        )
    return q / norm


def _linear(d: np.ndarray) -> np.ndarray:
    d0, d1 = d[:, 0], d[:, 1]
    safe = np.where(d1 > 0, d1, 1.0)
    w0 = np.where(d1 > 0, 0.5 + 0.5 * (d1 - d0) / safe, 0.5)
    return np.stack([w0, 1.0 - w0], axis=1)


def _barycentric(xyz: np.ndarray, q: np.ndarray, idx: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Barycentric weights of the central projection of q onto the neighbours' triangle.

    Solving [x₀ x₁ x₂] b = q and normalising b to sum 1 places t·q in the triangle's plane
    (gnomonic projection), so a query on the ray through a point of the triangle gets that
    point's planar barycentric coordinates, and a sampled direction gets (1, 0, 0).
    """
    m = np.stack([xyz[idx[:, 0]], xyz[idx[:, 1]], xyz[idx[:, 2]]], axis=2)  # columns x_i
    ok = np.abs(np.linalg.det(m)) > 1e-9
    m = np.where(ok[:, None, None], m, np.eye(3))
    b = np.linalg.solve(m, q[:, :, None])[:, :, 0]
    s = b.sum(axis=1, keepdims=True)
    ok &= s[:, 0] > 0
    w = np.clip(b / np.where(ok[:, None], s, 1.0), 0.0, None)
    t = w.sum(axis=1, keepdims=True)
    ok &= t[:, 0] > 0
    w = w / np.where(t > 0, t, 1.0)
    if not ok.all():  # degenerate (neighbours on a great circle): the release's 2-NN weights
        lin = np.zeros_like(w)
        lin[:, :2] = _linear(d[:, :2])
        w = np.where(ok[:, None], w, lin)
    return w


def angular_weights(
    directions: DirectionSet | np.ndarray,
    query: np.ndarray,
    scheme: Scheme | str = "linear",
    k: int | None = None,
    beta: float = 20.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Neighbour indices and weights of query directions (the α of Eq. 6, generalised).

    Parameters
    ----------
    directions : the sampled directions (a :class:`DirectionSet` or an (N, 3) array).
    query : (n, 3) directions in the same local frame (normalised here).
    scheme : "nearest", "linear", "barycentric" or "gaussian" (see the module docstring).
    k : number of neighbours; only "gaussian" accepts a choice (default 4).
    beta : Gaussian sharpness β in exp(−β d²) (release: 20).

    Returns
    -------
    index : (n, k) int32, nearest first. weight : (n, k) float64, rows summing to 1.
    """
    if scheme not in SCHEMES:
        raise BTFInputError(f"unknown interpolation {scheme!r}; choose one of {', '.join(SCHEMES)}")
    xyz = _as_xyz(directions)
    kk = DEFAULT_K[scheme]
    if k is not None:
        if scheme != "gaussian" and k != kk:
            raise BTFInputError(f"interpolation {scheme!r} uses k = {kk}, got k = {k}")
        kk = int(k)
    if not 1 <= kk <= xyz.shape[0]:
        raise BTFInputError(f"k must be in [1, {xyz.shape[0]}], got {kk}")
    if scheme == "gaussian" and not (np.isfinite(beta) and beta >= 0):
        raise BTFInputError(f"beta must be finite and >= 0, got {beta}")
    q = _unit_queries(query, "query")
    n = q.shape[0]
    index = np.empty((n, kk), dtype=np.int32)
    weight = np.empty((n, kk), dtype=np.float64)
    for s in range(0, n, _CHUNK):
        qs = q[s : s + _CHUNK]
        idx, d2 = k_nearest(xyz, qs, kk)
        if scheme == "nearest":
            w = np.ones((qs.shape[0], 1))
        elif scheme == "linear":
            w = _linear(np.sqrt(d2))
        elif scheme == "barycentric":
            w = _barycentric(xyz, qs, idx, np.sqrt(d2))
        else:
            w = np.exp(-beta * (d2 - d2[:, :1]))
            w /= w.sum(axis=1, keepdims=True)
        index[s : s + _CHUNK] = idx
        weight[s : s + _CHUNK] = w
    return index, weight


def neighbour_table(
    directions: DirectionSet | np.ndarray,
    k: int = 8,
    n_phi: int = 256,
    n_elevation: int = 64,
) -> np.ndarray:
    """Candidate neighbours over a (elevation, φ) grid of the upper hemisphere.

    Cell (e, a) covers elevation [e, e+1)·(π/2)/n_elevation and φ [a, a+1)·2π/n_phi − π; it
    lists the ``k`` directions nearest to the cell centre, nearest first. A shader looks up the
    cell of its query and ranks these few candidates by exact distance instead of scanning
    every direction; with k = 8 the true 3 nearest are among them (tested).

    Returns (n_elevation, n_phi, k) int16.
    """
    xyz = _as_xyz(directions)
    if not 1 <= k <= xyz.shape[0]:
        raise BTFInputError(f"k must be in [1, {xyz.shape[0]}], got {k}")
    el = (np.arange(n_elevation) + 0.5) * (np.pi / 2) / n_elevation
    ph = (np.arange(n_phi) + 0.5) * (2 * np.pi) / n_phi - np.pi
    e, a = np.meshgrid(el, ph, indexing="ij")
    centres = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1)
    idx, _ = k_nearest(xyz, centres.reshape(-1, 3), k)
    return idx.reshape(n_elevation, n_phi, k).astype(np.int16)
