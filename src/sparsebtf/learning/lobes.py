"""Per-texel highlight lobes (issue 46): a few parameters per texel that predict the band of
highlight values a log-domain code misses, added after the decode like the highlight store.

Where a glossy metal's highlight comes from one facet per texel (a brushed or grooved metal),
the residual of its code is one anisotropic GGX lobe per texel, and its hundreds of highlight
nodes follow from eight numbers (the sparse store pays 9 bytes for each node). The lobe of
texel x, in the frame (t, b, n) = R(ω)·(e_x, e_y, e_z) of the rotation vector ω::

    lobe(x, ω_i, ω_o) = A · D(h) / max(n·ω_o, NV_FLOOR)      where n·ω_i > 0, n·ω_o > 0
    D(h) = 1 / (π α_x α_y (h_t²/α_x² + h_b²/α_y² + h_n²)²),    h = (ω_i + ω_o) / |ω_i + ω_o|

(0 elsewhere), the microfacet term of a rough conductor with its Fresnel, shadowing and
constants folded into the linear-RGB amplitude A ≥ 0. Parameters per texel, binary16 in the
file: ``(ω_x, ω_y, ω_z, ln α_x, ln α_y, A_r, A_g, A_b)`` — :data:`LOBE_BYTES` a texel. On a
bumpy surface seen through a rectified camera each view sees another spot of the relief, and
no one lobe fits a texel (docs/benchmarks.md §17 measures both cases); the encoder keeps lobes
only where they lower the error at their bytes.

:func:`lobe_values` is the reference every decoder is tested against; :func:`fit_lobes` fits
the lobes of a batch of texels to a residual (Levenberg–Marquardt over the five shape
parameters, the amplitudes solved in closed form at each step: SciPy's ``least_squares``
solves one problem at a time, and a material has 160,000 texels of 68,000 values each).
"""

from __future__ import annotations

import numpy as np

from .._numba import HAVE_NUMBA
from .._numba import numba as _nb
from .cost import VALUE_BYTES

__all__ = [
    "LOBE_BYTES",
    "LOBE_PARAMS",
    "NV_FLOOR",
    "fit_lobes",
    "lobe_amplitudes",
    "lobe_amplitudes16",
    "lobe_frame",
    "lobe_values",
    "unit_lobes",
    "unit_lobes_at",
]

#: Parameters per texel: rotation vector (3), ln α_x, ln α_y, linear-RGB amplitude (3).
LOBE_PARAMS = 8
#: Bytes per texel (binary16 parameters, Table 4's value size).
LOBE_BYTES = LOBE_PARAMS * VALUE_BYTES
#: Lower bound on n·ω_o in the lobe's denominator (grazing views stay finite).
NV_FLOOR = 0.05
_ALPHA = (1e-3, 2.0)  # the fit keeps α_x, α_y in this range


def lobe_frame(omega: np.ndarray) -> np.ndarray:
    """Rodrigues' rotation of the rotation vectors ``omega`` (..., 3): (..., 3, 3) float64 whose
    columns are t, b, n. Series below 1e-4 rad (the exact formula divides by θ²)."""
    w = np.asarray(omega, dtype=np.float64)
    th2 = np.sum(w * w, axis=-1)[..., None, None]
    th = np.sqrt(th2)
    small = th2 < 1e-8
    safe = np.where(small, 1.0, th)
    a = np.where(small, 1 - th2 / 6, np.sin(safe) / safe)
    b = np.where(small, 0.5 - th2 / 24, (1 - np.cos(safe)) / np.where(small, 1.0, th2))
    k = np.zeros((*w.shape[:-1], 3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = w[..., 2], -w[..., 1], w[..., 0]
    return np.eye(3) + a * k + b * (k @ k)


def _microfacet(ht, hb, hn, nl, nv, ax, ay):
    """D(h) / max(n·ω_o, NV_FLOOR) from the half vector in the lobe's frame, n·ω_i, n·ω_o."""
    q = (ht / ax) ** 2 + (hb / ay) ** 2 + hn * hn
    d = 1.0 / (np.pi * ax * ay * q * q)
    return np.where((nl > 0) & (nv > 0), d / np.maximum(nv, NV_FLOOR), 0.0)


def _unit(w: np.ndarray) -> np.ndarray:
    """Directions ``w`` (..., 3) as float64 unit vectors."""
    w = np.asarray(w, dtype=np.float64)
    return w / np.maximum(np.linalg.norm(w, axis=-1, keepdims=True), 1e-300)


def _half(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    h = np.asarray(wi, dtype=np.float64) + np.asarray(wo, dtype=np.float64)
    return h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-12)


def unit_lobes(shape: np.ndarray, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """D(h) / max(n·ω_o, NV_FLOOR) of lobes of amplitude 1 (module docstring).

    ``shape`` (..., 5) = (ω, ln α_x, ln α_y); ``wi``, ``wo`` (..., 3) directions (normalised
    here), any shapes broadcasting with ``shape[..., :1]``. Returns float64 of the broadcast
    shape."""
    s = np.asarray(shape, dtype=np.float64)
    frame = lobe_frame(s[..., :3])
    t, b, n = frame[..., :, 0], frame[..., :, 1], frame[..., :, 2]
    wi, wo = _unit(wi), _unit(wo)
    h = _half(wi, wo)
    ht, hb, hn = (np.sum(h * v, axis=-1) for v in (t, b, n))
    nl, nv = np.sum(wi * n, axis=-1), np.sum(wo * n, axis=-1)
    return _microfacet(ht, hb, hn, nl, nv, np.exp(s[..., 3]), np.exp(s[..., 4]))


if HAVE_NUMBA:

    @_nb.njit(cache=True, nogil=True, inline="always")
    def _unit_nb(f, ax, ay, p, h, wi, wo):
        # D(h_p) / max(n·wo_p, NV_FLOOR) for the frame f (columns t, b, n) and α
        nl = wi[p, 0] * f[0, 2] + wi[p, 1] * f[1, 2] + wi[p, 2] * f[2, 2]
        nv = wo[p, 0] * f[0, 2] + wo[p, 1] * f[1, 2] + wo[p, 2] * f[2, 2]
        if nl <= 0.0 or nv <= 0.0:
            return 0.0
        ht = (h[p, 0] * f[0, 0] + h[p, 1] * f[1, 0] + h[p, 2] * f[2, 0]) / ax
        hb = (h[p, 0] * f[0, 1] + h[p, 1] * f[1, 1] + h[p, 2] * f[2, 1]) / ay
        hn = h[p, 0] * f[0, 2] + h[p, 1] * f[1, 2] + h[p, 2] * f[2, 2]
        q = ht * ht + hb * hb + hn * hn
        return 1.0 / (np.pi * ax * ay * q * q) / max(nv, NV_FLOOR)

    @_nb.njit(parallel=True, cache=True, nogil=True)
    def _grid_nb(frame, alpha, h, wi, wo, out):
        # out[t, p]: texel t's unit lobe at direction pair p
        for t in _nb.prange(frame.shape[0]):
            for p in range(h.shape[0]):
                out[t, p] = _unit_nb(frame[t], alpha[t, 0], alpha[t, 1], p, h, wi, wo)

    @_nb.njit(parallel=True, cache=True, nogil=True)
    def _normal_nb(frames, alphas, steps, amp, r, h, wi, wo, jtj, jtr):
        # Gauss-Newton's normal equations per texel in one pass over its nodes: frames[t, 0]
        # is the shape, frames[t, 1 + k] the shape with parameter k moved by steps[k]
        # (forward differences); w = Σ_c A_c (r_c − g A_c), the residual along the colour
        for t in _nb.prange(frames.shape[0]):
            jk = np.empty(5)
            for p in range(h.shape[0]):
                g0 = _unit_nb(frames[t, 0], alphas[t, 0, 0], alphas[t, 0, 1], p, h, wi, wo)
                w = 0.0
                for c in range(3):
                    w += amp[t, c] * (r[t, p, c] - g0 * amp[t, c])
                for k in range(5):
                    gk = _unit_nb(frames[t, 1 + k], alphas[t, 1 + k, 0], alphas[t, 1 + k, 1],
                                  p, h, wi, wo)  # fmt: skip
                    jk[k] = (gk - g0) / steps[k]
                for k in range(5):
                    jtr[t, k] += jk[k] * w
                    for m in range(5):
                        jtj[t, k, m] += jk[k] * jk[m]


def _unit_lobes_grid(shape: np.ndarray, h: np.ndarray, wi: np.ndarray,
                     wo: np.ndarray) -> np.ndarray:  # fmt: skip
    """:func:`unit_lobes` of T texels' shapes (T, 5) at the same P direction pairs (half
    vectors ``h``, ``wi``, ``wo`` (P, 3), unit): (T, P) — compiled, or by matrix products
    without numba (the fit's inner loop)."""
    if HAVE_NUMBA:
        out = np.empty((shape.shape[0], h.shape[0]))
        _grid_nb(np.ascontiguousarray(lobe_frame(shape[:, :3])), np.exp(shape[:, 3:5]),
                 h, wi, wo, out)  # fmt: skip
        return out
    frame = lobe_frame(shape[:, :3])  # (T, 3, 3), columns t, b, n
    hf = np.einsum("pk,tkj->jtp", h, frame, optimize=True)
    nl = frame[:, :, 2] @ wi.T
    nv = frame[:, :, 2] @ wo.T
    ax, ay = np.exp(shape[:, 3:4]), np.exp(shape[:, 4:5])
    return _microfacet(hf[0], hf[1], hf[2], nl, nv, ax, ay)


def unit_lobes_at(shape: np.ndarray, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """:func:`unit_lobes` of T shapes (T, 5) at the same P direction pairs ``wi``, ``wo``
    (P, 3): (T, P) float64 (compiled where numba is installed)."""
    wi, wo = _unit(wi), _unit(wo)
    return _unit_lobes_grid(np.asarray(shape, dtype=np.float64), _half(wi, wo), wi, wo)


def lobe_values(params: np.ndarray, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """The lobes' linear-RGB values: ``params`` (..., 8), directions (..., 3) broadcasting
    with ``params[..., :1]``; (..., 3) float64 — the reference of every decoder."""
    p = np.asarray(params, dtype=np.float64)
    return unit_lobes(p[..., :5], wi, wo)[..., None] * p[..., 5:8]


def lobe_amplitudes(g: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Least-squares amplitudes ≥ 0 of unit lobes ``g`` (T, P) against residuals ``r``
    (T, P, 3): (T, 3), max(gᵀr / gᵀg, 0) per channel (0 where g is 0)."""
    gg = np.einsum("tp,tp->t", g, g)
    gr = np.einsum("tp,tpc->tc", g, r)
    return np.maximum(gr / np.where(gg > 0, gg, 1.0)[:, None], 0.0) * (gg > 0)[:, None]


def lobe_amplitudes16(g: np.ndarray, r: np.ndarray) -> np.ndarray:
    """:func:`lobe_amplitudes` as stored: binary16, at most its largest finite value (a lobe
    narrower than the directions' spacing can ask for more; the clipped amplitude lies between
    0 and the best one, so the lobe still lowers the texel's error)."""
    big = float(np.finfo(np.float16).max)
    return np.minimum(lobe_amplitudes(g, r), big).astype(np.float16)


def _sse(g: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Per texel, the squared error left by the best amplitudes: ‖r‖² − Σ_c max(gᵀr_c, 0)²/gᵀg."""
    gg = np.einsum("tp,tp->t", g, g)
    gr = np.maximum(np.einsum("tp,tpc->tc", g, r), 0.0)
    return np.einsum("tpc,tpc->t", r, r) - (gr * gr).sum(1) / np.where(gg > 0, gg, np.inf)


def _start(r: np.ndarray, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Initial shapes: the frame that turns e_z to the half vector of each texel's largest
    residual, α = 0.1 both ways."""
    top = np.argmax(r.sum(-1), axis=1)
    h = wi[top] + wo[top]
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    axis = np.stack([-h[:, 1], h[:, 0], np.zeros(len(h))], axis=1)  # e_z × h
    s = np.linalg.norm(axis, axis=1, keepdims=True)
    ang = np.arctan2(s[:, 0], h[:, 2])[:, None]
    omega = np.where(s > 1e-9, axis / np.where(s > 1e-9, s, 1.0) * ang, 0.0)
    return np.concatenate([omega, np.full((len(h), 2), np.log(0.1))], axis=1)


def _wrapped(omega: np.ndarray) -> np.ndarray:
    """The same rotations with |ω| ≤ π (a rotation by θ about k is one by θ − 2π about k)."""
    th = np.linalg.norm(omega, axis=1, keepdims=True)
    over = th > np.pi
    turned = np.mod(th + np.pi, 2 * np.pi) - np.pi
    return np.where(over, omega * (turned / np.where(over, th, 1.0)), omega)


def _normal(theta: np.ndarray, step: np.ndarray, a: np.ndarray, r: np.ndarray, g: np.ndarray,
            w: np.ndarray | None, h: np.ndarray, wi: np.ndarray, wo: np.ndarray,
            shapes: object) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Σ_p J_p J_pᵀ and Σ_p J_p w_p per texel (T, 5, 5), (T, 5): J the forward-difference
    derivatives of the unit lobe by the five shape parameters, w the residual along the
    texel's colour (compiled in one pass; without numba, (T, P, 5) Jacobians)."""
    moved = np.repeat(theta[:, None, :], 6, axis=1)
    for k in range(5):
        moved[:, 1 + k, k] += step[k]
    if HAVE_NUMBA:
        t = len(theta)
        jtj, jtr = np.zeros((t, 5, 5)), np.zeros((t, 5))
        _normal_nb(np.ascontiguousarray(lobe_frame(moved[..., :3])), np.exp(moved[..., 3:]),
                   step, a, np.ascontiguousarray(r), h, wi, wo, jtj, jtr)  # fmt: skip
        return jtj, jtr
    jac = np.stack([(shapes(moved[:, 1 + k]) - g) / step[k] for k in range(5)], axis=-1)  # type: ignore[operator]
    return np.einsum("tpk,tpl->tkl", jac, jac), np.einsum("tpk,tp->tk", jac, w)


def fit_lobes(r: np.ndarray, wi: np.ndarray, wo: np.ndarray, iters: int = 25) -> np.ndarray:
    """Lobes fitted to the residuals ``r`` (T, P, 3) of T texels at P direction pairs
    (``wi``, ``wo`` (P, 3)): (T, 8) float16 — the shape by Levenberg–Marquardt on the squared
    error (forward-difference Jacobians, amplitudes solved at each step), then the amplitudes
    solved again for the binary16 shape. A texel whose lobe does not lower its error gets
    amplitude 0."""
    r = np.asarray(r, dtype=np.float64)
    wi, wo = _unit(wi), _unit(wo)
    h = _half(wi, wo)
    theta = _start(r, wi, wo)
    lam = np.full(len(theta), 1e-2)

    def shapes(th: np.ndarray) -> np.ndarray:
        return _unit_lobes_grid(th, h, wi, wo)

    g = shapes(theta)
    cost = _sse(g, r)
    step = np.array([1e-4, 1e-4, 1e-4, 1e-3, 1e-3])
    for _ in range(iters):
        a = lobe_amplitudes(g, r)
        w = None if HAVE_NUMBA else np.einsum("tpc,tc->tp", r - g[..., None] * a[:, None, :], a)
        a2 = (a * a).sum(1)
        jtj, jtr = _normal(theta, step, a, r, g, w, h, wi, wo, shapes)
        jtj *= a2[:, None, None]
        damp = jtj + lam[:, None, None] * (np.eye(5) * np.diagonal(jtj, axis1=1, axis2=2)[:, None]
                                           + 1e-12 * np.eye(5))  # fmt: skip
        delta = np.linalg.solve(damp, jtr[..., None])[..., 0]
        trial = theta + np.where(np.isfinite(delta), delta, 0.0)
        trial[:, :3] = _wrapped(trial[:, :3])
        trial[:, 3:] = np.clip(trial[:, 3:], *np.log(_ALPHA))
        g_new = shapes(trial)
        c_new = _sse(g_new, r)
        ok = c_new < cost
        theta[ok], g[ok], cost[ok] = trial[ok], g_new[ok], c_new[ok]
        lam = np.where(ok, lam / 3, lam * 4)
    shape16 = theta.astype(np.float16)
    g = shapes(shape16.astype(np.float64))
    amp = lobe_amplitudes16(g, r)
    return np.concatenate([shape16, amp], axis=1)
