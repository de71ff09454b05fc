"""BTFs from geometry: a virtual gonioreflectometer on Mitsuba 3 (``sparsebtf capture``).

For every (light, view) pair of a direction set, a material sample — a built-in one
(:data:`SAMPLES`) or any Mitsuba scene describing one period of it on the tile
x, y ∈ [−1, 1] around z = 0 — is lit by a distant directional light and seen by a
**rectified** orthographic camera: texel (x, y) is the same spot of the sample in every view,
as in UBO2014's rectified images. The sample repeats with period 2, so grazing rays and
shadows at the edges see the neighbouring relief. Values are π·(reflected radiance) per unit
irradiance: a Lambertian plane of albedo ρ gives ρ·cos θ_l in every view, the convention of
our synthetic materials and UBO2014 (``docs/format.md``).

Modules: :mod:`.geometry` (tile, texels, rectified view, copies needed), :mod:`.scene`
(loading and tiling scenes), :mod:`.samples` (the built-in samples), :mod:`.render` (one view,
all lights, one wavefront pass), :mod:`.writer` (streaming into the dense file, resume).

>>> from sparsebtf.data.capture import capture            # doctest: +SKIP
>>> capture("plane", "plane.h5", size=8, directions="tiny13", spp=16)   # doctest: +SKIP
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import BTFInputError
from ..directions import DirectionSet
from .samples import SAMPLES, Sample
from .writer import CAPTURE_VERSION, CaptureSpec, partial_path, write_capture

__all__ = [
    "CAPTURE_VERSION", "SAMPLES", "CaptureSpec", "Sample", "cached_capture", "capture",
    "capture_spec", "partial_path",
]  # fmt: skip

#: Largest capture side in texels.
MAX_SIZE = 8192


def _whole(name: str, value: object, lo: int, hi: int | None, unit: str) -> None:
    """One line unless ``value`` is an integer in [lo, hi] (no upper end: hi None)."""
    ok = not isinstance(value, bool) and isinstance(value, int | np.integer)
    ok = ok and lo <= int(value) and (hi is None or int(value) <= hi)  # type: ignore[arg-type]
    if not ok:
        span = f"[{lo}, {hi}]" if hi is not None else f">= {lo}"
        raise BTFInputError(f"{name} must be an integer {span}{' ' + unit if unit else ''}, "
                            f"got {value!r}")  # fmt: skip


def capture_spec(
    scene: str,
    size: int = 64,
    directions: str | DirectionSet = "ubo2014",
    *,
    spp: int = 16,
    seed: int = 0,
    max_depth: int = 3,
    crop: tuple[slice, slice] | None = None,
    backend: str = "auto",
    noise_seed: int | None = None,
) -> CaptureSpec:
    """A checked :class:`CaptureSpec` (errors are one line naming the option)."""
    from ..crop import crop_window
    from ..synth.materials import resolve_directions
    from .scene import resolve_source

    resolve_source(scene)
    _whole("size", size, 1, MAX_SIZE, "texels per side")
    _whole("spp", spp, 1, None, "paths per texel")
    _whole("max_depth", max_depth, 2, None, "path segments (2: direct light only)")
    _whole("seed", seed, 0, 2**32 - 1, "")
    if noise_seed is not None:
        _whole("noise_seed", noise_seed, 0, 2**32 - 1, "")
    dirs = resolve_directions(directions)
    if np.any(dirs.xyz[:, 2] <= 1e-6):
        raise BTFInputError(f"directions {dirs.name}: every direction must lie above the "
                            "horizon (z > 0) for a capture")  # fmt: skip
    rows, cols = crop if crop is not None else (slice(0, size), slice(0, size))
    window = [crop_window(s, size, axis, f"capture of {scene} ({size}x{size} texels)")
              for axis, s in (("rows", rows), ("cols", cols))]  # fmt: skip
    return CaptureSpec(
        scene=scene, size=int(size), rows=window[0], cols=window[1], spp=int(spp),
        max_depth=int(max_depth), seed=int(seed), directions_name=dirs.name,
        directions=tuple(tuple(float(c) for c in v) for v in dirs.xyz), backend=backend,
        noise_seed=None if noise_seed is None or noise_seed == seed else int(noise_seed),
    )  # fmt: skip


def capture(
    scene: str,
    output: str | os.PathLike[str],
    size: int = 64,
    directions: str | DirectionSet = "ubo2014",
    *,
    spp: int = 16,
    seed: int = 0,
    max_depth: int = 3,
    crop: tuple[slice, slice] | None = None,
    noise_seed: int | None = None,
    dtype: str = "float32",
    resume: bool = False,
    backend: str = "auto",
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool | None = None,
) -> Path:
    """Render a BTF of ``scene`` into the dense file ``output``; the path.

    ``size`` texels per side over the tile (``crop`` = (rows, cols) slices renders a window
    of them), ``spp`` camera paths per texel, ``max_depth`` path segments (3: one bounce of
    inter-reflection), ``seed`` the sample's geometry and the Monte Carlo noise, ``noise_seed``
    the noise alone (a twin of a capture: the same sample, independent noise, whose difference
    measures the capture's noise). Views run in this process, on a local Dask cluster of
    ``workers`` processes or on ``scheduler``'s.
    """
    from ...execution import executor

    spec = capture_spec(scene, size, directions, spp=spp, seed=seed, max_depth=max_depth,
                        crop=crop, backend=backend, noise_seed=noise_seed)  # fmt: skip
    stem = Path(scene).stem if scene.lower().endswith((".xml", ".py")) else scene.lower()
    name = f"capture-{stem}-{spec.shape[0]}x{spec.shape[1]}-s{seed}"
    if spec.noise_seed is not None:
        name += f"-n{spec.noise_seed}"
    attrs: dict[str, Any] = {"scene": scene}
    with executor(workers=workers, scheduler=scheduler) as ex:
        return write_capture(output, spec, dtype=dtype, resume=resume, executor=ex,
                             progress=progress, name=name, attrs=attrs)  # fmt: skip


def cached_capture(
    scene: str,
    size: int,
    directions: str | DirectionSet = "ubo2014",
    seed: int = 0,
    spp: int = 4,
    cache_dir: str | os.PathLike[str] | None = None,
) -> Any:
    """A captured built-in sample as a :class:`~sparsebtf.data.dense_file.DenseFileBTF`,
    rendered once into the synthetic-material cache (``$SPARSEBTF_CACHE``) and reused; the
    file name holds everything that decides its values (and :data:`CAPTURE_VERSION`); an
    interrupted capture there is continued."""
    from ..cache import announce_write, enforce_cap, mark_used, resolve_cache_dir
    from ..dense_file import DenseFileBTF, dense_file_bytes

    spec = capture_spec(scene, size, directions, spp=spp, seed=seed)
    key = spec.key(scene)
    digest = __import__("hashlib").sha256(repr(sorted(key.items())).encode()).hexdigest()[:12]
    path = resolve_cache_dir(cache_dir) / f"capture-{scene}-{size}-s{seed}-{digest}.h5"
    if path.exists():
        mark_used(path)
        return DenseFileBTF(path)
    announce_write(path, dense_file_bytes(spec.shape, "float32"))
    path.parent.mkdir(parents=True, exist_ok=True)
    # the cache is the library's own: a capture a kill interrupted there is continued (its
    # key was checked when it was begun, and is again)
    from .writer import partial_path

    capture(scene, path, size, directions, spp=spp, seed=seed,
            resume=partial_path(path).exists())  # fmt: skip
    enforce_cap(path)
    return DenseFileBTF(path)
