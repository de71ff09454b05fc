"""Path-traced renders of SparseBTF materials with Mitsuba 3, and coded-vs-reference comparisons.

:func:`render_material` renders one built-in scene (:mod:`sparsebtf.rendering.scenes`) with the
``sparsebtf`` plugin (a coded file) or ``sparsebtf_dense`` (a reference BTF);
:func:`compare_renders` gives the MSE / PSNR (linear radiance) and SSIM (tone-mapped sRGB) of two
renders, like the paper's Figures 7 and 8; :func:`save_side_by_side` writes the PNG.
Both renders of a comparison use the same sampler seed, so their Monte Carlo noise is
correlated and the difference shows the material, not the noise.
"""

from __future__ import annotations

import os
import time
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import BTFInputError

__all__ = [
    "RenderResult",
    "compare_renders",
    "render_material",
    "save_side_by_side",
    "tonemap_srgb",
    "uses_runtime",
]


#: Path samples per second of the ``scalar_rgb`` fallback (the BSDF runs in Python per ray):
#: a 32x32, 4 spp sphere render took 6.6 s on the 2-core development machine. Used only to
#: warn before long renders (:func:`scalar_seconds`).
SCALAR_SAMPLES_PER_SECOND = 600.0

#: ``render_material``'s Dr.Jit modes (``mode``).
MODES = ("auto", "symbolic", "evaluated")
#: Samples per pass on a Dr.Jit variant: in evaluated mode each step's arrays are materialised,
#: about 430 bytes a sample (a 512×512, 8-spp pass of a coded material raised the peak by
#: 0.88 GB against nothing in symbolic mode); in passes of 2²⁰ samples it rose by 0.36 GB
#: (512×512 at 4 spp) and 0.47 GB (at 16 spp, 4 passes).
PASS_LANES = 1 << 20


def scalar_seconds(size: tuple[int, int], spp: int, renders: int = 1) -> float:
    """About how long ``renders`` scalar_rgb renders of ``size`` (w, h) at ``spp`` take."""
    return renders * size[0] * size[1] * spp / SCALAR_SAMPLES_PER_SECOND


class RenderResult(dict):
    """``image`` (H, W, 3) float32 linear RGB, ``seconds`` (render incl. JIT), ``variant``,
    ``plugin`` (the BSDF's description), ``mode`` (Dr.Jit's: symbolic or evaluated)."""

    @property
    def image(self) -> np.ndarray:
        return self["image"]


def _setup(backend: str) -> tuple[Any, Any, str]:
    from .mitsuba import setup

    variant = setup(backend, quiet=False)
    import drjit as dr
    import mitsuba as mi

    return mi, dr, variant


def render_material(
    bsdf: dict[str, Any],
    *,
    scene: str = "sphere",
    size: tuple[int, int] = (256, 256),
    spp: int = 16,
    envmap: str | os.PathLike[str] | None = None,
    max_depth: int = 4,
    seed: int = 0,
    floor: str | None = None,
    backend: str = "auto",
    progress: bool | None = None,
    lod: str | None = None,
    mode: str = "auto",
) -> RenderResult:
    """Render ``bsdf`` (a ``sparsebtf``/``sparsebtf_dense`` plugin dict) in a built-in scene.

    ``size`` is (width, height). Returns a :class:`RenderResult`; non-finite pixels raise.
    A render of more than :data:`PASS_LANES` samples, or expected to take more than a few
    seconds (the scalar variant), runs in passes under a progress bar with ETA (``progress``:
    None = on a terminal). ``lod`` ("auto", "off"; None: the plugin dict's own, default auto)
    sets a ``sparsebtf`` plugin's level of detail, with this scene's camera
    (:func:`.scenes.lod_camera`) unless the dict gives one. ``mode``: Dr.Jit's "symbolic" (one
    megakernel) or "evaluated" (a kernel per step of the wavefront) mode; "auto" is evaluated
    where a ``sparsebtf`` plugin's lookups can go to the runtime's compiled kernel
    (:func:`uses_runtime`), else symbolic. The scalar variant has neither: symbolic.
    """
    if mode not in MODES:
        raise BTFInputError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    if spp < 1:
        raise BTFInputError(f"spp must be >= 1, got {spp}")
    w, h = (int(v) for v in size)
    if w < 1 or h < 1:
        raise BTFInputError(f"image size must be positive, got {w}x{h}")
    mi, dr, variant = _setup(backend)
    from .mitsuba import preload
    from .scenes import scene_dict

    bsdf = with_lod(bsdf, lod, scene, w)
    preload(bsdf)  # input errors as sparsebtf errors, not wrapped by Mitsuba
    t0 = time.perf_counter()
    loaded = mi.load_dict(bsdf)
    sd = scene_dict(mi, loaded, scene, w, h, envmap, max_depth, floor)
    scn = mi.load_dict(sd)
    t1 = time.perf_counter()
    if mode == "auto":
        mode = "evaluated" if uses_runtime(bsdf, variant) else "symbolic"
    if variant.startswith("scalar"):
        mode = "symbolic"
    from .mitsuba import evaluated

    with evaluated() if mode == "evaluated" else nullcontext():
        arr = _render_passes(mi, dr, scn, int(spp), int(seed), variant, progress)
    t2 = time.perf_counter()
    if not np.all(np.isfinite(arr)):
        bad = int((~np.isfinite(arr)).any(axis=-1).sum())
        raise BTFInputError(f"the render has {bad} non-finite pixels ({loaded})")
    return RenderResult(
        image=arr[..., :3],
        seconds=t2 - t1,
        setup_seconds=t1 - t0,
        variant=variant,
        plugin=str(loaded),
        mode=mode,
    )


def uses_runtime(bsdf: dict[str, Any], variant: str) -> bool:
    """Whether a ``sparsebtf`` plugin dict's lookups go to the runtime's compiled kernel in
    Dr.Jit's evaluated mode (:func:`.mitsuba.materials.host_lookups`): 5× faster than its
    Dr.Jit kernel in a megakernel (``benchmarks/bench_render.py``)."""
    from .mitsuba.materials import host_lookups

    return bsdf.get("type") == "sparsebtf" and host_lookups(bsdf.get("backend", "auto"), variant)


def with_lod(bsdf: dict[str, Any], lod: str | None, scene: str, width: int) -> dict[str, Any]:
    """A copy of a ``sparsebtf`` plugin dict with ``lod`` (when given) and, for ``auto``,
    the built-in scene's camera; other plugins unchanged."""
    if bsdf.get("type") != "sparsebtf":
        return bsdf
    from .scenes import lod_camera

    out = dict(bsdf)
    if lod is not None:
        out["lod"] = lod
    if out.get("lod", "auto") == "auto" and "lod_camera" not in out:
        out.update(lod_camera(scene, width))
    return out


def _render_passes(
    mi: Any, dr: Any, scn: Any, spp: int, seed: int, variant: str, progress: bool | None
) -> np.ndarray:
    """``mi.render`` at ``spp`` in passes, their sample-weighted mean being the image: the
    scalar variant renders up to 8 passes of fewer samples (seeds ``seed·8 + i``) with a
    progress bar; a Dr.Jit variant passes of at most :data:`PASS_LANES` samples (seeds
    ``seed·2¹⁶ + i`` when there are several), in either mode, so a coded render (evaluated)
    and its dense reference (symbolic) draw the same random numbers."""
    from .._progress import bar

    w, h = scn.sensors()[0].film().size()
    scalar = variant.startswith("scalar")
    slow = scalar and scalar_seconds((w, h), spp) > 5
    n = (min(spp, 8) if slow else 1) if scalar else min(spp, -(-w * h * spp // PASS_LANES))
    counts = [spp // n + (i < spp % n) for i in range(n)]
    acc = None
    with bar(spp, "render", "spp", progress if slow or n > 1 else False) as pb:
        for i, k in enumerate(counts):
            if n == 1:
                pass_seed = seed
            else:
                pass_seed = seed * 8 + i if scalar else (seed << 16) + i
            img = mi.render(scn, spp=k, seed=pass_seed)
            dr.eval(img)
            dr.sync_thread()
            part = np.array(img, dtype=np.float64) * (k / spp)
            acc = part if acc is None else acc + part
            pb.update(k)
    return np.asarray(acc, dtype=np.float32)


def tonemap_srgb(image: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """Linear RGB × ``exposure`` → sRGB transfer curve, clipped to [0, 1] (NaN → 0)."""
    x = np.nan_to_num(np.asarray(image, dtype=np.float64) * exposure, nan=0.0, posinf=1.0)
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def auto_exposure(image: np.ndarray, percentile: float = 99.0, target: float = 0.9) -> float:
    """Exposure mapping the ``percentile`` of luminance to ``target`` (1 for black images)."""
    lum = np.asarray(image, dtype=np.float64) @ np.array([0.2126, 0.7152, 0.0722])
    p = float(np.percentile(lum, percentile))
    return target / p if p > 0 and np.isfinite(p) else 1.0


def compare_renders(
    image: np.ndarray, reference: np.ndarray, exposure: float | None = None
) -> dict[str, float]:
    """MSE and PSNR of linear RGB, SSIM and MSE of the tone-mapped sRGB images.

    PSNR = 10·log10(peak² / MSE) with the project's fixed peak
    (:data:`sparsebtf.metrics.PSNR_PEAK`, returned as ``peak``), so renders compare;
    SSIM (scikit-image, RGB, data range 1) compares the images as displayed (same exposure,
    default :func:`auto_exposure` of the reference).
    """
    from skimage.metrics import structural_similarity

    from ..metrics import PSNR_PEAK, psnr

    a = np.asarray(image, dtype=np.float64)
    b = np.asarray(reference, dtype=np.float64)
    if a.shape != b.shape:
        raise BTFInputError(f"cannot compare images of shapes {a.shape} and {b.shape}")
    exposure = auto_exposure(b) if exposure is None else exposure
    mse = float(np.mean((a - b) ** 2))
    ta, tb = tonemap_srgb(a, exposure), tonemap_srgb(b, exposure)
    side = min(a.shape[:2])
    win = 7 if side >= 7 else (side if side % 2 else side - 1)  # odd, <= the image
    ssim = float(structural_similarity(ta, tb, data_range=1.0, channel_axis=2, win_size=win))
    return {
        "mse": mse,
        "psnr": psnr(mse),
        "peak": PSNR_PEAK,
        "mse_srgb": float(np.mean((ta - tb) ** 2)),
        "ssim": ssim,
        "exposure": exposure,
        "mean": float(a.mean()),
        "mean_reference": float(b.mean()),
    }


def save_png(
    path: str | os.PathLike[str], image: np.ndarray, exposure: float | None = None
) -> Path:
    """Tone-map a linear render (exposure: default :func:`auto_exposure`) and write an 8-bit PNG."""
    from ..figures import save_png as _save

    exposure = auto_exposure(image) if exposure is None else exposure
    return _save(path, tonemap_srgb(image, exposure))


def save_side_by_side(
    path: str | os.PathLike[str],
    image: np.ndarray,
    reference: np.ndarray,
    metrics: dict[str, float],
    labels: tuple[str, str] = ("SparseBTF", "reference"),
    error_scale: float = 4.0,
) -> Path:
    """[render | reference | false-colour |error| × ``error_scale``] with MSE/SSIM, as a PNG."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from ..figures import error_colorbar, error_image, save_figure

    exposure = metrics.get("exposure") or auto_exposure(reference)
    h, w = image.shape[:2]
    peak = max(float(np.percentile(reference, 99.5)), 1e-12)
    panels = [
        (tonemap_srgb(image, exposure), labels[0]),
        (tonemap_srgb(reference, exposure), labels[1]),
        (error_image(reference, image, scale=error_scale, norm=peak),
         f"|error| x{error_scale:g} (of the 99.5th pct)"),
    ]  # fmt: skip
    scale = max(1.0, 256 / max(h, w))
    fig, axes = plt.subplots(1, 3, figsize=(3 * w * scale / 100 + 0.3, h * scale / 100 + 0.7))
    for ax, (img, title) in zip(axes, panels, strict=True):
        ax.imshow(img, interpolation="nearest")
        ax.set_title(title, fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
    error_colorbar(fig, axes[2], error_scale, "/ reference 99.5th pct")
    fig.suptitle(
        f"linear RGB: MSE {metrics['mse']:.3g}, PSNR {metrics['psnr']:.2f} dB (peak "
        f"{metrics['peak']:.3g})   SSIM {metrics['ssim']:.4f}",
        fontsize=9,
    )
    return save_figure(fig, path, dpi=100)
