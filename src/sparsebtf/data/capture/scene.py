"""What a capture renders: a built-in sample, a Mitsuba XML file or a Python file, loaded as a
Mitsuba scene and repeated around the central tile.

A scene describes one period of the sample on the tile x, y ∈ [−1, 1] around z = 0
(:mod:`.geometry`): its shapes and their BSDFs. Sensors, emitters and integrators in a scene
file are ignored (the capture brings its own camera and lights). A Python file defines
``scene(seed)`` returning a ``mi.load_dict`` dictionary (or defines a dictionary ``scene``);
it runs with the Mitsuba variant already set, so it may ``import mitsuba as mi`` and build
meshes or bitmaps. The shapes are gathered into a ``shapegroup`` and instanced on a
(2k+1)² grid of period 2 (:func:`.geometry.ring_count`), so grazing rays and shadows at the
tile's edges see the neighbouring relief, never a void.
"""

from __future__ import annotations

import hashlib
import runpy
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ...errors import BTFInputError
from .geometry import PERIOD, ring_count

__all__ = ["SampleScene", "SceneSource", "load_sample", "resolve_source"]

#: Relief above the tallest point at which camera rays start (tile units).
_CLEARANCE = 1e-3


@dataclass(frozen=True)
class SceneSource:
    """Where a sample comes from: ``kind`` "builtin" (``name``), "xml" or "python" (``path``)."""

    kind: str
    name: str
    path: str | None = None

    def digest(self) -> str:
        """SHA-256 (16 hex digits) of the scene file's bytes; the name for a built-in."""
        if self.path is None:
            return self.name
        return hashlib.sha256(Path(self.path).read_bytes()).hexdigest()[:16]


def resolve_source(text: str) -> SceneSource:
    """A :class:`SceneSource` from a built-in sample name or a ``.xml`` / ``.py`` file path."""
    from .samples import SAMPLES

    key = text.strip().lower()
    if key in SAMPLES:
        return SceneSource("builtin", key)
    p = Path(text)
    suffix = p.suffix.lower()
    if suffix not in (".xml", ".py"):
        raise BTFInputError(
            f"scene {text!r}: not a built-in sample ({', '.join(SAMPLES)}) nor a Mitsuba scene "
            "file (.xml, or .py defining scene(seed))"
        )
    if not p.is_file():
        raise BTFInputError(f"scene {text}: no such file")
    return SceneSource("xml" if suffix == ".xml" else "python", p.stem, str(p.resolve()))


@dataclass
class SampleScene:
    """A loaded sample: the tiled Mitsuba ``scene``, the relief's z range and the rings."""

    scene: Any
    z_min: float
    z_max: float
    rings: int

    @property
    def z_top(self) -> float:
        """Where camera rays start: just above the tallest relief."""
        return self.z_max + _CLEARANCE * max(1.0, self.z_max - self.z_min)


def _one_line(e: BaseException) -> str:
    lines = [ln.strip() for ln in str(e).strip().splitlines() if ln.strip()]
    text = lines[-1] if lines else type(e).__name__
    return text if len(text) < 300 else text[:297] + "..."


def _python_scene(path: str, seed: int) -> dict[str, Any]:
    try:
        ns = runpy.run_path(path)
    except Exception as e:
        raise BTFInputError(f"{path}: running the scene file failed: {type(e).__name__}: "
                            f"{_one_line(e)}") from None  # fmt: skip
    entry = ns.get("scene")
    if callable(entry):
        try:
            entry = entry(seed)
        except Exception as e:
            raise BTFInputError(f"{path}: scene({seed}) failed: {type(e).__name__}: "
                                f"{_one_line(e)}") from None  # fmt: skip
    if not isinstance(entry, dict):
        raise BTFInputError(
            f"{path}: expected a function scene(seed) returning a Mitsuba scene dict (or a dict "
            f"named scene), found {type(entry).__name__}"
        )
    return entry


def _base_scene(source: SceneSource, seed: int) -> Any:
    """The untiled Mitsuba scene of ``source`` (the variant must be set)."""
    import mitsuba as mi

    from .samples import SAMPLES

    where = source.path or f"built-in sample {source.name!r}"
    try:
        if source.kind == "builtin":
            return mi.load_dict(SAMPLES[source.name].build(seed))
        if source.kind == "xml":
            return mi.load_file(source.path)
        d = _python_scene(source.path, seed)  # type: ignore[arg-type]
        d = dict(d)
        d.setdefault("type", "scene")
        return mi.load_dict(d)
    except BTFInputError:
        raise
    except Exception as e:
        raise BTFInputError(f"{where}: Mitsuba could not load the scene: {_one_line(e)}") from None


def _bounds(base: Any, where: str) -> tuple[float, float, float]:
    """(z_min, z_max, overhang beyond the tile) of the scene's shapes, checked."""
    shapes = list(base.shapes())
    if not shapes:
        raise BTFInputError(f"{where}: the scene has no shapes")
    if any(type(s).__name__ in ("Instance", "ShapeGroup") for s in shapes):
        raise BTFInputError(f"{where}: instances are not supported inside a captured sample "
                            "(it is instanced itself); give the shapes directly")  # fmt: skip
    box = base.bbox()
    lo = [float(v) for v in box.min]
    hi = [float(v) for v in box.max]
    if not all(map(_finite, lo + hi)):
        raise BTFInputError(f"{where}: the scene's bounding box is not finite ({lo}, {hi})")
    overhang = max(hi[0] - 1.0, -1.0 - lo[0], hi[1] - 1.0, -1.0 - lo[1], 0.0)
    if overhang > 1.0:
        raise BTFInputError(
            f"{where}: shapes reach x, y = [{lo[0]:.3g}, {hi[0]:.3g}] x [{lo[1]:.3g}, "
            f"{hi[1]:.3g}], more than half a tile beyond [-1, 1]: describe one period of the "
            "sample in the tile x, y in [-1, 1] (it repeats with period 2)"
        )
    return lo[2], hi[2], overhang


def _finite(v: float) -> bool:
    return v == v and abs(v) != float("inf")


def load_sample(source: SceneSource, seed: int, tan_view: float, tan_light: float) -> SampleScene:
    """Load ``source`` and repeat it on the grid of copies the directions need."""
    import mitsuba as mi

    where = source.path or f"built-in sample {source.name!r}"
    base = _base_scene(source, seed)
    z_min, z_max, overhang = _bounds(base, where)
    rings = ring_count(z_max - z_min, overhang, tan_view, tan_light)
    group: dict[str, Any] = {"type": "shapegroup"}
    for i, shape in enumerate(base.shapes()):
        group[f"shape{i}"] = shape
    tiled: dict[str, Any] = {"type": "scene", "sample": group}
    for i in range(-rings, rings + 1):
        for j in range(-rings, rings + 1):
            tiled[f"copy_{i + rings}_{j + rings}"] = {
                "type": "instance",
                "shapegroup": {"type": "ref", "id": "sample"},
                "to_world": mi.ScalarTransform4f().translate([PERIOD * i, PERIOD * j, 0.0]),
            }
    try:
        scene = mi.load_dict(tiled)
    except Exception as e:
        raise BTFInputError(f"{where}: Mitsuba could not tile the scene: {_one_line(e)}") from None
    return SampleScene(scene, z_min, z_max, rings)
