"""The angular response of a coded material from its codes alone (no decode of the BTF).

A renderer that samples directions in proportion to the BTF needs, for every (light, view) bin,
how bright the material is there. A data point's **spatial mean** (over its p×p texels) is a
cheap contraction of Eq. 5: for channel c of point p with dictionary k and coefficients
(v_s, l1_s … l4_s),

    X̄_p[L, V] = (1/p²) Σ_{i1,i2} X_p[i1, i2, L, V]
              = Σ_s v_s ū1[k, l1_s] ū2[k, l2_s] U3[k, L, l3_s] U4[k, V, l4_s]
              = (U3[k] C_p U4[k]ᵀ)[L, V],   C_p[l3, l4] = Σ_{s: (l3_s, l4_s) = (l3, l4)} v_s ū1 ū2

with ū_n[k, l] = mean over rows of U_n[k, ·, l]: one scatter of the coefficients into an
m3×m4 matrix and two products per point. The standardisation is affine, so σ·X̄ + μ is the
spatial mean of the point's log-YUV values exactly; its RGB (YUV → RGB, exp) is the per-channel
geometric mean of the point's texels. :func:`angular_response` returns the luminance of that,
per point or averaged over the points (an arithmetic mean across patches). Cost per point and
channel: 2·τ·L flops for the sparse step and 2·L·m4·V for one dense product (7 MFLOP at UBO2014
directions), done as one GEMM per dictionary.

A material coded with adaptive patch sizes (:class:`~sparsebtf.runtime.AdaptiveRuntimeBTF`):
the points are its nodes (:meth:`~sparsebtf.runtime.AdaptiveRuntimeBTF.arrays`), a node of
size p takes the mean of its p rows of the (zero-padded) spatial dictionaries, and the mean
over the material weighs each node by its p² texels: the mean over texels, as for one size.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..colour import yuv_to_rgb
from ..model import CHANNELS
from ..points.preprocessing import inverse_log_transform

__all__ = ["LUMINANCE", "angular_response", "mean_log_yuv"]

#: Rec. 709 luminance weights of linear RGB.
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def _unpack(code: np.ndarray) -> np.ndarray:
    code = code.astype(np.int64)
    return np.stack([code & 0xFF, (code >> 8) & 0xFF, (code >> 16) & 0xFF, code >> 24], axis=1)


def _spatial_means(arr: dict[str, np.ndarray], ch: str, pts: np.ndarray) -> np.ndarray:
    """X̄_p (n, L, V) float64 of channel ``ch`` for the points ``pts`` (the formula above).

    In two steps: B_p = Σ_s v_s ū1 ū2 e_{l4_s} U3[k, :, l3_s]ᵀ (m4 × L), a sparse product over
    the coefficients, then X̄_p = B_pᵀ U4[k]ᵀ as one GEMM for all points of each dictionary k.
    """
    from scipy import sparse

    off = arr[f"offsets_{ch}"].astype(np.int64)
    memb = arr[f"membership_{ch}"].astype(np.int64)
    d = [arr[f"dict{n}_{ch}"].astype(np.float64) for n in (1, 2, 3, 4)]
    adaptive = "node_patch" in arr
    if adaptive:  # padded to the largest size with zero rows: a node of size p sums its p rows
        m1, m2 = d[0].sum(axis=1), d[1].sum(axis=1)
    else:
        m1, m2 = d[0].mean(axis=1), d[1].mean(axis=1)  # (K, m): mean over rows
    n_l, m4, n_v = d[2].shape[1], d[3].shape[2], d[3].shape[1]
    start, stop = off[pts], off[pts + 1]
    cnt = stop - start
    owner = np.repeat(np.arange(pts.size), cnt)
    pos = np.repeat(start - np.cumsum(cnt) + cnt, cnt) + np.arange(int(cnt.sum()))
    loc = _unpack(arr[f"locations_{ch}"][pos])
    kp = memb[pts]
    k = kp[owner]
    a = arr[f"values_{ch}"][pos].astype(np.float64) * m1[k, loc[:, 0]] * m2[k, loc[:, 1]]
    if adaptive:
        a /= np.square(arr["node_patch"][pts].astype(np.float64))[owner]
    scatter = sparse.csr_matrix((a, (owner * m4 + loc[:, 3], np.arange(a.size))),
                                shape=(pts.size * m4, a.size))  # fmt: skip
    u3t = np.ascontiguousarray(np.swapaxes(d[2], 1, 2))  # (K, m3, L): columns as rows
    b = np.asarray(scatter @ u3t[k, loc[:, 2]]).reshape(pts.size, m4, n_l)
    out = np.empty((pts.size, n_l, n_v))
    for kk in np.unique(kp):
        sel = np.flatnonzero(kp == kk)
        bt = np.swapaxes(b[sel], 1, 2).reshape(-1, m4)  # (n_k·L, m4)
        out[sel] = (bt @ d[3][kk].T).reshape(sel.size, n_l, n_v)
    return out


def mean_log_yuv(rt: Any, points: np.ndarray | None = None) -> np.ndarray:
    """Spatial mean of each data point's de-standardised log-YUV values, (n, L, V, 3) float64.

    ``rt``: a :class:`~sparsebtf.runtime.RuntimeBTF` (its loaded τ) or an
    :class:`~sparsebtf.runtime.AdaptiveRuntimeBTF` (its points are its nodes); ``points``: the
    data point indices (default all).
    """
    n = int(_meta(rt)["n_points"])
    pts = np.arange(n) if points is None else np.asarray(points, np.int64)
    return _mean_log_yuv(rt.arrays(neighbours=False), pts)


def _mean_log_yuv(arr: dict[str, np.ndarray], pts: np.ndarray) -> np.ndarray:
    mean, std = arr["mean"].astype(np.float64), arr["std"].astype(np.float64)
    out = np.empty((pts.size, mean.shape[1], mean.shape[2], 3))
    for c, ch in enumerate(CHANNELS):
        s = c if mean.shape[0] == 3 else 0
        out[..., c] = std[s] * _spatial_means(arr, ch, pts) + mean[s]
    return out


def angular_response(rt: Any, per_point: bool = False, chunk: int = 32) -> np.ndarray:
    """Luminance of each data point's geometric-mean RGB at every (light, view) bin, ≥ 0.

    Returns (P, L, V) float32 with ``per_point``, else its mean over the P points (L, V):
    over the texels (an adaptive material's P nodes weighted by their sizes²).
    Computed ``chunk`` points at a time (memory: about chunk·L·V·40 bytes).
    """
    meta = _meta(rt)
    n = int(meta["n_points"])
    arr = rt.arrays(neighbours=False)
    weights = None
    if "node_patch" in arr:  # each node by its texels
        weights = np.square(arr["node_patch"].astype(np.float64))
        weights /= weights.sum()
    total = None
    rows = []
    for s in range(0, n, chunk):
        pts = np.arange(s, min(n, s + chunk))
        log_rgb = np.minimum(yuv_to_rgb(_mean_log_yuv(arr, pts)), arr["bound"][..., None])
        rgb = inverse_log_transform(log_rgb, float(meta["eps"]))
        lum = np.maximum(rgb @ LUMINANCE, 0.0)
        if per_point:
            rows.append(lum.astype(np.float32))
        else:
            part = lum.sum(axis=0) if weights is None else np.tensordot(weights[pts], lum, 1)
            total = part if total is None else total + part
    if per_point:
        return np.concatenate(rows, axis=0)
    return (total if weights is not None else total / n).astype(np.float32)


def _meta(rt: Any) -> dict[str, Any]:
    """The meta of ``rt``'s renderer arrays (an adaptive material's ``flat_meta``)."""
    return rt.flat_meta if hasattr(rt, "flat_meta") else rt.meta
