"""Pictures people would rather see than read: angular images, error maps, quality plots.

Display follows the paper (§4): images are tone-mapped with I_out = a·I_in^(1/γ), a = 1.3,
γ = 1.8; false-colour absolute error images are normalised and scaled by 2 (Figures 4, 5).
Every file is written atomically.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from ._atomic import atomic_output
from .data.btf import BTF
from .display import tone_map

__all__ = [
    "comparison_grid",
    "error_colorbar",
    "error_image",
    "quality_plot",
    "save_angular_images",
    "save_figure",
    "save_png",
    "tone_map",
]


def error_image(
    reference: np.ndarray, reconstruction: np.ndarray, scale: float = 2.0, norm: float | None = None
) -> np.ndarray:
    """False-colour |reference − reconstruction| (mean over RGB), normalised, ×``scale``."""
    err = np.abs(reference.astype(np.float64) - reconstruction).mean(axis=-1)
    norm = norm if norm is not None else max(float(reference.max()), 1e-12)
    return plt.get_cmap("inferno")(np.clip(scale * err / norm, 0, 1))[..., :3]


def error_colorbar(fig: Any, ax: Any, scale: float, what: str = "of the reference's peak") -> Any:
    """A colour bar beside an :func:`error_image` panel, in the units it shows: |error| as a
    fraction of ``norm`` (colour 1 = ``1/scale``)."""
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    bar = fig.colorbar(
        ScalarMappable(Normalize(0.0, 1.0 / scale), cmap="inferno"), ax=ax, fraction=0.046,
        pad=0.03,
    )
    bar.set_label(f"|error| {what}", fontsize=6)
    bar.ax.tick_params(labelsize=5)
    return bar


#: Axis words for the fields :func:`quality_plot` is asked to draw.
AXIS_WORDS = {
    "bytes_total": "storage with the shared dictionaries (bytes, paper Table 4)",
    "bytes_coefficients": "storage of the material's coefficients (bytes, paper Table 4)",
    "mse_rgb": "mean squared error, linear RGB (lower is better)",
    "mse_log": "mean squared error, log RGB (lower is better)",
    "psnr_rgb": "PSNR, linear RGB (dB, peak 1, higher is better)",
    "ssim": "SSIM of angular images (higher is better)",
}


def save_png(path: str | os.PathLike[str], image: np.ndarray) -> Path:
    """Write an (H, W, 3) float image in [0, 1] as an 8-bit PNG, atomically."""
    target = Path(path)
    with atomic_output(target) as tmp:
        plt.imsave(tmp, (np.clip(image, 0, 1) * 255).round().astype(np.uint8), format="png")
    return target


def save_figure(fig: Any, path: str | os.PathLike[str], dpi: float) -> Path:
    """Lay out a matplotlib figure, write it as PNG atomically and close it."""
    fig.tight_layout()
    target = Path(path)
    with atomic_output(target) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    return target


def _label(btf: BTF, light: int, view: int) -> str:
    li, vi = btf.lights, btf.views
    return (
        f"light θ={np.degrees(li.theta[light]):.1f}° φ={np.degrees(li.phi[light]):.1f}°, "
        f"view θ={np.degrees(vi.theta[view]):.1f}° φ={np.degrees(vi.phi[view]):.1f}°"
    )


def save_angular_images(
    btf: BTF, pairs: Sequence[tuple[int, int]], folder: str | os.PathLike[str]
) -> list[Path]:
    """One tone-mapped PNG per (light, view) pair: ``<name>_l<L>_v<V>.png``."""
    out = []
    for light, view in pairs:
        img = tone_map(btf.angular_image(light, view))
        out.append(save_png(Path(folder) / f"{btf.name}_l{light:03d}_v{view:03d}.png", img))
    return out


def comparison_grid(
    reference: BTF,
    reconstructions: dict[str, BTF],
    pairs: Sequence[tuple[int, int]],
    path: str | os.PathLike[str],
    zoom: int = 4,
) -> Path:
    """Rows = (light, view) pairs; columns = reference, then per reconstruction the image and
    its false-colour error ×2 (like the paper's Figures 4 and 5)."""
    cols = 1 + 2 * len(reconstructions)
    fig, axes = plt.subplots(
        len(pairs), cols, figsize=(2.2 * cols, 2.4 * len(pairs)), squeeze=False
    )
    for r, (light, view) in enumerate(pairs):
        ref = reference.angular_image(light, view)
        peak = max(float(ref.max()), 1e-12)
        axes[r, 0].imshow(tone_map(ref), interpolation="nearest")
        axes[r, 0].set_title("reference", fontsize=8)
        axes[r, 0].set_ylabel(_label(reference, light, view).replace(", ", "\n"), fontsize=6)
        for j, (name, rec) in enumerate(reconstructions.items()):
            img = rec.angular_image(light, view)
            axes[r, 1 + 2 * j].imshow(tone_map(img), interpolation="nearest")
            axes[r, 1 + 2 * j].set_title(name, fontsize=8)
            axes[r, 2 + 2 * j].imshow(error_image(ref, img, norm=peak), interpolation="nearest")
            axes[r, 2 + 2 * j].set_title(f"|error| x2 ({name})", fontsize=7)
            error_colorbar(fig, axes[r, 2 + 2 * j], 2.0, "/ image peak")
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    return save_figure(fig, path, dpi=60 + 20 * zoom)


def quality_plot(
    rows: Sequence[dict[str, Any]],
    path: str | os.PathLike[str],
    x: str = "bytes_total",
    y: str = "mse_rgb",
    label: str = "material",
) -> Path:
    """Log–log quality vs storage, one line per ``label`` value (like the paper's Figure 3)."""
    fig, ax = plt.subplots(figsize=(6, 4))
    groups: dict[str, list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault(str(row.get(label, "")), []).append(row)
    for name, g in groups.items():
        g = sorted(g, key=lambda r: r[x])
        ax.plot([r[x] for r in g], [r[y] for r in g], marker="o", label=name)
        for r in g:
            if "tau" in r:
                ax.annotate(
                    str(r["tau"]),
                    (r[x], r[y]),
                    fontsize=6,
                    xytext=(3, 3),
                    textcoords="offset points",
                )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(AXIS_WORDS.get(x, x.replace("_", " ")))
    ax.set_ylabel(AXIS_WORDS.get(y, y.replace("_", " ")))
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title("SparseBTF: quality vs storage")
    return save_figure(fig, path, dpi=110)
