"""The Mitsuba BSDF classes of ``sparsebtf`` and ``sparsebtf_dense``, bound to one variant.

A Python class deriving from ``mi.BSDF`` binds to the Mitsuba variant active when its
``class`` statement runs, so this module imports ``mitsuba`` at the top and must only be
imported once a variant is set: :func:`sparsebtf.rendering.mitsuba.register` imports it (and
reloads it when the active variant differs from :data:`VARIANT`, the one it was built for),
then registers its classes. Do not import it directly.

Parameters and conventions (which direction is the light, the local frame, sampling): the
table in :mod:`sparsebtf.rendering.mitsuba`. The lookups and the sampler live in
:mod:`.kernels` (NumPy sampling tables in :mod:`.sampling`), material loading and parameter
checks in :mod:`.materials`.
"""

from __future__ import annotations

import hashlib
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from ...errors import BTFInputError
from ...runtime.lod import COS_FLOOR, lod_tau
from . import sampling as np_sampling
from .kernels import (
    Candidates,
    CodedArrays,
    DenseArrays,
    SamplingArrays,
    btf_pdf,
    btf_sample,
    coded_lookup,
    dense_lookup,
    find_neighbours,
    point_of,
    scalar_coded,
    scalar_dense,
)
from .materials import (
    BSDF_PER_BTF_VALUE,
    DENSE_MAX_GIB,
    DENSE_PLUGIN,
    PLUGIN,
    cached,
    coded_params,
    coded_sampling,
    common_params,
    dense_sampling,
    flat_meta,
    host_lookups,
    load_dense,
    load_runtime,
    source_id,
)

__all__ = ["VARIANT", "SparseBTFBSDF", "SparseBTFDenseBSDF"]

#: The Mitsuba variant these classes were built for.
VARIANT: str = mi.variant()
_GLOSSY = mi.BSDFFlags.GlossyReflection
#: Lookup classes of the level of detail: eval at the first path vertex, sample() there (its
#: weight carries the continued path), any lookup at a later vertex.
LOD_CLASSES = ("first", "first_sampled", "later")


def _flip(v: Any, back: Any, flip: Any) -> Any:
    """Mitsuba's local frame ↔ the BTF's (its own inverse): z mirrored on two-sided back-face
    hits, y negated where the uv parametrisation is left-handed."""
    v = dr.select(back, mi.Vector3f(v.x, v.y, -v.z), v)
    return dr.select(flip, mi.Vector3f(v.x, -v.y, v.z), v)


class _Base(mi.BSDF):
    """What both plugins share: flags, the BTF frame, neighbours, cosine and BTF sampling.

    Subclasses set ``self.prm`` (:func:`.materials.common_params`), ``self.np_dirs``
    ({"lights", "views"}: (N, 3) float32), ``self.np_tables`` (:class:`.sampling.SamplingTables`
    or None) and, on Dr.Jit variants, ``self.cand`` ({"lights", "views"}: :class:`Candidates`)
    and ``self.tables`` (:class:`SamplingArrays` or None); they implement
    ``_jit_lookup(uv, light_nb, view_nb, active, level, dirs)`` (``dirs``: the (light, view)
    directions in the BTF frame, or None), ``_jit_row(uv)`` (the sampling table row)
    and ``_scalar_lookup(uv, light, view)`` (NumPy float64 arrays in, RGB out).

    Roles: in radiance transport ``si.wi`` is the view (known) and ``wo`` the light (sampled);
    in importance transport the reverse (:data:`.sampling.MODES`).
    """

    # A class attribute, not a module global: a reload for another variant rebinds the
    # module's globals, and classes already registered for this variant must keep theirs.
    _scalar: bool = not dr.is_jit_v(mi.Float)
    _variant: str = mi.variant()
    prm: dict[str, Any]

    def _setup(self, source: tuple, level: tuple, tables: Any) -> None:
        """Flags, and the Dr.Jit candidate lists and sampling tables (cached per variant;
        ``level`` tells apart loads of one source, as in the material's own cache key)."""
        flags = _GLOSSY | mi.BSDFFlags.FrontSide | mi.BSDFFlags.SpatiallyVarying
        if self.prm["two_sided"]:
            flags = flags | mi.BSDFFlags.BackSide
        self.m_flags = flags
        self.m_components = [flags]
        self.np_tables = tables
        if self._scalar:
            return
        k = self.prm["k"]
        self.cand = {}
        for name, xyz in self.np_dirs.items():
            digest = hashlib.sha1(np.ascontiguousarray(xyz).tobytes()).hexdigest()
            self.cand[name] = cached(("cand", mi.variant(), digest, k),
                                     lambda xyz=xyz: Candidates(mi, xyz, k))  # fmt: skip
        self.tables = None
        if tables is not None:
            p = self.prm
            ck = ("jittables", mi.variant(), source, *level, p["sampling_tables"],
                  p["sampling_grid"], p["sampling_mix"], p["interpolation"], p["k"], p["beta"])
            self.tables = cached(ck, lambda: SamplingArrays(mi, tables))

    # -- frames and roles -----------------------------------------------------------------------
    def _frame(self, si: Any, active: Any):
        """(uv, known direction in the BTF frame, back, flip, active)."""
        wi = mi.Vector3f(si.wi)
        back = (wi.z < 0) if self.prm["two_sided"] else mi.Bool(False)
        flip = dr.dot(si.sh_frame.t, si.dp_dv) < 0
        known = _flip(wi, back, flip)
        uv = mi.Point2f(si.uv) * self.prm["uv_scale"]
        return uv, known, back, flip, active & (known.z > 0)

    @staticmethod
    def _mode(ctx: Any) -> str:
        return "importance" if ctx.mode == mi.TransportMode.Importance else "radiance"

    @staticmethod
    def _sets(mode: str) -> tuple[str, str]:
        """(known set, sampled set)."""
        return ("lights", "views") if mode == "importance" else ("views", "lights")

    def _value(self, mode: str, uv: Any, known_nb: Any, w_nb: Any, active: Any,
               level: Any = None, dirs: tuple[Any, Any] | None = None) -> Any:
        """``dirs``: (known, w) in the BTF frame, the directions of ``known_nb``, ``w_nb``."""
        light_nb, view_nb = (known_nb, w_nb) if mode == "importance" else (w_nb, known_nb)
        if dirs is not None:  # (light, view), as the runtime's (wi, wo)
            dirs = dirs if mode == "importance" else (dirs[1], dirs[0])
        rgb = self._jit_lookup(uv, light_nb, view_nb, active, level, dirs)
        return dr.select(active, dr.maximum(rgb, 0.0) * BSDF_PER_BTF_VALUE, 0.0)

    def _density(self, mode: str, uv: Any, known_nb: Any, w: Any, active: Any) -> Any:
        if self.tables is None:
            return dr.select(active & (w.z > 0), w.z * dr.inv_pi, 0.0)
        return btf_pdf(mi, dr, self.tables, mode, self._jit_row(uv), known_nb, w, active)

    # -- the BSDF interface ---------------------------------------------------------------------
    def eval(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        """BTF(uv, ω_light = ``wo``, ω_view = ``si.wi``) / π, no extra cosine (roles swapped in
        importance transport); 0 below the horizon unless ``two_sided``."""
        return self.eval_pdf(ctx, si, wo, active, want_pdf=False)[0]

    def pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        """Density of :meth:`sample` per solid angle at ``wo`` (cosine or BTF-driven)."""
        if not ctx.is_enabled(_GLOSSY):
            return mi.Float(0.0)
        if self._scalar:
            return self._scalar_eval_pdf(ctx, si, wo, active, want_value=False)[1]
        mode = self._mode(ctx)
        uv, known, back, flip, active = self._frame(si, active)
        w = _flip(mi.Vector3f(wo), back, flip)
        known_nb = None
        if self.tables is not None:
            (known_nb,) = find_neighbours(mi, dr, self.prm,
                                          [(self.cand[self._sets(mode)[0]], known)], active)
        return self._density(mode, uv, known_nb, w, active)

    def eval_pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True, want_pdf: bool = True):
        if not ctx.is_enabled(_GLOSSY):
            return mi.Color3f(0.0), mi.Float(0.0)
        if self._scalar:
            return self._scalar_eval_pdf(ctx, si, wo, active)
        mode = self._mode(ctx)
        known_set, sampled_set = self._sets(mode)
        uv, known, back, flip, active = self._frame(si, active)
        w = _flip(mi.Vector3f(wo), back, flip)
        level = self._level(si, known, active, sampled=False)
        if self._host(level, uv, known, w):
            known_nb = None
            if want_pdf and self.tables is not None:
                (known_nb,) = find_neighbours(mi, dr, self.prm, [(self.cand[known_set], known)],
                                              active)  # fmt: skip
            value = self._host_value(mode, uv, known, w, active & (w.z > 0), level)
        else:
            known_nb, w_nb = find_neighbours(mi, dr, self.prm,
                                             [(self.cand[known_set], known),
                                              (self.cand[sampled_set], w)], active)  # fmt: skip
            value = self._value(mode, uv, known_nb, w_nb, active & (w.z > 0), level,
                                 (known, w))
        pdf = self._density(mode, uv, known_nb, w, active) if want_pdf else mi.Float(0.0)
        return value, pdf

    def sample(self, ctx: Any, si: Any, sample1: Any, sample2: Any, active: Any = True):
        """A direction from the BTF-driven density (``sampling = "btf"``) or the cosine-weighted
        hemisphere, on the side of ``si.wi``; weight = eval/pdf."""
        bs = dr.zeros(mi.BSDFSample3f)
        if not ctx.is_enabled(_GLOSSY):
            return bs, mi.Color3f(0.0)
        if self._scalar:
            return self._scalar_sample(ctx, si, sample1, sample2, active)
        mode = self._mode(ctx)
        known_set, sampled_set = self._sets(mode)
        uv, known, back, flip, active = self._frame(si, active)
        level = self._level(si, known, active, sampled=True)
        host = self._host(level, uv, known)  # the value from the runtime: no neighbours of w needed
        known_nb = w_nb = None
        if self.tables is None:
            w = mi.warp.square_to_cosine_hemisphere(sample2)
            if not host:
                known_nb, w_nb = find_neighbours(mi, dr, self.prm,
                                                 [(self.cand[known_set], known),
                                                  (self.cand[sampled_set], w)], active)  # fmt: skip
        else:
            (known_nb,) = find_neighbours(mi, dr, self.prm, [(self.cand[known_set], known)],
                                          active)  # fmt: skip
            w = btf_sample(mi, dr, self.tables, mode, self._jit_row(uv), known_nb, sample1,
                           sample2, active)  # fmt: skip
            if not host:
                (w_nb,) = find_neighbours(mi, dr, self.prm, [(self.cand[sampled_set], w)],
                                          active)  # fmt: skip
        active = active & (w.z > 0)
        bs.wo = _flip(w, back, flip)
        bs.pdf = self._density(mode, uv, known_nb, w, active)
        bs.eta = 1.0
        bs.sampled_type = mi.UInt32(+_GLOSSY)
        bs.sampled_component = mi.UInt32(0)
        if host:
            value = self._host_value(mode, uv, known, w, active, level)
        else:
            value = self._value(mode, uv, known_nb, w_nb, active, level, (known, w))
        ok = active & (bs.pdf > 0)
        return bs, dr.select(ok, value / dr.select(ok, bs.pdf, 1.0), 0.0)

    # -- scalar_rgb: one ray at a time in NumPy -------------------------------------------------
    def _scalar_frame(self, si: Any) -> tuple[np.ndarray, np.ndarray, bool, bool]:
        wi = np.array([si.wi.x, si.wi.y, si.wi.z], dtype=np.float64)
        back = bool(self.prm["two_sided"] and wi[2] < 0)
        flip = bool(dr.dot(si.sh_frame.t, si.dp_dv) < 0)
        uv = np.array([si.uv.x, si.uv.y], dtype=np.float64) * self.prm["uv_scale"]
        return uv, self._scalar_flip(wi, back, flip), back, flip

    @staticmethod
    def _scalar_flip(v: np.ndarray, back: bool, flip: bool) -> np.ndarray:
        return v * np.array([1.0, -1.0 if flip else 1.0, -1.0 if back else 1.0])

    def _scalar_known_nb(self, mode: str, known: np.ndarray):
        from ...runtime import angular_weights

        kk = self.prm["k"] if self.prm["interpolation"] == "gaussian" else None
        return angular_weights(self.np_dirs[self._sets(mode)[0]], known[None, :],
                               self.prm["interpolation"], kk, self.prm["beta"])  # fmt: skip

    def _scalar_density(self, mode: str, uv: np.ndarray, known: np.ndarray,
                        w: np.ndarray) -> float:
        if w[2] <= 0 or known[2] <= 0:
            return 0.0
        if self.np_tables is None:
            return float(np.float32(w[2] / np.pi))
        idx, wt = self._scalar_known_nb(mode, known)
        rows = np.array([self._scalar_row(uv)])
        p = np_sampling.pdf(self.np_tables, mode, rows, idx, wt, w[None, :])[0]
        return float(np.float32(p))  # as stored in BSDFSample3f (float32 in scalar_rgb)

    def _scalar_value(self, mode: str, uv: np.ndarray, known: np.ndarray,
                      w: np.ndarray) -> Any:
        if w[2] <= 0 or known[2] <= 0:
            return mi.Color3f(0.0)
        light, view = (known, w) if mode == "importance" else (w, known)
        rgb = self._scalar_lookup(uv, light, view)
        return mi.Color3f(*(max(float(v), 0.0) * BSDF_PER_BTF_VALUE for v in rgb))

    def _scalar_eval_pdf(self, ctx: Any, si: Any, wo: Any, active: Any,
                         want_value: bool = True):
        if not active:
            return mi.Color3f(0.0), 0.0
        mode = self._mode(ctx)
        uv, known, back, flip = self._scalar_frame(si)
        w = self._scalar_flip(np.array([wo.x, wo.y, wo.z], dtype=np.float64), back, flip)
        value = self._scalar_value(mode, uv, known, w) if want_value else mi.Color3f(0.0)
        return value, self._scalar_density(mode, uv, known, w)

    def _scalar_sample(self, ctx: Any, si: Any, sample1: Any, sample2: Any, active: Any):
        bs = dr.zeros(mi.BSDFSample3f)
        mode = self._mode(ctx)
        uv, known, back, flip = self._scalar_frame(si)
        if not active or known[2] <= 0:
            return bs, mi.Color3f(0.0)
        u2 = np.array([[sample2.x, sample2.y]], dtype=np.float64)
        if self.np_tables is None:
            w = np_sampling.square_to_cosine_hemisphere(u2)[0]
        else:
            idx, wt = self._scalar_known_nb(mode, known)
            rows = np.array([self._scalar_row(uv)])
            w = np_sampling.sample(self.np_tables, mode, rows, idx, wt,
                                   np.array([float(sample1)]), u2)[0]  # fmt: skip
        w = w.astype(np.float32).astype(np.float64)  # bs.wo holds float32: pdf(bs.wo) = bs.pdf
        bs.wo = mi.Vector3f(*self._scalar_flip(w, back, flip))
        bs.pdf = self._scalar_density(mode, uv, known, w)
        bs.eta = 1.0
        bs.sampled_type = +_GLOSSY
        bs.sampled_component = 0
        value = self._scalar_value(mode, uv, known, w)
        return bs, (value / bs.pdf if bs.pdf > 0 else mi.Color3f(0.0))

    def _scalar_row(self, uv: np.ndarray) -> int:
        return 0

    # -- subclass hooks -------------------------------------------------------------------------
    def _level(self, si: Any, known: Any, active: Any, sampled: bool) -> Any:
        """What ``_jit_lookup`` needs to choose τ per query (None: no level of detail);
        ``sampled``: the lookup of :meth:`sample` (else of :meth:`eval_pdf`)."""
        return None

    def _jit_lookup(self, uv: Any, light_nb: Any, view_nb: Any, active: Any,
                    level: Any = None, dirs: tuple[Any, Any] | None = None) -> Any:
        raise NotImplementedError

    def _jit_row(self, uv: Any) -> Any:
        return mi.UInt32(0)

    def _host(self, level: Any, *arrays: Any) -> bool:
        """Whether this lookup goes to the host runtime (:meth:`_host_value`), not Dr.Jit."""
        return False

    def _host_value(self, mode: str, uv: Any, known: Any, w: Any, active: Any,
                    level: Any) -> Any:
        raise NotImplementedError

    def _scalar_lookup(self, uv: np.ndarray, light: np.ndarray, view: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def traverse(self, cb: Any) -> None:
        pass  # nothing differentiable is exposed

    def parameters_changed(self, keys: Any = None) -> None:
        pass


class SparseBTFBSDF(_Base):
    """``sparsebtf``: a coded material evaluated with Eq. 5/6 at each shading point.

    Parameters (table in :mod:`sparsebtf.rendering.mitsuba`): ``filename`` (+ ``model``) or
    ``key``, ``tau``, ``uv_scale``, ``interpolation``, ``domain``, ``k``, ``beta``,
    ``two_sided``, ``sampling``, ``sampling_tables``, ``sampling_grid``, ``sampling_mix``. The
    material and its sampling tables are loaded once per process (:mod:`.materials`), their
    Dr.Jit arrays once per variant. A material coded with adaptive patch sizes is read through
    its :class:`~sparsebtf.runtime.AdaptiveRuntimeBTF` (its nodes are the data points).
    """

    def __init__(self, props: Any) -> None:
        super().__init__(props)
        self.prm = coded_params(props)
        source = source_id(props, PLUGIN)
        tau = props.get("tau") if "tau" in props else None
        self.rt = load_runtime(source, tau)
        self.meta = dict(self.rt.meta)
        self.np_dirs = {"lights": self.rt.coded.lights.xyz.astype(np.float32),
                        "views": self.rt.coded.views.xyz.astype(np.float32)}  # fmt: skip
        #: the renderer arrays' meta: for an adaptive material, its nodes are the data points
        self.flat = flat_meta(self.rt)
        tables = coded_sampling(self.prm, source, tau, self.rt)
        us = self.prm["uv_scale"]
        self.texel_area = 1.0 / (self.meta["height"] * self.meta["width"] * us * us)
        if self._scalar:
            self.prm["lod"] = "off"  # one ray at a time in NumPy: at the loaded τ
        else:
            self.data = cached(("jit", mi.variant(), source, str(tau)),
                               lambda: CodedArrays(mi, self.rt))  # fmt: skip
            #: lookups and loop iterations (Y, U, V) per lookup class (:data:`LOD_CLASSES`)
            self.lod_counts = dr.zeros(mi.UInt32, 4 * len(LOD_CLASSES))
        self._setup(source, (str(tau),), tables)

    def _jit_lookup(self, uv: Any, light_nb: Any, view_nb: Any, active: Any,
                    level: Any = None, dirs: tuple[Any, Any] | None = None) -> Any:
        if level is None:
            return coded_lookup(mi, dr, self.data, self.prm, uv, light_nb, view_nb, active,
                                dirs=dirs)  # fmt: skip
        fraction, cls = level
        stats = (self.lod_counts, cls) if self.prm["lod_stats"] else None
        return coded_lookup(mi, dr, self.data, self.prm, uv, light_nb, view_nb, active,
                            fraction, stats, dirs)  # fmt: skip

    def _level(self, si: Any, known: Any, active: Any, sampled: bool) -> Any:
        """(τ fraction, class index in :data:`LOD_CLASSES`) per query
        (:mod:`sparsebtf.runtime.lod`), or None with ``lod = "off"``.

        The first path vertex is the one whose ray starts at ``lod_camera`` (Mitsuba gives a
        Python BSDF neither the path depth nor ray differentials: ``si.duv_dx`` is 0). Its
        footprint is a ray cone (:func:`sparsebtf.runtime.lod.cone_texels_per_pixel`, the
        reference of this Dr.Jit twin).
        """
        if self.prm["lod"] == "off":
            return None
        cam = mi.Point3f(*self.prm["lod_camera"])
        origin = si.p + si.t * si.to_world(si.wi)
        # Mitsuba's perspective camera starts its rays on the near clip plane (near_clip
        # 0.01 by default, ``lod_near``): within a few near_clip of the camera's origin.
        reach = 2.0 * self.prm["lod_near"] + 1e-3 * (1.0 + si.t)
        first = dr.squared_norm(origin - cam) <= dr.square(reach)
        texel = dr.safe_sqrt(dr.norm(si.dp_du) * dr.norm(si.dp_dv) * self.texel_area)
        cos = dr.maximum(dr.abs(known.z), COS_FLOOR)
        rho = si.t * self.prm["lod_pixel"] * dr.rsqrt(cos) / dr.maximum(texel, 1e-12)
        rho = dr.maximum(rho, 1.0)
        near = dr.clip(dr.rcp(rho * rho), self.prm["lod_min"], 1.0)
        if sampled:  # sample()'s weight carries what the continued path finds
            near = dr.minimum(near, self.prm["lod_sampled"])
        cls = mi.UInt32(1 if sampled else 0)
        return (dr.select(first, near, self.prm["lod_later"]),
                dr.select(first, cls, mi.UInt32(2)))

    def _jit_row(self, uv: Any) -> Any:
        if self.prm["sampling_tables"] != "patch":
            return mi.UInt32(0)
        return point_of(mi, dr, self.data, uv)[0]

    def _host(self, level: Any, *arrays: Any) -> bool:
        """``backend`` numba, or auto on an LLVM variant, in an evaluated call (Dr.Jit's
        evaluated mode, :func:`~sparsebtf.rendering.mitsuba.evaluated`); Dr.Jit otherwise, and
        for what the host path does not cover: the level of detail of an adaptive material and
        ``lod_stats`` (which count the Dr.Jit kernel's loop iterations). ``auto`` also keeps
        Dr.Jit where gradients are tracked (the host path is not differentiable)."""
        backend = self.prm["backend"]
        if not host_lookups(backend, self._variant):
            return False
        if dr.flag(dr.JitFlag.SymbolicScope):
            if backend == "numba":
                raise BTFInputError(
                    f"{PLUGIN}: backend 'numba' needs Dr.Jit's evaluated mode (render inside "
                    "sparsebtf.mitsuba.evaluated(), or use backend 'auto' or 'drjit')"
                )  # fmt: skip
            return False
        if level is not None and (self.flat.get("adaptive") or self.prm["lod_stats"]):
            return False
        return backend == "numba" or not dr.grad_enabled(*arrays)

    def _host_value(self, mode: str, uv: Any, known: Any, w: Any, active: Any,
                    level: Any) -> Any:
        """:meth:`RuntimeBTF.evaluate <sparsebtf.runtime.RuntimeBTF.evaluate>` on the active
        lanes of an evaluated wavefront (NumPy views of Dr.Jit's arrays), the rest 0; the same
        values as :func:`.kernels.coded_lookup` within float32 rounding."""
        light, view = (known, w) if mode == "importance" else (w, known)
        n = max(dr.width(uv), dr.width(light), dr.width(view), dr.width(active))
        lanes = np.flatnonzero(np.broadcast_to(np.asarray(active, dtype=bool), (n,)))
        out = np.zeros((3, n), dtype=np.float32)
        if lanes.size:
            def rows(v: Any, k: int) -> np.ndarray:  # (k, n) Dr.Jit → (lanes, k) float64
                a = np.asarray(v, dtype=np.float64).reshape(k, -1)
                return np.broadcast_to(a, (k, n))[:, lanes].T

            p = self.prm
            tau = None
            if level is not None:
                tau = lod_tau(self.meta["tau"], rows(level[0], 1)[:, 0])
            rgb = self.rt.evaluate(
                rows(light, 3), rows(view, 3), uv=rows(uv, 2), interpolation=p["interpolation"],
                domain=p["domain"], k=p["k"] if p["interpolation"] == "gaussian" else None,
                beta=p["beta"], tau=tau, backend="numba",
            )  # fmt: skip
            out[:, lanes] = np.maximum(rgb, 0.0).T * BSDF_PER_BTF_VALUE
        return mi.Color3f(out)

    def _scalar_row(self, uv: np.ndarray) -> int:
        if self.prm["sampling_tables"] != "patch":
            return 0
        from ...runtime import texels_from_uv

        row, col = texels_from_uv(uv[None, :], self.meta["height"], self.meta["width"])
        if self.flat.get("adaptive"):  # per node: the node of the texel's cell
            s = self.flat["smallest"]
            if getattr(self, "_cells", None) is None:  # built on the first scalar lookup
                self._cells = self.rt.arrays(neighbours=False)["cells"]
            return int(self._cells[row[0] // s + (self.meta["height"] // s) * (col[0] // s)])
        p = self.meta["patch"]
        return int(row[0] // p + self.meta["n_rb"] * (col[0] // p))

    def _scalar_lookup(self, uv: np.ndarray, light: np.ndarray, view: np.ndarray) -> np.ndarray:
        return scalar_coded(self.rt, self.prm, uv, light, view)

    def to_string(self) -> str:
        m = self.meta
        tau = m["tau"]
        if self.flat.get("adaptive"):  # the loaded τ of each patch size
            tau = ", ".join(f"{p}x{p}: {rt.meta['tau']}" for p, rt in self.rt.layers.items())
            tau = f"adaptive {{{tau}}}"
        return (
            f"SparseBTF[{m['name']}, {m['height']}x{m['width']}, tau={tau}, "
            f"{self.prm['interpolation']}/{self.prm['domain']}, "
            f"uv_scale={self.prm['uv_scale']}, sampling={self._sampling_text()}, "
            f"lod={self._lod_text()}]"
        )

    def _lod_text(self) -> str:
        if self.prm["lod"] == "off" and self.prm["lod_asked"] == "auto":
            return "off (auto needs lod_camera)" if not self._scalar else "off (scalar)"
        return self.prm["lod"]

    def lod_stats(self) -> dict[str, Any]:
        """With ``lod_stats``: per lookup class (:data:`LOD_CLASSES`) the lookups and
        the mean loop iterations per lookup for Y, U, V (the τ' the plugin used, counted)."""
        c = np.array(self.lod_counts, dtype=np.float64).reshape(len(LOD_CLASSES), 4)
        return {name: {"lookups": int(row[0]),
                       "tau": (row[1:] / max(row[0], 1)).tolist()}
                for name, row in zip(LOD_CLASSES, c, strict=True)}  # fmt: skip

    def _sampling_text(self) -> str:
        if self.prm["sampling"] != "btf":
            return "cosine"
        return f"btf/{self.prm['sampling_tables']}/{self.prm['sampling_grid']}"


class SparseBTFDenseBSDF(_Base):
    """``sparsebtf_dense``: a dense (uncompressed) BTF table, the reference.

    Parameters (table in :mod:`sparsebtf.rendering.mitsuba`): ``filename`` (any BTF) or
    ``key``, ``uv_scale``, ``interpolation``, ``k``, ``beta``, ``two_sided``, ``sampling``
    (material tables only), ``sampling_grid``, ``sampling_mix``, ``sampling_key`` (the tables
    of that coded material) and ``max_gib`` (default 2): larger tables are refused.
    """

    def __init__(self, props: Any) -> None:
        super().__init__(props)
        self.prm = common_params(props, DENSE_PLUGIN)
        source = source_id(props, DENSE_PLUGIN)
        max_gib = float(props.get("max_gib", DENSE_MAX_GIB))
        self.np_data = load_dense(source, max_gib)
        self.np_dirs = {"lights": self.np_data[1], "views": self.np_data[2]}
        skey = str(props.get("sampling_key")) if "sampling_key" in props else None
        tables = dense_sampling(self.prm, source, max_gib, self.np_data, skey)
        if not self._scalar:
            self.data = cached(("jitdense", mi.variant(), source, max_gib),
                               lambda: DenseArrays(mi, self.np_data[0]))  # fmt: skip
        self._setup(source, (max_gib, ("key", skey)), tables)

    def _jit_lookup(self, uv: Any, light_nb: Any, view_nb: Any, active: Any,
                    level: Any = None, dirs: tuple[Any, Any] | None = None) -> Any:
        return dense_lookup(mi, dr, self.data, uv, light_nb, view_nb, active)

    def _scalar_lookup(self, uv: np.ndarray, light: np.ndarray, view: np.ndarray) -> np.ndarray:
        return scalar_dense(self.np_data, self.prm, uv, light, view)

    def to_string(self) -> str:
        h, w, nl, nv = self.np_data[0].shape[:4]
        return (f"SparseBTFDense[{h}x{w}, {nl}x{nv} directions, {self.prm['interpolation']}, "
                f"sampling={self.prm['sampling']}]")  # fmt: skip
