"""BTF-specific preprocessing (paper §3.1): log, BT.601 YUV, per-angular-image standardisation.

Forward, for linear RGB ``x`` at angular image j = (light, view)::

    y   = ln(x + 1e-5)                       dynamic-range reduction (release: eps 1e-5)
    yuv = M · y                              analog BT.601, on log values
    z_c = (yuv_c − μ_j,c) / σ_j,c            standardisation of every angular image

Two standardisation conventions are provided:

* ``"shared"`` — the release's (``official-release-format.md`` §3): one μ_j = mean of the three
  channel means, one σ_j = mean of the three channel standard deviations, each taken about the
  shared μ_j with an n−1 denominator. Normalised U and V are then not zero-mean.
* ``"per_channel"`` — each channel its own mean and n−1 standard deviation.

The inverse is exact (``np.linalg.inv`` of the forward matrix): the float64 round trip is at
rounding level. :data:`YUV_TO_RGB_RELEASE` holds the rounded inverse of the release's shader
for renderers that must match it bit for bit.

Statistics are gathered in one streaming pass over view blocks (:func:`gather_statistics`), or
by view ranges in separate tasks (:func:`statistic_sums`, :func:`combine_statistics`).

True black and high dynamic range. ln(x + 1e-5) turns an exact zero (a hard shadow, a masked
texel) into −11.5 among values near −2: standardisation and the sparse code then chase those
outliers, and the overshoot they cause comes back through exp() as values thousands of times
the material's maximum. Two defences, both recorded with the statistics:

* the **log offset** ε is chosen per material (:func:`choose_log_offset`, ``"auto"``):
  :data:`LOG_OFFSET_FRACTION` of the median positive value, never below the release's 1e-5;
  values far below ε lose their relative precision, which costs nothing in linear error;
  ``"release"`` keeps 1e-5;
* the **bound**: for every angular image the largest ln(x + ε) over its texels and R, G, B,
  rounded up to a multiple of 1/32. Every decoder clamps its log-RGB values to it
  (interpolated with the angular weights between sampled directions), so no decoded value
  exceeds the brightest value of its angular image by more than 3.2 %:
  :meth:`Standardization.clamp_log_rgb`.
"""

from __future__ import annotations

import itertools
import threading
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from .._progress import bar
from .._semantic import EPS_RANGE
from ..data.btf import BTF, LOG_EPS, Index, as_index
from ..data.validate import check_finite
from ..errors import BTFInputError

__all__ = [
    "BOUND_STEP",
    "EPS",
    "LOG_OFFSETS",
    "LOG_OFFSET_FRACTION",
    "RGB_TO_YUV",
    "STATS_READ_BYTES",
    "STD_MODES",
    "TRANSFORMS",
    "YUV_TO_RGB",
    "YUV_TO_RGB_RELEASE",
    "Preprocessor",
    "Standardization",
    "StatisticSums",
    "Transform",
    "check_std_mode",
    "choose_log_offset",
    "combine_statistics",
    "from_log_yuv",
    "gather_statistics",
    "inverse_log_transform",
    "log_transform",
    "resolve_log_offset",
    "rgb_to_yuv",
    "round_up_bound",
    "statistic_bands",
    "statistic_sums",
    "to_log_yuv",
    "warn_negatives",
    "yuv_to_rgb",
]

#: The log offset of §3.1 (and of UBO2014's dynamic-range reduction).
EPS = LOG_EPS
StdMode = Literal["shared", "per_channel"]
STD_MODES = ("shared", "per_channel")
#: ``"log_yuv"``: the paper's §3.1 processing. ``"identity"``: none at all — the codes hold raw
#: linear R, G, B in the channel slots Y, U, V (the [MHU19] baseline of the paper's Table 2).
Transform = Literal["log_yuv", "identity"]
TRANSFORMS = ("log_yuv", "identity")

#: Analog BT.601 RGB → YUV, applied to log values (release: ``DataBTF4D.inl``).
RGB_TO_YUV = np.array(
    [
        [0.299, 0.587, 0.114],
        [-0.14713, -0.28886, 0.436],
        [0.615, -0.51499, -0.10001],
    ]
)
_RGB_TO_YUV_F32 = RGB_TO_YUV.astype(np.float32)
#: Exact inverse of :data:`RGB_TO_YUV`.
YUV_TO_RGB = np.linalg.inv(RGB_TO_YUV)
#: The release shader's rounded inverse (|inv·fwd − I| ≤ 1.6e-5).
YUV_TO_RGB_RELEASE = np.array(
    [
        [1.0, 0.0, 1.13983],
        [1.0, -0.39465, -0.5806],
        [1.0, 2.03211, 0.0],
    ]
)


#: The per-material log offset: ε = max(:data:`EPS`, this share of the median positive value).
LOG_OFFSET_FRACTION = 0.01
#: The bound on ln(RGB + ε) is kept rounded up to a multiple of this (:func:`round_up_bound`).
BOUND_STEP = 1 / 32
#: Named log-offset rules: "auto" (:func:`choose_log_offset`) and "release" (ε = 1e-5).
LOG_OFFSETS = ("auto", "release")
#: A log offset must lie in [EPS, _MAX_LOG_OFFSET]: beyond it the log is all but linear (the
#: readers' bound, so that every offset the encoder takes makes a file they accept).
_MAX_LOG_OFFSET = EPS_RANGE[1]
#: Views read to choose the log offset (evenly spaced; all of them up to this many).
_OFFSET_VIEWS = 12
#: Log-spaced histogram of positive values for the median: 64 bins per decade, 1e-12 … 1e12.
_HIST_PER_DECADE, _HIST_LOW, _HIST_DECADES = 64, -12, 24
#: Texels per view block the median is taken over (a regular subsample of larger tiles).
_OFFSET_TEXELS = 10_000

LogOffset = float | Literal["auto", "release"]


def check_std_mode(mode: str) -> None:
    """Refuse a standardisation mode other than :data:`STD_MODES`."""
    if mode not in STD_MODES:
        raise BTFInputError(f"standardisation mode must be 'shared' or 'per_channel', got {mode!r}")


def log_transform(rgb: np.ndarray, eps: float = EPS) -> np.ndarray:
    """ln(x + eps): the dynamic-range reduction of §3.1."""
    return np.log(rgb + eps)


def inverse_log_transform(y: np.ndarray, eps: float = EPS) -> np.ndarray:
    """exp(y) − eps, the inverse of :func:`log_transform` (no clamping, as in the release)."""
    return np.exp(y) - eps


def rgb_to_yuv(x: np.ndarray) -> np.ndarray:
    """Colour transform on the last axis (size 3)."""
    return x @ RGB_TO_YUV.T.astype(x.dtype, copy=False)


def yuv_to_rgb(x: np.ndarray, release_matrix: bool = False) -> np.ndarray:
    """Inverse colour transform on the last axis; ``release_matrix`` uses the shader's rounding."""
    m = YUV_TO_RGB_RELEASE if release_matrix else YUV_TO_RGB
    return x @ m.T.astype(x.dtype, copy=False)


def to_log_yuv(rgb: np.ndarray, eps: float = EPS) -> np.ndarray:
    """Linear RGB → log-YUV (no standardisation)."""
    return rgb_to_yuv(log_transform(rgb, eps))


def from_log_yuv(yuv: np.ndarray, eps: float = EPS, release_matrix: bool = False) -> np.ndarray:
    """Log-YUV → linear RGB."""
    return inverse_log_transform(yuv_to_rgb(yuv, release_matrix), eps)


@dataclass(frozen=True, eq=False)
class Standardization:
    """Per-angular-image statistics of one BTF in the log-YUV domain.

    Attributes
    ----------
    mode : "shared" (the release's: one μ, σ for Y, U and V) or "per_channel".
    mean, std : (L, V, C) float64 with C = 1 (shared) or 3 (per channel). σ = 0 (a constant
        angular image) is stored as 1 so the forward map stays finite.
    eps : the log offset ε used (the release's 1e-5, or chosen per material).
    transform : "log_yuv" (default) or "identity" (no log, no YUV, μ = 0, σ = 1: raw RGB is
        coded as is, for the [MHU19] baseline; such statistics cannot be saved in a coded file).
    bound : (L, V) float32 or None: per angular image, the largest ln(x + ε) over its texels
        and R, G, B, rounded up to a multiple of 1/32 (:func:`round_up_bound`); decoders clamp
        to it.
        None for statistics made before bounds existed (no clamp).
    """

    mode: StdMode
    mean: np.ndarray
    std: np.ndarray
    eps: float = EPS
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
        """min(log_rgb, bound) in place on a (..., l, v, 3) block of ln(RGB + ε) values.

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
        bad, _ = clamp_offset(x, 0.0 if identity else self.stats.eps, q)
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
        standardise_log_rgb(q.reshape(-1, n_a, 3), _RGB_TO_YUV_F32, *self._full_f32,
                            out=out.reshape(3, -1, n_a) if planar else None)  # fmt: skip
        return out

    def __getstate__(self) -> dict[str, object]:
        # the threads' scratch arrays stay behind (a thread-local does not pickle)
        return {**self.__dict__, "_local": None}

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state, _local=threading.local())

    def _scratch(self, shape: tuple[int, ...]) -> np.ndarray:
        """A float32 array of ``shape`` owned by the calling thread, reused across calls."""
        buf = getattr(self._local, "buf", None)
        if buf is None or buf.shape != shape:
            buf = self._local.buf = np.empty(shape, dtype=np.float32)
        return buf

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
        y = to_log_yuv(np.asarray(rgb, dtype=dtype), self.stats.eps)
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
        return inverse_log_transform(log_rgb, self.stats.eps)


@dataclass(frozen=True, eq=False)
class StatisticSums:
    """Sums over the texels of one BTF's log-YUV values, for the views ``[v0, v1)``.

    Each view's sums are independent of the others, so a BTF's statistics can be gathered
    by view ranges in separate tasks (or machines) and combined by
    :func:`combine_statistics` into exactly what one pass gives. Sums are shifted by the first
    texel (``shift``) to keep Σ(x − μ)² accurate in float32.

    Attributes
    ----------
    views : (v0, v1).
    shift, s1, s2 : (L, v1 − v0, 3) float64: the first texel, Σ(x − shift), Σ(x − shift)².
    top : (L, v1 − v0) float64: the largest ln(x + ε) over texels and R, G, B.
    n_texels : H·W.
    negatives : values clamped to 0.
    """

    views: tuple[int, int]
    shift: np.ndarray
    s1: np.ndarray
    s2: np.ndarray
    top: np.ndarray
    n_texels: int
    negatives: int


#: Bytes of BTF values one statistics read holds (a band of rows of a few views), per thread,
#: unless one row of the file's chunks is larger: the pass's memory does not grow with the
#: number of views.
STATS_READ_BYTES = 32 * 2**20


def statistic_bands(btf: BTF) -> tuple[int, int]:
    """(rows, views) of one read of the statistics pass: :attr:`BTF.block_hint` views
    (a file's chunk) and as many whole rows (a multiple of the hint's) as fit
    :data:`STATS_READ_BYTES`, at least the hint's. Fixed per BTF, so every view's sums are
    added in the same bands whatever the view ranges of the tasks."""
    h, w, nl, nv, _ = btf.shape
    hint_rows, hint_views = (max(1, int(x)) for x in btf.block_hint)
    views = min(hint_views, nv)
    rows = max(1, STATS_READ_BYTES // max(1, 12 * w * nl * views))
    rows = max(hint_rows, rows - rows % hint_rows) if rows >= hint_rows else hint_rows
    return min(rows, h), views


def statistic_sums(
    btf: BTF,
    views: tuple[int, int] | None = None,
    eps: float = EPS,
    tick: Callable[[int], object] | None = None,
) -> StatisticSums:
    """The :class:`StatisticSums` of ``btf`` over ``views`` (default: all).

    Read in bands of rows of a few views (:func:`statistic_bands`; memory: a band per
    thread), the groups of views on the worker threads (:func:`~sparsebtf.learning.parallel.
    ordered_map`), each value touched in three passes (:mod:`.kernels`); ``tick(n)`` after
    each group of n views. NaN/Inf abort with their count and first location."""
    from ..learning.parallel import ordered_map

    h, w, nl, nv, _ = btf.shape
    v0, v1 = views if views is not None else (0, nv)
    if not 0 <= v0 < v1 <= nv:
        raise BTFInputError(f"{btf.label}: view range [{v0}, {v1}) is not inside [0, {nv})")
    n = h * w
    if n < 2:
        raise BTFInputError(f"{btf.label}: standardisation needs at least 2 texels, got {n}")
    rows, step = statistic_bands(btf)
    # groups aligned on the storage's view blocks (absolute indices), cut at [v0, v1)
    edges = sorted({v0, v1, *range(v0 - v0 % step + step, v1, step)})
    groups = list(itertools.pairwise(edges))
    s1 = np.zeros((nl, v1 - v0, 3))
    s2 = np.zeros((nl, v1 - v0, 3))
    shift = np.zeros((nl, v1 - v0, 3))
    top = np.zeros((nl, v1 - v0))
    negatives = 0

    def group_sums(vs: tuple[int, int]) -> tuple[np.ndarray, ...]:
        return _group_sums(btf, vs, rows, eps)

    for (a, b), (sh, g1, g2, gt, neg) in zip(
        groups, ordered_map(group_sums, groups), strict=True
    ):
        shift[:, a - v0 : b - v0] = sh
        s1[:, a - v0 : b - v0] = g1
        s2[:, a - v0 : b - v0] = g2
        top[:, a - v0 : b - v0] = gt
        negatives += neg
        if tick is not None:
            tick(b - a)
    return StatisticSums((v0, v1), shift, s1, s2, top, n, negatives)


def _group_sums(
    btf: BTF, views: tuple[int, int], rows: int, eps: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """Shift, Σd, Σd², top ((L, v, 3) or (L, v)) and the negative count of views
    ``[a, b)``, read in bands of ``rows`` rows; each view's sums in band order."""
    from .kernels import accumulate_sums, log_offset

    h, _, nl, _, _ = btf.shape
    a, b = views
    nvg = b - a
    shift = np.zeros((nl * nvg, 3), dtype=np.float32)
    s1 = np.zeros((nl * nvg, 3))
    s2 = np.zeros((nl * nvg, 3))
    top = np.full(nl * nvg, -np.inf)
    negatives = 0
    for r0 in range(0, h, rows):
        block = btf.read(slice(r0, min(r0 + rows, h)), slice(None), slice(None), slice(a, b))
        # float32 transforms (the release computed its statistics in single precision),
        # float64 accumulators.
        logs, bad, neg = log_offset(block, eps)
        if bad:
            check_finite(block, btf.label, offset=(r0, 0, 0, a))
        negatives += neg
        accumulate_sums(logs.reshape(-1, nl * nvg, 3), _RGB_TO_YUV_F32, shift, s1, s2, top,
                        first=r0 == 0)  # fmt: skip
    return (
        shift.reshape(nl, nvg, 3).astype(np.float64),
        s1.reshape(nl, nvg, 3),
        s2.reshape(nl, nvg, 3),
        top.reshape(nl, nvg),
        negatives,
    )


def combine_statistics(
    parts: Sequence[StatisticSums], mode: StdMode = "shared", eps: float = EPS
) -> Standardization:
    """The :class:`Standardization` from :class:`StatisticSums` of consecutive view ranges
    covering every view (bit for bit the same whatever the ranges)."""
    check_std_mode(mode)
    if not parts or parts[0].views[0] != 0 or any(
        a.views[1] != b.views[0] for a, b in itertools.pairwise(parts)
    ):
        raise BTFInputError("statistic sums must cover consecutive view ranges from view 0")
    n = parts[0].n_texels
    shift, s1, s2, top = (np.concatenate([getattr(p, a) for p in parts], axis=1)
                          for a in ("shift", "s1", "s2", "top"))  # fmt: skip
    # With y = x − K: Σ(x − μ)² = Σy² + 2(K − μ)Σy + n(K − μ)².
    if mode == "shared":
        mean = (shift + s1 / n).mean(axis=2, keepdims=True)
        # per channel, about the shared μ (release convention)
        d = shift - mean
        ss = s2 + 2 * d * s1 + n * d**2
        std = np.sqrt(np.maximum(ss, 0) / (n - 1)).mean(axis=2, keepdims=True)
    else:
        mean = shift + s1 / n
        std = np.sqrt(np.maximum(s2 - s1**2 / n, 0) / (n - 1))
    std = np.where(std > 0, std, 1.0)
    return Standardization(mode=mode, mean=mean, std=std, eps=eps, bound=round_up_bound(top))


def round_up_bound(x: np.ndarray) -> np.ndarray:
    r"""float32 copy of ``x`` rounded up to a multiple of :data:`BOUND_STEP` (never below
    ``x``; exact in binary16 for \|x\| < 64), the precision a bound is kept in.

    A coarse step costs little: the clamp may let a value through at most e^(1/32) = 3.2 %
    above its angular image's brightest, and the stored bound compresses to half the bytes of
    a binary16 rounding (12.9 vs 26.8 KB per material at 151 × 151 directions).
    """
    return (np.ceil(np.asarray(x, dtype=np.float64) / BOUND_STEP) * BOUND_STEP).astype(np.float32)


def resolve_log_offset(rule: LogOffset) -> LogOffset:
    """Check a log-offset rule: "auto", "release" or a number in [1e-5, 1e3]."""
    if isinstance(rule, str):
        if rule in LOG_OFFSETS:
            return rule  # type: ignore[return-value]
        try:
            rule = float(rule)
        except ValueError:
            raise BTFInputError(
                f"log offset must be 'auto', 'release' or a number, got {rule!r}"
            ) from None
    value = float(rule)
    if not EPS <= value <= _MAX_LOG_OFFSET:  # also refuses NaN
        raise BTFInputError(
            f"log offset must be between {EPS:g} and {_MAX_LOG_OFFSET:g}, got {value:g}"
        )
    return value


def choose_log_offset(btf: BTF, rule: LogOffset = "auto") -> float:
    """The log offset ε of ``btf``: a number as given, 1e-5 for "release", and for "auto"
    max(1e-5, :data:`LOG_OFFSET_FRACTION` × the median positive value).

    The median comes from a log-spaced histogram (64 bins per decade) of up to
    :data:`_OFFSET_VIEWS` evenly spaced view blocks, on a regular subsample of about
    :data:`_OFFSET_TEXELS` texels of each (every texel of a tile up to 100×100), so it costs a
    few view reads and memory of one block. A material with a stray-light floor far above 1 %
    of its median keeps values in the same order; one with exact zeros gets a floor that the
    zeros no longer dominate.
    """
    rule = resolve_log_offset(rule)
    if rule == "release":
        return EPS
    if not isinstance(rule, str):
        return float(rule)
    median, _ = positive_median(btf)
    if median is None:
        return EPS
    # Round to 3 significant digits: the offset is a recorded parameter, not a measurement.
    return float(f"{max(EPS, min(LOG_OFFSET_FRACTION * median, _MAX_LOG_OFFSET)):.3g}")


def positive_median(btf: BTF) -> tuple[float | None, float]:
    """(median of the positive values, share of values <= 0) of ``btf``, on the sample the
    ``auto`` log offset uses (:func:`choose_log_offset`): up to :data:`_OFFSET_VIEWS` evenly
    spaced view blocks, a regular subsample of about :data:`_OFFSET_TEXELS` texels of each;
    the median is its log-spaced histogram bin's geometric centre (64 bins per decade), None
    when no value is positive. NaN/Inf abort with their count and a location."""
    h, w, _, nv, _ = btf.shape
    views = np.unique(np.linspace(0, nv - 1, min(nv, _OFFSET_VIEWS)).round().astype(int))
    step = max(1, int(np.sqrt(h * w / _OFFSET_TEXELS)))
    n_bins = _HIST_DECADES * _HIST_PER_DECADE
    counts = np.zeros(n_bins, dtype=np.int64)
    sub = slice(None, None, step)
    seen = 0
    for v in views:
        block = btf.read(sub, sub, slice(None), [int(v)])  # the subsample only
        bad = ~np.isfinite(block)
        if bad.any():  # located in the whole BTF: rows and cols of the subsample × step
            r, c, li, _, ch = (int(i[0]) for i in np.nonzero(bad))
            raise BTFInputError(
                f"{btf.label}: {int(bad.sum())} NaN/Inf values; first at row {r * step}, "
                f"col {c * step}, "
                f"light {li}, view {int(v)}, channel {ch}"
            )
        seen += block.size
        x = block.ravel()
        x = x[x > 0].astype(np.float64)
        # bin = ⌊64·(log10 x + 12)⌋: one pass, no search over the edges
        b = np.floor((np.log10(x) - _HIST_LOW) * _HIST_PER_DECADE).astype(np.int64)
        counts += np.bincount(np.clip(b, 0, n_bins - 1), minlength=n_bins)
    total = int(counts.sum())
    zeros = 1.0 - total / seen if seen else 0.0
    if total == 0:
        return None, zeros
    k = int(np.searchsorted(np.cumsum(counts), (total + 1) // 2))
    return float(10.0 ** (_HIST_LOW + (k + 0.5) / _HIST_PER_DECADE)), zeros  # bin centre


def warn_negatives(name: str, parts: Sequence[StatisticSums]) -> None:
    """One warning with the total count of negative values clamped to 0, if any."""
    negatives = sum(p.negatives for p in parts)
    if negatives:
        warnings.warn(f"{name}: clamped {negatives} negative values to 0", stacklevel=3)


def gather_statistics(
    btf: BTF,
    mode: StdMode = "shared",
    eps: float = EPS,
    progress: bool | None = None,
    transform: Transform = "log_yuv",
) -> Standardization:
    """μ and σ of every angular image of ``btf`` in log-YUV, in one pass over view blocks.

    Memory is one view block (H·W·L·3 values). NaN/Inf abort with their count and first
    location; negative values are clamped to 0 with one warning giving the total count.
    ``transform="identity"`` reads nothing and returns μ = 0, σ = 1 (no processing at all).
    The pass is :func:`statistic_sums` + :func:`combine_statistics`.
    """
    check_std_mode(mode)
    if transform not in TRANSFORMS:
        raise BTFInputError(
            f"preprocessing transform must be one of {TRANSFORMS}, got {transform!r}"
        )
    _, _, nl, nv, _ = btf.shape
    if transform == "identity":
        c = 1 if mode == "shared" else 3
        return Standardization(
            mode=mode, mean=np.zeros((nl, nv, c)), std=np.ones((nl, nv, c)), eps=eps,
            transform="identity",
        )
    with bar(nv, "statistics", "view", progress) as pb:
        sums = statistic_sums(btf, eps=eps, tick=pb.update)
    warn_negatives(btf.label, [sums])
    return combine_statistics([sums], mode, eps)
