"""BTF-driven importance sampling for the plugins: tables and a NumPy reference (no Mitsuba).

The plugins sample the unknown direction of a BSDF query (the light in radiance transport, where
``si.wi`` is the view; the view in importance transport) from a density built from the
material's own angular response M[L, V] ≥ 0 (:func:`sparsebtf.runtime.response.angular_response`
for codes, the mean of the table for a dense BTF), never from a decode of the BTF:

* **Cells.** The hemisphere is cut into ``grid``² cells of equal solid angle 2π/grid²: a
  regular grid on the unit square mapped by Mitsuba's equal-area concentric map
  (``mi.warp.square_to_uniform_hemisphere``, twin: :func:`square_to_uniform_hemisphere`).
* **Tables.** For every bin b of the *known* direction's set, a discrete distribution over the
  cells: P(cell | b) ∝ the mean, over ``supersample``² points of the cell, of M interpolated
  over the sampled set with the plugin's angular weights, i.e. Σ_a w_a M[S_a, b]. Stored as
  float32 CDFs (last entry exactly 1); a cell's probability is the difference of two entries,
  so what :func:`pdf` reads is what :func:`sample` draws. Rows with a zero response are uniform.
* **Conditioning.** The known direction is not a bin: its angular neighbours b_a and weights
  w_a (the lookup's own, ``interpolation``) mix the rows: p_tab(ω) = Σ_a w_a P(cell(ω) | b_a)
  · grid²/2π, uniform within a cell ("refined within the chosen bin" at the cell size).
* **Defensive mixture.** With probability ``mix`` the sample is cosine-weighted instead, so

      pdf(ω) = mix · cos θ/π + (1 − mix) · p_tab(ω)

  is positive over the whole hemisphere, wherever the BTF can be.

Memory: rows × (bins of the known set) × grid² × 4 bytes per transport mode; both modes are
built. One table per material (rows = 1) at UBO2014 directions, grid 32: 0.62 MB per mode.
Per-patch tables (``sampling_tables = "patch"``, rows = data points) cost that per point: a
400×400 UBO2014 material (1600 points) at grid 16 needs 247 MB per mode, 0.5 GB in all.

The Dr.Jit twins are :func:`sparsebtf.rendering.mitsuba.kernels.btf_sample` /
:func:`~sparsebtf.rendering.mitsuba.kernels.btf_pdf`; :func:`sample` and :func:`pdf` here are
their vectorised NumPy references (and the ``scalar_rgb`` path).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import BTFInputError
from ...runtime.angular import angular_weights

__all__ = [
    "MODES",
    "SamplingTables",
    "build_tables",
    "cell_of",
    "component",
    "dense_response",
    "pdf",
    "sample",
    "square_to_cosine_hemisphere",
    "square_to_uniform_hemisphere",
    "table_bytes",
    "uniform_hemisphere_to_square",
]

#: Transport modes: which direction is known (conditioning) and which is sampled.
#: radiance: known = view (si.wi), sampled = light; importance: the reverse.
MODES = ("radiance", "importance")
#: The largest float32 below 1 (a rescaled uniform number stays in [0, 1)).
ONE_MINUS_EPS = float(np.nextafter(np.float32(1), np.float32(0)))


# -- Mitsuba's warps, in NumPy (float64) ----------------------------------------------------------
def _square_to_disk(u: np.ndarray) -> np.ndarray:
    """``mi.warp.square_to_uniform_disk_concentric`` (Shirley–Chiu, Cline's form): (n,2) → (n,2)."""
    x, y = 2.0 * u[:, 0] - 1.0, 2.0 * u[:, 1] - 1.0
    q13 = np.abs(x) < np.abs(y)
    r = np.where(q13, y, x)
    rp = np.where(q13, x, y)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = 0.25 * np.pi * rp / r
    phi = np.where(q13, 0.5 * np.pi - phi, phi)
    phi = np.where((x == 0) & (y == 0), 0.0, phi)
    return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)


def _disk_to_square(p: np.ndarray) -> np.ndarray:
    """``mi.warp.uniform_disk_to_square_concentric``: (n,2) → (n,2)."""
    q02 = np.abs(p[:, 0]) > np.abs(p[:, 1])
    r_sign = np.where(q02, p[:, 0], p[:, 1])
    sgn = np.where(r_sign < 0, -1.0, 1.0)
    r = np.hypot(p[:, 0], p[:, 1]) * sgn
    phi = np.arctan2(p[:, 1] * sgn, p[:, 0] * sgn)
    t = 4.0 / np.pi * phi
    t = np.where(q02, t, 2.0 - t) * r
    a = np.where(q02, r, t)
    b = np.where(q02, t, r)
    return np.stack([(a + 1.0) * 0.5, (b + 1.0) * 0.5], axis=1)


def square_to_uniform_hemisphere(u: np.ndarray) -> np.ndarray:
    """``mi.warp.square_to_uniform_hemisphere`` (equal-area: Jacobian 2π everywhere)."""
    p = _square_to_disk(np.asarray(u, dtype=np.float64))
    z = 1.0 - np.sum(p * p, axis=1)
    p = p * np.sqrt(z + 1.0)[:, None]
    return np.stack([p[:, 0], p[:, 1], z], axis=1)


def uniform_hemisphere_to_square(w: np.ndarray) -> np.ndarray:
    """``mi.warp.uniform_hemisphere_to_square``, the inverse of the above."""
    w = np.asarray(w, dtype=np.float64)
    return _disk_to_square(w[:, :2] / np.sqrt(w[:, 2:3] + 1.0))


def square_to_cosine_hemisphere(u: np.ndarray) -> np.ndarray:
    """``mi.warp.square_to_cosine_hemisphere`` (density cos θ/π)."""
    p = _square_to_disk(np.asarray(u, dtype=np.float64))
    z = np.sqrt(np.maximum(1.0 - np.sum(p * p, axis=1), 0.0))
    return np.stack([p[:, 0], p[:, 1], z], axis=1)


def cell_of(w: np.ndarray, grid: int) -> np.ndarray:
    """The cell (row·grid + col of the unit square) of upper-hemisphere directions (n,)."""
    sq = np.clip(uniform_hemisphere_to_square(w), 0.0, 1.0)
    ix = np.minimum((sq[:, 0] * grid).astype(np.int64), grid - 1)
    iy = np.minimum((sq[:, 1] * grid).astype(np.int64), grid - 1)
    return iy * grid + ix


# -- tables ---------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class SamplingTables:
    """CDFs over the cells, per transport mode: ``cdf[mode]`` (rows, bins of the known set,
    grid²) float32, last entry 1; ``mix`` the cosine share; ``grid`` the cells per side."""

    grid: int
    mix: float
    cdf: dict[str, np.ndarray]

    @property
    def n_cells(self) -> int:
        return self.grid * self.grid

    @property
    def nbytes(self) -> int:
        return sum(int(a.nbytes) for a in self.cdf.values())


def table_bytes(rows: int, n_lights: int, n_views: int, grid: int) -> int:
    """Bytes of the tables of both modes (float32)."""
    return 4 * rows * (n_lights + n_views) * grid * grid


def _cell_weights(xyz: np.ndarray, grid: int, supersample: int, scheme: str, k: int | None,
                  beta: float) -> np.ndarray:
    """(grid², N) dense matrix: the mean angular weights of each cell's sub-sample points."""
    s = supersample
    j = (np.arange(grid * s) + 0.5) / (grid * s)
    uy, ux = np.meshgrid(j, j, indexing="ij")
    w = square_to_uniform_hemisphere(np.stack([ux.ravel(), uy.ravel()], axis=1))
    idx, wt = angular_weights(xyz, w, scheme, k, beta)
    iy, ix = np.meshgrid(np.arange(grid * s) // s, np.arange(grid * s) // s, indexing="ij")
    cell = (iy * grid + ix).ravel()
    out = np.zeros((grid * grid, xyz.shape[0]))
    np.add.at(out, (np.repeat(cell, idx.shape[1]), idx.ravel()), wt.ravel() / (s * s))
    return out


def _cdf(t: np.ndarray) -> np.ndarray:
    """Row-normalised cumulative sums along the last axis, float32, last entry 1."""
    t = np.where(np.isfinite(t), np.maximum(t, 0.0), 0.0)
    tot = t.sum(axis=-1, keepdims=True)
    t = np.where(tot > 0, t, 1.0)
    c = np.cumsum(t, axis=-1)
    c = (c / c[..., -1:]).astype(np.float32)
    c[..., -1] = 1.0
    return c


def build_tables(
    response: np.ndarray,
    lights: np.ndarray,
    views: np.ndarray,
    scheme: str = "linear",
    k: int | None = None,
    beta: float = 20.0,
    grid: int = 32,
    mix: float = 0.2,
    supersample: int = 3,
) -> SamplingTables:
    """Sampling tables of both transport modes from an angular response.

    ``response``: (L, V) or (rows, L, V) ≥ 0 (one table per row, e.g. per data point);
    ``lights`` (L, 3), ``views`` (V, 3): the sampled directions; ``scheme``/``k``/``beta``:
    the angular interpolation of the lookup (:func:`~sparsebtf.runtime.angular_weights`).
    """
    m = np.asarray(response, dtype=np.float64)
    m = m[None] if m.ndim == 2 else m
    if m.ndim != 3 or m.shape[1:] != (len(lights), len(views)):
        raise BTFInputError(
            f"angular response must be (L, V) or (rows, L, V) with L = {len(lights)}, "
            f"V = {len(views)}; got {np.shape(response)}"
        )
    if not (isinstance(grid, int | np.integer) and 2 <= grid <= 256):
        raise BTFInputError(f"sampling grid must be an integer in [2, 256], got {grid!r}")
    if not 0.0 < mix <= 1.0:
        raise BTFInputError(f"sampling mix (cosine share) must be in (0, 1], got {mix}")
    kk = k if scheme == "gaussian" else None
    cdf = {}
    for mode, sampled, mm in (("radiance", lights, m), ("importance", views,
                                                        np.swapaxes(m, 1, 2))):
        wc = _cell_weights(np.asarray(sampled, np.float64), grid, supersample, scheme, kk, beta)
        # per row: T[known bin, cell] = Σ_s wc[cell, s] M[s, known bin], ≤ 64 MB at a time
        out = np.empty((mm.shape[0], mm.shape[2], grid * grid), dtype=np.float32)
        step = max(1, (1 << 23) // max(1, mm.shape[2] * grid * grid))
        for r in range(0, mm.shape[0], step):
            t = np.einsum("cs,rsk->rkc", wc, mm[r : r + step], optimize=True)
            out[r : r + step] = _cdf(t)
        cdf[mode] = out
    return SamplingTables(int(grid), float(mix), cdf)


def dense_response(log_table: np.ndarray, log_offset: float) -> np.ndarray:
    """Angular response of a dense BTF: luminance of the mean over texels of
    exp(``log_table``) − ``log_offset`` (the table of :func:`.materials.dense_table`), (L, V)
    ≥ 0."""
    from ...runtime.response import LUMINANCE

    h = log_table.shape[0]
    acc = np.zeros(log_table.shape[2:4])
    for r in range(h):  # a row of texels at a time: the table may be large
        lin = np.exp(log_table[r].astype(np.float64)) - log_offset
        acc += np.einsum("wlvc,c->lv", lin, LUMINANCE)
    return np.maximum(acc / (h * log_table.shape[1]), 0.0)


# -- NumPy reference of the Dr.Jit sampler ----------------------------------------------------
def component(cond_w: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pick a mixture component a with probability ``cond_w[:, a]`` using u ∈ [0, 1); returns
    (a, u rescaled to [0, 1) within the component)."""
    start = np.concatenate([np.zeros((u.size, 1)), np.cumsum(cond_w[:, :-1], axis=1)], axis=1)
    a = (u[:, None] >= start[:, 1:]).sum(axis=1)
    lo = np.take_along_axis(start, a[:, None], 1)[:, 0]
    w = np.take_along_axis(cond_w, a[:, None], 1)[:, 0]
    return a, np.clip((u - lo) / np.maximum(w, 1e-12), 0.0, ONE_MINUS_EPS)


def pdf(tables: SamplingTables, mode: str, rows: np.ndarray, cond_idx: np.ndarray,
        cond_w: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Density (per solid angle) of :func:`sample` at ``wo`` (n, 3), 0 below the horizon.

    ``rows`` (n,): table row (0, or the data point); ``cond_idx``/``cond_w`` (n, k): the known
    direction's neighbours among its set and their weights (summing to 1).
    """
    cdf = tables.cdf[mode]
    n_cells = tables.n_cells
    wo = np.asarray(wo, dtype=np.float64)
    cell = cell_of(wo, tables.grid)
    p_tab = np.zeros(wo.shape[0])
    for a in range(cond_idx.shape[1]):
        row = cdf[rows, cond_idx[:, a]]
        hi = np.take_along_axis(row, cell[:, None], 1)[:, 0].astype(np.float64)
        lo = np.where(cell > 0, np.take_along_axis(row, np.maximum(cell - 1, 0)[:, None], 1)[:, 0],
                      0.0)
        p_tab += cond_w[:, a] * (hi - lo)
    cos = np.maximum(wo[:, 2], 0.0)
    out = tables.mix * cos / np.pi + (1 - tables.mix) * p_tab * n_cells / (2 * np.pi)
    return np.where(wo[:, 2] > 0, out, 0.0)


def sample(tables: SamplingTables, mode: str, rows: np.ndarray, cond_idx: np.ndarray,
           cond_w: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Directions (n, 3) drawn from :func:`pdf`'s density, from uniform u1 (n,), u2 (n, 2)."""
    cdf = tables.cdf[mode]
    g = tables.grid
    u1 = np.asarray(u1, dtype=np.float64)
    u2 = np.asarray(u2, dtype=np.float64)
    use_cos = u1 < tables.mix
    u = np.clip((u1 - tables.mix) / (1 - tables.mix), 0.0, ONE_MINUS_EPS)
    a, ur = component(np.asarray(cond_w, np.float64), u)
    b = np.take_along_axis(cond_idx, a[:, None], 1)[:, 0]
    row = cdf[rows, b]  # (n, cells)
    cell = np.minimum((row <= ur[:, None]).sum(axis=1), g * g - 1)
    sq = np.stack([(cell % g + u2[:, 0]) / g, (cell // g + u2[:, 1]) / g], axis=1)
    return np.where(use_cos[:, None], square_to_cosine_hemisphere(u2),
                    square_to_uniform_hemisphere(sq))
