"""The paper's Figure 8, for every method: renders of each reconstruction beside the reference.

Figure 8 compares path-traced renders of SparseBTF and [RGJW20] materials; "model, view and
lighting environment were the same for all these renderings". :func:`render_methods` does that
for any set of reconstructions of one material:

* every reconstruction (and the reference) is decoded on the measured grid, view block by view
  block, into an in-memory (H, W, L, V, 3) float32 table — so every method, coded or neural,
  is rendered by the same code, the dense plugin ``sparsebtf_dense``
  (:mod:`sparsebtf.rendering.mitsuba`), with the same angular interpolation (``linear``);
  only benchmark sizes (≤ :data:`MAX_TEXELS` × :data:`MAX_TEXELS` texels) are accepted, and
  one material's tables are held at a time;
* every render uses the same scene (the built-in sphere on a floor of the material, under the
  procedural sky, :func:`sparsebtf.rendering.render.render_material`), the same spp and the same
  sampler seed, with **cosine** direction sampling: it does not depend on the material, so all
  renders draw the same paths from the same random numbers and their difference is the
  material's, not Monte Carlo noise (BTF-driven sampling builds its tables from each
  material's own values, and would draw other directions for each method);
* metrics per method against the reference render: ``image_mse`` (linear radiance),
  ``image_mse_display`` (after the paper's display mapping clip(1.3·max(x, 0)^(1/1.8), 0, 1),
  :func:`sparsebtf.display.tone_map`, the one rule) and ``flip``, the mean **HDR-ꟻLIP**
  (``flip_evaluator``, Andersson et al. 2021) of the linear renders: the renders are
  high-dynamic-range (a sky with a sun; the display mapping clips about half of the test
  sphere to white), and HDR-ꟻLIP compares them over the range of exposures the reference
  spans (its start/stop exposures come from the reference, so every method is judged on the
  same ones) rather than at one tone mapping;
* ``out_dir/figure8.png``: the reference and every method as displayed (the paper's mapping),
  and under each method its ꟻLIP map with a colour bar, titled with the label and metrics;
  ``out_dir/<label>.png`` each display-mapped render, ``out_dir/renders.npz`` the linear
  renders.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .._atomic import atomic_output
from .._limits import check_allocation
from .._progress import bar
from ..data.btf import BTF, ArrayBTF
from ..errors import BTFInputError
from ..metrics import display_values

__all__ = ["MAX_TEXELS", "SCENE", "dense_copy", "flip_hdr", "render_methods"]

#: The largest side (texels) of a material :func:`render_methods` decodes into memory.
MAX_TEXELS = 100
#: The built-in scene of every render, and its plugin parameters (the same for every method).
SCENE = "sphere"
_PLUGIN = {"type": "sparsebtf_dense", "interpolation": "linear", "two_sided": True,
           "sampling": "cosine"}  # fmt: skip
#: The key under which the material being rendered is added (replaced for each, then removed).
_KEY = "sparsebtf-evaluation-renders"


def dense_copy(btf: BTF, what: str, progress: bool | None = None) -> ArrayBTF:
    """``btf`` decoded on its measured grid into memory, one view block (H, W, L, 3) at a time
    (a coded BTF decodes each block with Eq. 4 restricted to that view); refuses more than
    :data:`MAX_TEXELS` texels a side and non-finite values (naming ``what``)."""
    h, w, _, nv, _ = btf.shape
    if h > MAX_TEXELS or w > MAX_TEXELS:
        raise BTFInputError(
            f"{what}: renders decode a material into memory, up to {MAX_TEXELS}x{MAX_TEXELS} "
            f"texels (the benchmark's sizes); {btf.label} has {h}x{w}; crop it first "
            "(sparsebtf convert BTF -o crop.h5 --crop R0:R1,C0:C1)"
        )
    check_allocation(btf.n_values * 4, f"{what}: {btf.label} as a dense table", BTFInputError)
    data = np.empty(btf.shape, dtype=np.float32)
    with bar(nv, f"decode {what}", "view", progress) as pb:
        for v in range(nv):
            data[:, :, :, v] = btf.view_block(v)
            pb.update(1)
    bad = ~np.isfinite(data)
    if bad.any():
        first = tuple(int(i) for i in np.argwhere(bad)[0][:4])
        raise BTFInputError(
            f"{what}: {btf.label} has {int(bad.sum())} non-finite values (first at row, col, "
            f"light, view {first}); it cannot be rendered"
        )
    return ArrayBTF(data, btf.lights, btf.views, name=btf.name)


def flip_hdr(reference: np.ndarray, test: np.ndarray) -> tuple[np.ndarray, float, dict]:
    """HDR-ꟻLIP of two linear (H, W, 3) renders: (error map (H, W) in [0, 1], its mean, the
    parameters used — exposures from ``reference``)."""
    import flip_evaluator as flip

    ref = np.ascontiguousarray(np.maximum(reference, 0), dtype=np.float32)
    if not np.any(ref > 0):
        raise BTFInputError("the reference render is black: HDR-FLIP has no exposure range")
    tst = np.ascontiguousarray(np.maximum(test, 0), dtype=np.float32)
    err, mean, params = flip.evaluate(ref, tst, "HDR", applyMagma=False)
    return np.asarray(err, dtype=np.float32)[..., 0], float(mean), dict(params)


def _slug(label: str, taken: set[str]) -> str:
    """A file name for ``label``: letters, digits, ``.-_``; unique among ``taken``."""
    base = re.sub(r"[^A-Za-z0-9._-]+", "_", label).strip("._") or "method"
    name, i = base, 1
    while name.lower() in taken:
        i += 1
        name = f"{base}_{i}"
    taken.add(name.lower())
    return name


def _check_renderer(size: int, spp: int, renders: int) -> None:
    """Set up Mitsuba; refuse a scalar-variant run estimated over a minute."""
    from ..rendering.mitsuba import setup
    from ..rendering.render import scalar_seconds

    variant = setup("auto", quiet=False)
    seconds = scalar_seconds((size, size), spp, renders)
    if variant.startswith("scalar") and seconds > 60:
        raise BTFInputError(
            f"Mitsuba runs its scalar fallback here (no usable libLLVM >= 17); {renders} renders "
            f"of {size}x{size} at {spp} spp would take about {seconds / 60:.0f} min: install "
            "libLLVM ('apt-get install libllvm19') or lower image_size/spp"
        )


def _render(btf: BTF, what: str, opts: dict[str, Any], progress: bool | None) -> np.ndarray:
    """One render of ``btf`` (decoded into memory) with the dense plugin; its tables are
    removed from the plugins' registry afterwards."""
    from ..rendering.mitsuba import add_material, remove_material
    from ..rendering.render import render_material

    table = dense_copy(btf, what, progress)
    gib = table.n_values * 4 / 2**30
    add_material(table, _KEY)
    try:
        # max_gib: the texel cap bounds the table; the plugin's 2 GiB default would refuse a
        # 100 x 100 UBO2014 material (2.6 GiB)
        res = render_material({**_PLUGIN, "key": _KEY, "max_gib": max(2.0, 1.01 * gib)},
                              progress=progress, **opts)  # fmt: skip
    finally:
        remove_material(_KEY)
    return res.image


def render_methods(
    reference: BTF,
    reconstructions: Mapping[str, BTF],
    out_dir: Path,
    *,
    spp: int = 16,
    image_size: int = 128,
    seed: int = 0,
    progress: bool | None = None,
) -> dict:
    """Figure 8 for every method: render ``reference`` and each reconstruction the same way
    (module docstring), compare, and write ``out_dir/figure8.png``.

    ``reconstructions``: {label: BTF} of the reference's shape and directions. Returns
    {label: {"image_mse", "image_mse_display", "flip", "png"}} — the MSE of the linear
    (H, W, 3) renders, the MSE of the display-mapped renders, the mean HDR-ꟻLIP and the
    name of that method's display-mapped PNG in ``out_dir``.
    """
    for label, rec in reconstructions.items():
        if rec.shape != reference.shape:
            raise BTFInputError(f"{label}: shape {rec.shape}, the reference {reference.label} "
                                f"has {reference.shape}")  # fmt: skip
        if not (reference.lights.equals(rec.lights) and reference.views.equals(rec.views)):
            raise BTFInputError(f"{label}: its direction tables differ from the reference's")
    if spp < 1 or image_size < 1:
        raise BTFInputError(f"spp and image_size must be >= 1, got {spp} and {image_size}")
    for what, btf in (("reference", reference), *reconstructions.items()):
        if btf.height > MAX_TEXELS or btf.width > MAX_TEXELS:
            dense_copy(btf, what)  # raises its one line before any render starts
    _check_renderer(image_size, spp, 1 + len(reconstructions))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    opts = {"scene": SCENE, "size": (image_size, image_size), "spp": int(spp), "seed": int(seed)}
    ref_img = _render(reference, "reference", opts, progress)
    ref_shown = display_values(ref_img)
    taken = {"figure8", "renders", "reference"}
    results: dict[str, dict] = {}
    images, maps = {}, {}
    for label, rec in reconstructions.items():
        img = _render(rec, label, opts, progress)
        err, mean_flip, _ = flip_hdr(ref_img, img)
        png = out / f"{_slug(label, taken)}.png"
        _save_png(png, display_values(img))
        results[label] = {
            "image_mse": float(np.mean(np.square(img.astype(np.float64) - ref_img))),
            "image_mse_display": float(np.mean(np.square(
                display_values(img).astype(np.float64) - ref_shown))),
            "flip": mean_flip,
            "png": png.name,  # in out_dir: a results.json copied elsewhere names no folder
        }  # fmt: skip
        images[label], maps[label] = img, err
    _save_png(out / "reference.png", ref_shown)
    with atomic_output(out / "renders.npz") as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, reference=ref_img, **{
            Path(r["png"]).stem: images[k] for k, r in results.items()})  # fmt: skip
    _figure(out / "figure8.png", ref_img, images, maps, results, opts)
    return results


def _save_png(path: Path, shown: np.ndarray) -> None:
    from ..figures import save_png

    save_png(path, shown)


def _figure(path: Path, ref_img: np.ndarray, images: dict, maps: dict, results: dict,
            opts: dict) -> None:  # fmt: skip
    """[reference | method …] as displayed, and under each method its ꟻLIP map (magma, 0–1)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    from ..figures import save_figure

    n = 1 + len(images)
    fig, axes = plt.subplots(2, n, figsize=(2.2 * n + 0.6, 4.9), squeeze=False)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    axes[0, 0].imshow(display_values(ref_img), interpolation="nearest")
    axes[0, 0].set_title("reference", fontsize=8)
    axes[1, 0].axis("off")
    axes[1, 0].text(0.0, 0.5, f"{opts['scene']}, {opts['size'][0]}x{opts['size'][1]},\n"
                              f"{opts['spp']} spp, seed {opts['seed']}\n(same for all)\n\n"
                              "top: clip(1.3 x^(1/1.8), 0, 1)\nbottom: HDR-FLIP vs the\n"
                              "reference", fontsize=7, va="center")  # fmt: skip
    for j, (label, img) in enumerate(images.items(), start=1):
        r = results[label]
        axes[0, j].imshow(display_values(img), interpolation="nearest")
        axes[0, j].set_title(f"{label}\nMSE {r['image_mse']:.3g} (display "
                             f"{r['image_mse_display']:.3g})", fontsize=7)  # fmt: skip
        axes[1, j].imshow(maps[label], cmap="magma", vmin=0.0, vmax=1.0, interpolation="nearest")
        axes[1, j].set_title(f"HDR-FLIP, mean {r['flip']:.4f}", fontsize=7)
    if images:
        bar = fig.colorbar(ScalarMappable(Normalize(0.0, 1.0), cmap="magma"), ax=axes[1, -1],
                           fraction=0.046, pad=0.03)  # fmt: skip
        bar.set_label("HDR-FLIP error", fontsize=6)
        bar.ax.tick_params(labelsize=5)
    save_figure(fig, path, dpi=100)
