"""The Mitsuba BSDF classes of ``sparsebtf`` and ``sparsebtf_dense``, bound to one variant.

A Python class deriving from ``mi.BSDF`` binds to the Mitsuba variant active when its
``class`` statement runs, so this module imports ``mitsuba`` at the top and must only be
imported once a variant is set: :func:`sparsebtf.rendering.mitsuba.register` imports it (and
reloads it when the active variant differs from :data:`VARIANT`, the one it was built for),
then registers its classes. Do not import it directly.

Parameters and conventions (which direction is the light, the local frame, sampling): the
table in :mod:`sparsebtf.rendering.mitsuba`. The lookups themselves live in :mod:`.kernels`,
material loading and parameter checks in :mod:`.materials`.
"""

from __future__ import annotations

from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from .kernels import (
    CodedArrays,
    DenseArrays,
    coded_lookup,
    dense_lookup,
    scalar_coded,
    scalar_dense,
)
from .materials import (
    DENSE_MAX_GIB,
    DENSE_PLUGIN,
    PLUGIN,
    cached,
    coded_params,
    common_params,
    load_dense,
    load_runtime,
    source_id,
)

__all__ = ["VARIANT", "SparseBTFBSDF", "SparseBTFDenseBSDF"]

#: The Mitsuba variant these classes were built for.
VARIANT: str = mi.variant()


class _Base(mi.BSDF):
    """What both plugins share: flags, the BTF frame, cosine-weighted sampling, the pdf.

    Subclasses set ``self.prm`` (:func:`.materials.common_params`) and implement
    ``_jit_lookup(uv, light, view, active)`` (Dr.Jit variants) and
    ``_scalar_lookup(uv, light, view)`` (``scalar_rgb``; NumPy float64 arrays in, RGB out).
    """

    # A class attribute, not a module global: a reload for another variant rebinds the
    # module's globals, and classes already registered for this variant must keep theirs.
    _scalar: bool = not dr.is_jit_v(mi.Float)
    prm: dict[str, Any]

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
        """(uv, light, view, active) in the BTF's frame; see the package docstring."""
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
        if self._scalar:
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

    def _jit_lookup(self, uv: Any, light: Any, view: Any, active: Any) -> Any:
        raise NotImplementedError

    def _scalar_lookup(self, uv: np.ndarray, light: np.ndarray, view: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def eval(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        """BTF(uv, ω_light = ``wo``, ω_view = ``si.wi``), no extra cosine (roles swapped in
        importance transport); 0 below the horizon unless ``two_sided``."""
        if not ctx.is_enabled(mi.BSDFFlags.GlossyReflection):
            return mi.Color3f(0.0)
        return self._value(ctx, si, wo, active)

    def pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
        """cos θ_o / π on the side of ``si.wi``."""
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
        pass  # nothing differentiable is exposed

    def parameters_changed(self, keys: Any = None) -> None:
        pass


class SparseBTFBSDF(_Base):
    """``sparsebtf``: a coded material evaluated with Eq. 5/6 at each shading point.

    Parameters (table in :mod:`sparsebtf.rendering.mitsuba`): ``filename`` (+ ``model``) or
    ``key``, ``tau``, ``uv_scale``, ``interpolation``, ``domain``, ``k``, ``beta``,
    ``two_sided``. The material is loaded once per process (:func:`.materials.load_runtime`),
    its Dr.Jit arrays once per variant.
    """

    def __init__(self, props: Any) -> None:
        super().__init__(props)
        self.prm = coded_params(props)
        source = source_id(props, PLUGIN)
        tau = props.get("tau") if "tau" in props else None
        self.rt = load_runtime(source, tau)
        self.meta = dict(self.rt.meta)
        self._setup_flags(self.prm["two_sided"])
        if not self._scalar:
            self.data = cached(("jit", mi.variant(), source, str(tau)),
                               lambda: CodedArrays(mi, self.rt))  # fmt: skip

    def _jit_lookup(self, uv: Any, light: Any, view: Any, active: Any) -> Any:
        return coded_lookup(mi, dr, self.data, self.prm, uv, light, view, active)

    def _scalar_lookup(self, uv: np.ndarray, light: np.ndarray, view: np.ndarray) -> np.ndarray:
        return scalar_coded(self.rt, self.prm, uv, light, view)

    def to_string(self) -> str:
        m = self.meta
        return (
            f"SparseBTF[{m['name']}, {m['height']}x{m['width']}, tau={m['tau']}, "
            f"{self.prm['interpolation']}/{self.prm['domain']}, "
            f"uv_scale={self.prm['uv_scale']}]"
        )


class SparseBTFDenseBSDF(_Base):
    """``sparsebtf_dense``: a dense (uncompressed) BTF table, the reference.

    Parameters (table in :mod:`sparsebtf.rendering.mitsuba`): ``filename`` (any BTF) or
    ``key``, ``uv_scale``, ``interpolation``, ``k``, ``beta``, ``two_sided``, and ``max_gib``
    (default 2): larger tables are refused.
    """

    def __init__(self, props: Any) -> None:
        super().__init__(props)
        self.prm = common_params(props, DENSE_PLUGIN)
        source = source_id(props, DENSE_PLUGIN)
        max_gib = float(props.get("max_gib", DENSE_MAX_GIB))
        self.np_data = load_dense(source, max_gib)
        self._setup_flags(self.prm["two_sided"])
        if not self._scalar:
            self.data = cached(("jitdense", mi.variant(), source, max_gib),
                               lambda: DenseArrays(mi, *self.np_data))  # fmt: skip

    def _jit_lookup(self, uv: Any, light: Any, view: Any, active: Any) -> Any:
        return dense_lookup(mi, dr, self.data, self.prm, uv, light, view, active)

    def _scalar_lookup(self, uv: np.ndarray, light: np.ndarray, view: np.ndarray) -> np.ndarray:
        return scalar_dense(self.np_data, self.prm, uv, light, view)

    def to_string(self) -> str:
        h, w, nl, nv = self.np_data[0].shape[:4]
        return f"SparseBTFDense[{h}x{w}, {nl}x{nv} directions, {self.prm['interpolation']}]"
