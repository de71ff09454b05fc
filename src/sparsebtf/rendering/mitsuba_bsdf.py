"""Mitsuba 3 BSDF plugins: ``sparsebtf`` (coded BTFs, Eq. 5/6) and ``sparsebtf_dense`` (reference).

Use :mod:`sparsebtf.mitsuba` (``import sparsebtf.mitsuba``), which picks a variant and calls
:func:`register`. This module defines the plugin classes for whatever variant is active.

``sparsebtf`` — a coded material
--------------------------------
Evaluates a coded BTF locally at each shading point, never reconstructing a data point: the
texel's data point p, its dictionary k = M[p] and its stored coefficients (v_s, l_s), then per
YUV channel (paper Eq. 5, with Eq. 6's coefficient-space angular interpolation)::

    X_c = Σ_s v_s U1[i1,l1] U2[i2,l2] (Σ_a wl_a U3[L_a,l3]) (Σ_b wv_b U4[V_b,l4])

followed by the inverse preprocessing (de-standardisation with μ, σ blended by the same
weights, YUV → RGB, exp). On the ``llvm_ad_*``/``cuda_ad_*`` variants everything is Dr.Jit:
``dr.gather`` from flat arrays (:meth:`sparsebtf.runtime.RuntimeBTF.arrays`), a symbolic
``dr.while_loop`` over the coefficients of each channel and one over the sampled directions
(brute-force k-nearest by chord distance, as :func:`sparsebtf.runtime.angular_weights`). On
``scalar_rgb`` the lookup calls :meth:`RuntimeBTF.evaluate` per ray (tiny renders only).

Convention (what ``eval`` returns). Mitsuba calls ``eval(ctx, si, wo)`` with ``si.wi`` towards
the camera (the previous path vertex) and ``wo`` towards the light, both in the local shading
frame, and expects f·cos θ_o. A measured BTF value (UBO-style) is already the reflected
radiance per unit incident radiance *including* the foreshortening of the light, i.e. f·cos θ_light.
So::

    eval(ctx, si, wo) = BTF(uv, ω_light = wo, ω_view = si.wi)        (no extra cosine)

i.e. :meth:`RuntimeBTF.evaluate(wi=wo, wo=si.wi, uv=si.uv·uv_scale)` (the runtime's ``wi`` is
the light). In ``TransportMode.Importance`` (light tracing) the roles swap. The decoder's floor
of −1e-5 (exp(·) − 1e-5) is clamped to 0. Directions below the horizon give 0 unless
``two_sided`` is set, which mirrors both directions to the upper side on back-face hits.

Local frame. The BTF's azimuth is measured from the +u texture axis towards +v (z = normal).
Mitsuba's shading frame has s = ∂p/∂u (Gram–Schmidt against n) and t = n × s; where the surface
parametrisation is left-handed (t points along −∂p/∂v, e.g. Mitsuba's built-in sphere, whose v
runs from the north pole down) the local y of both directions is negated, so the material's
angular behaviour stays consistent with its texture (a mirror image of the sample, as the
texture itself is mirrored there).

Sampling: cosine-weighted hemisphere (on the side of ``si.wi``); ``pdf`` is cos θ_o/π and
``sample`` returns eval/pdf, so ``sample``, ``pdf`` and ``eval`` agree (checked with
``mitsuba.chi2`` in ``tests/test_mitsuba.py``).

Parameters (``mi.load_dict({"type": "sparsebtf", ...})``):

============== ========= ==============================================================
filename       string    coded file (``sparsebtf encode`` / ``import-release``)
model          string    model file; default: the one the coded file names
key            string    instead of ``filename``: a material added with
                         :func:`sparsebtf.mitsuba.add_material` (a RuntimeBTF/CodedBTF)
tau            string    level of detail τ' at load time: "885,64,64", "32" or a fraction
                         "0.25" of the coded τ (default: every stored coefficient)
uv_scale       float     texture tiling: uv ↦ uv·uv_scale (default 1; wraps)
interpolation  string    nearest | linear (release 2-NN, default) | barycentric | gaussian
domain         string    standardized (Eq. 6, default) | log (the release shader)
k              integer   neighbours of the gaussian scheme (default 4)
beta           float     gaussian sharpness β in exp(−β d²) (default 20)
two_sided      boolean   shade back faces like front faces (default false)
============== ========= ==============================================================

``sparsebtf_dense`` — the uncompressed reference
------------------------------------------------
The same lookup from a dense (H, W, L, V, 3) table: texel by uv, the same angular neighbours
and weights, the weighted blend taken of ln(x + 1e-5) (the log domain of the coded decoder,
so ``nearest`` is an exact table lookup and the blends are comparable), then exp(·) − 1e-5.
Parameters: ``filename`` (any BTF: dense ``.h5``, ``synth:…``, UBO2014 ``.btf``, a coded file)
or ``key``, ``uv_scale``, ``interpolation``, ``k``, ``beta``, ``two_sided`` as above, and
``max_gib`` (float, default 2): larger tables are refused with an error (crop the BTF first,
``sparsebtf convert --crop``).
"""

from __future__ import annotations

import math
import os
import threading
from typing import Any

import numpy as np

from ..errors import BTFInputError

__all__ = [
    "DENSE_PLUGIN",
    "PLUGIN",
    "add_material",
    "dense_table",
    "load_runtime",
    "preload",
    "register",
]

PLUGIN = "sparsebtf"
DENSE_PLUGIN = "sparsebtf_dense"
SCHEMES = ("nearest", "linear", "barycentric", "gaussian")
DEFAULT_K = {"nearest": 1, "linear": 2, "barycentric": 3, "gaussian": 4}
#: Dense reference tables above this size (GiB) are refused by default.
DENSE_MAX_GIB = 2.0
LOG_EPS = 1e-5

_lock = threading.Lock()
_materials: dict[str, Any] = {}
_cache: dict[tuple, Any] = {}


# -- material sources ---------------------------------------------------------------------------
def add_material(obj: Any, key: str | None = None) -> str:
    """Make an in-memory material available to the plugins under ``key`` (returned).

    ``obj``: a :class:`~sparsebtf.runtime.RuntimeBTF` or a :class:`~sparsebtf.model.CodedBTF`
    with its model (for ``sparsebtf``), or a :class:`~sparsebtf.data.btf.BTF` (for
    ``sparsebtf_dense``). Adding under an existing key replaces that material.
    """
    with _lock:
        key = key or f"mem{len(_materials)}-{id(obj):x}"
        _materials[key] = obj
        for ck in [ck for ck in _cache if ("key", key) in ck]:  # replaced: drop stale data
            del _cache[ck]
    return key


def _source_id(props: Any, what: str) -> tuple:
    if "key" in props:
        key = str(props.get("key"))
        if key not in _materials:
            raise BTFInputError(f"{what}: no material was added under key {key!r}")
        return ("key", key)
    if "filename" not in props:
        raise BTFInputError(f"{what}: give 'filename' (a file) or 'key' (an added material)")
    path = str(props.get("filename"))
    if path.startswith("synth:"):
        return ("file", path, None, 0.0)
    if not os.path.exists(path):
        raise BTFInputError(f"{what}: file {path!r} does not exist")
    model = str(props.get("model")) if "model" in props else None
    return ("file", os.path.abspath(path), model, os.path.getmtime(path))


def _parse_tau(text: Any) -> Any:
    if text is None:
        return None
    if isinstance(text, int | float) and not isinstance(text, bool):
        return text
    s = str(text).strip()
    if not s or s.lower() in ("none", "all", "full"):
        return None
    try:
        if "," in s:
            return s
        f = float(s)
    except ValueError:
        raise BTFInputError(
            f"tau must be 'a,b,c', an integer or a fraction, got {text!r}"
        ) from None
    return int(f) if f.is_integer() and f >= 1 else f


def _cached(ck: tuple, make: Any) -> Any:
    """``_cache[ck]``, made by ``make()`` on first use (one value per key, even if two
    threads race to make it)."""
    with _lock:
        if ck in _cache:
            return _cache[ck]
    value = make()
    with _lock:
        return _cache.setdefault(ck, value)


def load_runtime(source: tuple, tau: Any = None):
    """A :class:`~sparsebtf.runtime.RuntimeBTF` for a plugin source (cached per process)."""
    from ..model import CodedBTF
    from ..runtime import RuntimeBTF


    def make() -> RuntimeBTF:
        if source[0] != "key":
            return RuntimeBTF.from_file(source[1], source[2], tau)
        obj = _materials[source[1]]
        if isinstance(obj, CodedBTF):
            return RuntimeBTF(obj, tau)
        if isinstance(obj, RuntimeBTF):
            return obj if tau is None else obj.with_tau(tau)
        raise BTFInputError(
            f"material {source[1]!r} is a {type(obj).__name__}; the sparsebtf plugin needs "
            "a RuntimeBTF or a CodedBTF (use sparsebtf_dense for dense BTFs)"
        )

    return _cached(("runtime", source, str(tau)), make)


def dense_table(btf: Any, max_gib: float = DENSE_MAX_GIB) -> np.ndarray:
    """ln(max(x, 0) + 1e-5) of a whole BTF as float32 (H, W, L, V, 3); refuses > ``max_gib``."""
    h, w, nl, nv, c = btf.shape
    need = h * w * nl * nv * c * 4
    if need > max_gib * 2**30:
        raise BTFInputError(
            f"reference BTF {btf.name!r} ({h}x{w} texels, {nl} lights x {nv} views) needs "
            f"{need / 2**30:.1f} GiB as a float32 table, above the {max_gib:g} GiB limit; crop "
            "it first (sparsebtf convert BTF -o crop.h5 --crop R0:R1,C0:C1) or raise max_gib"
        )
    arr = np.asarray(btf.to_array(), dtype=np.float32)
    return np.log(np.maximum(arr, 0) + np.float32(LOG_EPS)).astype(np.float32)


def _load_dense(source: tuple, max_gib: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ck = ("dense", source, max_gib)
    with _lock:
        if ck in _cache:
            return _cache[ck]
    if source[0] == "key":
        btf = _materials[source[1]]
        if not hasattr(btf, "to_array"):
            raise BTFInputError(
                f"material {source[1]!r} is a {type(btf).__name__}; sparsebtf_dense needs a BTF"
            )
    else:
        from ..data.io import open_btf

        btf = open_btf(source[1], source[2])
    table = dense_table(btf, max_gib)
    out = (table, btf.lights.xyz.astype(np.float32), btf.views.xyz.astype(np.float32))
    with _lock:
        _cache[ck] = out
    return out


def _common_params(props: Any, what: str) -> dict[str, Any]:
    interp = str(props.get("interpolation", "linear"))
    if interp not in SCHEMES:
        raise BTFInputError(
            f"{what}: interpolation must be one of {', '.join(SCHEMES)}, got {interp!r}"
        )
    k = int(props.get("k", DEFAULT_K[interp]))
    if interp != "gaussian" and k != DEFAULT_K[interp]:
        raise BTFInputError(f"{what}: interpolation {interp!r} uses k = {DEFAULT_K[interp]}")
    if k < 1:
        raise BTFInputError(f"{what}: k must be >= 1, got {k}")
    beta = float(props.get("beta", 20.0))
    uv_scale = float(props.get("uv_scale", 1.0))
    if not (math.isfinite(uv_scale) and uv_scale != 0):
        raise BTFInputError(f"{what}: uv_scale must be finite and non-zero, got {uv_scale}")
    return {
        "interpolation": interp,
        "k": k,
        "beta": beta,
        "uv_scale": uv_scale,
        "two_sided": bool(props.get("two_sided", False)),
    }


def preload(bsdf: dict[str, Any]) -> Any:
    """Load what a plugin dict needs, outside Mitsuba, so errors surface as themselves.

    (An exception inside a plugin constructor reaches the caller as Mitsuba's RuntimeError.)
    Returns the RuntimeBTF (``sparsebtf``), the dense log table (``sparsebtf_dense``) or None.
    """
    kind = bsdf.get("type")
    if kind == PLUGIN:
        _common_params(bsdf, PLUGIN)
        domain = str(bsdf.get("domain", "standardized"))
        if domain not in ("standardized", "log"):
            raise BTFInputError(f"{PLUGIN}: domain must be standardized or log, got {domain!r}")
        return load_runtime(_source_id(bsdf, PLUGIN), _parse_tau(bsdf.get("tau")))
    if kind == DENSE_PLUGIN:
        _common_params(bsdf, DENSE_PLUGIN)
        max_gib = float(bsdf.get("max_gib", DENSE_MAX_GIB))
        return _load_dense(_source_id(bsdf, DENSE_PLUGIN), max_gib)
    return None


# -- Dr.Jit kernels -----------------------------------------------------------------------------
def _knn_scan(mi: Any, dr: Any, tables: list[tuple[Any, int, Any]], k: int, active: Any):
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


def _weights(mi: Any, dr: Any, scheme: str, flat: Any, q: Any, ii: list, dd: list,
             beta: float, active: Any) -> list:
    """Interpolation weights of the k neighbours (the runtime's schemes, in float32)."""
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


def _texel(mi: Any, dr: Any, uv: Any, height: int, width: int):
    f = uv - dr.floor(uv)
    col = dr.minimum(mi.UInt32(f.x * width), width - 1)
    row = dr.minimum(mi.UInt32(f.y * height), height - 1)
    return row, col


class _CodedJit:
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


def _coded_lookup(mi: Any, dr: Any, data: _CodedJit, prm: dict[str, Any], uv: Any,
                  light: Any, view: Any, active: Any) -> Any:
    """Eq. 5/6 for a wavefront of queries: linear RGB (Color3f), Dr.Jit variants."""
    k, scheme = prm["k"], prm["interpolation"]
    row, col = _texel(mi, dr, uv, data.height, data.width)
    p = data.patch
    pt = row // p + data.n_rb * (col // p)
    i1, i2 = row % p, col % p
    ql, qv = dr.normalize(light), dr.normalize(view)
    (li, dl), (vi, dv) = _knn_scan(
        mi, dr, [(data.lights, data.n_lights, ql), (data.views, data.n_views, qv)], k, active
    )
    lw = _weights(mi, dr, scheme, data.lights, ql, li, dl, prm["beta"], active)
    vw = _weights(mi, dr, scheme, data.views, qv, vi, dv, prm["beta"], active)
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


class _DenseJit:
    def __init__(self, mi: Any, table: np.ndarray, lights: np.ndarray, views: np.ndarray) -> None:
        self.height, self.width, self.n_lights, self.n_views = (int(v) for v in table.shape[:4])
        self.table = mi.Float(table.ravel())
        self.lights = mi.Float(lights.ravel())
        self.views = mi.Float(views.ravel())


def _dense_lookup(mi: Any, dr: Any, data: _DenseJit, prm: dict[str, Any], uv: Any,
                  light: Any, view: Any, active: Any) -> Any:
    k, scheme = prm["k"], prm["interpolation"]
    row, col = _texel(mi, dr, uv, data.height, data.width)
    ql, qv = dr.normalize(light), dr.normalize(view)
    (li, dl), (vi, dv) = _knn_scan(
        mi, dr, [(data.lights, data.n_lights, ql), (data.views, data.n_views, qv)], k, active
    )
    lw = _weights(mi, dr, scheme, data.lights, ql, li, dl, prm["beta"], active)
    vw = _weights(mi, dr, scheme, data.views, qv, vi, dv, prm["beta"], active)
    base = (row * data.width + col) * (data.n_lights * data.n_views)
    acc = mi.Color3f(0.0)
    for x in range(len(lw)):
        for y in range(len(vw)):
            idx = base + li[x] * data.n_views + vi[y]
            acc += (lw[x] * vw[y]) * dr.gather(mi.Color3f, data.table, idx, active)
    return dr.exp(acc) - LOG_EPS


# -- scalar (numpy) lookups ---------------------------------------------------------------------
def _scalar_coded(rt: Any, prm: dict[str, Any], uv: np.ndarray, light: np.ndarray,
                  view: np.ndarray) -> np.ndarray:
    return rt.evaluate(
        light[None, :], view[None, :], uv=uv[None, :], interpolation=prm["interpolation"],
        domain=prm["domain"], k=prm["k"] if prm["interpolation"] == "gaussian" else None,
        beta=prm["beta"],
    )[0]  # fmt: skip


def _scalar_dense(data: tuple, prm: dict[str, Any], uv: np.ndarray, light: np.ndarray,
                  view: np.ndarray) -> np.ndarray:
    from ..runtime import angular_weights, texels_from_uv

    table, lights, views = data
    kk = prm["k"] if prm["interpolation"] == "gaussian" else None
    li, lw = angular_weights(lights, light[None, :], prm["interpolation"], kk, prm["beta"])
    vi, vw = angular_weights(views, view[None, :], prm["interpolation"], kk, prm["beta"])
    row, col = texels_from_uv(uv[None, :], table.shape[0], table.shape[1])
    vals = table[row[0], col[0]][li[0][:, None], vi[0][None, :]]  # (kl, kv, 3)
    w = lw[0][:, None] * vw[0][None, :]
    return np.exp(np.einsum("ab,abc->c", w, vals)) - LOG_EPS


# -- plugin classes -----------------------------------------------------------------------------
_registered: set[str] = set()


def _define(mi: Any, dr: Any) -> tuple[type, type]:
    scalar = not dr.is_jit_v(mi.Float)
    if "rgb" not in mi.variant():
        raise BTFInputError(
            f"the sparsebtf plugins need an RGB variant (llvm_ad_rgb, cuda_ad_rgb or scalar_rgb); "
            f"the active Mitsuba variant is {mi.variant()}"
        )

    class _Base(mi.BSDF):
        def _setup_flags(self, two_sided: bool) -> None:
            flags = (
                mi.BSDFFlags.GlossyReflection
                | mi.BSDFFlags.FrontSide
                | mi.BSDFFlags.SpatiallyVarying
            )
            if two_sided:
                flags = flags | mi.BSDFFlags.BackSide
            self.m_flags = flags
            self.m_components = [flags]

        def _frame(self, si: Any, wo: Any, active: Any, importance: bool = False):
            """(uv, light, view, active) in the BTF's frame; see the module docstring."""
            wi = mi.Vector3f(si.wi)
            wo = mi.Vector3f(wo)
            if self.prm["two_sided"]:
                back = wi.z < 0
                wi = dr.select(back, mi.Vector3f(wi.x, wi.y, -wi.z), wi)
                wo = dr.select(back, mi.Vector3f(wo.x, wo.y, -wo.z), wo)
            active = active & (wi.z > 0) & (wo.z > 0)
            flip = dr.dot(si.sh_frame.t, si.dp_dv) < 0
            wi = dr.select(flip, mi.Vector3f(wi.x, -wi.y, wi.z), wi)
            wo = dr.select(flip, mi.Vector3f(wo.x, -wo.y, wo.z), wo)
            uv = mi.Point2f(si.uv) * self.prm["uv_scale"]
            light, view = (wi, wo) if importance else (wo, wi)
            return uv, light, view, active

        def _value(self, ctx: Any, si: Any, wo: Any, active: Any) -> Any:
            importance = ctx.mode == mi.TransportMode.Importance
            uv, light, view, active = self._frame(si, wo, active, importance)
            if scalar:
                if not active:
                    return mi.Color3f(0.0)
                rgb = self._scalar_lookup(
                    np.array([uv.x, uv.y], dtype=np.float64),
                    np.array([light.x, light.y, light.z], dtype=np.float64),
                    np.array([view.x, view.y, view.z], dtype=np.float64),
                )
                return mi.Color3f(*(max(float(v), 0.0) for v in rgb))
            rgb = self._jit_lookup(uv, light, view, active)
            return dr.select(active, dr.maximum(rgb, 0.0), 0.0)

        def _pdf(self, ctx: Any, si: Any, wo: Any, active: Any) -> Any:
            cos_i = mi.Frame3f.cos_theta(si.wi)
            cos_o = mi.Frame3f.cos_theta(wo)
            if self.prm["two_sided"]:
                ok = cos_i * cos_o > 0
                return dr.select(active & ok, dr.abs(cos_o) * dr.inv_pi, 0.0)
            ok = (cos_i > 0) & (cos_o > 0)
            return dr.select(active & ok, cos_o * dr.inv_pi, 0.0)

        def eval(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
            if not ctx.is_enabled(mi.BSDFFlags.GlossyReflection):
                return mi.Color3f(0.0)
            return self._value(ctx, si, wo, active)

        def pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
            if not ctx.is_enabled(mi.BSDFFlags.GlossyReflection):
                return mi.Float(0.0)
            return self._pdf(ctx, si, wo, active)

        def eval_pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def sample(self, ctx: Any, si: Any, sample1: Any, sample2: Any, active: Any = True):
            """Cosine-weighted hemisphere sampling on the side of ``si.wi``; weight = eval/pdf."""
            bs = dr.zeros(mi.BSDFSample3f)
            cos_i = mi.Frame3f.cos_theta(si.wi)
            wo = mi.warp.square_to_cosine_hemisphere(sample2)
            if self.prm["two_sided"]:
                wo = dr.select(cos_i < 0, mi.Vector3f(wo.x, wo.y, -wo.z), wo)
                active = active & (cos_i != 0)
            else:
                active = active & (cos_i > 0)
            if not ctx.is_enabled(mi.BSDFFlags.GlossyReflection):
                return bs, mi.Color3f(0.0)
            bs.wo = wo
            bs.pdf = self._pdf(ctx, si, wo, active)
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
            bs.sampled_component = mi.UInt32(0)
            value = self._value(ctx, si, wo, active)
            ok = active & (bs.pdf > 0)
            weight = dr.select(ok, value / dr.select(ok, bs.pdf, 1.0), 0.0)
            return bs, weight

        def traverse(self, cb: Any) -> None:
            pass

        def parameters_changed(self, keys: Any = None) -> None:
            pass

    class SparseBTFBSDF(_Base):
        """Coded SparseBTF material (Eq. 5/6); parameters: module docstring."""

        def __init__(self, props: Any) -> None:
            _Base.__init__(self, props)
            self.prm = _common_params(props, PLUGIN)
            domain = str(props.get("domain", "standardized"))
            if domain not in ("standardized", "log"):
                raise BTFInputError(f"{PLUGIN}: domain must be standardized or log, got {domain!r}")
            self.prm["domain"] = domain
            source = _source_id(props, PLUGIN)
            tau = _parse_tau(props.get("tau", None) if "tau" in props else None)
            self.rt = load_runtime(source, tau)
            self.meta = dict(self.rt.meta)
            self._setup_flags(self.prm["two_sided"])
            if not scalar:
                self.data = _cached(("jit", mi.variant(), source, str(tau)),
                                    lambda: _CodedJit(mi, self.rt))  # fmt: skip

        def _jit_lookup(self, uv, light, view, active):
            return _coded_lookup(mi, dr, self.data, self.prm, uv, light, view, active)

        def _scalar_lookup(self, uv, light, view):
            return _scalar_coded(self.rt, self.prm, uv, light, view)

        def to_string(self) -> str:
            m = self.meta
            return (
                f"SparseBTF[{m['name']}, {m['height']}x{m['width']}, tau={m['tau']}, "
                f"{self.prm['interpolation']}/{self.prm['domain']}, "
                f"uv_scale={self.prm['uv_scale']}]"
            )

    class SparseBTFDenseBSDF(_Base):
        """Dense (uncompressed) BTF table, the reference; parameters: module docstring."""

        def __init__(self, props: Any) -> None:
            _Base.__init__(self, props)
            self.prm = _common_params(props, DENSE_PLUGIN)
            source = _source_id(props, DENSE_PLUGIN)
            max_gib = float(props.get("max_gib", DENSE_MAX_GIB))
            self.np_data = _load_dense(source, max_gib)
            self._setup_flags(self.prm["two_sided"])
            if not scalar:
                self.data = _cached(("jitdense", mi.variant(), source, max_gib),
                                    lambda: _DenseJit(mi, *self.np_data))  # fmt: skip

        def _jit_lookup(self, uv, light, view, active):
            return _dense_lookup(mi, dr, self.data, self.prm, uv, light, view, active)

        def _scalar_lookup(self, uv, light, view):
            return _scalar_dense(self.np_data, self.prm, uv, light, view)

        def to_string(self) -> str:
            h, w, nl, nv = self.np_data[0].shape[:4]
            return f"SparseBTFDense[{h}x{w}, {nl}x{nv} directions, {self.prm['interpolation']}]"

    return SparseBTFBSDF, SparseBTFDenseBSDF


def register() -> str:
    """Register ``sparsebtf`` and ``sparsebtf_dense`` for the active Mitsuba variant (idempotent).

    Returns the variant. Call after ``mi.set_variant`` (:mod:`sparsebtf.mitsuba` does both).
    """
    import drjit as dr
    import mitsuba as mi

    variant = mi.variant()
    if variant is None:
        raise BTFInputError("no Mitsuba variant is set; call mi.set_variant(...) first")
    if variant in _registered:
        return variant
    coded_cls, dense_cls = _define(mi, dr)
    mi.register_bsdf(PLUGIN, lambda props: coded_cls(props))
    mi.register_bsdf(DENSE_PLUGIN, lambda props: dense_cls(props))
    _registered.add(variant)
    return variant
