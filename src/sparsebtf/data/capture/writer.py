"""Streaming a capture into our dense BTF file: view by view, resumable, atomic at the end.

The file is written as ``OUT.partial`` beside the output: the dense layout of
:mod:`sparsebtf.data.dense_file` (header, direction tables, the chunked ``/btf``) plus two
root attributes, ``capture_json`` (everything that decides the values: :meth:`CaptureSpec.key`)
and ``capture_done`` (one flag per view). Each rendered view is written and flagged at once,
so memory holds one view block (H·W·L·3 values), and an interrupted capture keeps its finished
views: ``resume=True`` checks that the partial file was made by the same capture and renders
only the views not flagged. Every view's Monte Carlo noise depends only on (noise seed, view),
so a resumed capture writes the values an uninterrupted one writes. When the last view is in, the
two attributes are removed and the file is renamed to the output.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from ...errors import BTFInputError, OutputError
from ..dense_file import DEFAULT_CHUNK, write_header
from ..directions import DirectionSet, from_vectors
from .geometry import grazing_tan

__all__ = ["CAPTURE_VERSION", "CaptureSpec", "partial_path", "render_block", "write_capture"]

#: Bump whenever a change alters captured values: it is part of every capture's key.
CAPTURE_VERSION = "1"
_CHUNK = DEFAULT_CHUNK


@dataclass(frozen=True)
class CaptureSpec:
    """Everything that decides a capture's values (picklable: Dask tasks carry it).

    ``scene`` is a built-in sample name or a scene file path; ``rows``/``cols`` the texel
    window ``(start, stop)`` of the ``size``×``size`` grid; ``directions`` the (n, 3) unit
    vectors used as lights and as views, named ``directions_name``; ``noise_seed`` the seed of
    the Monte Carlo paths when it is not ``seed`` (None: ``seed`` seeds both).
    """

    scene: str
    size: int
    rows: tuple[int, int]
    cols: tuple[int, int]
    spp: int
    max_depth: int
    seed: int
    directions_name: str
    directions: tuple[tuple[float, float, float], ...] = field(repr=False)
    backend: str = "auto"
    noise_seed: int | None = None

    @property
    def paths_seed(self) -> int:
        """The seed of the Monte Carlo paths."""
        return self.seed if self.noise_seed is None else self.noise_seed

    @property
    def direction_set(self) -> DirectionSet:
        return from_vectors(np.asarray(self.directions, dtype=np.float64),
                            name=self.directions_name)  # fmt: skip

    @property
    def shape(self) -> tuple[int, int, int, int, int]:
        n = len(self.directions)
        return (self.rows[1] - self.rows[0], self.cols[1] - self.cols[0], n, n, 3)

    def key(self, scene_digest: str) -> dict[str, Any]:
        """The JSON fingerprint a resumed capture must match."""
        d = asdict(self)
        d.pop("backend")
        if d["noise_seed"] is None:  # the keys of captures made before the option stay valid
            d.pop("noise_seed")
        d["directions"] = _digest(np.asarray(self.directions, dtype=np.float64))
        d["scene_digest"] = scene_digest
        d["capture_version"] = CAPTURE_VERSION
        return json.loads(json.dumps(d))  # as a file gives it back: lists, not tuples


def _digest(a: np.ndarray) -> str:
    import hashlib

    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]


def partial_path(output: str | os.PathLike[str]) -> Path:
    """Where a capture into ``output`` keeps its finished views until it is complete."""
    out = Path(output)
    return out.with_name(out.name + ".partial")


# --------------------------------------------------------------------------- rendering

_loaded: dict[str, Any] = {}


def _sample(spec: CaptureSpec) -> Any:
    """The tiled scene of ``spec`` (loaded once per process; Dask workers keep theirs)."""
    from ...llvm import activate_variant
    from .scene import load_sample, resolve_source

    key = json.dumps([spec.scene, spec.seed, spec.backend, spec.directions_name,
                      _digest(np.asarray(spec.directions))])  # fmt: skip
    if key not in _loaded:
        variant, why = activate_variant(spec.backend, quiet=True)
        if variant.startswith("scalar"):
            why = " ".join(why.split())
            raise BTFInputError(f"capture renders whole views at once and needs Mitsuba's LLVM "
                                f"or CUDA backend, not {variant}: {why}")  # fmt: skip
        threads = os.environ.get("SPARSEBTF_THREADS")
        if threads:
            import drjit as dr

            dr.set_thread_count(int(threads))
        xyz = np.asarray(spec.directions, dtype=np.float64)
        tan = grazing_tan(xyz)
        _loaded.clear()
        _loaded[key] = load_sample(resolve_source(spec.scene), spec.seed, tan, tan)
    return _loaded[key]


def render_block(spec: CaptureSpec, view: int) -> np.ndarray:
    """View ``view`` of the capture, all texels of the window and all lights: (h, w, L, 3)."""
    from .render import render_view

    sample = _sample(spec)
    xyz = np.asarray(spec.directions, dtype=np.float64)
    block = render_view(sample.scene, sample.z_top, spec.size, slice(*spec.rows),
                        slice(*spec.cols), xyz[view], xyz, spp=spec.spp,
                        max_depth=spec.max_depth, seed=spec.paths_seed,
                        view_index=view)  # fmt: skip
    bad = ~np.isfinite(block)
    if bad.any():
        r, c, li, ch = (int(x[0]) for x in np.nonzero(bad))
        raise BTFInputError(f"{spec.scene}: {int(bad.sum())} NaN/Inf values in view {view}; "
                            f"first at row {r}, col {c}, light {li}, channel {ch}")  # fmt: skip
    return block


def check_scene(spec: CaptureSpec) -> dict[str, Any]:
    """Load the scene here (one-line errors before any file is made); what it is."""
    sample = _sample(spec)
    return {"z_min": sample.z_min, "z_max": sample.z_max, "rings": sample.rings}


# --------------------------------------------------------------------------- the file


def _new_partial(path: Path, spec: CaptureSpec, key: dict[str, Any], name: str,
                 attrs: dict[str, Any], dtype: str) -> h5py.File:  # fmt: skip
    from ..._hdf5 import LIBVER, write_str_attr

    f = h5py.File(path, "w", libver=LIBVER)
    try:
        shape = spec.shape
        dirs = spec.direction_set
        write_header(f, shape, dtype, name, attrs, dirs, dirs, _CHUNK)
        write_str_attr(f, "capture_json", json.dumps(key, sort_keys=True))
        f.attrs["capture_done"] = np.zeros(shape[3], dtype=np.uint8)
        f.flush()
    except BaseException:
        f.close()
        path.unlink(missing_ok=True)
        raise
    return f


def _open_partial(path: Path, key: dict[str, Any], dtype: str) -> h5py.File:
    """The partial file of an interrupted capture, checked against this capture's key."""
    try:
        f = h5py.File(path, "r+")
    except OSError as e:
        raise BTFInputError(f"--resume: cannot open {path} ({e}); delete it to start "
                            "over") from None  # fmt: skip
    try:
        raw = f.attrs.get("capture_json")
        found = json.loads(raw.decode() if isinstance(raw, bytes) else str(raw)) if raw else None
        if found != key:
            diff = sorted(k for k in set(key) | set(found or {})
                          if (found or {}).get(k) != key.get(k))  # fmt: skip
            raise BTFInputError(
                f"--resume: {path} was made by a different capture (differs in "
                f"{', '.join(diff) or 'its key'}); repeat its options or delete it to start over"
            )
        if str(f["btf"].dtype) != dtype:
            raise BTFInputError(f"--resume: {path} stores {f['btf'].dtype}, not --dtype {dtype}")
    except BaseException:
        f.close()
        raise
    return f


def write_capture(
    output: str | os.PathLike[str],
    spec: CaptureSpec,
    *,
    dtype: str = "float32",
    resume: bool = False,
    executor: Any = None,
    progress: bool | None = None,
    name: str | None = None,
    attrs: dict[str, Any] | None = None,
) -> Path:
    """Render ``spec`` view by view into the dense file ``output`` (see the module docstring).

    ``executor``: a :class:`sparsebtf.execution.Executor` spreading views over workers
    (default: this process). Returns the output path.
    """
    from ...execution import InProcess
    from .scene import resolve_source

    if dtype not in ("float32", "float16"):
        raise BTFInputError(f"dense files store float32 or float16, not {dtype!r}")
    out = Path(output)
    part = partial_path(out)
    key = spec.key(resolve_source(spec.scene).digest())
    if part.exists() and not resume:
        raise BTFInputError(
            f"{part} holds an interrupted capture; add --resume to continue it, or delete it "
            "to start over"
        )
    if resume and not part.exists():
        raise BTFInputError(f"--resume: no interrupted capture at {part}")
    ex = executor or InProcess()
    f = _open_partial(part, key, dtype) if resume else None
    if f is None:
        check_scene(spec)  # a bad scene fails here, before a file exists
        meta = {"generator": "sparsebtf.data.capture", **key, **(attrs or {})}
        f = _new_partial(part, spec, key, name or f"capture-{Path(spec.scene).stem}", meta,
                         dtype)  # fmt: skip
    done = np.array(f.attrs["capture_done"], dtype=np.uint8)
    todo = [v for v in range(len(done)) if not done[v]]
    ok = False
    try:
        handles = [ex.submit(render_block, spec, v) for v in todo]
        for v, block in zip(todo, ex.results(handles, desc="capture", unit="view",
                                             progress=progress), strict=True):  # fmt: skip
            handles = []
            f["btf"][:, :, :, v, :] = block
            done[v] = 1
            f.attrs["capture_done"] = done
            f.flush()
        del f.attrs["capture_done"]
        del f.attrs["capture_json"]
        ok = True
    except OSError as e:
        raise OutputError(f"{e} while writing {part}; the views written so far are kept: "
                          "rerun with --resume") from None  # fmt: skip
    finally:
        f.close()
        if not ok:
            _after_failure(part, int(done.sum()), len(done))
    try:
        os.replace(part, out)
    except OSError as e:
        raise OutputError(f"cannot move {part} to {out}: {e.strerror or e}") from None
    return out


def _after_failure(part: Path, n_done: int, n_views: int) -> None:
    """Keep a partial file with finished views (and say how to resume); drop an empty one."""
    if n_done == 0:
        with contextlib.suppress(OSError):
            part.unlink()
        return
    print(f"sparsebtf: note: {n_done} of {n_views} views are kept in {part}; rerun with "
          "--resume to continue", file=sys.stderr)  # fmt: skip
