"""The highlight store's correction in the ``sparsebtf`` plugin's Dr.Jit lookup (issue 46).

As :mod:`sparsebtf.runtime.highlight_lookup` (whose NumPy references are
:func:`sparsebtf.learning.highlights.correction` and
:func:`~sparsebtf.learning.highlights.lobe_corrections`): the decoded linear RGB plus
Σ_ab wl_a · wv_b · c(x, l_a, v_b) over the lookup's own angular neighbours, plus the texel's
highlight lobe at the lane's own light and view directions (:mod:`sparsebtf.learning.lobes`,
float32 here), clamped at 0, with c found by a binary search of the node's key in its point's
range of the sorted keys.
``dr.binary_search`` takes scalar bounds only (one range for every lane), so the search here
is written out with per-lane bounds and a fixed number of steps: enough for the largest
point's range. Like :mod:`.kernels`, it takes ``mi`` and ``dr`` as arguments.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...learning.lobes import NV_FLOOR

__all__ = ["HighlightArrays", "add_highlights", "lobe"]


class HighlightArrays:
    """A highlight store as Dr.Jit arrays of the active variant: ``offsets`` (P + 1) and
    ``keys`` (N) UInt32, ``rgb`` (3N) Float interleaved (``keys`` None without entries: no
    search is traced, and no gather reads an empty array), ``steps`` the binary search's steps
    (bits of the largest per-point count), the key's strides, and ``lobes`` (8·P·p²) Float,
    the lobes' parameters by texel row ``point·p² + i1·p + i2`` (None without lobes)."""

    def __init__(self, mi: Any, arrays: dict[str, np.ndarray], patch: int, n_lights: int,
                 n_views: int) -> None:  # fmt: skip
        offsets = arrays["highlight_offsets"]
        self.steps = int(np.diff(offsets.astype(np.int64)).max(initial=0)).bit_length()
        self.offsets = mi.UInt32(offsets)
        keys = arrays["highlight_keys"]
        self.keys = mi.UInt32(keys) if keys.size else None
        self.rgb = mi.Float(arrays["highlight_rgb"].ravel()) if keys.size else None
        lobes = arrays.get("highlight_lobes")
        self.lobes = None if lobes is None else mi.Float(lobes.astype(np.float32).ravel())
        self.patch, self.n_lights, self.n_views = int(patch), int(n_lights), int(n_views)

    @classmethod
    def of(cls, mi: Any, arrays: dict[str, np.ndarray], patch: int, n_lights: int,
           n_views: int) -> HighlightArrays | None:  # fmt: skip
        """The store among the renderer arrays ``arrays`` (``RuntimeBTF.arrays()``: uint32
        offsets and keys, float32 RGB), or None where they have none (no store, no entries,
        an adaptive material): the lookup is then traced exactly as without."""
        if "highlight_keys" not in arrays:
            return None
        return cls(mi, arrays, patch, n_lights, n_views)


def _lower_bound(mi: Any, dr: Any, hl: HighlightArrays, lo: Any, hi: Any, key: Any,
                 active: Any) -> Any:
    """First index in [lo, hi) whose key is >= ``key`` (hi if none), per lane."""
    for _ in range(hl.steps):
        open_ = lo < hi
        mid = (lo + hi) >> 1
        less = open_ & (dr.gather(mi.UInt32, hl.keys, mid, active & open_) < key)
        lo = dr.select(less, mid + 1, lo)
        hi = dr.select(open_ & ~less, mid, hi)
    return lo


def correction(mi: Any, dr: Any, hl: HighlightArrays, pt: Any, i1: Any, i2: Any,
               light_nb: tuple[list, list], view_nb: tuple[list, list], active: Any) -> Any:
    """Σ_ab wl_a · wv_b · c(point, key(i1, i2, l_a, v_b)) per lane: Color3f (0 where no node
    of the lane's neighbour pairs has an entry)."""
    li, lw = light_nb
    vi, vw = view_nb
    out = mi.Color3f(0.0)
    if hl.keys is None:  # a store of lobes only
        return out
    s0 = dr.gather(mi.UInt32, hl.offsets, pt, active)
    s1 = dr.select(active, dr.gather(mi.UInt32, hl.offsets, pt + 1, active), s0)
    texel = i1 * hl.patch + i2
    for a in range(len(lw)):
        base = (texel * hl.n_lights + li[a]) * hl.n_views
        for b in range(len(vw)):
            key = base + vi[b]
            j = _lower_bound(mi, dr, hl, mi.UInt32(s0), mi.UInt32(s1), key, active)
            hit = active & (j < s1)
            hit &= dr.gather(mi.UInt32, hl.keys, j, hit) == key
            c = dr.gather(mi.Color3f, hl.rgb, j, hit)  # 0 where masked off
            out += (lw[a] * vw[b]) * c
    return out


def lobe(mi: Any, dr: Any, hl: HighlightArrays, pt: Any, i1: Any, i2: Any, light: Any,
         view: Any, active: Any) -> Any:
    """The texel's lobe A·D(h) / max(n·ω_o, NV_FLOOR) at the lane's ``light`` (ω_i) and
    ``view`` (ω_o) (Vector3f, normalised here), 0 where n·ω_i ≤ 0 or n·ω_o ≤ 0: Color3f, as
    :func:`sparsebtf.learning.lobes.lobe_values` in float32."""
    row = ((pt * hl.patch + i1) * hl.patch + i2) * 8
    prm = [dr.gather(mi.Float, hl.lobes, row + k, active) for k in range(8)]
    wx, wy, wz = prm[0], prm[1], prm[2]
    # Rodrigues: R = (1 − bθ²)·I + a·K + b·ωωᵀ, columns t, b, n (lobe_frame); 1 − cos θ as
    # 2·sin²(θ/2), which keeps float32 digits at small θ
    th2 = wx * wx + wy * wy + wz * wz
    small = th2 < 1e-8
    th = dr.sqrt(dr.select(small, 1.0, th2))
    half = dr.sin(0.5 * th)
    a = dr.select(small, 1.0 - th2 / 6.0, dr.sin(th) / th)
    b = dr.select(small, 0.5 - th2 / 24.0, 2.0 * half * half / (th * th))
    d = 1.0 - b * th2
    t = mi.Vector3f(d + b * wx * wx, a * wz + b * wy * wx, -a * wy + b * wz * wx)
    bt = mi.Vector3f(-a * wz + b * wx * wy, d + b * wy * wy, a * wx + b * wz * wy)
    n = mi.Vector3f(a * wy + b * wx * wz, -a * wx + b * wy * wz, d + b * wz * wz)
    wi = light / dr.maximum(dr.norm(light), 1e-30)
    wo = view / dr.maximum(dr.norm(view), 1e-30)
    h = wi + wo
    h = h / dr.maximum(dr.norm(h), 1e-12)
    ax, ay = dr.exp(prm[3]), dr.exp(prm[4])
    ht, hb, hn = dr.dot(h, t) / ax, dr.dot(h, bt) / ay, dr.dot(h, n)
    q = ht * ht + hb * hb + hn * hn
    nl, nv = dr.dot(wi, n), dr.dot(wo, n)
    g = dr.rcp(dr.pi * ax * ay * q * q) / dr.maximum(nv, NV_FLOOR)
    g = dr.select(active & (nl > 0) & (nv > 0), g, 0.0)
    return mi.Color3f(g * prm[5], g * prm[6], g * prm[7])


def add_highlights(mi: Any, dr: Any, hl: HighlightArrays | None, rgb: Any, pt: Any, i1: Any,
                   i2: Any, light_nb: tuple[list, list], view_nb: tuple[list, list],
                   active: Any, dirs: tuple[Any, Any] | None = None) -> Any:
    """max(``rgb`` + :func:`correction` + :func:`lobe`, 0); ``rgb`` itself (no clamp)
    without a store. ``dirs``: the lanes' (light, view) directions in the BTF frame, the
    ones whose neighbours ``light_nb``, ``view_nb`` are (needed where the store has lobes)."""
    if hl is None:
        return rgb
    c = correction(mi, dr, hl, pt, i1, i2, light_nb, view_nb, active)
    if hl.lobes is not None:
        if dirs is None:
            raise ValueError("a highlight store with lobes needs the lookup's directions")
        c = c + lobe(mi, dr, hl, pt, i1, i2, dirs[0], dirs[1], active)
    return dr.maximum(rgb + c, 0.0)
