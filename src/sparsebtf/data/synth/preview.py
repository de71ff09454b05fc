"""Contact sheets: a grid of tone-mapped angular images of any BTF, written as a PNG.

Rows are view directions, columns light directions, each cell labelled with its θ/φ in
degrees. Tone mapping follows the paper's display operator a·I^(1/γ) (a = 1.3, γ = 1.8),
clipped to [0, 1].
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..._atomic import atomic_output
from ...display import tone_map
from ...errors import BTFInputError
from ..btf import BTF
from ..directions import DirectionSet

__all__ = ["DEFAULT_LIGHT_TARGETS", "DEFAULT_VIEW_TARGETS", "contact_sheet", "tone_map"]

#: (θ, φ) in degrees of the directions shown by default; the nearest sampled ones are used.
DEFAULT_VIEW_TARGETS = ((0.0, 0.0), (30.0, 0.0), (60.0, 0.0), (75.0, 90.0))
DEFAULT_LIGHT_TARGETS = ((0.0, 0.0), (30.0, 180.0), (60.0, 0.0), (60.0, 90.0), (75.0, 180.0))


def _nearest(dirs: DirectionSet, targets: Sequence[tuple[float, float]]) -> list[int]:
    th = np.radians([t[0] for t in targets])
    ph = np.radians([t[1] for t in targets])
    q = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=1)
    idx, _ = dirs.nearest(q, k=1)
    out: list[int] = []
    for i in idx[:, 0].tolist():
        if i not in out:
            out.append(int(i))
    return out


def _indices(given: Sequence[int] | None, dirs: DirectionSet, default: tuple, what: str) -> list:
    if given is None:
        return _nearest(dirs, default)
    out = [int(i) for i in given]
    if not out:
        raise BTFInputError(f"contact sheet needs at least one {what} index")
    bad = [i for i in out if not 0 <= i < len(dirs)]
    if bad:
        raise BTFInputError(f"{what} index {bad[0]} is out of range [0, {len(dirs)})")
    return out


def _label(dirs: DirectionSet, i: int, prefix: str) -> str:
    return f"{prefix}{i}: θ={np.degrees(dirs.theta[i]):.0f}° φ={np.degrees(dirs.phi[i]):.0f}°"


def contact_sheet(
    btf: BTF,
    path: str | os.PathLike[str],
    lights: Sequence[int] | None = None,
    views: Sequence[int] | None = None,
    *,
    title: str | None = None,
    cell_inches: float = 1.9,
    dpi: int = 100,
) -> Path:
    """Write a PNG grid of tone-mapped angular images of ``btf`` and return its path.

    ``lights`` / ``views`` are index lists into ``btf.lights`` / ``btf.views``; by default a
    few directions spread over the hemisphere (normal to grazing). Works for any :class:`BTF`
    through :meth:`BTF.angular_image`. The file is written atomically.
    """
    if not isinstance(btf, BTF):
        raise BTFInputError(f"contact_sheet needs a BTF, got {type(btf).__name__}")
    li = _indices(lights, btf.lights, DEFAULT_LIGHT_TARGETS, "light")
    vi = _indices(views, btf.views, DEFAULT_VIEW_TARGETS, "view")

    # A bare Figure renders with Agg and never touches pyplot's global backend state.
    from matplotlib.figure import Figure

    fig = Figure(figsize=(cell_inches * len(li), cell_inches * len(vi) + 0.5), dpi=dpi)
    axes = fig.subplots(len(vi), len(li), squeeze=False)
    for r, v in enumerate(vi):
        for c, lt in enumerate(li):
            ax = axes[r, c]
            ax.imshow(tone_map(btf.angular_image(lt, v)), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(_label(btf.lights, lt, "light "), fontsize=7)
            if c == 0:
                ax.set_ylabel(_label(btf.views, v, "view "), fontsize=7)
    fig.suptitle(title or btf.name, fontsize=9)
    fig.tight_layout()
    target = Path(path)
    with atomic_output(target) as tmp:
        with open(tmp, "wb") as fh:
            fig.savefig(fh, format="png")
    return target
