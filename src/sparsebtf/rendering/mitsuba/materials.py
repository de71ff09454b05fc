"""Where the plugins' materials come from, and the parameters they share (no Mitsuba import).

A plugin names its material by ``filename`` (a coded file, or for ``sparsebtf_dense`` any BTF
:func:`sparsebtf.open.open_btf` reads) or by ``key`` (an object added with
:func:`add_material`). Loaded materials are cached per process, keyed by their source, so a
scene that uses one material many times loads it once; the plugin classes
(:mod:`.plugins`) and :func:`preload` (which runs the same checks outside Mitsuba, so errors
reach the caller as :class:`~sparsebtf.errors.BTFInputError` rather than Mitsuba's
``RuntimeError``) both go through here. The parameters are documented in
:mod:`sparsebtf.rendering.mitsuba`.
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from ...errors import BTFInputError
from ...points.preprocessing import RELEASE_LOG_OFFSET
from ...runtime.angular import DEFAULT_K, SCHEMES
from ...runtime.kernels import HAVE_NUMBA

#: Mitsuba's ``eval`` returns f_r·cos θ; a BTF value is π·f_r·cos θ_light (docs/format.md,
#: Conventions: a white Lambertian plane reads cos θ_light), so a plugin returns value / π, and
#: a Lambertian BTF of albedo ρ renders as Mitsuba's ``diffuse`` of reflectance ρ.
BSDF_PER_BTF_VALUE = 1.0 / math.pi

__all__ = [
    "DENSE_MAX_GIB",
    "DENSE_PLUGIN",
    "PLUGIN",
    "add_material",
    "cached",
    "coded_params",
    "coded_sampling",
    "common_params",
    "dense_sampling",
    "dense_table",
    "flat_meta",
    "load_dense",
    "load_runtime",
    "preload",
    "remove_material",
    "runtime_for",
    "sampling_params",
    "sampling_tables",
    "source_id",
]

PLUGIN = "sparsebtf"
DENSE_PLUGIN = "sparsebtf_dense"
#: Dense reference tables above this size (GiB) are refused by default.
DENSE_MAX_GIB = 2.0
#: ``domain`` values of the ``sparsebtf`` plugin (Eq. 6 blend, or the release shader's).
DOMAINS = ("standardized", "log")
#: ``sampling`` values: cosine-weighted hemisphere, or BTF-driven (:mod:`.sampling`).
SAMPLINGS = ("btf", "cosine")
#: ``sampling_tables`` values: one table per material, or one per data point (coded only).
SAMPLING_TABLES = ("material", "patch")
#: Per-patch sampling tables above this size (GiB) are refused by default.
SAMPLING_MAX_GIB = 1.0

# Mitsuba may construct plugins from several threads while loading a scene.
_lock = threading.Lock()
_materials: dict[str, Any] = {}
_cache: dict[tuple, Any] = {}


def add_material(obj: Any, key: str | None = None) -> str:
    """Make an in-memory material available to the plugins under ``key`` (returned).

    ``obj``: a :class:`~sparsebtf.runtime.RuntimeBTF` or a :class:`~sparsebtf.model.CodedBTF`
    with its model, or their adaptive twins (:class:`~sparsebtf.runtime.AdaptiveRuntimeBTF`,
    :class:`~sparsebtf.patch_tree.AdaptiveCodedBTF`), for ``sparsebtf``; or a
    :class:`~sparsebtf.data.btf.BTF`, for ``sparsebtf_dense``. Adding under an existing key
    replaces that material.
    """
    with _lock:
        key = key or f"mem{len(_materials)}-{id(obj):x}"
        _materials[key] = obj
        for ck in [ck for ck in _cache if ("key", key) in ck]:  # replaced: drop stale data
            del _cache[ck]
    return key


def remove_material(key: str) -> None:
    """Forget the material added under ``key`` and everything loaded from it (its tables),
    so their memory can be freed; an unknown key is ignored."""
    with _lock:
        _materials.pop(key, None)
        for ck in [ck for ck in _cache if ("key", key) in ck]:
            del _cache[ck]


def source_id(props: Any, what: str) -> tuple:
    """The cache identity of a plugin's material: ``("key", key)`` or
    ``("file", path, model, mtime)`` (the mtime, so an edited file is loaded again).

    ``props``: Mitsuba ``Properties`` or a plugin dict; ``what``: the plugin name for errors.
    """
    if "key" in props:
        key = str(props.get("key"))
        if key not in _materials:
            raise BTFInputError(f"{what}: no material was added under key {key!r}")
        return ("key", key)
    if "filename" not in props:
        raise BTFInputError(f"{what}: give 'filename' (a file) or 'key' (an added material)")
    path = str(props.get("filename"))
    if path.startswith("synth:"):
        return ("file", path, None, 0.0)
    if not os.path.exists(path):
        raise BTFInputError(f"{what}: file {path!r} does not exist")
    model = str(props.get("model")) if "model" in props else None
    return ("file", os.path.abspath(path), model, os.path.getmtime(path))


def cached(ck: tuple, make: Callable[[], Any]) -> Any:
    """``_cache[ck]``, made by ``make()`` on first use (one value per key, even if two
    threads race to make it)."""
    with _lock:
        if ck in _cache:
            return _cache[ck]
    value = make()
    with _lock:
        return _cache.setdefault(ck, value)


def runtime_for(coded: Any, tau: Any = None) -> Any:
    """The runtime of a coded material: a :class:`~sparsebtf.runtime.RuntimeBTF`, or an
    :class:`~sparsebtf.runtime.AdaptiveRuntimeBTF` for one coded with adaptive patch sizes
    (both parse ``tau`` alike)."""
    from ...patch_tree import AdaptiveCodedBTF
    from ...runtime import AdaptiveRuntimeBTF, RuntimeBTF

    if isinstance(coded, AdaptiveCodedBTF):
        return AdaptiveRuntimeBTF(coded, tau)
    return RuntimeBTF(coded, tau)


def flat_meta(rt: Any) -> dict[str, Any]:
    """The meta of ``rt``'s renderer arrays (:meth:`~sparsebtf.runtime.RuntimeBTF.arrays`):
    for an adaptive material its ``flat_meta`` (the data points are its nodes)."""
    from ...runtime import AdaptiveRuntimeBTF

    return rt.flat_meta if isinstance(rt, AdaptiveRuntimeBTF) else rt.meta


def load_runtime(source: tuple, tau: Any = None) -> Any:
    """The runtime of a plugin source (cached per process): a
    :class:`~sparsebtf.runtime.RuntimeBTF`, or an :class:`~sparsebtf.runtime.AdaptiveRuntimeBTF`
    for a material coded with adaptive patch sizes.

    ``tau`` is the plugin's string (or number) as given; the runtime parses it.
    """
    from ...model import CodedBTF
    from ...patch_tree import AdaptiveCodedBTF
    from ...runtime import AdaptiveRuntimeBTF, RuntimeBTF

    def make() -> Any:
        if source[0] != "key":
            from ...storage import load_coded_with_model

            return runtime_for(load_coded_with_model(source[1], source[2], adaptive=True), tau)
        obj = _materials[source[1]]
        if isinstance(obj, (CodedBTF, AdaptiveCodedBTF)):
            return runtime_for(obj, tau)
        if isinstance(obj, (RuntimeBTF, AdaptiveRuntimeBTF)):
            return obj if tau is None else obj.with_tau(tau)
        raise BTFInputError(
            f"material {source[1]!r} is a {type(obj).__name__}; the sparsebtf plugin needs "
            "a RuntimeBTF or a CodedBTF, or their adaptive twins (use sparsebtf_dense for "
            "dense BTFs)"
        )

    return cached(("runtime", source, str(tau)), make)


def dense_table(btf: Any, max_gib: float = DENSE_MAX_GIB) -> np.ndarray:
    """ln(max(x, 0) + 1e-5) of a whole BTF as float32 (H, W, L, V, 3); refuses > ``max_gib``."""
    h, w, nl, nv, c = btf.shape
    need = h * w * nl * nv * c * 4
    if need > max_gib * 2**30:
        raise BTFInputError(
            f"reference BTF {btf.label} ({h}x{w} texels, {nl} lights x {nv} views) needs "
            f"{need / 2**30:.1f} GiB as a float32 table, above the {max_gib:g} GiB limit; crop "
            "it first (sparsebtf convert BTF -o crop.h5 --crop R0:R1,C0:C1) or raise max_gib "
            "(sparsebtf render --max-gib)"
        )
    arr = np.array(btf.to_array(), dtype=np.float32)  # one copy; the log is taken in place
    np.maximum(arr, 0, out=arr)
    arr += np.float32(RELEASE_LOG_OFFSET)
    return np.log(arr, out=arr)


def load_dense(source: tuple, max_gib: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(log table (H, W, L, V, 3), light xyz (L, 3), view xyz (V, 3)) of a dense source, as
    float32 (cached per process)."""
    ck = ("dense", source, max_gib)
    with _lock:
        if ck in _cache:
            return _cache[ck]
    if source[0] == "key":
        btf = _materials[source[1]]
        if not hasattr(btf, "to_array"):
            raise BTFInputError(
                f"material {source[1]!r} is a {type(btf).__name__}; sparsebtf_dense needs a BTF"
            )
    else:
        from ...open import open_btf

        btf = open_btf(source[1], source[2])
    table = dense_table(btf, max_gib)
    out = (table, btf.lights.xyz.astype(np.float32), btf.views.xyz.astype(np.float32))
    with _lock:
        _cache[ck] = out
    return out


def common_params(props: Any, what: str) -> dict[str, Any]:
    """The parameters both plugins take, checked: ``interpolation``, ``k``, ``beta``,
    ``uv_scale``, ``two_sided``."""
    interp = str(props.get("interpolation", "linear"))
    if interp not in SCHEMES:
        raise BTFInputError(
            f"{what}: interpolation must be one of {', '.join(SCHEMES)}, got {interp!r}"
        )
    k = int(props.get("k", DEFAULT_K[interp]))
    if interp != "gaussian" and k != DEFAULT_K[interp]:
        raise BTFInputError(f"{what}: interpolation {interp!r} uses k = {DEFAULT_K[interp]}")
    if k < 1:
        raise BTFInputError(f"{what}: k must be >= 1, got {k}")
    beta = float(props.get("beta", 20.0))
    uv_scale = float(props.get("uv_scale", 1.0))
    if not (math.isfinite(uv_scale) and uv_scale != 0):
        raise BTFInputError(f"{what}: uv_scale must be finite and non-zero, got {uv_scale}")
    return {
        "interpolation": interp,
        "k": k,
        "beta": beta,
        "uv_scale": uv_scale,
        "two_sided": bool(props.get("two_sided", False)),
        **sampling_params(props, what),
    }


def sampling_params(props: Any, what: str) -> dict[str, Any]:
    """``sampling``, ``sampling_tables``, ``sampling_grid``, ``sampling_mix``, checked."""
    sampling = str(props.get("sampling", "btf"))
    if sampling not in SAMPLINGS:
        raise BTFInputError(f"{what}: sampling must be btf or cosine, got {sampling!r}")
    tables = str(props.get("sampling_tables", "material"))
    if tables not in SAMPLING_TABLES:
        raise BTFInputError(f"{what}: sampling_tables must be material or patch, got {tables!r}")
    if tables == "patch" and what != PLUGIN:
        raise BTFInputError(f"{what}: sampling_tables 'patch' needs a coded material ({PLUGIN})")
    grid = int(props.get("sampling_grid", 32 if tables == "material" else 16))
    if not 2 <= grid <= 256:
        raise BTFInputError(f"{what}: sampling_grid must be in [2, 256], got {grid}")
    mix = float(props.get("sampling_mix", 0.2))
    if not (math.isfinite(mix) and 0.0 < mix <= 1.0):
        raise BTFInputError(f"{what}: sampling_mix (cosine share) must be in (0, 1], got {mix}")
    return {"sampling": sampling, "sampling_tables": tables, "sampling_grid": grid,
            "sampling_mix": mix}  # fmt: skip


def sampling_tables(prm: dict[str, Any], ck: tuple, make_response: Callable[[], np.ndarray],
                    lights: np.ndarray, views: np.ndarray, rows: int, what: str) -> Any:
    """The :class:`.sampling.SamplingTables` of a plugin (cached per process), or None for
    cosine sampling. ``make_response()`` gives the angular response, (L, V) or (rows, L, V);
    per-patch tables above :data:`SAMPLING_MAX_GIB` are refused before they are built."""
    from .sampling import build_tables, table_bytes

    if prm["sampling"] != "btf":
        return None
    n_rows = rows if prm["sampling_tables"] == "patch" else 1
    need = table_bytes(n_rows, len(lights), len(views), prm["sampling_grid"])
    if need > SAMPLING_MAX_GIB * 2**30:
        raise BTFInputError(
            f"{what}: per-patch sampling tables need {need / 2**30:.2f} GiB ({n_rows} points x "
            f"({len(lights)} + {len(views)}) bins x {prm['sampling_grid']}^2 cells x 4 bytes), "
            f"above {SAMPLING_MAX_GIB:g} GiB; lower sampling_grid or use sampling_tables "
            "'material'"
        )
    key = (prm["sampling_tables"], prm["sampling_grid"], prm["sampling_mix"],
           prm["interpolation"], prm["k"], prm["beta"])  # fmt: skip
    return cached(("tables", *ck, *key), lambda: build_tables(
        make_response(), lights, views, prm["interpolation"], prm["k"], prm["beta"],
        prm["sampling_grid"], prm["sampling_mix"]))  # fmt: skip


def coded_params(props: Any) -> dict[str, Any]:
    """:func:`common_params` of the ``sparsebtf`` plugin plus its ``domain``, checked."""
    prm = common_params(props, PLUGIN)
    domain = str(props.get("domain", "standardized"))
    if domain not in DOMAINS:
        raise BTFInputError(f"{PLUGIN}: domain must be standardized or log, got {domain!r}")
    prm["domain"] = domain
    prm.update(lod_params(props))
    prm["backend"] = lookup_backend(props)
    return prm


#: ``backend`` of the ``sparsebtf`` plugin: who answers a wavefront's lookups.
BACKENDS = ("auto", "drjit", "numba")


def lookup_backend(props: Any) -> str:
    """``backend``: "drjit" (the Dr.Jit kernel, any mode), "numba" (the runtime's compiled
    lookup, :meth:`~sparsebtf.runtime.RuntimeBTF.evaluate`, on the host; needs Dr.Jit's
    evaluated mode) or "auto" (numba where a lookup is evaluated on an LLVM variant, else Dr.Jit);
    checked."""
    backend = str(props.get("backend", "auto"))
    if backend not in BACKENDS:
        raise BTFInputError(f"{PLUGIN}: backend must be one of {', '.join(BACKENDS)}, "
                            f"got {backend!r}")  # fmt: skip
    if backend == "numba" and not HAVE_NUMBA:
        raise BTFInputError(f"{PLUGIN}: backend 'numba' needs numba (pip install numba)")
    return backend


def host_lookups(backend: str, variant: str) -> bool:
    """Whether a ``sparsebtf`` plugin with this ``backend`` on ``variant`` answers its
    evaluated calls with the runtime's compiled lookup: numba, or auto on an LLVM variant
    with numba installed."""
    return backend == "numba" or (backend == "auto" and variant.startswith("llvm")
                                  and HAVE_NUMBA)  # fmt: skip


def lod_params(props: Any) -> dict[str, Any]:
    """``lod`` (auto | off), ``lod_camera`` ("x,y,z": the camera's origin, or None),
    ``lod_near`` (its near_clip, Mitsuba's default 0.01: primary rays start there) and
    ``lod_pixel`` (the angle of one pixel, radians), ``lod_later``, ``lod_sampled`` and
    ``lod_min`` (the fractions of :mod:`sparsebtf.runtime.lod`), ``lod_stats`` (count the τ
    used per lookup class), checked.
    ``auto`` without ``lod_camera`` cannot tell the first path vertex: it is off."""
    from ...runtime.lod import LATER_FRACTION, LODS, MIN_FRACTION, SAMPLED_FRACTION

    lod = str(props.get("lod", "auto"))
    if lod not in LODS:
        raise BTFInputError(f"{PLUGIN}: lod must be one of {', '.join(LODS)}, got {lod!r}")
    camera = None
    if "lod_camera" in props:
        text = str(props.get("lod_camera"))
        try:
            camera = [float(v) for v in text.split(",")]
        except ValueError:
            camera = []
        if len(camera) != 3 or not all(math.isfinite(v) for v in camera):
            raise BTFInputError(f"{PLUGIN}: lod_camera must be 'x,y,z' (3 numbers), got {text!r}")
    near = float(props.get("lod_near", 0.01))
    if not (math.isfinite(near) and near >= 0):
        raise BTFInputError(f"{PLUGIN}: lod_near (the camera's near_clip) must be >= 0, got {near}")
    pixel = float(props.get("lod_pixel", 0.0))
    if not (math.isfinite(pixel) and pixel >= 0):
        raise BTFInputError(f"{PLUGIN}: lod_pixel (radians per pixel) must be >= 0, got {pixel}")
    fractions = {}
    for name, default in (("lod_later", LATER_FRACTION), ("lod_min", MIN_FRACTION),
                          ("lod_sampled", SAMPLED_FRACTION)):
        f = float(props.get(name, default))
        if not (math.isfinite(f) and 0.0 < f <= 1.0):
            raise BTFInputError(f"{PLUGIN}: {name} (a fraction of tau) must be in (0, 1], got {f}")
        fractions[name] = f
    return {"lod": lod if camera is not None else "off", "lod_asked": lod,
            "lod_camera": camera, "lod_near": near, "lod_pixel": pixel, **fractions,
            "lod_stats": bool(props.get("lod_stats", False))}  # fmt: skip


def coded_sampling(prm: dict[str, Any], source: tuple, tau: Any, rt: Any) -> Any:
    """:func:`sampling_tables` of a coded material: the response of its codes
    (:func:`sparsebtf.runtime.response.angular_response`, per point for per-patch tables:
    per node for a material coded with adaptive patch sizes)."""
    from ...runtime.response import angular_response

    per_point = prm["sampling_tables"] == "patch"
    return sampling_tables(
        prm, ("coded", source, str(tau)), lambda: angular_response(rt, per_point),
        rt.coded.lights.xyz, rt.coded.views.xyz, int(flat_meta(rt)["n_points"]), PLUGIN,
    )  # fmt: skip


def dense_sampling(prm: dict[str, Any], source: tuple, max_gib: float, data: tuple,
                   sampling_key: str | None = None) -> Any:
    """:func:`sampling_tables` of a dense material (``data`` as :func:`load_dense` returns it):
    the mean over texels of its linear values, or, with ``sampling_key``, the tables of that
    coded material (:func:`add_material`), so a coded render and its reference draw the same
    directions from the same random numbers (correlated noise)."""
    from .sampling import dense_response

    table, lights, views = data
    if sampling_key is not None:
        coded = source_id({"key": sampling_key}, DENSE_PLUGIN)
        rt = load_runtime(coded, None)
        if not (np.allclose(rt.coded.lights.xyz, lights, atol=1e-6)
                and np.allclose(rt.coded.views.xyz, views, atol=1e-6)):  # fmt: skip
            raise BTFInputError(
                f"{DENSE_PLUGIN}: sampling_key {sampling_key!r} has {len(rt.coded.lights)}x"
                f"{len(rt.coded.views)} directions that differ from this BTF's "
                f"{len(lights)}x{len(views)}"
            )
        return coded_sampling(prm, coded, None, rt)
    return sampling_tables(prm, ("dense", source, max_gib),
                           lambda: dense_response(table, RELEASE_LOG_OFFSET), lights, views, 1,
                           DENSE_PLUGIN)  # fmt: skip


def preload(bsdf: dict[str, Any]) -> Any:
    """Load what a plugin dict needs, outside Mitsuba, so errors surface as themselves.

    (An exception inside a plugin constructor reaches the caller as Mitsuba's RuntimeError.)
    Returns the RuntimeBTF or AdaptiveRuntimeBTF (``sparsebtf``), the dense (log table, light
    xyz, view xyz) (``sparsebtf_dense``, as :func:`load_dense`) or None for any other plugin type.
    """
    kind = bsdf.get("type")
    if kind == PLUGIN:
        prm = coded_params(bsdf)
        source = source_id(bsdf, PLUGIN)
        rt = load_runtime(source, bsdf.get("tau"))
        coded_sampling(prm, source, bsdf.get("tau"), rt)
        return rt
    if kind == DENSE_PLUGIN:
        prm = common_params(bsdf, DENSE_PLUGIN)
        max_gib = float(bsdf.get("max_gib", DENSE_MAX_GIB))
        source = source_id(bsdf, DENSE_PLUGIN)
        data = load_dense(source, max_gib)
        skey = str(bsdf["sampling_key"]) if "sampling_key" in bsdf else None
        dense_sampling(prm, source, max_gib, data, skey)
        return data
    return None
