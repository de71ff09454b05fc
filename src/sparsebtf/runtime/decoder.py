"""The runtime decoder: BTF values at (texel or uv, ω_i, ω_o) from the sparse codes (paper §3.4).

:class:`RuntimeBTF` answers a batch of queries locally from each query's data point: Eq. 5 at
measured directions, Eq. 6 (coefficient-space angular interpolation) at any other, then the
inverse preprocessing (de-standardisation, YUV → RGB, exp). It never reconstructs a data point.

Level of detail: coefficients are stored by decreasing magnitude, so keeping τ' ≤ τ of them is
a prefix; :meth:`RuntimeBTF.with_tau` truncates at load time (smaller arrays) and the ``tau``
argument of :meth:`RuntimeBTF.evaluate` caps the sum at run time (the paper's real-time knob),
for the whole batch or per query (a renderer's level of detail: fractional τ fades the last
coefficient in, :func:`~sparsebtf.runtime.kernels.prefix_weights`).

The compiled lookup (numba) groups a batch's queries by data point
(:mod:`~sparsebtf.runtime.wavefront`); the first call builds each channel's compact columns
(:mod:`~sparsebtf.runtime.compact`: about 1 s and 18 bytes per coefficient for a 400 × 400
material at τ 885) and keeps them.

A material with a highlight store (``coded.highlights``, :mod:`sparsebtf.learning.highlights`)
gets its corrections added to the linear-RGB values, with the interpolation's own angular
weights, and those values clamped at 0 (:mod:`.highlight_lookup`); without one nothing changes.

The flat arrays a GPU or Dr.Jit shader needs come from :meth:`RuntimeBTF.arrays` (layout in
``docs/format.md``, "Renderer arrays").
"""

from __future__ import annotations

import os
from dataclasses import replace
from typing import Any, Literal

import numpy as np

from ..colour import YUV_TO_RGB, YUV_TO_RGB_RELEASE, yuv_to_rgb
from ..errors import BTFInputError
from ..model import CHANNELS, CodedBTF, TauSpec
from ..patch_tree import refuse_adaptive
from ..points.grid import PatchGrid
from ..points.preprocessing import inverse_log_transform
from . import grouping, kernels, wavefront
from .angular import (
    SCHEMES,
    DirectionIndex,
    Scheme,
    angular_weights,
    neighbour_count,
    neighbour_table,
)
from .compact import CompactLayout, channel_layout
from .finish import finish
from .highlight_lookup import HighlightTable, add_highlights

__all__ = ["NO_BOUND", "Domain", "RuntimeBTF", "query_texels", "texels_from_uv"]

#: The bound of a material without one (older files): far above any ln(RGB + offset).
NO_BOUND = 1e30

Domain = Literal["standardized", "log"]


def texels_from_uv(uv: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """(row, col) of texture coordinates; they wrap, so a texture tiles (uv ≥ 1 and < 0).

    col = ⌊frac(u)·W⌋, row = ⌊frac(v)·H⌋: u runs along columns, v along rows.
    """
    uv = np.asarray(uv, dtype=np.float64)
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise BTFInputError(f"uv must have shape (n, 2), got {uv.shape}")
    if not np.all(np.isfinite(uv)):
        i = int(np.flatnonzero(~np.isfinite(uv).all(axis=1))[0])
        raise BTFInputError(f"uv {i} is not finite")
    f = uv - np.floor(uv)
    col = np.minimum((f[:, 0] * width).astype(np.int64), width - 1)
    row = np.minimum((f[:, 1] * height).astype(np.int64), height - 1)
    return row, col


def query_texels(uv: np.ndarray | None, texel: np.ndarray | None, height: int, width: int
                 ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(row, col) int64 of a batch of queries given by exactly one of ``uv`` (wrapping,
    :func:`texels_from_uv`) and ``texel`` ((n, 2) integers inside the texture)."""
    if (uv is None) == (texel is None):
        raise BTFInputError("give exactly one of uv and texel")
    if uv is not None:
        return texels_from_uv(uv, height, width)
    t = np.asarray(texel)
    if t.ndim != 2 or t.shape[1] != 2 or t.dtype.kind not in "iu":
        raise BTFInputError(f"texel must be (n, 2) integers (row, col), got {t.shape}")
    row, col = t[:, 0].astype(np.int64), t[:, 1].astype(np.int64)
    bad = (row < 0) | (row >= height) | (col < 0) | (col >= width)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise BTFInputError(
            f"texel {i} = ({row[i]}, {col[i]}) is outside the {height}x{width} texture"
        )
    return row, col


class RuntimeBTF:
    """Local evaluation of a coded BTF for renderers (Eq. 5, Eq. 6).

    Parameters
    ----------
    coded : a :class:`~sparsebtf.model.CodedBTF` with its model attached, channels Y, U, V.
    tau : level of detail τ' per channel: None (all stored coefficients), an int, "885,64,64",
        a sequence, a {channel: τ'} dict, or a fraction in (0, 1) of the coded τ. Each data
        point keeps its τ' largest coefficients (a prefix of the stored order).
    dtype : float32 (renderer precision, default) or float64 for the dictionaries and values.

    Attributes
    ----------
    coded : the (truncated) codes; ``tau`` : the τ' per channel; ``meta`` : sizes and flags.
    """

    def __init__(
        self, coded: CodedBTF, tau: TauSpec = None, dtype: type = np.float32
    ) -> None:
        refuse_adaptive(coded, "RuntimeBTF")
        model = coded.require_model()
        if tuple(coded.channels) != CHANNELS:
            raise BTFInputError(
                f"{coded.label}: the runtime needs channels Y, U and V as separate 4D codes, "
                f"this file has {coded.channels}"
            )
        if coded.stats.transform != "log_yuv":
            raise BTFInputError(
                f"{coded.label}: coded without the log-YUV preprocessing "
                f"({coded.stats.transform!r}); the runtime decodes log-YUV codes only"
            )
        sizes = model.mode_sizes
        if len(sizes) != 4 or max(sizes) > 256:
            raise BTFInputError(
                f"{coded.label}: the runtime needs 4D data points with every mode <= 256 "
                f"(packed locations), got {sizes}"
            )
        self.tau = coded.resolve_tau(tau)
        codes = {
            ch: c.truncate(self.tau[ch]) if np.max(c.counts, initial=0) > self.tau[ch] else c
            for ch, c in coded.codes.items()
        }
        self.coded = replace(
            coded, codes=codes, params=dict(coded.params), attrs=dict(coded.attrs)
        )
        self.dtype = np.dtype(dtype)
        self._channels = {ch: self._channel_arrays(ch) for ch in CHANNELS}
        st = coded.stats
        self._mean = np.ascontiguousarray(np.moveaxis(st.mean, 2, 0), dtype=np.float64)
        self._std = np.ascontiguousarray(np.moveaxis(st.std, 2, 0), dtype=np.float64)
        self.log_offset = float(st.log_offset)
        self._bound = None if st.bound is None else np.asarray(st.bound, dtype=np.float64)
        self._indices: dict[tuple[str, int], DirectionIndex] = {}
        self._highlights = self._highlight_table(coded)
        self._layouts: dict[str, CompactLayout] = {}
        self.meta: dict[str, Any] = {
            "name": coded.name,
            "height": coded.height,
            "width": coded.width,
            "patch": coded.patch,
            "n_rb": coded.height // coded.patch,
            "n_points": coded.n_points,
            "channels": list(CHANNELS),
            "std_mode": st.mode,
            "eps": self.log_offset,  # the renderer arrays' name (docs/format.md §6)
            "bounded": self._bound is not None,
            "tau": dict(self.tau),
            "n_lights": len(coded.lights),
            "n_views": len(coded.views),
            "n_dictionaries": {ch: model.n_dictionaries(ch) for ch in CHANNELS},
            "mode_sizes": list(sizes),
            "nnz": {ch: int(codes[ch].nnz) for ch in CHANNELS},
        }

    @staticmethod
    def _highlight_table(coded: CodedBTF) -> HighlightTable | None:
        """The store in the decoder's types, checked against the material (None: none, or
        no entries)."""
        h = coded.highlights
        nl, nv = len(coded.lights), len(coded.views)
        if h is not None:
            h.check(coded.n_points, coded.patch, nl, nv, f"{coded.label}: highlights")
        return HighlightTable.of(h, coded.patch, nl, nv)

    @classmethod
    def from_file(
        cls,
        path: str | os.PathLike[str],
        model: str | os.PathLike[str] | None = None,
        tau: TauSpec = None,
        dtype: type = np.float32,
    ) -> RuntimeBTF:
        """Load a coded file for rendering, with ``model`` (a file or a bundled model's name)
        or else the model it names (a bundled model by hash, or its recorded model file)."""
        from ..storage import load_coded_with_model

        return cls(load_coded_with_model(path, model), tau, dtype)

    def with_tau(self, tau: TauSpec) -> RuntimeBTF:
        """A copy truncated to τ' ≤ the current τ per channel (level of detail at load time)."""
        new = self.coded.resolve_tau(tau)
        bigger = {ch: v for ch, v in new.items() if v > self.tau[ch]}
        if bigger:
            raise BTFInputError(f"cannot raise tau above the loaded level {self.tau}: {bigger}")
        return RuntimeBTF(self.coded, new, self.dtype.type)

    # -- arrays ---------------------------------------------------------------------------------
    def _channel_arrays(self, ch: str) -> dict[str, np.ndarray]:
        c = self.coded.codes[ch]
        model = self.coded.require_model()
        loc = c.locations.astype(np.uint32)
        packed = loc[:, 0] | (loc[:, 1] << 8) | (loc[:, 2] << 16) | (loc[:, 3] << 24)
        if c.nnz >= 2**31:
            raise BTFInputError(f"channel {ch}: {c.nnz} coefficients exceed int32 offsets")
        d = [np.ascontiguousarray(m, dtype=self.dtype) for m in model.dictionaries[ch]]
        return {
            "membership": c.membership.astype(np.int32),
            "offsets": c.offsets.astype(np.int32),
            "values": np.ascontiguousarray(c.values, dtype=self.dtype),
            "locations": packed.astype(np.uint32),
            "dict1": d[0],
            "dict2": d[1],
            "dict3": d[2],
            "dict4": d[3],
        }

    def arrays(self, neighbours: bool = True) -> dict[str, np.ndarray]:
        """The flat arrays of a shader implementation (float32 whatever ``dtype``).

        ``lights_xyz``, ``views_xyz`` (N, 3); ``mean``, ``std`` (S, L, V) with S = 1 (shared
        standardisation) or 3; ``yuv_to_rgb`` (3, 3); per channel c: ``membership_c`` (P,)
        int32, ``offsets_c`` (P+1,) int32, ``values_c`` (nnz,) float32 by decreasing |v| per
        point, ``locations_c`` (nnz,) uint32 = l1 | l2<<8 | l3<<16 | l4<<24, ``dict1_c`` …
        ``dict4_c`` (K, m, m) float32 with dict_n[k, x, l] = U_n^(k)[x, l]; with
        ``neighbours``, ``neighbours_lights``/``neighbours_views`` (64, 256, 8) int16 candidate
        tables (:func:`~sparsebtf.runtime.angular.neighbour_table`); with a highlight store
        (:mod:`sparsebtf.learning.highlights`), ``highlight_offsets`` (P+1,) uint32,
        ``highlight_keys`` (N,) uint32 and ``highlight_rgb`` (N, 3) float32, and where it has
        lobes ``highlight_lobes`` (P·p², 8) float32, row ``point·p² + i1·p + i2``.
        """
        out: dict[str, np.ndarray] = {
            "lights_xyz": self.coded.lights.xyz.astype(np.float32),
            "views_xyz": self.coded.views.xyz.astype(np.float32),
            "mean": self._mean.astype(np.float32),
            "std": self._std.astype(np.float32),
            "bound": self.bound_table().astype(np.float32),
            "yuv_to_rgb": YUV_TO_RGB.astype(np.float32),
        }
        for ch, arrs in self._channels.items():
            for name, a in arrs.items():
                out[f"{name}_{ch}"] = a.astype(np.float32) if a.dtype.kind == "f" else a
        h = self.coded.highlight_store
        if h is not None:
            out["highlight_offsets"] = h.offsets.astype(np.uint32)
            out["highlight_keys"] = h.keys.astype(np.uint32)
            out["highlight_rgb"] = h.rgb.astype(np.float32)
            if h.lobes is not None:
                out["highlight_lobes"] = h.lobes.reshape(-1, h.lobes.shape[-1]).astype(np.float32)
        if neighbours:
            out["neighbours_lights"] = neighbour_table(self.coded.lights)
            out["neighbours_views"] = neighbour_table(self.coded.views)
        return out

    def bound_table(self) -> np.ndarray:
        """(L, V) float64: the clamp on ln(RGB + offset) per angular image; without a bound
        :data:`NO_BOUND` (finite in every shader, and no sum of weights overflows it)."""
        if self._bound is None:
            return np.full(self._mean.shape[1:], NO_BOUND)
        return self._bound

    # -- evaluation -----------------------------------------------------------------------------
    def _texels(self, uv: np.ndarray | None, texel: np.ndarray | None, n: int):
        h, w, p = self.coded.height, self.coded.width, self.coded.patch
        if kernels.HAVE_NUMBA and (uv is None) != (texel is None):
            # query_texels and PatchGrid.locate in one compiled pass; a batch it does not
            # take (a wrong shape or dtype, a bad query) goes on to their one-line errors
            t = np.asarray(uv, dtype=np.float64) if uv is not None else np.asarray(texel)
            if (t.ndim == 2 and t.shape == (n, 2) and t.dtype.kind in "fiu"
                    and (uv is not None or t.dtype.kind in "iu")):  # fmt: skip
                pts, i1, i2, _, n_bad = grouping.locate_nb(
                    np.ascontiguousarray(t), h, w, p, uv is not None)  # fmt: skip
                if not n_bad:
                    return pts, i1, i2
        row, col = query_texels(uv, texel, h, w)
        if row.shape[0] != n:
            raise BTFInputError(f"{row.shape[0]} texels for {n} direction pairs")
        pts, i1, i2 = PatchGrid(h, w, p).locate(row, col)
        return pts.astype(np.int64), i1.astype(np.int64), i2.astype(np.int64)

    def _weights(self, which: str, q: np.ndarray, scheme: str, k: int | None, beta: float,
                 table: bool, order: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """Neighbours and weights of light or view queries; with ``table`` the search scans
        grid-cell candidate lists (:class:`DirectionIndex`, built once per set and k), and
        ``order`` (a permutation) puts row i on query ``order[i]``."""
        dirs = self.coded.lights if which == "lights" else self.coded.views
        if not table:
            return angular_weights(dirs, q, scheme, k, beta)
        kk = neighbour_count(scheme, k, beta, len(dirs))
        index = self._indices.get((which, kk))
        if index is None:
            index = self._indices[(which, kk)] = DirectionIndex(dirs, kk)
        return index.weights(q, scheme, beta, order)

    def _layout(self, ch: str) -> CompactLayout:
        """The channel's compact columns (:mod:`.compact`), built on the first compiled
        lookup and kept."""
        lay = self._layouts.get(ch)
        if lay is None:
            lay = self._layouts[ch] = channel_layout(self._channels[ch])
        return lay

    def _select_backend(self, backend: str) -> str:
        if backend == "auto":
            return "numba" if kernels.HAVE_NUMBA else "numpy"
        if backend not in ("numpy", "numba"):
            raise BTFInputError(f"backend must be 'auto', 'numpy' or 'numba', got {backend!r}")
        if backend == "numba" and not kernels.HAVE_NUMBA:
            raise BTFInputError("backend 'numba' requested but numba is not installed")
        return backend

    def _run_tau(self, tau: TauSpec | np.ndarray, n: int) -> dict[str, Any]:
        """The run-time τ' per channel: an int, or (n,) float64 per query (``tau`` array)."""
        if isinstance(tau, np.ndarray):
            return self._per_query_tau(tau, n)
        caps = self.tau if tau is None else self.coded.resolve_tau(tau)
        over = {ch: v for ch, v in caps.items() if v > self.tau[ch]}
        if over:
            raise BTFInputError(f"run-time tau {over} exceeds the loaded tau {self.tau}")
        return caps

    def _per_query_tau(self, tau: np.ndarray, n: int) -> dict[str, np.ndarray]:
        if tau.shape not in ((n,), (n, len(CHANNELS))) or tau.dtype.kind not in "iuf":
            raise BTFInputError(
                f"a per-query tau must be a real array of shape ({n},) or ({n}, "
                f"{len(CHANNELS)}), got {tau.dtype} {tau.shape}"
            )
        t = np.asarray(tau, dtype=np.float64).reshape(n, -1)
        out = {}
        for c, ch in enumerate(CHANNELS):
            col = t[:, c if t.shape[1] > 1 else 0]
            bad = ~((col >= 0) & (col <= self.tau[ch]))
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise BTFInputError(
                    f"per-query tau of query {i}, channel {ch}: {col[i]} is not in "
                    f"[0, {self.tau[ch]}] (the loaded tau)"
                )
            out[ch] = np.ascontiguousarray(col)
        return out

    def evaluate(
        self,
        wi: np.ndarray,
        wo: np.ndarray,
        uv: np.ndarray | None = None,
        texel: np.ndarray | None = None,
        interpolation: Scheme | str = "linear",
        domain: Domain | str = "standardized",
        k: int | None = None,
        beta: float = 20.0,
        tau: TauSpec | np.ndarray = None,
        backend: str = "auto",
        output: Literal["rgb", "log_yuv"] = "rgb",
        release_matrix: bool = False,
    ) -> np.ndarray:
        """BTF values of a batch of queries, linear RGB (n, 3) float32.

        Parameters
        ----------
        wi, wo : (n, 3) light and view directions in the local frame (z = normal, azimuth
            from +u). They are matched to the sampled directions whatever their elevation;
            masking below the horizon is the renderer's business.
        uv or texel : (n, 2) texture coordinates (wrapping) or integer (row, col).
        interpolation : "nearest", "linear" (release 2-NN), "barycentric" or "gaussian",
            used for light and view alike (:func:`~sparsebtf.runtime.angular.angular_weights`).
        domain : "standardized" — Eq. 6: the coefficient-space sum interpolates the
            standardised values and μ, σ are interpolated with the same weights; "log" — the
            release shader: Σ_ab wl_a wv_b (σ_ab X_ab + μ_ab), the bilinear blend of the
            de-standardised log values, from the same single pass over the coefficients.
            Both equal the blend of separately decoded bins in their domain.
        tau : run-time cap τ' (≤ the loaded τ) per channel; None = all loaded coefficients.
            A NumPy array is per query: (n,) (the same τ' for every channel) or (n, 3) (Y, U,
            V), real values in [0, loaded τ]: ⌊τ'⌋ coefficients count fully and the next one
            with weight τ' − ⌊τ'⌋ (:func:`~sparsebtf.runtime.kernels.prefix_weights`), so the
            value is continuous in τ' (a level of detail without seams). Give per-channel
            levels as a list, tuple, dict or string.
        backend : "numba" (compiled, parallel), "numpy", or "auto" (numba when installed).
        output : "rgb" or "log_yuv" (the de-standardised log-YUV values, before YUV → RGB and
            before the bound, and without the highlight corrections: they are linear RGB).
        release_matrix : use the release shader's rounded YUV → RGB matrix.

        The log-RGB values are clamped to the material's bound, interpolated with the same
        angular weights (Σ_ab wl_a wv_b bound_ab): no value exceeds the brightest of the
        angular images it is interpolated from.

        A material with a highlight store gets, in "rgb" output, max(value + Σ_ab wl_a wv_b
        c(x, l_a, v_b), 0) with the same neighbours and weights (c = 0 at nodes without an
        entry). The corrections are stored at full detail: they are added whatever the τ'
        (a level of detail thins the code, never the highlights).
        """
        if domain not in ("standardized", "log"):
            raise BTFInputError(f"domain must be 'standardized' or 'log', got {domain!r}")
        if interpolation not in SCHEMES:
            raise BTFInputError(
                f"unknown interpolation {interpolation!r}; choose one of {', '.join(SCHEMES)}"
            )
        wi = np.asarray(wi)
        wo = np.asarray(wo)
        if wi.shape != wo.shape:
            raise BTFInputError(f"wi {wi.shape} and wo {wo.shape} must have the same shape")
        n = wi.shape[0] if wi.ndim == 2 else -1
        pts, i1, i2 = self._texels(uv, texel, n)
        caps = self._run_tau(tau, pts.size)
        be = self._select_backend(backend)
        fast = be == "numba"
        if fast and domain == "standardized":
            return self._evaluate_compiled(pts, i1, i2, wi, wo, (interpolation, k, beta), caps,
                                           output, release_matrix)  # fmt: skip
        li, lw = self._weights("lights", wi, interpolation, k, beta, fast)
        vi, vw = self._weights("views", wo, interpolation, k, beta, fast)
        # Neighbour-pair weights and statistics: (n, kl, kv).
        w2 = lw[:, :, None] * vw[:, None, :]
        s = self._mean.shape[0]
        mu = self._mean[:, li[:, :, None], vi[:, None, :]]  # (S, n, kl, kv)
        sd = self._std[:, li[:, :, None], vi[:, None, :]]
        log = np.empty((pts.size, 3), dtype=np.float64)
        for c, ch in enumerate(CHANNELS):
            arr = self._channels[ch]
            si = c if s == 3 else 0
            if domain == "standardized":
                x = kernels.separable_sum(arr, pts, i1, i2, li, lw, vi, vw, caps[ch], be)
                log[:, c] = x * np.einsum("nab,nab->n", w2, sd[si]) + np.einsum(
                    "nab,nab->n", w2, mu[si]
                )
            else:
                xp = kernels.pair_sums(arr, pts, i1, i2, li, vi, caps[ch], be)
                log[:, c] = np.einsum("nab,nab->n", w2, sd[si] * xp + mu[si])
        if output == "log_yuv":
            return log.astype(np.float32)
        log_rgb = yuv_to_rgb(log, release_matrix)
        if self._bound is not None:
            bound = np.einsum("nab,nab->n", w2, self._bound[li[:, :, None], vi[:, None, :]])
            np.minimum(log_rgb, bound[:, None], out=log_rgb)
        rgb = inverse_log_transform(log_rgb, self.log_offset)
        # the corrections in float64, before the value's one rounding to float32
        add_highlights(rgb, self._highlights, pts, i1, i2, li, lw, vi, vw, backend=be)
        return rgb.astype(np.float32)

    def _evaluate_compiled(self, pts, i1, i2, wi, wo, scheme, caps, output, release_matrix
                           ) -> np.ndarray:  # fmt: skip
        """The numba path of :meth:`evaluate` (domain "standardized"): queries grouped by
        data point where that pays, the angular weights found in group order, the sums of
        Eq. 6 by :func:`~sparsebtf.runtime.wavefront.separable_sums`, then
        de-standardisation, colour, bound and exp fused per query, each answer written back
        to its query's row; then the highlight corrections (:mod:`.highlight_lookup`)."""
        n = pts.size
        # A handful of queries cannot fill a group: skip the sort.
        few = n < 2 * grouping.GROUP
        groups = None if few else grouping.group_queries(pts, i1, i2, self.coded.n_points,
                                                         self.coded.patch)  # fmt: skip
        order = None
        if groups is not None:
            # Every query input in group order once: the three channels' loops then read
            # them sequentially (in arrival order each would gather them at random).
            order = groups[0]
            pts, i1, i2 = (grouping.rows_in_order(a, order) for a in (pts, i1, i2))
            caps = {ch: grouping.rows_in_order(t, order) if isinstance(t, np.ndarray) else t
                    for ch, t in caps.items()}  # fmt: skip
            groups = (np.arange(n, dtype=np.int64), groups[1])
        li, lw = self._weights("lights", wi, *scheme, True, order)
        vi, vw = self._weights("views", wo, *scheme, True, order)
        x = np.empty((n, 3), dtype=np.float64)
        dt = self._channels["Y"]["values"].dtype  # the sums' weights in it, converted once
        lw_s, vw_s = lw.astype(dt, copy=False), vw.astype(dt, copy=False)
        for c, ch in enumerate(CHANNELS):
            x[:, c] = wavefront.separable_sums(self._channels[ch], pts, i1, i2, li, lw_s, vi,
                                               vw_s, kernels._per_query(caps[ch], n), groups,
                                               layout=self._layout(ch))  # fmt: skip
        matrix = YUV_TO_RGB_RELEASE if release_matrix else YUV_TO_RGB
        out = finish(x, li, lw, vi, vw, self._mean, self._std, self._bound, matrix,
                     self.log_offset, output == "rgb", order)  # fmt: skip
        if output == "rgb":
            # rows in group order, like finish's: row q answers query order[q]
            add_highlights(out, self._highlights, pts, i1, i2, li, lw, vi, vw, order)
        return out

    def image(
        self,
        light: np.ndarray,
        view: np.ndarray,
        size: tuple[int, int] | None = None,
        **kwargs: Any,
    ) -> np.ndarray:
        """An (H, W, 3) image of the texture at one light and view direction (e.g. a Figure 6
        tile); ``size`` resamples by uv (tiling beyond 1), default the texture's own size."""
        h, w = size or (self.coded.height, self.coded.width)
        v, u = np.meshgrid((np.arange(h) + 0.5) / h, (np.arange(w) + 0.5) / w, indexing="ij")
        uv = np.stack([u.ravel(), v.ravel()], axis=1)
        n = uv.shape[0]
        wi = np.broadcast_to(np.asarray(light, dtype=np.float64), (n, 3))
        wo = np.broadcast_to(np.asarray(view, dtype=np.float64), (n, 3))
        return self.evaluate(wi, wo, uv=uv, **kwargs).reshape(h, w, 3)
