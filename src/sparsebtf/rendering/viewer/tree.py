"""The viewer's part of a material coded with adaptive patch sizes (issue 35): the texel-to-node
table and the node classes the shader reads besides the fixed-size textures.

:meth:`AdaptiveRuntimeBTF.arrays <sparsebtf.runtime.AdaptiveRuntimeBTF.arrays>` gives the tree
as ``cells`` (the node of each cell of the smallest size's grid), ``node_patch`` (each node's
size) and ``tau_<C>`` (each node's loaded τ per channel). The shader reads:

* ``sb_tree`` (R32I): ``cells``, entry ``row // s + (H / s)·(col // s)``;
* the fourth component of each node's ``sb_points`` record: its *class*, the index of its
  (size, τ_Y, τ_U, τ_V) among the material's distinct ones (one per size as the encoder
  codes: every node of a size shares its layer's τ);
* the uniform ``sb_class[j]`` = (size, τ'_Y, τ'_U, τ'_V) of class j, which the page sets
  from the manifest's ``adaptive.classes`` and the level-of-detail slider: τ' = max(1,
  ⌈f·τ⌉), computed in double precision in JavaScript, so the shader gets exactly the
  runtime's per-query τ (a float32 ⌈f·τ⌉ in the shader could miss by one).

A uniform array rather than per-node τ: the slider changes a few uniforms, not a texture,
and the integers stay exact.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...errors import BTFInputError

__all__ = ["MAX_CLASSES", "pack_tree"]

#: Distinct (size, τ) classes the shader's ``sb_class`` holds (``SB_MAX_CLASSES``): a model's
#: sizes nest by halving at least, so ≤ 9 sizes for patches ≤ 256 texels.
MAX_CLASSES = 16
_CHANNELS = ("Y", "U", "V")


def pack_tree(
    arrays: dict[str, np.ndarray], meta: dict[str, Any], n_points: int, where: str
) -> tuple[np.ndarray, np.ndarray, dict[str, Any], dict[str, Any]]:
    """The adaptive part of :func:`~sparsebtf.rendering.viewer.pack_textures`.

    Returns ``(cells, classes, uniforms, manifest)``: the ``sb_tree`` entries (int32), each
    node's class (for ``sb_points``' fourth component), the uniform ``sb_adaptive`` = (1,
    s, H / s, number of classes), and the manifest's ``adaptive`` entry (``sizes``,
    ``smallest``, ``nodes`` per size, ``classes`` as [size, τ_Y, τ_U, τ_V] lists). One
    :class:`~sparsebtf.errors.BTFInputError` line names an array that is missing, of the
    wrong shape, or out of range.
    """
    missing = [n for n in ("cells", "node_patch", *(f"tau_{c}" for c in _CHANNELS))
               if n not in arrays]  # fmt: skip
    if missing:
        raise BTFInputError(f"{where}: adaptive patch sizes need the arrays {', '.join(missing)}")
    height, width, big = int(meta["height"]), int(meta["width"]), int(meta["patch"])
    small = int(meta["smallest"])
    if small < 1 or big % small or height % big or width % big:
        raise BTFInputError(f"{where}: smallest size {small} does not divide the largest {big} "
                            f"or the {height}x{width} texture")  # fmt: skip
    n_cells = (height // small) * (width // small)
    cells = np.asarray(arrays["cells"])
    if cells.shape != (n_cells,) or cells.dtype.kind not in "iu":
        raise BTFInputError(f"{where}: cells of shape {cells.shape} ({cells.dtype}), expected "
                            f"({n_cells},) integers: one per {small}x{small} cell")  # fmt: skip
    if n_cells and (cells.min() < 0 or cells.max() >= n_points):
        bad = int(np.flatnonzero((cells < 0) | (cells >= n_points))[0])
        raise BTFInputError(f"{where}: cell {bad} names node {int(cells[bad])}, outside the "
                            f"{n_points} nodes")  # fmt: skip
    size = np.asarray(arrays["node_patch"])
    tau = [np.asarray(arrays[f"tau_{c}"]) for c in _CHANNELS]
    for name, a in (("node_patch", size), *zip((f"tau_{c}" for c in _CHANNELS), tau, strict=True)):
        if a.shape != (n_points,) or a.dtype.kind not in "iu":
            raise BTFInputError(f"{where}: {name} of shape {a.shape} ({a.dtype}), expected "
                                f"({n_points},) integers: one per node")  # fmt: skip
    bad = (size < small) | (size > big) | (size % small != 0) | (big % np.maximum(size, 1) != 0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise BTFInputError(f"{where}: node {i} has size {int(size[i])}, expected a divisor of "
                            f"{big} and a multiple of {small}")  # fmt: skip
    if any((t < 0).any() for t in tau):
        raise BTFInputError(f"{where}: a node's tau is negative")
    rows = np.stack([size, *tau], axis=1).astype(np.int64)
    table, classes = np.unique(rows, axis=0, return_inverse=True)
    table = table[::-1]  # largest size first, as the tree orders its nodes
    classes = (len(table) - 1 - classes.ravel()).astype(np.int32)
    if len(table) > MAX_CLASSES:
        raise BTFInputError(f"{where}: {len(table)} distinct (node size, tau) pairs, the "
                            f"viewer's shader holds {MAX_CLASSES}")  # fmt: skip
    sizes = [int(p) for p in meta.get("patch_sizes", sorted(set(size.tolist()), reverse=True))]
    manifest = {
        "sizes": sizes,
        "smallest": small,
        "nodes": {str(p): int((size == p).sum()) for p in sizes},
        "classes": table.tolist(),
    }
    uniforms = {"sb_adaptive": [1, small, height // small, len(table)]}
    return cells.astype(np.int32), classes, uniforms, manifest
