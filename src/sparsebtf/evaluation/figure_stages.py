"""The quality benchmark's figures: the image grids of Figures 4 and 5, and on the first
test material Figure 8's renders and Table 1's decode speed (stages of :mod:`.runner`).
"""

from __future__ import annotations

import time

import numpy as np

from ..data.btf import BTF
from ..figures import comparison_grid
from .benchmark_set import reference_level
from .methods import PAPER

#: the methods of the Figure 5 image (reference, SparseBTF(32) and these at 32) when present
FIGURE5 = ("rgjw20",)


def _figure_pairs(btf: BTF) -> list[tuple[int, int]]:
    """The paper's Figure 4/5 configurations snapped to the nearest sampled directions."""

    def d(theta: float, phi: float) -> np.ndarray:
        t, p = np.radians(theta), np.radians(phi)
        return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])

    wanted = [((23.5, 270.0), (11.0, 15.0)), ((45.0, 0.0), (60.0, 15.0))]
    return [
        (int(btf.lights.nearest(d(*lt))[0][0]), int(btf.views.nearest(d(*vw))[0][0]))
        for lt, vw in wanted
    ]


def _view_at(views: dict[tuple[int, str], BTF], level: int) -> BTF | None:
    """A method's reconstruction at ``level`` from its views by (level, matching): the
    reference's (matching ""), else the paper's matching where the method was coded under it,
    else any other; None when it has none at that level."""
    for key in ((level, ""), (level, PAPER)):
        if key in views:
            return views[key]
    return next((v for (lv, _), v in views.items() if lv == level), None)


class _FigureStages:
    """The figure stages of :class:`~.runner._QualityRun`, which holds their state
    (``cfg``, ``seed``, ``say``, ``progress``, the methods, ``out``, ``grids``)."""

    def grid(self, btf: BTF, recs: dict[str, BTF], name: str) -> None:
        t0 = time.perf_counter()
        path = comparison_grid(btf, recs, _figure_pairs(btf), self.out / name)
        self.grids.append(path.name)
        self.stage("figures", t0)

    def figure5_grid(self, label: str, btf: BTF, views: dict) -> str | None:
        """Figure 5's image: the reference, SparseBTF(32) and RGJW20(32) (the paper's
        matching where coded under it), when RGJW20 is in the run."""
        lv = reference_level(self.cfg.levels)
        recs = {f"{self.ref.label}({lv})": views[self.ref.name][(lv, "")]}
        for m in self.others:
            if m.name in FIGURE5 and m.name in views:
                v = _view_at(views[m.name], lv)
                if v is not None:
                    recs[f"{m.label}({lv})"] = v
        if len(recs) < 2:
            return None
        self.grid(btf, recs, f"figure5_{label}.png")
        return self.grids[-1]

    def renders_and_speed(self, label: str, btf: BTF, views: dict) -> None:
        """Figure 8 (each method's reconstruction at the reference level rendered beside the
        reference, :func:`~.renders.render_methods`) and Table 1's single-value decode speed
        (:func:`~.speed.decode_speed`), on the first test material."""
        cfg = self.cfg
        lv = reference_level(cfg.levels)
        recs: dict[str, BTF] = {}
        for m in self.methods:
            v = _view_at(views.get(m.name, {}), lv)
            if v is not None:
                recs[f"{m.label}({lv})"] = v
        if cfg.speed_seconds > 0:
            from .speed import decode_speed

            t0 = time.perf_counter()
            self.say(f"{label}: single-value decode speed of {len(recs)} methods")
            self.speed = {"material": label, "level": lv, "methods": decode_speed(
                recs, batch=cfg.speed_batch, seconds=cfg.speed_seconds, seed=self.seed)}
            self.stage("decode_speed", t0)
        if cfg.render_spp > 0:
            from .renders import render_methods

            t0 = time.perf_counter()
            self.say(f"{label}: Figure 8, {len(recs)} methods rendered at {cfg.render_spp} spp")
            res = render_methods(btf, recs, self.out / "figure8", spp=cfg.render_spp,
                                 image_size=cfg.render_size, seed=self.seed,
                                 progress=self.progress)
            self.figure8 = {"material": label, "level": lv, "spp": cfg.render_spp,
                            "image_size": cfg.render_size, "methods": res}
            self.stage("figure8", t0)
