"""Render a synthetic material once into our dense HDF5 file and reopen it afterwards.

The cache key hashes everything that determines the values — class, seed, size, the exact
direction vectors and :data:`~sparsebtf.data.synth.materials.GENERATOR_VERSION` — so a change
to any of them renders a new file instead of returning stale data.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from ..btf import BTF
from ..cache import announce_write, enforce_cap, mark_used, resolve_cache_dir
from ..dense_file import DenseFileBTF, dense_file_bytes, write_dense
from ..directions import DirectionSet
from .materials import (
    GENERATOR_VERSION,
    check_material,
    check_seed,
    check_size,
    resolve_directions,
    synthesize,
)

__all__ = ["cache_key", "cache_path", "cached", "resolve_cache_dir"]


def cache_key(
    material: str, size: tuple[int, int], seed: int, directions: DirectionSet, black: bool = False
) -> str:
    """Hex SHA-256 of everything that determines a synthetic BTF's values."""
    fields: dict[str, object] = {
        "material": material,
        "size": list(size),
        "seed": seed,
        "generator_version": GENERATOR_VERSION,
    }
    if black:  # absent for the default variant: existing cache keys stay valid
        fields["black"] = True
    head = json.dumps(fields, sort_keys=True).encode()
    xyz = np.ascontiguousarray(directions.xyz, dtype="<f8").tobytes()
    return hashlib.sha256(head + b"\0" + xyz).hexdigest()


def cache_path(
    material: str,
    size: int | tuple[int, int] = 64,
    directions: str | DirectionSet = "ubo2014",
    seed: int = 0,
    cache_dir: str | os.PathLike[str] | None = None,
    black: bool = False,
) -> Path:
    """Where :func:`cached` keeps (or would keep) this material's file."""
    mat = check_material(material)
    hw = check_size(size)
    sd = check_seed(seed)
    dirs = resolve_directions(directions)
    key = cache_key(mat, hw, sd, dirs, bool(black))
    variant = "-black" if black else ""
    name = f"synth-{mat}{variant}-{hw[0]}x{hw[1]}-s{sd}-{dirs.name}-{key[:16]}.h5"
    return resolve_cache_dir(cache_dir) / name


def cached(
    material: str,
    size: int | tuple[int, int] = 64,
    directions: str | DirectionSet = "ubo2014",
    seed: int = 0,
    cache_dir: str | os.PathLike[str] | None = None,
    progress: bool = False,
    black: bool = False,
) -> BTF:
    """The synthetic BTF as a file-backed :class:`DenseFileBTF`, rendering it on first use.

    The file (float32) is written atomically, so an interrupted render leaves no partial
    file behind and concurrent callers at worst render twice. ``black``: the true-black,
    high-dynamic-range variant. A large write is announced first and the cache's cap applied
    after (:mod:`sparsebtf.data.cache`).
    """
    path = cache_path(material, size, directions, seed, cache_dir, black)
    if path.exists():
        mark_used(path)
        return DenseFileBTF(path)
    (h, w), n_dirs = check_size(size), len(resolve_directions(directions))
    announce_write(path, dense_file_bytes((h, w, n_dirs, n_dirs, 3), "float32"))
    btf = synthesize(material, size, directions, seed, black)
    write_dense(path, btf, dtype="float32", attrs={"cache_key": path.stem}, progress=progress)
    enforce_cap(path)  # (sparsebtf.data.cache: $SPARSEBTF_CACHE_MAX)
    return DenseFileBTF(path)
