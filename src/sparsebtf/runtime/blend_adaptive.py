"""Blending materials coded with adaptive patch sizes whose trees differ (beyond the paper).

The blend's tree is the **common refinement** of the inputs' trees (those of non-zero weight):
at every texel the smallest node any of them has there (:func:`union_tree`). Each node of the
blend, of size s at (r, c), then takes from every input j the node of size S_j ≥ s covering it:

* S_j = s: that node's codes as they are (on its dictionary p);
* S_j > s: the part of the coarse node inside (r, c, s), **re-expressed in a dictionary of size
  s** — with U⁽ⁿ⁾ the coarse node's dictionary (S_j rows in the spatial modes) and V⁽ⁿ⁾ the
  target dictionary of size s, S̃ = S ×_1 V⁽¹⁾ᵀU⁽¹⁾[r − R : r − R + s] ×_2 V⁽²⁾ᵀU⁽²⁾[c − C :
  c − C + s] ×_3 V⁽³⁾ᵀU⁽³⁾ ×_4 V⁽⁴⁾ᵀU⁽⁴⁾ ((R, C) the coarse node's corner). V is a complete
  orthonormal basis of the s-texel data points, so this is exact: S̃ reconstructs on V to the
  coarse node's values on those texels. It is Eq. 8–9 with the coarse basis cut to the node's
  rows, in coefficient space, from the stored coefficients (no decode of the material).

The target dictionary of a node is the membership of the input of largest weight among those
that have a node of exactly that size there (Eq. 7's dominant-input rule, restricted to the
inputs whose dictionaries of that size describe that node). The weighted sum is then cut back
to the node's cap τ_s = ⌈τ·(s/P)²⌉ (τ per point of the largest size P, as the encoder's caps).
Where every input has the node itself, this is the fixed-size blend of those nodes
(:func:`~.blend_codes.blend_channel`); a weight 0 input does not refine the tree, so α = 0 and
1 return the inputs' trees and codes.

Cost: a refined node sums each input's coefficients through four small matrices (the coarse
node's coefficients only: a sparse reconstruction, ``reconstruct_sparse``), once per channel.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .._progress import bar
from .._threads import parallel_map
from ..errors import BTFInputError
from ..learning.coding import SparseCodes, topk_abs
from ..learning.tensor import reconstruct_sparse
from ..model import Model
from ..patch_tree import AdaptiveCodedBTF, PatchTree, expand_points, node_taus, select_points
from ..points.grid import PatchGrid
from .blend_codes import blend_channel

__all__ = ["blend_trees", "union_tree"]


def union_tree(trees: Sequence[PatchTree]) -> PatchTree:
    """The common refinement of ``trees`` (one texture, one list of sizes): at every texel the
    smallest node any of them has there. Nested cuts refine into a cut (checked)."""
    first = trees[0]
    for t in trees[1:]:
        if (t.height, t.width, t.sizes) != (first.height, first.width, first.sizes):
            raise BTFInputError(
                f"trees of {first.height}x{first.width} in sizes {list(first.sizes)} and "
                f"{t.height}x{t.width} in sizes {list(t.sizes)} cannot be refined into one"
            )
    fine = np.minimum.reduce([t.size_map() for t in trees])
    small = first.sizes[-1]
    nodes = []
    for p in first.sizes:
        k = p // small
        blocks = fine.reshape(fine.shape[0] // k, k, fine.shape[1] // k, k)
        r, c = np.nonzero((blocks == p).all(axis=(1, 3)))  # an aligned block all of size p
        nodes.append(np.stack([r * p, c * p, np.full(r.size, p)], axis=1))
    return PatchTree.from_nodes(first.height, first.width, first.sizes, np.concatenate(nodes))


def _covering(coded: AdaptiveCodedBTF, rows: np.ndarray, cols: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(size, point on that size's grid) of the node of ``coded`` covering texels (rows, cols)."""
    size = coded.tree.sizes_at(rows, cols)
    point = rows // size + (coded.height // size) * (cols // size)
    return size, point


def _refined_node(
    inputs: list[tuple[float, SparseCodes, list[np.ndarray], int, int, int]],
    fine: list[np.ndarray],
    k: int,
    s: int,
    tau: int,
) -> tuple[np.ndarray, np.ndarray, float]:
    """One node of size ``s`` from inputs (weight, codes of the covering node's layer,
    that layer's dictionaries, point, row and column offset of the node in it): the weighted
    sum on the target dictionary ``k`` of ``fine`` (the size-s dictionaries), its ``tau``
    largest coefficients (values, locations) and the mean square dropped."""
    shape = tuple(int(d.shape[1]) for d in fine)
    acc = np.zeros(shape)
    for w, codes, dicts, q, dr, dc in inputs:
        loc, val = codes.point(q)
        p = int(codes.membership[q])
        if dicts[0].shape[1] == s and p == k:  # the node itself, on the target dictionary
            acc += w * codes.dense(q)
            continue
        rows = [slice(dr, dr + s), slice(dc, dc + s), slice(None), slice(None)]
        mats = [fine[n][k].T @ dicts[n][p][rows[n]] for n in range(4)]
        acc += w * reconstruct_sparse(loc, val.astype(np.float64), mats)
    flat = acc.ravel()
    top = topk_abs(flat, min(tau, flat.size))
    kept = flat[top]
    err = max(float(flat @ flat - kept @ kept), 0.0) / flat.size
    return kept, np.stack(np.unravel_index(top, shape), axis=1), err


def _blend_size(
    coded: Sequence[AdaptiveCodedBTF], w: np.ndarray, tree: PatchTree, s: int, ch: str,
    model: Model, tau: int, progress: bool | None,
) -> SparseCodes:  # fmt: skip
    """The codes of the blend's nodes of size ``s`` on channel ``ch``, as a layer (the whole
    grid of size s, empty outside those nodes)."""
    h, wd = tree.height, tree.width
    grid = PatchGrid(h, wd, s)
    pts = tree.points(s)
    rows, cols = (pts % (h // s)) * s, (pts // (h // s)) * s
    active = [j for j in range(len(coded)) if w[j] != 0]
    cover = {j: _covering(coded[j], rows, cols) for j in active}
    shared = np.ones(pts.size, dtype=bool)
    for j in active:
        shared &= cover[j][0] == s
    fine = model.for_patch(s).dictionaries[ch]
    mode_sizes = tuple(int(d.shape[1]) for d in fine)
    vals: list[np.ndarray] = [np.empty(0)] * pts.size
    locs: list[np.ndarray] = [np.empty((0, 4), dtype=np.int64)] * pts.size
    member = np.zeros(pts.size, dtype=np.int64)
    errors = np.zeros(pts.size)

    # Nodes every input has: the fixed-size blend (Eq. 7–9) of those nodes.
    idx = np.flatnonzero(shared)
    if idx.size:
        part = blend_channel(
            [select_points(c.layers[s].codes[ch], pts[idx]) for c in coded], w, fine, tau,
            progress, f"blend {ch} {s}x{s}",
        )  # fmt: skip
        for n, i in enumerate(idx):
            locs[i], vals[i] = part.point(n)
        member[idx], errors[idx] = part.membership, part.errors

    # Nodes inside a coarser node of some input: that node re-expressed at size s.
    refined = np.flatnonzero(~shared)

    def task(i: int) -> tuple[int, int, np.ndarray, np.ndarray, float]:
        own = [j for j in active if cover[j][0][i] == s]
        lead = max(own, key=lambda j: (w[j], -j))  # the heaviest, the first of equal weights
        k = int(coded[lead].layers[s].codes[ch].membership[cover[lead][1][i]])
        parts = []
        for j in active:
            size, q = int(cover[j][0][i]), int(cover[j][1][i])
            layer = coded[j].layers[size]
            parts.append((float(w[j]), layer.codes[ch], model.for_patch(size).dictionaries[ch],
                          q, int(rows[i] % size), int(cols[i] % size)))  # fmt: skip
        kept, loc, err = _refined_node(parts, fine, k, s, tau)
        return i, k, kept, loc, err

    with bar(refined.size, f"blend {ch} {s}x{s} (refined)", "node", progress) as pb:
        for i, k, kept, loc, err in parallel_map(task, refined.tolist()):
            vals[i], locs[i], member[i], errors[i] = kept, loc, k, err
            pb.update(1)

    first = coded[0].layers[s].codes[ch]
    nodes = SparseCodes(
        mode_sizes, member.astype(first.membership.dtype),
        np.array([v.size for v in vals], dtype=np.int64),
        np.concatenate(vals).astype(np.float32),
        np.concatenate(locs).astype(first.locations.dtype), errors,
    )  # fmt: skip
    return expand_points(nodes, pts, grid.n_points)


def blend_trees(
    coded: Sequence[AdaptiveCodedBTF], w: np.ndarray, taus: dict[str, int],
    progress: bool | None = None,
) -> tuple[PatchTree, dict[int, dict[str, SparseCodes]]]:  # fmt: skip
    """The blend's tree and, per size and channel, its layer codes (``taus`` per point of the
    largest size; each size's cap by :func:`~sparsebtf.patch_tree.node_taus`)."""
    model = coded[0].require_model()
    tree = union_tree([c.tree for c, wj in zip(coded, w, strict=True) if wj != 0])
    layers = {}
    for s in tree.sizes:
        caps = node_taus(taus, model, s)
        layers[s] = {ch: _blend_size(coded, w, tree, s, ch, model, caps[ch], progress)
                     for ch in coded[0].channels}  # fmt: skip
    return tree, layers
