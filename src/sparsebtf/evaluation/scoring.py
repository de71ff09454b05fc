"""The benchmark's metrics for many reconstructions of one material in one pass over it.

:func:`sparsebtf.metrics.compare` scores one reconstruction: it reads and logs the reference,
decodes the reconstruction to linear RGB, takes its log again and decodes the SSIM images a
second time. The benchmark scores some twenty reconstructions per material, so
:func:`score_many` does the same arithmetic with the shared work done once:

* the reference is read, clamped and logged **once per material** (per spatial tile), however
  many reconstructions it is compared with;
* every reconstruction is decoded **once** (per tile, all directions): coded BTFs are decoded
  to standardised log-YUV (:meth:`~sparsebtf.runtime.dense.DecodedBTF.read_standardised`),
  mapped to log-RGB ℓ, and their clamped log ln(max(exp ℓ − ε, 0) + ε) = max(ℓ, ln ε) needs no
  exp/log round trip; linear RGB is exp ℓ − ε;
* the SSIM images are cut from the same decoded tiles;
* ``mse_std`` of a coded BTF comes from its coefficients by Parseval (no decode at all): the
  coded-domain residual ‖X − Ŝ ×_q U_q‖² = ‖X‖² − ‖Ŝ‖² that the encoder already stored per
  point (``SparseCodes.errors``), i.e. the MSE on the standardised tensors that the release's
  ``btf4Drecon`` reports. :func:`compare` gets the same number from the decoded RGB when no
  value needs clamping (tests check both).

Every metric keeps :func:`compare`'s definition (linear-RGB MSE over every value, log MSE on
ln(RGB + 1e-5), ``mse_display`` — the MSE after the paper's display mapping
clip(1.3·max(RGB, 0)^(1/1.8), 0, 1), :func:`sparsebtf.display.tone_map`, of the same decoded
tiles (the reference's mapped once per tile), PSNR with the fixed peak ``metrics.PSNR_PEAK``,
mean SSIM over the same regular sample of angular images); ``tests/test_evaluation.py``
checks the two agree.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, TypeGuard

import numpy as np
from skimage.metrics import structural_similarity

from .._progress import bar
from .._threads import single_threaded_blas
from ..colour import yuv_to_rgb
from ..data.btf import BTF
from ..errors import BTFInputError
from ..metrics import (
    PSNR_PEAK,
    TOP_SHARE,
    angular_sample,
    display_values,
    psnr,
    squared_sum,
    top_k_largest,
)
from ..model import CodedBTF
from ..points.preprocessing import RELEASE_LOG_OFFSET
from ..runtime.dense import DecodedBTF

__all__ = ["coded_mse_std", "score_many"]


def coded_mse_std(coded: CodedBTF) -> float:
    """MSE per value in the standardised domain, from the codes by Parseval (no decode)."""
    total = sum(
        float(np.sum(c.errors, dtype=np.float64)) * int(np.prod(c.mode_sizes))
        for c in coded.codes.values()
    )
    n = coded.height * coded.width * len(coded.lights) * len(coded.views) * 3
    return total / n


def _log_codes_alone(rec: BTF) -> TypeGuard[DecodedBTF]:
    """Whether ``rec`` decodes log-YUV codes and nothing else: its log values come straight
    from the code, and the codes' own error (Parseval) is the material's (a highlight store's
    corrections are linear, added after: such a material is read as its decoders read it)."""
    return (isinstance(rec, DecodedBTF) and rec.coded.stats.transform == "log_yuv"
            and rec.coded.highlight_store is None)


def _log_rgb(rec: BTF, rows: slice, cols: slice) -> tuple[np.ndarray, np.ndarray]:
    """(linear RGB, clamped log RGB ln(max(x, 0) + ε)) of a tile of a reconstruction."""
    if _log_codes_alone(rec):
        z = rec.read_standardised(rows, cols, slice(None), slice(None))
        yuv = rec.coded.stats.invert(z)
        # One (n, 3) × (3, 3) GEMM, not one per (row, col, light) slab; single-threaded: two
        # BLAS threads on this thin product ran 30× slower whenever a core was busy.
        with single_threaded_blas():
            log_rgb = yuv_to_rgb(yuv.reshape(-1, 3)).reshape(yuv.shape)
        st = rec.coded.stats
        st.clamp_log_rgb(log_rgb)  # the decoder's bound, as every decoder applies it
        lin = np.exp(log_rgb)
        lin -= np.float32(st.log_offset)
        if st.log_offset == RELEASE_LOG_OFFSET:
            # ln(max(exp ℓ − ε, 0) + ε) = max(ℓ, ln ε): no log of the exp.
            return lin, np.maximum(log_rgb, np.float32(np.log(RELEASE_LOG_OFFSET)))
        return lin, np.log(np.maximum(lin, 0) + np.float32(RELEASE_LOG_OFFSET))
    lin = rec.region(rows, cols).astype(np.float32, copy=False)
    return lin, np.log(np.maximum(lin, 0) + np.float32(RELEASE_LOG_OFFSET))


def score_many(
    reference: BTF,
    reconstructions: Sequence[BTF],
    *,
    tile: int = 10,
    ssim_images: int = 16,
    progress: bool | None = None,
) -> list[dict[str, Any]]:
    """:func:`~sparsebtf.metrics.compare` of every reconstruction against ``reference``, in
    one streamed pass over the reference (memory: one tile of each, plus the SSIM images).

    Each result has ``mse_display``, the MSE of the display-mapped values (the paper's
    clip(1.3·max(x, 0)^(1/1.8), 0, 1), :func:`~sparsebtf.metrics.display_values`), from the
    same decoded tiles. Reconstructions that are decoded coded BTFs (:class:`DecodedBTF`) also
    get ``mse_std`` (:func:`coded_mse_std`) unless their model codes raw RGB.
    """
    for rec in reconstructions:
        if rec.shape != reference.shape:
            raise BTFInputError(
                f"cannot compare {reference.label} {reference.shape} with {rec.label} {rec.shape}"
            )
        if not (reference.lights.equals(rec.lights) and reference.views.equals(rec.views)):
            raise BTFInputError(
                f"{reference.label} and {rec.label} have different direction tables"
            )
    h, w = reference.height, reference.width
    pairs = angular_sample(len(reference.lights), len(reference.views), ssim_images)
    li = np.array([p[0] for p in pairs])
    vi = np.array([p[1] for p in pairs])
    n_rec = len(reconstructions)
    sums = np.zeros((n_rec, 3))  # linear RGB, log, display-mapped
    ref_img = np.zeros((len(pairs), h, w, 3), dtype=np.float32)
    rec_img = np.zeros((n_rec, len(pairs), h, w, 3), dtype=np.float32)
    ref_max = 0.0  # SSIM's data range
    n = 0
    k_top = max(1, int(np.ceil(TOP_SHARE * reference.n_values)))
    worst = [np.empty(0, dtype=np.float32) for _ in range(n_rec)]
    top = [-np.inf] * n_rec
    tiles = [(r, c) for c in range(0, w, tile) for r in range(0, h, tile)]
    with bar(len(tiles) * (n_rec + 1), f"score {reference.label}", "tile", progress) as pb:
        for r, c in tiles:
            rows, cols = slice(r, min(r + tile, h)), slice(c, min(c + tile, w))
            a = np.maximum(reference.region(rows, cols).astype(np.float32), 0)
            la = np.log(a + np.float32(RELEASE_LOG_OFFSET))
            da = display_values(a)
            ref_max = max(ref_max, float(a.max()))
            n += a.size
            if ssim_images:
                ref_img[:, rows, cols] = np.moveaxis(a[:, :, li, vi], 2, 0)
            pb.update(1)
            for j, rec in enumerate(reconstructions):
                b, lb = _log_rgb(rec, rows, cols)
                d2 = np.square(a - b)
                sums[j, 0] += float(np.sum(d2, dtype=np.float64))
                worst[j] = top_k_largest(worst[j], d2, k_top)
                top[j] = max(top[j], float(b.max()))
                sums[j, 1] += squared_sum(la - lb)
                sums[j, 2] += squared_sum(da - display_values(b))
                if ssim_images:
                    rec_img[j, :, rows, cols] = np.moveaxis(b[:, :, li, vi], 2, 0)
                pb.update(1)
    win = min(7, h if h % 2 else h - 1, w if w % 2 else w - 1)
    if ssim_images and win < 3:
        raise BTFInputError(f"SSIM needs at least 3x3 texels, got {h}x{w}")
    out = []
    for j, rec in enumerate(reconstructions):
        mse_rgb = sums[j, 0] / n
        res: dict[str, Any] = {
            "mse_rgb": mse_rgb,
            "psnr_rgb": psnr(mse_rgb),
            "peak": PSNR_PEAK,
            "mse_log": sums[j, 1] / n,
            "mse_display": sums[j, 2] / n,
            "ssim": float(np.mean([
                structural_similarity(ref_img[i].astype(np.float64),
                                      rec_img[j, i].astype(np.float64), data_range=ref_max,
                                      channel_axis=2, win_size=win)
                for i in range(len(pairs))
            ])) if ssim_images else None,
            "ssim_images": len(pairs) if ssim_images else 0,
            "ssim_data_range": ref_max,
            "reference_max": ref_max,
            "max_decoded": top[j],
            "top_error_share": (float(np.sum(worst[j], dtype=np.float64)) / sums[j, 0]
                                if sums[j, 0] > 0 else 0.0),
        }  # fmt: skip
        if _log_codes_alone(rec):
            res["mse_std"] = coded_mse_std(rec.coded)
        out.append(res)
    return out
