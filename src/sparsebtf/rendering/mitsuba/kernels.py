"""The lookups behind both plugins, apart from the plugin classes (as Mitsuba 3's ``ad/bsdfs``).

Dr.Jit kernels (the ``llvm_ad_*``/``cuda_ad_*`` variants), evaluated for a wavefront of shading
points at once:

* :func:`knn_scan` — the k nearest sampled light and view directions of each query, brute force
  by chord distance in one symbolic ``dr.while_loop`` (as
  :func:`sparsebtf.runtime.angular_weights`),
* :func:`neighbour_weights` — the runtime's interpolation schemes on those neighbours,
* :func:`coded_lookup` — Eq. 5/6 from the flat renderer arrays (:class:`CodedArrays`), then the
  inverse preprocessing,
* :func:`dense_lookup` — the log-domain blend of a dense table (:class:`DenseArrays`).

Scalar lookups (``scalar_rgb``, one ray at a time in NumPy): :func:`scalar_coded` calls
:meth:`sparsebtf.runtime.RuntimeBTF.evaluate`, :func:`scalar_dense` blends the table with
:func:`sparsebtf.runtime.angular_weights`.

The kernels take the ``mitsuba`` and ``drjit`` modules as arguments (``mi``, ``dr``) instead of
importing them, so this module loads without Mitsuba and the arrays they build belong to
whichever variant is active when they run. ``prm`` is a plugin's checked parameters
(:func:`.materials.common_params` / :func:`.materials.coded_params`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...points.preprocessing import EPS as LOG_EPS

__all__ = [
    "CodedArrays",
    "DenseArrays",
    "coded_lookup",
    "dense_lookup",
    "knn_scan",
    "neighbour_weights",
    "scalar_coded",
    "scalar_dense",
    "texel",
]


# -- Dr.Jit kernels -----------------------------------------------------------------------------
def knn_scan(
    mi: Any, dr: Any, tables: list[tuple[Any, int, Any]], k: int, active: Any
) -> list[tuple[list[Any], list[Any]]]:
    """k nearest sampled directions of each query, by squared chord distance (one symbolic loop).

    ``tables``: [(flat xyz Float, n, query Vector3f)], scanned together over j < max n.
    Returns per table (indices [UInt32]*k, squared distances [Float]*k), nearest first;
    ties keep the lower index (as :func:`sparsebtf.runtime.angular_weights`).
    """
    big = 1e30
    n_max = max(n for _, n, _ in tables)
    state: list[Any] = [mi.UInt32(0)]
    for _ in tables:
        state += [dr.zeros(mi.UInt32, 1) for _ in range(k)] + [mi.Float(big) for _ in range(k)]

    def cond(*st):
        return st[0] < n_max

    def body(*st):
        st = list(st)
        j = st[0]
        out = [j + 1]
        for t, (flat, n, q) in enumerate(tables):
            ii = list(st[1 + t * 2 * k : 1 + t * 2 * k + k])
            dd = list(st[1 + t * 2 * k + k : 1 + (t + 1) * 2 * k])
            ok = j < n
            x = dr.gather(mi.Vector3f, flat, dr.minimum(j, n - 1), active & ok)
            cd = dr.select(ok, dr.squared_norm(q - x), big)
            ci = mi.UInt32(j)
            for s in range(k):
                sw = cd < dd[s]
                dd[s], cd = dr.select(sw, cd, dd[s]), dr.select(sw, dd[s], cd)
                ii[s], ci = dr.select(sw, ci, ii[s]), dr.select(sw, ii[s], ci)
            out += ii + dd
        return tuple(out)

    res = dr.while_loop(tuple(state), cond, body, label="sparsebtf_knn")
    outs = []
    for t in range(len(tables)):
        ii = list(res[1 + t * 2 * k : 1 + t * 2 * k + k])
        dd = list(res[1 + t * 2 * k + k : 1 + (t + 1) * 2 * k])
        outs.append((ii, dd))
    return outs


def neighbour_weights(mi: Any, dr: Any, scheme: str, flat: Any, q: Any, ii: list, dd: list,
                      beta: float, active: Any) -> list:
    """Interpolation weights of the k neighbours (the runtime's schemes, in float32).

    ``flat``: the sampled directions (flat xyz), ``q``: the normalised queries, ``ii``/``dd``:
    the neighbours' indices and squared distances from :func:`knn_scan`. Returns one weight
    array per neighbour (a single 1 for ``nearest``).
    """
    if scheme == "nearest":
        return [mi.Float(1.0)]

    def linear():
        d0, d1 = dr.safe_sqrt(dd[0]), dr.safe_sqrt(dd[1])
        w0 = dr.select(d1 > 0, 0.5 + 0.5 * (d1 - d0) / dr.select(d1 > 0, d1, 1.0), 0.5)
        return [w0, 1.0 - w0]

    if scheme == "linear":
        return linear()
    if scheme == "gaussian":
        w = [dr.exp(-beta * (d - dd[0])) for d in dd]
        tot = w[0]
        for x in w[1:]:
            tot = tot + x
        return [x / tot for x in w]
    # barycentric: central projection of q onto the triangle of the 3 nearest, i.e. solve
    # [x0 x1 x2] b = q (Cramer's rule), normalise b to sum 1, clip negatives, renormalise
    x0, x1, x2 = (dr.gather(mi.Vector3f, flat, i, active) for i in ii)
    c12, c20, c01 = dr.cross(x1, x2), dr.cross(x2, x0), dr.cross(x0, x1)
    det = dr.dot(x0, c12)
    ok = dr.abs(det) > 1e-9
    b = [dr.dot(q, c12), dr.dot(q, c20), dr.dot(q, c01)]  # b_i · det
    b = [dr.select(det < 0, -x, x) for x in b]  # b_i · |det|: the signs of b, scale-free
    s = b[0] + b[1] + b[2]
    ok &= s > 0
    w = [dr.maximum(x / dr.select(ok, s, 1.0), 0.0) for x in b]
    t = w[0] + w[1] + w[2]
    ok &= t > 0
    safe = dr.select(ok, t, 1.0)
    lin = linear()
    return [
        dr.select(ok, w[0] / safe, lin[0]),
        dr.select(ok, w[1] / safe, lin[1]),
        dr.select(ok, w[2] / safe, 0.0),
    ]


def texel(mi: Any, dr: Any, uv: Any, height: int, width: int) -> tuple[Any, Any]:
    """(row, col) of the texel under ``uv``, which wraps (u along columns, v along rows)."""
    f = uv - dr.floor(uv)
    col = dr.minimum(mi.UInt32(f.x * width), width - 1)
    row = dr.minimum(mi.UInt32(f.y * height), height - 1)
    return row, col


class CodedArrays:
    """The flat renderer arrays of one coded material as Dr.Jit arrays of the active variant."""

    def __init__(self, mi: Any, rt: Any) -> None:
        a = rt.arrays(neighbours=False)
        m = rt.meta
        self.height, self.width, self.patch = int(m["height"]), int(m["width"]), int(m["patch"])
        self.n_rb = int(m["n_rb"])
        self.n_lights, self.n_views = int(m["n_lights"]), int(m["n_views"])
        self.eps = float(m["eps"])
        self.lights = mi.Float(a["lights_xyz"].ravel())
        self.views = mi.Float(a["views_xyz"].ravel())
        self.n_stats = int(a["mean"].shape[0])
        self.mean = mi.Float(a["mean"].ravel())
        self.std = mi.Float(a["std"].ravel())
        self.yuv_to_rgb = [[float(v) for v in row] for row in a["yuv_to_rgb"]]
        self.channels = []
        for ch in ("Y", "U", "V"):
            d1 = a[f"dict1_{ch}"]
            self.channels.append(
                {
                    "membership": mi.UInt32(a[f"membership_{ch}"].astype(np.uint32)),
                    "offsets": mi.UInt32(a[f"offsets_{ch}"].astype(np.uint32)),
                    "values": mi.Float(a[f"values_{ch}"]),
                    "locations": mi.UInt32(a[f"locations_{ch}"]),
                    "dict1": mi.Float(d1.ravel()),
                    "dict2": mi.Float(a[f"dict2_{ch}"].ravel()),
                    "dict3": mi.Float(a[f"dict3_{ch}"].ravel()),
                    "dict4": mi.Float(a[f"dict4_{ch}"].ravel()),
                    "p": int(d1.shape[1]),
                    "L": int(a[f"dict3_{ch}"].shape[1]),
                    "V": int(a[f"dict4_{ch}"].shape[1]),
                }
            )


def coded_lookup(mi: Any, dr: Any, data: CodedArrays, prm: dict[str, Any], uv: Any,
                 light: Any, view: Any, active: Any) -> Any:
    """Eq. 5/6 for a wavefront of queries: linear RGB (Color3f), Dr.Jit variants.

    ``uv`` (tiled, wraps), ``light``/``view`` in the BTF's local frame; ``prm`` needs
    ``interpolation``, ``k``, ``beta`` and ``domain``. The decoder's floor (−eps) is kept:
    the plugin clamps to 0.
    """
    k, scheme = prm["k"], prm["interpolation"]
    row, col = texel(mi, dr, uv, data.height, data.width)
    p = data.patch
    pt = row // p + data.n_rb * (col // p)
    i1, i2 = row % p, col % p
    ql, qv = dr.normalize(light), dr.normalize(view)
    (li, dl), (vi, dv) = knn_scan(
        mi, dr, [(data.lights, data.n_lights, ql), (data.views, data.n_views, qv)], k, active
    )
    lw = neighbour_weights(mi, dr, scheme, data.lights, ql, li, dl, prm["beta"], active)
    vw = neighbour_weights(mi, dr, scheme, data.views, qv, vi, dv, prm["beta"], active)
    kl, kv = len(lw), len(vw)
    nl, nv = data.n_lights, data.n_views
    log_domain = prm["domain"] == "log"
    logs = []
    for c, ch in enumerate(data.channels):
        s_idx = c if data.n_stats == 3 else 0
        kk = dr.gather(mi.UInt32, ch["membership"], pt, active)
        s0 = dr.gather(mi.UInt32, ch["offsets"], pt, active)
        s1 = dr.gather(mi.UInt32, ch["offsets"], pt + 1, active)
        pp, cl, cv = ch["p"], ch["L"], ch["V"]
        b1 = kk * (pp * pp) + i1 * pp
        b2 = kk * (pp * pp) + i2 * pp
        b3 = [kk * (cl * cl) + li[a] * cl for a in range(kl)]
        b4 = [kk * (cv * cv) + vi[b] * cv for b in range(kv)]
        n_acc = kl * kv if log_domain else 1
        s1 = dr.select(active, s1, s0)

        def cond(s, *acc, s1=s1):
            return s < s1

        def body(s, *acc, ch=ch, b1=b1, b2=b2, b3=b3, b4=b4):
            v = dr.gather(mi.Float, ch["values"], s)
            code = dr.gather(mi.UInt32, ch["locations"], s)
            l1, l2 = code & 0xFF, (code >> 8) & 0xFF
            l3, l4 = (code >> 16) & 0xFF, code >> 24
            a = v * dr.gather(mi.Float, ch["dict1"], b1 + l1) * dr.gather(
                mi.Float, ch["dict2"], b2 + l2
            )
            g3 = [dr.gather(mi.Float, ch["dict3"], b + l3) for b in b3]
            g4 = [dr.gather(mi.Float, ch["dict4"], b + l4) for b in b4]
            if log_domain:
                new = [acc[x * kv + y] + a * g3[x] * g4[y] for x in range(kl) for y in range(kv)]
            else:
                s3 = g3[0] * lw[0]
                for x in range(1, kl):
                    s3 = s3 + g3[x] * lw[x]
                s4 = g4[0] * vw[0]
                for y in range(1, kv):
                    s4 = s4 + g4[y] * vw[y]
                new = [acc[0] + a * s3 * s4]
            return (s + 1, *new)

        res = dr.while_loop(
            (mi.UInt32(s0), *[mi.Float(0.0) for _ in range(n_acc)]),
            cond,
            body,
            label=f"sparsebtf_sum_{'YUV'[c]}",
        )
        acc = res[1:]
        base = s_idx * nl * nv
        log = mi.Float(0.0)
        mu_t = mi.Float(0.0)
        sd_t = mi.Float(0.0)
        for x in range(kl):
            for y in range(kv):
                j = base + li[x] * nv + vi[y]
                w = lw[x] * vw[y]
                mu = dr.gather(mi.Float, data.mean, j, active)
                sd = dr.gather(mi.Float, data.std, j, active)
                if log_domain:
                    log += w * (sd * acc[x * kv + y] + mu)
                else:
                    mu_t += w * mu
                    sd_t += w * sd
        if not log_domain:
            log = acc[0] * sd_t + mu_t
        logs.append(log)
    m = data.yuv_to_rgb
    rgb = [dr.exp(m[r][0] * logs[0] + m[r][1] * logs[1] + m[r][2] * logs[2]) - data.eps
           for r in range(3)]
    return mi.Color3f(*rgb)


class DenseArrays:
    """A dense log table and its direction sets as Dr.Jit arrays of the active variant."""

    def __init__(self, mi: Any, table: np.ndarray, lights: np.ndarray, views: np.ndarray) -> None:
        self.height, self.width, self.n_lights, self.n_views = (int(v) for v in table.shape[:4])
        self.table = mi.Float(table.ravel())
        self.lights = mi.Float(lights.ravel())
        self.views = mi.Float(views.ravel())


def dense_lookup(mi: Any, dr: Any, data: DenseArrays, prm: dict[str, Any], uv: Any,
                 light: Any, view: Any, active: Any) -> Any:
    """exp(Σ w_a w_b ln(x + 1e-5)) − 1e-5 over the angular neighbours of a dense table (the
    reference lookup, ``nearest`` an exact table value): linear RGB (Color3f)."""
    k, scheme = prm["k"], prm["interpolation"]
    row, col = texel(mi, dr, uv, data.height, data.width)
    ql, qv = dr.normalize(light), dr.normalize(view)
    (li, dl), (vi, dv) = knn_scan(
        mi, dr, [(data.lights, data.n_lights, ql), (data.views, data.n_views, qv)], k, active
    )
    lw = neighbour_weights(mi, dr, scheme, data.lights, ql, li, dl, prm["beta"], active)
    vw = neighbour_weights(mi, dr, scheme, data.views, qv, vi, dv, prm["beta"], active)
    base = (row * data.width + col) * (data.n_lights * data.n_views)
    acc = mi.Color3f(0.0)
    for x in range(len(lw)):
        for y in range(len(vw)):
            idx = base + li[x] * data.n_views + vi[y]
            acc += (lw[x] * vw[y]) * dr.gather(mi.Color3f, data.table, idx, active)
    return dr.exp(acc) - LOG_EPS


# -- scalar (numpy) lookups ---------------------------------------------------------------------
def scalar_coded(rt: Any, prm: dict[str, Any], uv: np.ndarray, light: np.ndarray,
                 view: np.ndarray) -> np.ndarray:
    """One query through :meth:`RuntimeBTF.evaluate <sparsebtf.runtime.RuntimeBTF.evaluate>`
    (``uv`` (2,), ``light``/``view`` (3,) float64): RGB (3,)."""
    return rt.evaluate(
        light[None, :], view[None, :], uv=uv[None, :], interpolation=prm["interpolation"],
        domain=prm["domain"], k=prm["k"] if prm["interpolation"] == "gaussian" else None,
        beta=prm["beta"],
    )[0]  # fmt: skip


def scalar_dense(data: tuple, prm: dict[str, Any], uv: np.ndarray, light: np.ndarray,
                 view: np.ndarray) -> np.ndarray:
    """:func:`dense_lookup` for one query in NumPy; ``data`` as
    :func:`.materials.load_dense` returns it. RGB (3,)."""
    from ...runtime import angular_weights, texels_from_uv

    table, lights, views = data
    kk = prm["k"] if prm["interpolation"] == "gaussian" else None
    li, lw = angular_weights(lights, light[None, :], prm["interpolation"], kk, prm["beta"])
    vi, vw = angular_weights(views, view[None, :], prm["interpolation"], kk, prm["beta"])
    row, col = texels_from_uv(uv[None, :], table.shape[0], table.shape[1])
    vals = table[row[0], col[0]][li[0][:, None], vi[0][None, :]]  # (kl, kv, 3)
    w = lw[0][:, None] * vw[0][None, :]
    return np.exp(np.einsum("ab,abc->c", w, vals)) - LOG_EPS

