"""The highlight store (:mod:`sparsebtf.learning.highlights`) as textures of the WebGL2 viewer.

A coded material with highlight entries gets three more data textures (laid out like every
1D array of the viewer: entry i at texel ``(i % 4096, i // 4096)``) and the uniform
``sb_highlights = 1``; ``shaders/sparsebtf_lookup.glsl`` then adds
``Σ_ab wl_a wv_b c(point, key(i1, i2, l_a, v_b))`` after the decode and clamps at 0, finding
each node by a binary search in its point's range of keys. Without entries nothing is added
(no texture, no uniform: the shader's default 0 skips the search, the output is unchanged).

* ``sb_hlOffsets`` R32UI  (P + 1,) the first entry of each point, then the entry count
* ``sb_hlKeys``    R32UI  (N,) node keys ``((i1·p + i2)·L + light)·V + view``, sorted per point
* ``sb_hlRgb``     RGB16F (N, 3) the binary16 corrections as stored (no rounding on upload)

A store with per-texel lobes (:mod:`sparsebtf.learning.lobes`, ``highlight_lobes`` of
``RuntimeBTF.arrays()``) gets the uniform ``sb_lobes = 1`` and

* ``sb_hlLobes``   RGBA16F (2·P·p²,) texel ``2r`` = (ω_x, ω_y, ω_z, ln α_x), ``2r + 1`` =
  (ln α_y, A_r, A_g, A_b) of lobe row ``r = point·p² + i1·p + i2``, binary16 as stored;

the shader evaluates each fragment's lobe at its own light and view, adds it before the clamp.
A store of lobes and no entries gets only this texture (entries' textures would be empty).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ...errors import BTFInputError
from ...learning.highlights import Highlights
from ...learning.lobes import LOBE_PARAMS

__all__ = ["HIGHLIGHT_ARRAYS", "LOBE_ARRAY", "highlight_textures"]

#: Names of the renderer arrays of a highlight store's entries (``RuntimeBTF.arrays()``, which
#: gives them only for a material with a store: without them the viewer carries nothing).
HIGHLIGHT_ARRAYS = ("highlight_offsets", "highlight_keys", "highlight_rgb")
#: Name of the renderer array of a store's lobes, (P·p², 8), given only where it has lobes.
LOBE_ARRAY = "highlight_lobes"


def highlight_textures(arrays: dict[str, np.ndarray], meta: dict[str, Any], n_points: int,
                       n_lights: int, n_views: int, where: str
                       ) -> tuple[list[tuple[str, str, np.ndarray]], dict[str, int],
                                  dict[str, int]]:  # fmt: skip
    """Texture specs ``(name, format, flat array)``, uniforms and manifest entries
    (``highlights``: the entry count, ``lobes``: the lobe count, each only if not 0) of the
    store in ``arrays`` (``RuntimeBTF.arrays()``); ``([], {}, {})`` without one.

    Raises :class:`~sparsebtf.errors.BTFInputError` (naming ``where``) when only some of the
    entries' arrays are given, when the material has adaptive patch sizes (a store's keys and
    lobe rows assume one patch size), or when the store does not fit the material
    (:meth:`Highlights.check`).
    """
    given = [n for n in HIGHLIGHT_ARRAYS if n in arrays]
    lobes = arrays.get(LOBE_ARRAY)
    if not given and lobes is None:
        return [], {}, {}
    if given and len(given) != len(HIGHLIGHT_ARRAYS):
        missing = sorted(set(HIGHLIGHT_ARRAYS) - set(given))
        raise BTFInputError(f"{where}: highlight store incomplete, missing {', '.join(missing)}")
    if meta.get("adaptive"):
        raise BTFInputError(f"{where}: the viewer reads a highlight store of one patch size only")
    patch = int(meta["patch"])
    if given:
        offsets, keys, rgb = (arrays[n] for n in HIGHLIGHT_ARRAYS)
        if int(offsets[-1]) >= 2**31:  # the shader indexes the textures with int
            raise BTFInputError(f"{where}: {int(offsets[-1])} highlight entries exceed the "
                                "shader's int32 offsets")  # fmt: skip
        store = Highlights(offsets.astype(np.int64), keys, rgb)
    else:  # lobes only (the runtime may leave out the arrays of no entries)
        store = Highlights.empty(n_points)
    if lobes is not None:
        rows = (n_points * patch * patch, LOBE_PARAMS)
        if lobes.shape != rows:
            raise BTFInputError(f"{where}: {LOBE_ARRAY} has shape {lobes.shape}, expected "
                                f"{rows} ({n_points} points of {patch}x{patch})")  # fmt: skip
        store = replace(store, lobes=lobes.reshape(n_points, patch * patch, LOBE_PARAMS))
    store.check(n_points, patch, n_lights, n_views, where)
    spec: list[tuple[str, str, np.ndarray]] = []
    uniforms: dict[str, int] = {}
    part: dict[str, int] = {}
    if store.n_entries:
        spec += [
            ("sb_hlOffsets", "R32UI", store.offsets.astype(np.uint32)),
            ("sb_hlKeys", "R32UI", store.keys.astype(np.uint32)),
            # binary16 as stored (the runtime's float32 copy widens them exactly)
            ("sb_hlRgb", "RGB16F", store.rgb.astype(np.float16)),
        ]
        uniforms["sb_highlights"] = 1
        part["highlights"] = store.n_entries
    if lobes is not None:
        # binary16 as stored, as the corrections: half the bytes of float32 and the same values;
        # 8 parameters = two RGBA texels per lobe (texture rows hold 4096 texels, not 4096 lobes)
        spec.append(("sb_hlLobes", "RGBA16F", lobes.astype(np.float16)))
        uniforms["sb_lobes"] = 1
        part["lobes"] = int(lobes.shape[0])
    return spec, uniforms, part
