"""Adaptive patch sizes (beyond the paper, its §5): a material cut into nodes of several sizes.

A model with several nested patch sizes (:attr:`Model.patch_sizes`, e.g. 20, 10, 5) codes a
material as a tree per block of the largest size: each block is one data point, or splits into
(big / small)² blocks of the next size, recursively down to the smallest
(:mod:`sparsebtf.codec.adaptive` chooses the tree). :class:`PatchTree` is that cut: one row
(row, col, size) in texels per node, every texel in exactly one node. :class:`AdaptiveCodedBTF`
holds the tree and, per size, a :class:`~sparsebtf.model.CodedBTF` **layer** on the whole grid
of that size whose points outside the tree's nodes of that size are empty (no coefficient):
every fixed-size decoder then serves a layer as it is, and a texel is read from the layer of
the node that covers it (:mod:`sparsebtf.runtime.adaptive`). Files: schema 4 of the coded file
(:mod:`sparsebtf.storage.adaptive_file`, ``docs/format.md``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import BTFInputError, ModelMismatchError
from .learning.coding import SparseCodes
from .model import CodedBTF, Model, model_text
from .points.grid import PatchGrid, check_nested

__all__ = [
    "AdaptiveCodedBTF", "PatchTree", "coefficient_indices", "expand_points", "node_taus",
    "refuse_adaptive", "select_points",
]  # fmt: skip


@dataclass(frozen=True)
class PatchTree:
    """The nodes of a material's adaptive cut: ``nodes`` (N, 3) int64 rows (row, col, size)
    in texels, in the canonical order: by decreasing size, within a size by the release
    numbering of that size's grid (``row_block + n_row_blocks·col_block``). ``sizes``: the
    patch sizes it may use, largest first (each divides the next larger)."""

    height: int
    width: int
    sizes: tuple[int, ...]
    nodes: np.ndarray = field(repr=False)

    @classmethod
    def from_nodes(cls, height: int, width: int, sizes: Sequence[int], nodes: np.ndarray,
                   where: str = "tree", error: type[Exception] = BTFInputError
                   ) -> PatchTree:  # fmt: skip
        """The tree of ``nodes`` in canonical order, checked (:meth:`check`); ``error`` is
        the exception of a refusal (a reader's :class:`~sparsebtf.errors.FileFormatError`)."""
        try:
            ordered = check_nested(sizes)
        except BTFInputError as e:
            raise error(f"{where}: {e}") from None
        a = np.asarray(nodes)
        if a.ndim != 2 or a.shape[1] != 3 or a.dtype.kind not in "iu":
            raise error(f"{where}: nodes must be (N, 3) integers (row, col, size), "
                        f"found {a.dtype} {a.shape}")  # fmt: skip
        a = a.astype(np.int64)
        tree = cls(int(height), int(width), ordered, a)
        tree.check(where, error)
        return cls(tree.height, tree.width, ordered, a[tree._canonical()])

    def _canonical(self) -> np.ndarray:
        r, c, s = self.nodes.T
        n_rb = self.height // np.maximum(s, 1)
        return np.lexsort((r // np.maximum(s, 1) + n_rb * (c // np.maximum(s, 1)), -s))

    def check(self, where: str = "tree", error: type[Exception] = BTFInputError) -> None:
        """One line for a tree that is not a cut of the texture into its sizes: a size it does
        not have, a node off its size's grid or outside the texture, texels covered twice
        (overlapping nodes) or not at all (missing nodes)."""
        big, small = self.sizes[0], self.sizes[-1]
        if self.height % big or self.width % big:
            raise error(f"{where}: size {self.height}x{self.width} is not a multiple of the "
                        f"largest patch {big}")  # fmt: skip
        r, c, s = (self.nodes[:, j] for j in range(3))
        bad = ~np.isin(s, self.sizes)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise error(f"{where}: node {i} has size {s[i]}, not one of the patch sizes "
                        f"{list(self.sizes)}")  # fmt: skip
        bad = (r < 0) | (c < 0) | (r + s > self.height) | (c + s > self.width)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise error(f"{where}: node {i} ({r[i]}, {c[i]}, size {s[i]}) is outside the "
                        f"{self.height}x{self.width} texture")  # fmt: skip
        bad = (r % s != 0) | (c % s != 0)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise error(f"{where}: node {i} ({r[i]}, {c[i]}, size {s[i]}) is not on the "
                        f"{s[i]}x{s[i]} grid (row and column must be multiples of {s[i]})")
        cover = np.zeros((self.height // small, self.width // small), dtype=np.int64)
        for size in self.sizes:
            m = s == size
            k = size // small
            for dr in range(k):  # each node paints its k x k cells of the finest grid
                for dc in range(k):
                    np.add.at(cover, (r[m] // small + dr, c[m] // small + dc), 1)
        if (cover > 1).any():
            y, x = (int(v[0]) * small for v in np.nonzero(cover > 1))
            raise error(f"{where}: nodes overlap: texel ({y}, {x}) is in more than one node")
        if (cover == 0).any():
            y, x = (int(v[0]) * small for v in np.nonzero(cover == 0))
            raise error(f"{where}: nodes are missing: texel ({y}, {x}) is in no node")

    @property
    def n_nodes(self) -> int:
        return int(self.nodes.shape[0])

    def points(self, size: int) -> np.ndarray:
        """The point numbers, on the grid of ``size``, of the nodes of that size (increasing:
        the order of their codes)."""
        m = self.nodes[:, 2] == size
        grid = PatchGrid(self.height, self.width, size)
        return np.asarray(grid.index(self.nodes[m, 0] // size, self.nodes[m, 1] // size),
                          dtype=np.int64)  # fmt: skip

    def counts(self) -> dict[int, int]:
        """Nodes per size, largest first (0 for a size the tree does not use)."""
        return {p: int((self.nodes[:, 2] == p).sum()) for p in self.sizes}

    def size_map(self) -> np.ndarray:
        """(H / smallest, W / smallest) int64: the size of the node covering each cell of the
        finest grid."""
        small = self.sizes[-1]
        out = np.zeros((self.height // small, self.width // small), dtype=np.int64)
        for r, c, s in self.nodes:
            out[r // small:(r + s) // small, c // small:(c + s) // small] = s
        return out

    def sizes_at(self, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        """The node size at texels (row, col) (in range)."""
        small = self.sizes[-1]
        return self.size_map()[np.asarray(row) // small, np.asarray(col) // small]

    def flags(self) -> int:
        """Split flags that code the tree (the Table 4 accounting's tree bits): one per node
        of the tree above the smallest size, leaf or split."""
        s = self.nodes[:, 2]
        area = {p: int(((s == p) * s**2).sum()) for p in self.sizes}  # texels in leaves of p
        total = 0
        for p in self.sizes[:-1]:  # leaves of p, and the split nodes of p above smaller ones
            below = sum(a for q, a in area.items() if q < p)
            total += area[p] // p**2 + below // p**2
        return total

    def tree_bytes(self) -> int:
        """Table 4-style bytes of the tree: its split flags, one bit each."""
        return math.ceil(self.flags() / 8)


def node_taus(tau: dict[str, int], model: Model, size: int) -> dict[str, int]:
    """The cap of a node of ``size``: τ (per point of the model's largest size P) scaled to
    the node's texels, ⌈τ·(size/P)²⌉, at least 1 and at most the point's coefficients."""
    big = model.patch_sizes[0]
    one = model.for_patch(size)
    return {ch: min(math.prod(int(d.shape[1]) for d in one.dictionaries[ch]),
                    max(1, math.ceil(t * size * size / (big * big))))
            for ch, t in tau.items()}  # fmt: skip


def coefficient_indices(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """The runs start_i, start_i + 1, …, start_i + count_i − 1 of every i, concatenated
    (int64): the coefficients of some points, by their first coefficient and count."""
    counts = np.asarray(counts, dtype=np.int64)
    shift = np.asarray(starts, dtype=np.int64) - (np.cumsum(counts) - counts)
    return np.arange(int(counts.sum()), dtype=np.int64) + np.repeat(shift, counts)


def select_points(codes: SparseCodes, points: np.ndarray) -> SparseCodes:
    """The codes of ``points`` (in that order), each point's coefficients as they are."""
    idx = np.asarray(points, dtype=np.int64)
    o = codes.offsets
    take = coefficient_indices(o[idx], o[idx + 1] - o[idx])
    return SparseCodes(codes.mode_sizes, codes.membership[idx], codes.counts[idx],
                       codes.values[take], codes.locations[take], codes.errors[idx])  # fmt: skip


def expand_points(codes: SparseCodes, points: np.ndarray, n_points: int) -> SparseCodes:
    """Codes of ``n_points`` points holding ``codes`` at ``points`` (increasing) and no
    coefficient elsewhere (dictionary 0, count 0): a layer of an adaptive material."""
    idx = np.asarray(points, dtype=np.int64)
    if idx.size != codes.n_points or (idx.size > 1 and (np.diff(idx) <= 0).any()):
        raise BTFInputError(f"{codes.n_points} coded nodes for {idx.size} increasing points")
    member = np.zeros(n_points, dtype=codes.membership.dtype)
    counts = np.zeros(n_points, dtype=codes.counts.dtype)
    errors = np.zeros(n_points, dtype=codes.errors.dtype)
    member[idx], counts[idx], errors[idx] = codes.membership, codes.counts, codes.errors
    return SparseCodes(codes.mode_sizes, member, counts, codes.values, codes.locations, errors)


@dataclass(eq=False)
class AdaptiveCodedBTF:
    """A material coded with adaptive patch sizes: its :class:`PatchTree` and one
    :class:`~sparsebtf.model.CodedBTF` layer per size (the whole grid of that size, empty
    outside the tree's nodes of that size; statistics, directions and parameters shared).
    The layers' ``params`` are the material's; ``model`` is the model of every size."""

    tree: PatchTree
    layers: dict[int, CodedBTF]
    model: Model | None = None

    def __post_init__(self) -> None:
        if set(self.layers) != set(self.tree.sizes):
            raise BTFInputError(f"layers {sorted(self.layers)} do not match the tree's sizes "
                                f"{list(self.tree.sizes)}")  # fmt: skip
        for p, layer in self.layers.items():
            if (layer.patch, layer.height, layer.width) != (p, self.tree.height, self.tree.width):
                raise BTFInputError(f"layer {p}: a {layer.height}x{layer.width} texture in "
                                    f"{layer.patch}x{layer.patch} patches does not fit the tree")
            used = np.zeros(layer.n_points, dtype=bool)
            used[self.tree.points(p)] = True
            for ch, c in layer.codes.items():
                if np.any(c.counts[~used]):
                    raise BTFInputError(f"layer {p}, channel {ch}: coefficients outside the "
                                        "tree's nodes")  # fmt: skip

    @property
    def first(self) -> CodedBTF:
        return self.layers[self.tree.sizes[0]]

    # what every layer shares, by the largest size's
    @property
    def name(self) -> str:
        return self.first.name

    @property
    def label(self) -> str:
        return self.first.label

    @property
    def source(self) -> str | None:
        return self.first.source

    @property
    def params(self) -> dict[str, Any]:
        return self.first.params

    @property
    def attrs(self) -> dict[str, Any]:
        return self.first.attrs

    @property
    def stats(self) -> Any:
        return self.first.stats

    @property
    def height(self) -> int:
        return self.tree.height

    @property
    def width(self) -> int:
        return self.tree.width

    @property
    def patch(self) -> int:
        """The largest size (the blocks the tree splits)."""
        return self.tree.sizes[0]

    @property
    def lights(self) -> Any:
        return self.first.lights

    @property
    def views(self) -> Any:
        return self.first.views

    @property
    def model_hash(self) -> str:
        return self.first.model_hash

    @property
    def model_file(self) -> str | None:
        return self.first.model_file

    @property
    def channels(self) -> tuple[str, ...]:
        return self.first.channels

    @property
    def dictionary_rule(self) -> tuple[str, int | None]:
        return self.first.dictionary_rule

    @property
    def objective(self) -> str:
        return self.first.objective

    @property
    def n_points(self) -> int:
        """Data points stored: the tree's nodes."""
        return self.tree.n_nodes

    def nnz(self) -> dict[str, int]:
        return {ch: sum(layer.codes[ch].nnz for layer in self.layers.values())
                for ch in self.channels}  # fmt: skip

    def node_codes(self, size: int) -> dict[str, SparseCodes]:
        """The codes of the nodes of ``size``, in the tree's order (what the file stores)."""
        pts = self.tree.points(size)
        return {ch: select_points(c, pts) for ch, c in self.layers[size].codes.items()}

    def attach(self, model: Model) -> AdaptiveCodedBTF:
        """Attach the model of every size (its hash is the one the codes name)."""
        if model.content_hash != self.model_hash:
            raise ModelMismatchError(
                f"{self.label}: coded with {model_text(self.model_hash, self.model_file)}, but "
                f"the given model is {model_text(model.content_hash, model.file)}"
            )
        lacking = [p for p in self.tree.sizes if p not in model.patch_sizes]
        if lacking:
            raise ModelMismatchError(
                f"{self.label}: nodes of size {lacking[0]}, but "
                f"{model_text(model.content_hash, model.file)} has patch sizes "
                f"{list(model.patch_sizes)}"
            )
        for p, layer in self.layers.items():
            layer.attach(model.for_patch(p))
        self.model = model
        return self

    def require_model(self) -> Model:
        """The attached model, or the one line a coded BTF without one gives."""
        return CodedBTF.require_model(self)  # type: ignore[arg-type]


def refuse_adaptive(coded: object, what: str) -> None:
    """One line where a reader of one patch size (``what``) is given an adaptive material."""
    if isinstance(coded, AdaptiveCodedBTF):
        raise BTFInputError(
            f"{coded.label}: coded with adaptive patch sizes; {what} reads materials of one "
            "patch size only so far (read it with sparsebtf.decode or "
            "sparsebtf.runtime.AdaptiveRuntimeBTF)"
        )
