"""The lookups and the sampler behind both plugins, apart from the plugin classes (as Mitsuba 3's
``ad/bsdfs``).

Dr.Jit kernels (the ``llvm_ad_*``/``cuda_ad_*`` variants), evaluated for a wavefront of shading
points at once:

* :func:`find_neighbours` — the k nearest sampled directions of each query and their weights
  (:func:`neighbour_weights`, the runtime's schemes). Each query scans only the candidate list
  of its grid cell (:class:`Candidates`, :func:`sparsebtf.runtime.angular.candidate_lists`,
  provably complete), 2–3 directions on average instead of all 151;
* :func:`coded_lookup` — Eq. 5/6 from the flat renderer arrays (:class:`CodedArrays`), then the
  inverse preprocessing; :func:`dense_lookup` — the log-domain blend of a dense table
  (:class:`DenseArrays`). Both take the neighbours found once per query by the plugin;
* :func:`btf_sample` / :func:`btf_pdf` — BTF-driven importance sampling from the tables of
  :mod:`.sampling` (:class:`SamplingArrays`), mixed with cosine sampling.

Scalar lookups (``scalar_rgb``, one ray at a time in NumPy): :func:`scalar_coded` calls
:meth:`sparsebtf.runtime.RuntimeBTF.evaluate`, :func:`scalar_dense` blends the table with
:func:`sparsebtf.runtime.angular_weights`; sampling there uses :mod:`.sampling`'s NumPy twins.

The kernels take the ``mitsuba`` and ``drjit`` modules as arguments (``mi``, ``dr``) instead of
importing them, so this module loads without Mitsuba and the arrays they build belong to
whichever variant is active when they run. ``prm`` is a plugin's checked parameters
(:func:`.materials.common_params` / :func:`.materials.coded_params`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...points.preprocessing import RELEASE_LOG_OFFSET
from ...runtime.angular import candidate_lists
from .highlights import HighlightArrays, add_highlights
from .sampling import ONE_MINUS_EPS, SamplingTables

__all__ = [
    "Candidates",
    "CodedArrays",
    "DenseArrays",
    "SamplingArrays",
    "btf_pdf",
    "btf_sample",
    "coded_lookup",
    "dense_lookup",
    "find_neighbours",
    "neighbour_weights",
    "point_of",
    "scalar_coded",
    "scalar_dense",
    "texel",
]

#: Build the U1 ⊗ U2 product table (one gather per coefficient instead of two) up to this
#: many entries (K·p⁴; 80 000 for K = 8, p = 10).
D12_MAX = 1 << 22
#: Grid of the candidate lists (that of :func:`sparsebtf.runtime.angular.neighbour_table`).
N_ELEVATION, N_PHI = 64, 256


# -- neighbours ---------------------------------------------------------------------------------
class Candidates:
    """One direction set as Dr.Jit arrays: flat xyz and, per grid cell, the directions that can
    be among the ``k`` nearest of a query there
    (:func:`~sparsebtf.runtime.angular.candidate_lists`)."""

    def __init__(self, mi: Any, xyz: np.ndarray, k: int) -> None:
        offsets, indices = candidate_lists(xyz, k, N_PHI, N_ELEVATION)
        self.n = int(xyz.shape[0])
        self.xyz = mi.Float(np.asarray(xyz, dtype=np.float32).ravel())
        self.offsets = mi.UInt32(offsets.astype(np.uint32))
        self.indices = mi.UInt32(indices.astype(np.uint32))


def _cell(mi: Any, dr: Any, q: Any) -> Any:
    """Grid cell e·N_PHI + a of unit queries (as :func:`sparsebtf.runtime.angular.cell_of`)."""
    el = dr.asin(dr.clip(q.z, 0.0, 1.0))
    az = dr.atan2(q.y, q.x)
    e = dr.minimum(mi.UInt32(el * (2.0 / dr.pi * N_ELEVATION)), N_ELEVATION - 1)
    a = dr.minimum(mi.UInt32(dr.maximum(az + dr.pi, 0.0) * (0.5 / dr.pi * N_PHI)), N_PHI - 1)
    return e * N_PHI + a


def find_neighbours(mi: Any, dr: Any, prm: dict[str, Any], queries: list[tuple[Candidates, Any]],
                    active: Any) -> list[tuple[list[Any], list[Any]]]:
    """Angular neighbours of each query: per query (indices [UInt32]*k, weights [Float]*k).

    ``queries``: [(direction set, query Vector3f)], searched together in one symbolic loop over
    the candidates of each query's cell; the k nearest by squared chord distance, nearest first,
    ties to the lower index (as :func:`sparsebtf.runtime.angular_weights`), then the weights of
    ``prm["interpolation"]`` (``k``, ``beta``).
    """
    k, big = prm["k"], 1e30
    qs = [dr.normalize(q) for _, q in queries]
    starts, counts = [], []
    for (cand, _), q in zip(queries, qs, strict=True):
        c = _cell(mi, dr, q)
        s0 = dr.gather(mi.UInt32, cand.offsets, c, active)
        starts.append(s0)
        counts.append(dr.select(active, dr.gather(mi.UInt32, cand.offsets, c + 1, active) - s0, 0))
    n_max = counts[0]
    for c in counts[1:]:
        n_max = dr.maximum(n_max, c)
    state: list[Any] = [mi.UInt32(0)]
    for _ in queries:
        state += [dr.zeros(mi.UInt32, 1) for _ in range(k)] + [mi.Float(big) for _ in range(k)]

    def body(*st):
        st = list(st)
        j = st[0]
        out = [j + 1]
        for t, ((cand, _), q) in enumerate(zip(queries, qs, strict=True)):
            ii = list(st[1 + t * 2 * k : 1 + t * 2 * k + k])
            dd = list(st[1 + t * 2 * k + k : 1 + (t + 1) * 2 * k])
            ok = j < counts[t]
            ci = dr.gather(mi.UInt32, cand.indices, starts[t] + j, ok)
            x = dr.gather(mi.Vector3f, cand.xyz, ci, ok)
            cd = dr.select(ok, dr.squared_norm(q - x), big)
            for s in range(k):
                sw = cd < dd[s]
                dd[s], cd = dr.select(sw, cd, dd[s]), dr.select(sw, dd[s], cd)
                ii[s], ci = dr.select(sw, ci, ii[s]), dr.select(sw, ii[s], ci)
            out += ii + dd
        return tuple(out)

    res = dr.while_loop(tuple(state), lambda *st: st[0] < n_max, body, label="sparsebtf_knn")
    outs = []
    for t, ((cand, _), q) in enumerate(zip(queries, qs, strict=True)):
        ii = list(res[1 + t * 2 * k : 1 + t * 2 * k + k])
        dd = list(res[1 + t * 2 * k + k : 1 + (t + 1) * 2 * k])
        w = neighbour_weights(mi, dr, prm["interpolation"], cand.xyz, q, ii, dd, prm["beta"],
                              active)  # fmt: skip
        outs.append((ii[: len(w)], w))
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
    """The flat renderer arrays of one coded material as Dr.Jit arrays of the active variant.

    Per channel: ``packed`` interleaves each coefficient's value (float32 bits) and packed
    location, so one 8-byte gather reads both; ``d12`` = U1[k, i1, l1]·U2[k, i2, l2] at
    [k, i1, i2, l1, l2] (K·p⁴ floats, when at most :data:`D12_MAX`) replaces two gathers by one;
    ``tau`` the loaded τ (what a level-of-detail fraction multiplies); ``highlights`` the
    highlight store (:class:`.highlights.HighlightArrays`; None: none, or an adaptive material).

    A material coded with adaptive patch sizes (an
    :class:`~sparsebtf.runtime.AdaptiveRuntimeBTF`, ``adaptive``): the data points are its
    nodes (:meth:`~sparsebtf.runtime.AdaptiveRuntimeBTF.arrays`), ``cells`` gives the node of
    each cell of the finest grid and ``node_patch`` its size; the spatial dictionaries are
    padded to the largest size P, so ``p`` (the stride, and ``d12``'s) is P; ``tau`` is per
    node (the loaded τ of its size). The fixed-size path is unchanged: :func:`point_of` and
    :func:`coded_lookup` branch in Python on ``adaptive``, so its kernels are traced as before.
    """

    def __init__(self, mi: Any, rt: Any) -> None:
        a = rt.arrays(neighbours=False)
        self.adaptive = hasattr(rt, "flat_meta")
        m = rt.flat_meta if self.adaptive else rt.meta
        self.height, self.width, self.patch = int(m["height"]), int(m["width"]), int(m["patch"])
        self.n_rb = int(m["n_rb"])
        if self.adaptive:
            self.smallest = int(m["smallest"])
            self.cells = mi.UInt32(a["cells"].astype(np.uint32))
            self.node_patch = mi.UInt32(a["node_patch"].astype(np.uint32))
        self.n_lights, self.n_views = int(m["n_lights"]), int(m["n_views"])
        self.log_offset = float(m["eps"])
        self.n_stats = int(a["mean"].shape[0])
        self.mean = mi.Float(a["mean"].ravel())
        self.std = mi.Float(a["std"].ravel())
        self.bound = mi.Float(a["bound"].ravel())
        self.yuv_to_rgb = [[float(v) for v in row] for row in a["yuv_to_rgb"]]
        self.highlights = HighlightArrays.of(mi, a, self.patch, self.n_lights, self.n_views)
        self.channels = []
        for ch in ("Y", "U", "V"):
            d1, d2 = a[f"dict1_{ch}"], a[f"dict2_{ch}"]
            values, locations = a[f"values_{ch}"], a[f"locations_{ch}"]
            packed = np.empty(2 * values.size, dtype=np.uint32)
            packed[0::2] = values.astype(np.float32).view(np.uint32)
            packed[1::2] = locations
            k, p = d1.shape[0], d1.shape[1]
            d12 = None
            if k * p**4 <= D12_MAX:
                d12 = np.einsum("kax,kby->kabxy", d1.astype(np.float64), d2.astype(np.float64))
                d12 = mi.Float(d12.astype(np.float32).ravel())
            tau = (mi.Float(a[f"tau_{ch}"].astype(np.float32)) if self.adaptive
                   else float(rt.tau[ch]))  # fmt: skip
            self.channels.append(
                {
                    "membership": mi.UInt32(a[f"membership_{ch}"].astype(np.uint32)),
                    "offsets": mi.UInt32(a[f"offsets_{ch}"].astype(np.uint32)),
                    "packed": mi.UInt32(packed),
                    "d12": d12,
                    "dict1": mi.Float(d1.ravel()),
                    "dict2": mi.Float(d2.ravel()),
                    "dict3": mi.Float(a[f"dict3_{ch}"].ravel()),
                    "dict4": mi.Float(a[f"dict4_{ch}"].ravel()),
                    "p": int(p),
                    "L": int(a[f"dict3_{ch}"].shape[1]),
                    "V": int(a[f"dict4_{ch}"].shape[1]),
                    "tau": tau,
                }
            )


def point_of(mi: Any, dr: Any, data: CodedArrays, uv: Any) -> tuple[Any, Any, Any]:
    """(data point, i1, i2) of the texel under ``uv`` (the release's point order); for an
    adaptive material (node, row % p, col % p), the node from ``cells`` and p its size."""
    row, col = texel(mi, dr, uv, data.height, data.width)
    if data.adaptive:
        s = data.smallest
        node = dr.gather(mi.UInt32, data.cells, row // s + (data.height // s) * (col // s))
        # at least 1: the masked tail lanes of an LLVM packet gather 0, and an integer
        # division by 0 traps (SIGFPE) even where its result is unused
        p = dr.maximum(dr.gather(mi.UInt32, data.node_patch, node), 1)
        return node, row % p, col % p
    p = data.patch
    return row // p + data.n_rb * (col // p), row % p, col % p


def coded_lookup(mi: Any, dr: Any, data: CodedArrays, prm: dict[str, Any], uv: Any,
                 light_nb: tuple[list, list], view_nb: tuple[list, list], active: Any,
                 fraction: Any = None, stats: tuple | None = None,
                 dirs: tuple[Any, Any] | None = None) -> Any:
    """Eq. 5/6 for a wavefront of queries: linear RGB (Color3f), Dr.Jit variants.

    ``uv`` (tiled, wraps); ``light_nb``/``view_nb``: the (indices, weights) of
    :func:`find_neighbours`; ``prm`` needs ``domain``. The decoder's floor (−log offset) is kept:
    the plugin clamps to 0. The log-RGB values are clamped to the material's bound interpolated
    with the angular weights, as :meth:`~sparsebtf.runtime.RuntimeBTF.evaluate` does. A
    material with highlights gets their correction added, at any level of detail, and is
    clamped at 0 here (:mod:`.highlights`); ``dirs`` (light, view) Vector3f in the BTF frame,
    the directions the neighbours were found for, where its lobes are evaluated.

    ``fraction``: None (every loaded coefficient), or a Float of per-query fractions f of the
    loaded τ: channel c reads τ'_c = max(f·τ_c, min(1, τ_c)) (:func:`sparsebtf.runtime.lod.
    lod_tau`; τ_c per node for an adaptive material), fractional: the first ⌊τ'⌋ coefficients
    count fully, the next with weight τ' − ⌊τ'⌋ (as
    :func:`sparsebtf.runtime.kernels.prefix_weights`). ``stats``: (UInt32 buffer, class index)
    to count lookups and loop iterations per channel at ``4·class + (0, 1, 2, 3)``.

    Per coefficient the loop reads one packed (value, location) pair, U1·U2 from ``d12`` and
    the kl + kv angular factors: 2 + kl + kv gathers (4 + kl + kv before the packing and d12).
    Blending the neighbours' U3/U4 rows once per query into ``dr.alloc_local`` arrays (as the
    numba kernel does) measured 12 % faster outside a render, but Dr.Jit 1.5's LLVM backend
    fails to compile local arrays inside Mitsuba's recorded virtual calls ("use of undefined
    value %arr"), so it is not done.
    """
    li, lw = light_nb
    vi, vw = view_nb
    pt, i1, i2 = point_of(mi, dr, data, uv)
    kl, kv = len(lw), len(vw)
    nl, nv = data.n_lights, data.n_views
    log_domain = prm["domain"] == "log"
    logs = []
    for c, ch in enumerate(data.channels):
        s_idx = c if data.n_stats == 3 else 0
        kk = dr.gather(mi.UInt32, ch["membership"], pt, active)
        s0 = dr.gather(mi.UInt32, ch["offsets"], pt, active)
        s1 = dr.select(active, dr.gather(mi.UInt32, ch["offsets"], pt + 1, active), s0)
        t = None
        if fraction is not None:
            if data.adaptive:  # the loaded τ of the node's size
                cap = dr.gather(mi.Float, ch["tau"], pt, active)
                t = dr.maximum(fraction * cap, dr.minimum(cap, 1.0))
            else:
                cap = ch["tau"]
                t = mi.Float(dr.maximum(fraction * cap, min(1.0, cap)))
        if t is not None:  # a last coefficient of weight < 1e-4 (float32 f·τ rounding) unread
            s1 = dr.minimum(s1, s0 + mi.UInt32(dr.ceil(t - 1e-4)))
        if stats is not None:
            if c == 0:
                dr.scatter_reduce(dr.ReduceOp.Add, stats[0], mi.UInt32(1), 4 * stats[1], active)
            dr.scatter_reduce(dr.ReduceOp.Add, stats[0], s1 - s0, 4 * stats[1] + 1 + c, active)
        pp, cl, cv = ch["p"], ch["L"], ch["V"]
        b3 = [kk * (cl * cl) + li[a] * cl for a in range(kl)]
        b4 = [kk * (cv * cv) + vi[b] * cv for b in range(kv)]
        b12 = kk * pp**4 + (i1 * pp + i2) * (pp * pp)
        b1, b2 = kk * (pp * pp) + i1 * pp, kk * (pp * pp) + i2 * pp
        n_acc = kl * kv if log_domain else 1

        def body(s, *acc, ch=ch, pp=pp, b12=b12, b1=b1, b2=b2, b3=b3, b4=b4, s0=s0, t=t):
            vc = dr.gather(mi.Vector2u, ch["packed"], s)
            v, code = dr.reinterpret_array(mi.Float, vc.x), vc.y
            if t is not None:  # the fractional level fades the last coefficient in
                v = v * dr.minimum(t - mi.Float(s - s0), 1.0)
            l1, l2 = code & 0xFF, (code >> 8) & 0xFF
            l3, l4 = (code >> 16) & 0xFF, code >> 24
            if ch["d12"] is not None:
                a = v * dr.gather(mi.Float, ch["d12"], b12 + l1 * pp + l2)
            else:
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
            lambda s, *acc, s1=s1: s < s1,
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
    bound = mi.Float(0.0)
    for x in range(kl):
        for y in range(kv):
            bound += lw[x] * vw[y] * dr.gather(mi.Float, data.bound, li[x] * nv + vi[y], active)
    m = data.yuv_to_rgb
    rgb = [
        dr.exp(dr.minimum(m[r][0] * logs[0] + m[r][1] * logs[1] + m[r][2] * logs[2], bound))
        - data.log_offset
        for r in range(3)
    ]
    return add_highlights(mi, dr, data.highlights, mi.Color3f(*rgb), pt, i1, i2, light_nb,
                          view_nb, active, dirs)


class DenseArrays:
    """A dense log table as a Dr.Jit array of the active variant."""

    def __init__(self, mi: Any, table: np.ndarray) -> None:
        self.height, self.width, self.n_lights, self.n_views = (int(v) for v in table.shape[:4])
        self.table = mi.Float(table.ravel())


def dense_lookup(mi: Any, dr: Any, data: DenseArrays, uv: Any, light_nb: tuple[list, list],
                 view_nb: tuple[list, list], active: Any) -> Any:
    """exp(Σ w_a w_b ln(x + 1e-5)) − 1e-5 over the angular neighbours of a dense table (the
    reference lookup, ``nearest`` an exact table value): linear RGB (Color3f)."""
    li, lw = light_nb
    vi, vw = view_nb
    row, col = texel(mi, dr, uv, data.height, data.width)
    base = (row * data.width + col) * (data.n_lights * data.n_views)
    acc = mi.Color3f(0.0)
    for x in range(len(lw)):
        for y in range(len(vw)):
            idx = base + li[x] * data.n_views + vi[y]
            acc += (lw[x] * vw[y]) * dr.gather(mi.Color3f, data.table, idx, active)
    return dr.exp(acc) - RELEASE_LOG_OFFSET


# -- BTF-driven sampling --------------------------------------------------------------------------
class SamplingArrays:
    """:class:`.sampling.SamplingTables` as Dr.Jit arrays: per mode the flat CDF rows and the
    number of bins of the known set."""

    def __init__(self, mi: Any, tables: SamplingTables) -> None:
        self.grid, self.mix = tables.grid, tables.mix
        self.n_cells = tables.n_cells
        self.per_row = {m: c.shape[0] > 1 for m, c in tables.cdf.items()}
        self.n_cond = {m: int(c.shape[1]) for m, c in tables.cdf.items()}
        self.cdf = {m: mi.Float(c.ravel()) for m, c in tables.cdf.items()}


def _row_base(sa: SamplingArrays, mode: str, row: Any, b: Any) -> Any:
    """Offset of the CDF row of known bin ``b`` (in table ``row`` when per point)."""
    if sa.per_row[mode]:
        return (row * sa.n_cond[mode] + b) * sa.n_cells
    return b * sa.n_cells


def btf_pdf(mi: Any, dr: Any, sa: SamplingArrays, mode: str, row: Any,
            known_nb: tuple[list, list], wo: Any, active: Any) -> Any:
    """Density of :func:`btf_sample` per solid angle at ``wo`` (BTF frame), 0 below the horizon:
    mix·cos θ/π + (1 − mix)·Σ_a w_a P(cell(wo) | b_a)·grid²/2π (:mod:`.sampling`)."""
    g = sa.grid
    sq = dr.clip(mi.warp.uniform_hemisphere_to_square(wo), 0.0, 1.0)
    cell = dr.minimum(mi.UInt32(sq.y * g), g - 1) * g + dr.minimum(mi.UInt32(sq.x * g), g - 1)
    cdf = sa.cdf[mode]
    p_tab = mi.Float(0.0)
    for b, w in zip(*known_nb, strict=True):
        base = _row_base(sa, mode, row, b) + cell
        hi = dr.gather(mi.Float, cdf, base, active)
        lo = dr.gather(mi.Float, cdf, base - 1, active & (cell > 0))
        p_tab += w * (hi - lo)
    pdf = sa.mix * dr.inv_pi * wo.z + (1.0 - sa.mix) * (sa.n_cells / (2 * np.pi)) * p_tab
    return dr.select(active & (wo.z > 0), pdf, 0.0)


def btf_sample(mi: Any, dr: Any, sa: SamplingArrays, mode: str, row: Any,
               known_nb: tuple[list, list], u1: Any, u2: Any, active: Any) -> Any:
    """A direction (BTF frame, upper hemisphere) from :func:`btf_pdf`'s density.

    u1 < mix: cosine-weighted from u2. Otherwise u1 rescaled picks a neighbour b_a of the known
    direction with probability w_a, then a cell from its CDF row (binary search), and u2 a
    uniform point of that cell (equal-area map): as :func:`.sampling.sample`.
    """
    ii, ww = known_nb
    use_cos = u1 < sa.mix
    u = dr.clip((u1 - sa.mix) / (1.0 - sa.mix), 0.0, ONE_MINUS_EPS)
    b, lo, wsel, acc = ii[0], mi.Float(0.0), ww[0], ww[0]
    for a in range(1, len(ww)):
        take = u >= acc
        b = dr.select(take, ii[a], b)
        lo = dr.select(take, acc, lo)
        wsel = dr.select(take, ww[a], wsel)
        acc = acc + ww[a]
    ur = dr.clip((u - lo) / dr.maximum(wsel, 1e-12), 0.0, ONE_MINUS_EPS)
    base = _row_base(sa, mode, row, b)
    cdf = sa.cdf[mode]
    cell = dr.binary_search(
        0, sa.n_cells - 1, lambda i: dr.gather(mi.Float, cdf, base + i, active) <= ur
    )
    g = sa.grid
    sq = mi.Point2f((mi.Float(cell % g) + u2.x) / g, (mi.Float(cell // g) + u2.y) / g)
    return dr.select(use_cos, mi.warp.square_to_cosine_hemisphere(u2),
                     mi.warp.square_to_uniform_hemisphere(sq))


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
    return np.exp(np.einsum("ab,abc->c", w, vals)) - RELEASE_LOG_OFFSET

