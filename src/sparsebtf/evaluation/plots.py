"""The plots of a ``bench quality`` run: Figure 3 and quality against storage."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from ..figures import save_figure
from .rows import levels as _levels
from .rows import materials as _materials
from .rows import rows as _rows
from .tables import gmean as _gmean
from .tables import label_with_matching, method_matchings

__all__ = ["figure3", "quality_storage", "tree_figure"]


def figure3(result: dict[str, Any], path: Path) -> Path:
    """log10 MSE vs coefficients per data point, one line per test material (Figure 3)."""
    fig, ax = plt.subplots(figsize=(7, 4.5))
    mats = _materials(result, "test")
    cmap = plt.get_cmap("tab20")
    for i, m in enumerate(mats):
        rs = sorted(_rows(result, material=m, method="sparsebtf", set="test"),
                    key=lambda r: r["coefficients_per_point"])
        ax.plot([r["coefficients_per_point"] for r in rs],
                [np.log10(r["mse_rgb"]) for r in rs], marker="o", ms=3,
                color=cmap(i % 20), label=m)
    ax.set_xscale("log", base=2)
    ax.set_xlabel("coefficients per data point (tau_Y + tau_U + tau_V)")
    ax.set_ylabel("log10 MSE (linear RGB)")
    ax.set_title(f"SparseBTF: error vs sparsity, {len(mats)} unseen materials (cf. Figure 3)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=6, ncol=2, loc="upper right")
    return save_figure(fig, path, dpi=110)


def quality_storage(result: dict[str, Any], path: Path) -> Path:
    """Geometric-mean MSE vs bytes per texel, one line per method and material set."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), squeeze=False)
    for ax, which, title in ((axes[0, 0], "test", "test materials"),
                             (axes[0, 1], "table5", "Table-5 materials (vs PCA)")):
        for m, matching in method_matchings(result, (which,)):
            pts = []
            for lv in _levels(result):
                rs = [r for r in _rows(result, method=m, level=lv, set=which)
                      if r.get("budget_factor", 1) in (1, 2) and r["mse_rgb"] is not None
                      and r.get("matching", "") == matching]  # fmt: skip
                for f in sorted({r.get("budget_factor", 1) for r in rs}):
                    sub = [r for r in rs if r.get("budget_factor", 1) == f]
                    b = np.mean([r["material_bytes"] / np.prod(r["size"]) for r in sub])
                    pts.append((b, _gmean([r["mse_rgb"] for r in sub])))
            if pts:
                pts.sort()
                ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o",
                        label=label_with_matching(result, m, matching))
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("bytes per texel (per material, Table 4 accounting)")
        ax.set_ylabel("MSE, linear RGB (geo. mean)")
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    return save_figure(fig, path, dpi=110)



def learning_curve_rows(result: dict[str, Any], n_materials: int = 2
                        ) -> dict[str, dict[str, dict[int, list[list[float]]]]]:  # fmt: skip
    """The held-out loss curves of the run's trained methods: method → material → latent size
    (or NeuMIP's channels) → [[queries per texel, held-out loss], ...], for the first
    ``n_materials`` test materials that have curves; {} when no row carries one."""
    out: dict[str, dict[str, dict[int, list[list[float]]]]] = {}
    mats = [m for m in _materials(result, "test")
            if any(r.get("loss_curve") for r in _rows(result, material=m, set="test"))]
    for mat in mats[:n_materials]:
        for r in _rows(result, material=mat, set="test"):
            # a fine-tuned coding's own training is its fine-tuning (the shared curve is
            # its base method's)
            curve = (r.get("finetune") or {}).get("loss_curve") or r.get("loss_curve")
            size = r.get("latent_size", r.get("channels"))
            if curve and size:
                out.setdefault(r["method"], {}).setdefault(mat, {}).setdefault(int(size), curve)
    return out


def learning_curves(result: dict[str, Any], path: Path) -> Path | None:
    """Held-out loss vs training queries per texel, one panel per trained method and material
    (two materials), one line per latent size (NeuMIP: channels C; a fine-tuned method: its
    fine-tuning); a marker where the training stopped, hollow
    when it stopped at its cap before converging. None (nothing written) without curves."""
    data = learning_curve_rows(result)
    if not data:
        return None
    methods = list(data)
    mats = sorted({m for d in data.values() for m in d})
    fig, axes = plt.subplots(len(methods), len(mats), figsize=(5.2 * len(mats),
                             3.4 * len(methods)), squeeze=False)  # fmt: skip
    converged = {(r["method"], r["material"], int(r.get("latent_size", r.get("channels", 0)))):
                 (r.get("finetune") or r).get("converged") for r in result["rows"]
                 if r.get("loss_curve")}  # fmt: skip
    symbol = {r["method"]: "C" if "channels" in r else "L" for r in result["rows"]}
    for i, m in enumerate(methods):
        for j, mat in enumerate(mats):
            ax = axes[i, j]
            for size, curve in sorted(data[m].get(mat, {}).items()):
                q = [p[0] for p in curve]
                loss = [p[1] for p in curve]
                (line,) = ax.plot(q, loss, label=f"{symbol.get(m, 'L')} = {size}")
                done = converged.get((m, mat, size))
                ax.plot(q[-1:], loss[-1:], marker="o", color=line.get_color(),
                        fillstyle="full" if done else "none")  # fmt: skip
            ax.set_xscale("symlog", linthresh=100)
            ax.set_yscale("log")
            ax.set_xlabel("training queries per texel")
            ax.set_ylabel("held-out loss (log space)")
            ax.set_title(f"{result.get('methods', {}).get(m, m)}: {mat}")
            ax.grid(True, which="both", alpha=0.3)
            if ax.lines:
                ax.legend(fontsize=7)
    return save_figure(fig, path, dpi=110)


#: border colour of each node size in :func:`tree_figure`, largest size first
TREE_COLOURS = ("tab:cyan", "tab:orange", "tab:red", "tab:green")


def tree_figure(texture: np.ndarray, nodes: np.ndarray, sizes: tuple[int, ...], path: Path,
                title: str) -> Path:  # fmt: skip
    """An adaptive material's tree over its texture: ``texture`` (H, W, 3) display values in
    [0, 1], ``nodes`` (N, 3) rows (row, col, size) in texels, each node's border coloured by
    its size (:data:`TREE_COLOURS`, in the order of ``sizes``, largest first)."""
    from matplotlib.patches import Patch, Rectangle

    h, w = texture.shape[:2]
    fig, ax = plt.subplots(figsize=(4.6, 4.6 * h / w + 0.6))
    ax.imshow(np.clip(texture, 0, 1), interpolation="nearest")
    colour = {int(s): TREE_COLOURS[i % len(TREE_COLOURS)] for i, s in enumerate(sizes)}
    # smallest first, so the larger nodes' borders are drawn over the finer ones
    for r, c, s in sorted((tuple(map(int, n)) for n in nodes), key=lambda n: n[2]):
        ax.add_patch(Rectangle((c - 0.5, r - 0.5), s, s, fill=False, lw=1.6,
                               edgecolor=colour[s]))  # fmt: skip
    counts = {s: int((np.asarray(nodes)[:, 2] == s).sum()) for s in colour}
    ax.legend(handles=[Patch(facecolor="none", edgecolor=colour[s],
                             label=f"{s}x{s}: {counts[s]} nodes") for s in colour],
              loc="upper center", bbox_to_anchor=(0.5, -0.02), ncol=len(colour), fontsize=7,
              frameon=False)  # fmt: skip
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(title, fontsize=8)
    return save_figure(fig, path, dpi=110)
