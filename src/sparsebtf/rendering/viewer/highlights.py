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
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...errors import BTFInputError
from ...learning.highlights import Highlights

__all__ = ["HIGHLIGHT_ARRAYS", "highlight_textures"]

#: Names of the renderer arrays of a highlight store (``RuntimeBTF.arrays()``, which gives
#: them only for a material with entries: without them the viewer carries nothing).
HIGHLIGHT_ARRAYS = ("highlight_offsets", "highlight_keys", "highlight_rgb")


def highlight_textures(arrays: dict[str, np.ndarray], meta: dict[str, Any], n_points: int,
                       n_lights: int, n_views: int, where: str
                       ) -> tuple[list[tuple[str, str, np.ndarray]], dict[str, int]]:  # fmt: skip
    """Texture specs ``(name, format, flat array)`` and uniforms of the store in ``arrays``
    (``RuntimeBTF.arrays()``); ``([], {})`` without one.

    Raises :class:`~sparsebtf.errors.BTFInputError` (naming ``where``) when only some of the
    arrays are given, when the material has adaptive patch sizes (a store's keys assume one
    patch size), or when the store does not fit the material (:meth:`Highlights.check`).
    """
    given = [n for n in HIGHLIGHT_ARRAYS if n in arrays]
    if not given:
        return [], {}
    if len(given) != len(HIGHLIGHT_ARRAYS):
        missing = sorted(set(HIGHLIGHT_ARRAYS) - set(given))
        raise BTFInputError(f"{where}: highlight store incomplete, missing {', '.join(missing)}")
    if meta.get("adaptive"):
        raise BTFInputError(f"{where}: the viewer reads a highlight store of one patch size only")
    offsets, keys, rgb = (arrays[n] for n in HIGHLIGHT_ARRAYS)
    if int(offsets[-1]) >= 2**31:  # the shader indexes the textures with int
        raise BTFInputError(f"{where}: {int(offsets[-1])} highlight entries exceed the "
                            "shader's int32 offsets")  # fmt: skip
    store = Highlights(offsets.astype(np.int64), keys, rgb)
    store.check(n_points, int(meta["patch"]), n_lights, n_views, where)
    spec = [
        ("sb_hlOffsets", "R32UI", offsets.astype(np.uint32)),
        ("sb_hlKeys", "R32UI", keys.astype(np.uint32)),
        # binary16 as stored (the runtime's float32 copy widens them exactly)
        ("sb_hlRgb", "RGB16F", rgb.astype(np.float16)),
    ]
    return spec, {"sb_highlights": 1}
