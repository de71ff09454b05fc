"""Quality metrics between a reference BTF and a reconstruction (paper §4, Tables 2, 3, 5).

* ``mse_rgb`` — mean squared error on linear RGB over every value (the paper's tables).
* ``mse_log`` — the same on ln(RGB + 1e-5).
* ``mse_display`` — the same after the paper's display mapping of both BTFs,
  clip(1.3·max(RGB, 0)^(1/1.8), 0, 1) (:func:`sparsebtf.display.tone_map`, the one rule):
  the error a viewer sees. Linear-RGB MSE is dominated by the highlights of high-dynamic-range
  materials; here every value counts within [0, 1] and a value above white is white.
* ``mse_std`` — the same in the standardised log-YUV domain the codes live in (the release's
  ``btf4Drecon`` reports this one), using the reconstruction's statistics (and log offset) for
  both.
* ``psnr_rgb`` — 10·log10(peak² / mse_rgb) with the fixed peak :data:`PSNR_PEAK` = 1.0
  (reflectance 1), reported as ``peak``: the same for every material, size and render, so two
  PSNRs compare as their MSEs do. (A peak taken from the reference, its largest value, moved
  with one noisy texel or pixel: MSE 0.0039 gave 31.6 dB and MSE 0.0069 36.8 dB.)
* ``ssim`` — mean SSIM (scikit-image, RGB, data range = the reference's largest value,
  reported as ``ssim_data_range``) over a regular sample of angular images.
* ``max_decoded`` against ``reference_max`` (the reference's largest value), and
  ``top_error_share`` — the share of the squared error held by the worst :data:`TOP_SHARE` of
  values: near 1 when a few fireworks (decoded values far above anything in the material)
  carry the error.

Both BTFs are streamed by patch-aligned spatial tiles; memory is one tile of each.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from skimage.metrics import structural_similarity

from ._progress import bar
from .colour import RGB_TO_YUV
from .data.btf import BTF
from .display import tone_map
from .errors import BTFInputError
from .points.preprocessing import RELEASE_LOG_OFFSET, Standardization

__all__ = [
    "PSNR_PEAK",
    "TOP_SHARE",
    "angular_sample",
    "compare",
    "display_values",
    "psnr",
    "squared_sum",
    "ssim_angular",
    "top_k_largest",
]

#: The peak of every PSNR the project reports (eval, render, benchmarks): reflectance 1.
PSNR_PEAK = 1.0
#: The share of values whose squared errors ``top_error_share`` adds up: the worst 0.01 %.
TOP_SHARE = 1e-4


def top_k_largest(kept: np.ndarray, new: np.ndarray, k: int) -> np.ndarray:
    """The ``k`` largest of ``kept`` and ``new`` together (unordered), for a running top-k
    over streamed tiles: memory is k values, not the BTF."""
    new = new.ravel()
    if new.size > k:
        new = np.partition(new, new.size - k)[-k:]
    both = np.concatenate([kept, new])
    return both if both.size <= k else np.partition(both, both.size - k)[-k:]


def squared_sum(x: np.ndarray) -> float:
    """Σx² of a float32 array with a float64 (pairwise) accumulator."""
    return float(np.sum(np.square(x), dtype=np.float64))


def display_values(x: np.ndarray) -> np.ndarray:
    """Linear RGB as displayed, float32: :func:`sparsebtf.display.tone_map` (the paper's
    clip(1.3·max(x, 0)^(1/1.8), 0, 1)); ``mse_display`` is the MSE of these values."""
    return tone_map(x, dtype=np.float32)


def psnr(mse: float, peak: float = PSNR_PEAK) -> float:
    """Peak signal-to-noise ratio 10·log10(peak² / mse) in dB (inf for a perfect
    reconstruction); every PSNR the project reports uses the default, fixed peak."""
    if mse <= 0:
        return float("inf")
    return float(10 * np.log10(peak**2 / mse))


def angular_sample(n_lights: int, n_views: int, count: int) -> list[tuple[int, int]]:
    """``count`` (light, view) pairs spread regularly over the L·V angular images."""
    total = n_lights * n_views
    count = max(1, min(count, total))
    flat = np.unique(np.linspace(0, total - 1, count).round().astype(np.int64))
    return [(int(j // n_views), int(j % n_views)) for j in flat]


def ssim_angular(
    reference: BTF, reconstruction: BTF, pairs: list[tuple[int, int]], peak: float
) -> float:
    """Mean SSIM over the given angular images (RGB, data range ``peak``)."""
    values = []
    h, w = reference.height, reference.width
    win = min(7, h if h % 2 else h - 1, w if w % 2 else w - 1)
    if win < 3:
        raise BTFInputError(f"SSIM needs at least 3x3 texels, got {h}x{w}")
    for light, view in pairs:
        a = reference.angular_image(light, view).astype(np.float64)
        b = reconstruction.angular_image(light, view).astype(np.float64)
        values.append(structural_similarity(a, b, data_range=peak, channel_axis=2, win_size=win))
    return float(np.mean(values))


#: Values (texels × directions × 3) of one streamed tile of :func:`compare`: a dozen arrays
#: of this size live at once (both BTFs, differences, logs, decoding), 32 MiB each in float32.
TILE_VALUES = 8 * 2**20


def compare_tile(n_directions: int) -> int:
    """The side of :func:`compare`'s tiles: a multiple of 10 texels (the paper's patch), the
    largest whose values fit :data:`TILE_VALUES`, at least 10 (10 at UBO2014's 151 × 151
    directions: 0.4 GB at the peak of a comparison instead of 1.4 GB with 20)."""
    side = int(np.sqrt(TILE_VALUES / (3 * max(1, n_directions))))
    return max(10, side - side % 10)


def compare(
    reference: BTF,
    reconstruction: BTF,
    *,
    stats: Standardization | None = None,
    tile: int | None = None,
    ssim_images: int = 16,
    progress: bool | None = None,
) -> dict[str, Any]:
    """All metrics of ``reconstruction`` against ``reference`` (same shape and directions).

    ``stats`` enables ``mse_std`` (standardised log-YUV). ``tile`` is the side of the spatial
    tiles streamed (a multiple of the patch size keeps decoding aligned); by default
    :func:`compare_tile`, whose arrays stay near :data:`TILE_VALUES` values.
    """
    if reference.shape != reconstruction.shape:
        raise BTFInputError(
            f"cannot compare {reference.label} {reference.shape} with "
            f"{reconstruction.label} {reconstruction.shape}"
        )
    if not (
        reference.lights.equals(reconstruction.lights)
        and reference.views.equals(reconstruction.views)
    ):
        raise BTFInputError(
            f"{reference.label} and {reconstruction.label} have different direction tables"
        )
    h, w = reference.height, reference.width
    tile = tile or compare_tile(len(reference.lights) * len(reference.views))
    sums = {"rgb": 0.0, "log": 0.0, "display": 0.0, "std": 0.0}
    ref_max = 0.0
    decoded_max = -np.inf
    n = 0
    k_top = max(1, int(np.ceil(TOP_SHARE * reference.n_values)))
    worst = np.empty(0, dtype=np.float32)
    yuv = RGB_TO_YUV.T.astype(np.float32)
    # 1/σ of every angular image, once (not per tile).
    inv_sd = None if stats is None else (1.0 / stats.std).astype(np.float32)
    tiles = [(r, c) for c in range(0, w, tile) for r in range(0, h, tile)]
    with bar(len(tiles), "evaluate", "tile", progress) as pb:
        for r, c in tiles:
            rows, cols = slice(r, min(r + tile, h)), slice(c, min(c + tile, w))
            # float32 arithmetic, float64 accumulation: errors are far above float32 rounding.
            a = np.maximum(reference.region(rows, cols).astype(np.float32), 0)
            b = reconstruction.region(rows, cols).astype(np.float32)
            ref_max = max(ref_max, float(a.max()))
            decoded_max = max(decoded_max, float(b.max()))
            d2 = np.square(a - b)
            sums["rgb"] += float(np.sum(d2, dtype=np.float64))
            worst = top_k_largest(worst, d2, k_top)
            e = np.float32(RELEASE_LOG_OFFSET)
            dl = np.log(a + e) - np.log(np.maximum(b, 0) + e)
            sums["log"] += squared_sum(dl)
            sums["display"] += squared_sum(display_values(a) - display_values(b))
            if inv_sd is not None:
                # z_a − z_b = YUV(ln(a + o) − ln(b + o)) / σ with the material's own offset
                # o: the mean cancels.
                if stats.log_offset != RELEASE_LOG_OFFSET:
                    e = np.float32(stats.log_offset)
                    dl = np.log(a + e) - np.log(np.maximum(b, 0) + e)
                dz = (dl @ yuv) * inv_sd
                sums["std"] += squared_sum(dz)
            n += a.size
            pb.update(1)
    mse_rgb = sums["rgb"] / n
    pairs = angular_sample(len(reference.lights), len(reference.views), ssim_images)
    out: dict[str, Any] = {
        "mse_rgb": mse_rgb,
        "psnr_rgb": psnr(mse_rgb),
        "peak": PSNR_PEAK,
        "mse_log": sums["log"] / n,
        "mse_display": sums["display"] / n,
        "ssim": ssim_angular(reference, reconstruction, pairs, ref_max) if ssim_images else None,
        "ssim_images": len(pairs) if ssim_images else 0,
        "ssim_data_range": ref_max,
        "reference_max": ref_max,
        "max_decoded": decoded_max,
        "top_error_share": (
            float(np.sum(worst, dtype=np.float64)) / sums["rgb"] if sums["rgb"] > 0 else 0.0
        ),
    }
    if stats is not None:
        out["mse_std"] = sums["std"] / n
    return out
