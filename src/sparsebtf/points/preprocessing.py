"""BTF-specific preprocessing (paper §3.1): log, BT.601 YUV, per-angular-image standardisation.

Forward, for linear RGB ``x`` at angular image j = (light, view)::

    y   = ln(x + 1e-5)                       dynamic-range reduction (release: offset 1e-5)
    yuv = M · y                              analog BT.601, on log values
    z_c = (yuv_c − μ_j,c) / σ_j,c            standardisation of every angular image

Two standardisation conventions are provided:

* ``"shared"`` — the release's (``official-release-format.md`` §3): one μ_j = mean of the three
  channel means, one σ_j = mean of the three channel standard deviations, each taken about the
  shared μ_j with an n−1 denominator. Normalised U and V are then not zero-mean.
* ``"per_channel"`` — each channel its own mean and n−1 standard deviation.

The inverse is exact (``np.linalg.inv`` of the forward matrix): the float64 round trip is at
rounding level. The colour matrices live in :mod:`sparsebtf.colour`; the statistics (μ, σ, the
bound, the log offset) are measured by :mod:`.statistics`.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import Literal

import numpy as np

from .._semantic import LOG_OFFSET_RANGE
from .._threads import thread_buffer
from ..colour import RGB_TO_YUV_F32, rgb_to_yuv, yuv_to_rgb
from ..constraints import Interval, StrOptions, check_option
from ..data.btf import RELEASE_LOG_OFFSET, Index, as_index
from ..data.validate import check_finite
from ..errors import BTFInputError

__all__ = [
    "BOUND_STEP",
    "LOG_OFFSETS",
    "LOG_OFFSET_RULE",
    "MAX_LOG_OFFSET",
    "RELEASE_LOG_OFFSET",
    "STD_MODES",
    "TRANSFORMS",
    "LogOffset",
    "Preprocessor",
    "Standardization",
    "StdMode",
    "Transform",
    "check_std_mode",
    "from_log_yuv",
    "inverse_log_transform",
    "log_transform",
    "resolve_log_offset",
    "round_up_bound",
    "to_log_yuv",
]

StdMode = Literal["shared", "per_channel"]
STD_MODES = ("shared", "per_channel")
#: ``"log_yuv"``: the paper's §3.1 processing. ``"identity"``: none at all — the codes hold raw
#: linear R, G, B in the channel slots Y, U, V (the [MHU19] baseline of the paper's Table 2).
Transform = Literal["log_yuv", "identity"]
TRANSFORMS = ("log_yuv", "identity")

#: The bound on ln(RGB + offset) is kept rounded up to a multiple of this (:func:`round_up_bound`).
BOUND_STEP = 1 / 32
#: Named log-offset rules: "auto" (:func:`~.statistics.choose_log_offset`) and "release" (1e-5).
LOG_OFFSETS = ("auto", "release")
#: A log offset must lie in [RELEASE_LOG_OFFSET, MAX_LOG_OFFSET]: beyond it the log is all but
#: linear (the readers' bound, so that every offset the encoder takes makes a file they accept).
MAX_LOG_OFFSET = LOG_OFFSET_RANGE[1]

LogOffset = float | Literal["auto", "release"]
#: What a log-offset rule may be: the option tables' entry (:mod:`sparsebtf.constraints`).
LOG_OFFSET_RULE = [
    StrOptions(LOG_OFFSETS, what="log offset rule"),
    Interval(float, RELEASE_LOG_OFFSET, MAX_LOG_OFFSET, unit="(the offset of ln(x + offset))"),
]


def check_std_mode(mode: str) -> None:
    """Refuse a standardisation mode other than :data:`STD_MODES`."""
    if mode not in STD_MODES:
        raise BTFInputError(f"standardisation mode must be 'shared' or 'per_channel', got {mode!r}")


def log_transform(rgb: np.ndarray, log_offset: float = RELEASE_LOG_OFFSET) -> np.ndarray:
    """ln(x + log_offset): the dynamic-range reduction of §3.1."""
    return np.log(rgb + log_offset)


def inverse_log_transform(y: np.ndarray, log_offset: float = RELEASE_LOG_OFFSET) -> np.ndarray:
    """exp(y) − log_offset, the inverse of :func:`log_transform` (no clamping, as in the
    release)."""
    return np.exp(y) - log_offset




def to_log_yuv(rgb: np.ndarray, log_offset: float = RELEASE_LOG_OFFSET) -> np.ndarray:
    """Linear RGB → log-YUV (no standardisation)."""
    return rgb_to_yuv(log_transform(rgb, log_offset))


def from_log_yuv(
    yuv: np.ndarray, log_offset: float = RELEASE_LOG_OFFSET, release_matrix: bool = False
) -> np.ndarray:
    """Log-YUV → linear RGB."""
    return inverse_log_transform(yuv_to_rgb(yuv, release_matrix), log_offset)


@dataclass(frozen=True, eq=False)
class Standardization:
    """Per-angular-image statistics of one BTF in the log-YUV domain.

    Attributes
    ----------
    mode : "shared" (the release's: one μ, σ for Y, U and V) or "per_channel".
    mean, std : (L, V, C) float64 with C = 1 (shared) or 3 (per channel). σ = 0 (a constant
        angular image) is stored as 1 so the forward map stays finite.
    log_offset : the offset of ln(x + offset) used (the release's 1e-5, or chosen per
        material; the coded file's ``stats@eps``).
    transform : "log_yuv" (default) or "identity" (no log, no YUV, μ = 0, σ = 1: raw RGB is
        coded as is, for the [MHU19] baseline; such statistics cannot be saved in a coded file).
    bound : (L, V) float32 or None: per angular image, the largest ln(x + offset) over its texels
        and R, G, B, rounded up to a multiple of 1/32 (:func:`round_up_bound`); decoders clamp
        to it.
        None for statistics made before bounds existed (no clamp).
    """

    mode: StdMode
    mean: np.ndarray
    std: np.ndarray
    log_offset: float = RELEASE_LOG_OFFSET
    transform: Transform = "log_yuv"
    bound: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.transform not in TRANSFORMS:
            raise BTFInputError(
                f"preprocessing transform must be one of {TRANSFORMS}, got {self.transform!r}"
            )
        check_std_mode(self.mode)
        if self.mean.shape != self.std.shape or self.mean.ndim != 3:
            raise BTFInputError(
                f"mean and std must both be (L, V, C); got {self.mean.shape} and {self.std.shape}"
            )
        c = 1 if self.mode == "shared" else 3
        if self.mean.shape[2] != c:
            raise BTFInputError(f"{self.mode} statistics need C = {c}, got {self.mean.shape[2]}")
        if self.bound is not None and self.bound.shape != self.mean.shape[:2]:
            raise BTFInputError(
                f"bound must be (L, V) = {self.mean.shape[:2]}, got {self.bound.shape}"
            )

    @property
    def n_lights(self) -> int:
        return int(self.mean.shape[0])

    @property
    def n_views(self) -> int:
        return int(self.mean.shape[1])

    def select(self, lights: Index, views: Index) -> tuple[np.ndarray, np.ndarray]:
        """μ, σ at the outer product of light and view indices: (l, v, C) each."""
        li = as_index(lights, self.n_lights, "light")
        vi = as_index(views, self.n_views, "view")
        return self.mean[np.ix_(li, vi)], self.std[np.ix_(li, vi)]

    def _full(
        self, lights: Index, views: Index, dtype: np.dtype, invert_std: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """μ and σ (or 1/σ) as contiguous (l, v, 3) arrays of ``dtype``.

        A trailing axis of 1 against the data's trailing 3 would make numpy loop over
        3-element rows; full contiguous operands keep the arithmetic vectorised.
        """
        mu, sd = self.select(lights, views)
        dt = np.float32 if np.dtype(dtype) == np.float32 else np.float64
        shape = (*mu.shape[:2], 3)
        mu = np.ascontiguousarray(np.broadcast_to(mu, shape), dtype=dt)
        sd = np.ascontiguousarray(np.broadcast_to(1.0 / sd if invert_std else sd, shape), dtype=dt)
        return mu, sd

    def apply(
        self, yuv: np.ndarray, lights: Index = slice(None), views: Index = slice(None)
    ) -> np.ndarray:
        """Standardise a log-YUV block (..., l, v, 3)."""
        mu, inv = self._full(lights, views, yuv.dtype, invert_std=True)
        out = yuv - mu
        out *= inv
        return out

    def invert(
        self, z: np.ndarray, lights: Index = slice(None), views: Index = slice(None)
    ) -> np.ndarray:
        """Undo :meth:`apply`."""
        mu, sd = self._full(lights, views, z.dtype, invert_std=False)
        out = z * sd
        out += mu
        return out

    def clamp_log_rgb(
        self, log_rgb: np.ndarray, lights: Index = slice(None), views: Index = slice(None)
    ) -> np.ndarray:
        """min(log_rgb, bound) in place on a (..., l, v, 3) block of ln(RGB + offset) values.

        No value then decodes above its angular image's brightest (over texels and R, G, B);
        the clamp never moves a value away from the truth, which is below the bound.
        Statistics without a bound (older files) leave the values as they are.
        """
        if self.bound is None:
            return log_rgb
        li = as_index(lights, self.n_lights, "light")
        vi = as_index(views, self.n_views, "view")
        b = self.bound[np.ix_(li, vi)].astype(log_rgb.dtype, copy=False)
        np.minimum(log_rgb, b[..., None], out=log_rgb)
        return log_rgb


class Preprocessor:
    """Linear RGB ⇄ standardised log-YUV for one BTF, given its :class:`Standardization`."""

    def __init__(self, stats: Standardization) -> None:
        self.stats = stats
        self._full_f32: tuple[np.ndarray, np.ndarray] | None = None
        self._local = threading.local()

    def forward_into(
        self, rgb: np.ndarray, out: np.ndarray, where: str = "btf", offset: tuple[int, ...] = ()
    ) -> np.ndarray:
        """(..., L, V, 3) linear RGB of every direction → standardised log-YUV in ``out``
        (float32, rgb's shape), in three passes (:mod:`.kernels`): clamp and offset, log,
        colour transform and standardisation. NaN/Inf raise with their count and first
        location (``where``, ``offset`` as :func:`~sparsebtf.data.validate.check_finite`);
        negative values count as 0. Equals :meth:`forward` to float32 rounding (the colour
        transform is summed term by term here)."""
        from .kernels import clamp_offset, standardise_log_rgb

        x = np.ascontiguousarray(rgb, dtype=np.float32)
        planar = out.shape == (3, *x.shape[:-1])
        if out.dtype != np.float32 or not (
            (planar and out[0].flags.c_contiguous)
            or (out.shape == x.shape and out.flags.c_contiguous)
        ):
            raise BTFInputError(
                f"forward_into needs a C-contiguous float32 {x.shape} output or three "
                f"C-contiguous {x.shape[:-1]} channels, got {out.dtype} {out.shape}"
            )
        # planar: the per-value passes run in a scratch array of this thread, reused
        q = self._scratch(x.shape) if planar else out
        identity = self.stats.transform == "identity"
        bad, _ = clamp_offset(x, 0.0 if identity else self.stats.log_offset, q)
        if bad:
            check_finite(x, where, offset)
        if identity:
            if planar:
                out[...] = np.moveaxis(q, -1, 0)
            return out
        np.log(q, out=q)
        if self._full_f32 is None:
            mu, inv = self.stats._full(slice(None), slice(None), np.dtype(np.float32), True)
            self._full_f32 = (mu.reshape(-1, 3), inv.reshape(-1, 3))
        n_a = self._full_f32[0].shape[0]
        standardise_log_rgb(q.reshape(-1, n_a, 3), RGB_TO_YUV_F32, *self._full_f32,
                            out=out.reshape(3, -1, n_a) if planar else None)  # fmt: skip
        return out

    def __getstate__(self) -> dict[str, object]:
        # the threads' scratch arrays stay behind (a thread-local does not pickle)
        return {**self.__dict__, "_local": None}

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state, _local=threading.local())

    def _scratch(self, shape: tuple[int, ...]) -> np.ndarray:
        """A float32 array of ``shape`` owned by the calling thread, reused across calls."""
        return thread_buffer(self._local, math.prod(shape), np.float32).reshape(shape)

    def forward(
        self,
        rgb: np.ndarray,
        lights: Index = slice(None),
        views: Index = slice(None),
        dtype: type = np.float64,
    ) -> np.ndarray:
        """(..., l, v, 3) linear RGB → standardised log-YUV (clamp negative inputs first)."""
        if self.stats.transform == "identity":
            return np.asarray(rgb, dtype=dtype)
        y = to_log_yuv(np.asarray(rgb, dtype=dtype), self.stats.log_offset)
        return self.stats.apply(y, lights, views).astype(dtype, copy=False)

    def inverse(
        self,
        z: np.ndarray,
        lights: Index = slice(None),
        views: Index = slice(None),
        release_matrix: bool = False,
    ) -> np.ndarray:
        """Standardised log-YUV (..., l, v, 3) → linear RGB."""
        if self.stats.transform == "identity":
            return np.asarray(z)
        log_rgb = yuv_to_rgb(self.stats.invert(z, lights, views), release_matrix)
        self.stats.clamp_log_rgb(log_rgb, lights, views)
        return inverse_log_transform(log_rgb, self.stats.log_offset)


def round_up_bound(x: np.ndarray) -> np.ndarray:
    r"""float32 copy of ``x`` rounded up to a multiple of :data:`BOUND_STEP` (never below
    ``x``; exact in binary16 for \|x\| < 64), the precision a bound is kept in.

    A coarse step costs little: the clamp may let a value through at most e^(1/32) = 3.2 %
    above its angular image's brightest, and the stored bound compresses to half the bytes of
    a binary16 rounding (12.9 vs 26.8 KB per material at 151 × 151 directions).
    """
    return (np.ceil(np.asarray(x, dtype=np.float64) / BOUND_STEP) * BOUND_STEP).astype(np.float32)


def resolve_log_offset(rule: LogOffset | str, name: str = "log offset") -> LogOffset:
    """A log-offset rule checked (:data:`LOG_OFFSET_RULE`): "auto", "release" or a number in
    [1e-5, 1e3], also written as text ("0.002"); a refusal names it ``name``."""
    if isinstance(rule, str) and rule not in LOG_OFFSETS:
        try:
            rule = float(rule)
        except ValueError:
            pass
    check_option(name, rule, LOG_OFFSET_RULE)
    return rule if isinstance(rule, str) else float(rule)  # type: ignore[return-value]
