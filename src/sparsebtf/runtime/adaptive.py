"""Decoding adaptive patch sizes (:mod:`sparsebtf.patch_tree`), layer by layer.

A material coded with adaptive patch sizes holds one layer of codes per size, each a fixed-size
coded BTF that is empty outside the nodes of its size. Every texel is read from the layer of
the node that covers it, by the fixed-size decoders: :class:`AdaptiveDecodedBTF` (the lazy
dense decode, Eq. 4 / Eq. 5 per layer) and :class:`AdaptiveRuntimeBTF` (the runtime's
queries, Eq. 5 / Eq. 6, by either backend: a layer is an ordinary fixed-size coded BTF, so
its NumPy reference and its numba kernels serve the queries routed to it as they are). Cost: a
dense read decodes the requested block once per size that has nodes in it (up to the number
of sizes times a fixed-size read); a query costs what it costs in the layer of its node. The
renderer arrays (:meth:`AdaptiveRuntimeBTF.arrays`, for the Mitsuba plugin and the WebGL
viewer) hold every node in one set of flat arrays, with a table from texel to node.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from ..data.btf import BTF, Index
from ..errors import BTFInputError
from ..model import TauSpec, parse_tau
from ..patch_tree import AdaptiveCodedBTF, coefficient_indices, node_taus
from ..points.preprocessing import Preprocessor
from .decoder import RuntimeBTF, query_texels
from .dense import DecodedBTF

__all__ = ["AdaptiveDecodedBTF", "AdaptiveRuntimeBTF", "decoded_view"]


class AdaptiveDecodedBTF(BTF):
    """An adaptive material seen as a lazy :class:`~sparsebtf.data.btf.BTF` (linear RGB):
    every read decodes each size's layer where its nodes are and undoes the preprocessing."""

    def __init__(self, coded: AdaptiveCodedBTF) -> None:
        coded.require_model()
        super().__init__(coded.height, coded.width, coded.lights, coded.views, coded.name,
                         dict(coded.attrs))  # fmt: skip
        self.source = coded.source
        self.coded = coded
        self.layers = {p: DecodedBTF(layer) for p, layer in coded.layers.items()}
        self.sizes = coded.tree.size_map()
        self.pre = Preprocessor(coded.stats)

    def read(self, rows: Index, cols: Index, lights: Index, views: Index) -> np.ndarray:
        _, _, li, vi = self.indices(rows, cols, lights, views)
        z = self.read_standardised(rows, cols, lights, views)
        return self.pre.inverse(z, li, vi).astype(np.float32, copy=False)

    def read_standardised(self, rows: Index, cols: Index, lights: Index, views: Index
                          ) -> np.ndarray:  # fmt: skip
        """(rows, cols, l, v, 3) standardised log-YUV, each texel from its node's layer."""
        r, c, li, vi = self.indices(rows, cols, lights, views)
        small = self.coded.tree.sizes[-1]
        which = self.sizes[(r // small)[:, None], (c // small)[None, :]]
        z = np.empty((r.size, c.size, li.size, vi.size, 3), dtype=np.float32)
        for p, layer in self.layers.items():
            m = which == p
            if not m.any():
                continue
            # only the rows and columns where this size has nodes
            rs, cs = np.flatnonzero(m.any(axis=1)), np.flatnonzero(m.any(axis=0))
            part = layer.read_standardised(r[rs], c[cs], li, vi)
            sub = m[np.ix_(rs, cs)]
            block = z[np.ix_(rs, cs)]
            block[sub] = part[sub]
            z[np.ix_(rs, cs)] = block
        return z


def decoded_view(coded: AdaptiveCodedBTF) -> AdaptiveDecodedBTF:
    """The decoded BTF of an adaptive material (its model attached)."""
    return AdaptiveDecodedBTF(coded)


def _is_fraction(tau: TauSpec) -> bool:
    """Whether ``tau`` is the τ syntax's fraction (a number or string in (0, 1))."""
    try:
        return 0.0 < float(tau) < 1.0  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False


class AdaptiveRuntimeBTF:
    """:class:`~sparsebtf.runtime.decoder.RuntimeBTF`'s queries on an adaptive material: each
    query answered by the runtime of its node's layer, on the backend asked for (``tau``: counts
    per channel cap every node alike; a fraction is of each size's own cap, the coded τ scaled
    to the node's texels as the encoder capped it, :func:`~sparsebtf.patch_tree.node_taus`)."""

    def __init__(self, coded: AdaptiveCodedBTF, tau: TauSpec = None,
                 dtype: type = np.float32) -> None:  # fmt: skip
        coded.require_model()
        self.coded = coded
        self.layers = {p: RuntimeBTF(layer, t, dtype) for p, layer, t in self._layer_taus(tau)}
        self.sizes = coded.tree.size_map()
        first = self.layers[coded.tree.sizes[0]]
        self.meta: dict[str, Any] = {**first.meta, "patch_sizes": list(coded.tree.sizes),
                                     "nodes": coded.tree.counts()}  # fmt: skip

    def _layer_taus(self, tau: TauSpec) -> list[tuple[int, Any, TauSpec]]:
        """(size, layer, τ' of that size): a fraction of the size's own cap (a layer's
        ``params["tau"]`` is the material's, per point of the largest size), anything else
        as given."""
        coded = self.coded
        if tau is None:
            return [(p, layer, None) for p, layer in coded.layers.items()]
        model, nominal = coded.require_model(), coded.first.coded_tau
        return [(p, layer, parse_tau(tau, coded.channels, full=layer.stored_tau,
                                     nominal=node_taus(nominal, model, p)))
                for p, layer in coded.layers.items()]  # fmt: skip

    @classmethod
    def from_file(cls, path: Any, model: Any = None, tau: TauSpec = None,
                  dtype: type = np.float32) -> AdaptiveRuntimeBTF:  # fmt: skip
        from ..storage import load_coded_with_model

        coded = load_coded_with_model(path, model, adaptive=True)
        if not isinstance(coded, AdaptiveCodedBTF):
            raise BTFInputError(f"{path}: coded with one patch size; use RuntimeBTF")
        return cls(coded, tau, dtype)

    def with_tau(self, tau: TauSpec) -> AdaptiveRuntimeBTF:
        """A copy truncated to τ' ≤ the loaded τ of every size (:meth:`RuntimeBTF.with_tau`
        layer by layer: a fraction is of each size's coded τ)."""
        out = copy.copy(self)
        out.layers = {}
        for p, layer, t in self._layer_taus(tau):
            if _is_fraction(tau):  # of a size's cap, which a sparse layer may not fill
                t = {ch: min(v, self.layers[p].tau[ch]) for ch, v in layer.resolve_tau(t).items()}
            out.layers[p] = self.layers[p].with_tau(t)
        out.meta = {**out.layers[self.coded.tree.sizes[0]].meta,
                    "patch_sizes": self.meta["patch_sizes"], "nodes": self.meta["nodes"]}
        return out

    def arrays(self, neighbours: bool = True) -> dict[str, np.ndarray]:
        """The flat renderer arrays of :meth:`RuntimeBTF.arrays` for the whole tree, so a
        shader reads an adaptive material as it reads a fixed-size one, with one more step:
        the texel's node comes from a table, not from arithmetic.

        The data points are the tree's nodes, in the tree's order (largest size first).
        ``cells`` (H/s · W/s,) int32, s the smallest size: the node of each cell of the finest
        grid, in the release's order (cell ``row // s + (H / s)·(col // s)``);
        ``node_patch`` (N,) int32: each node's size p (the texel's i1, i2 are row % p,
        col % p: nodes lie on their size's grid). Per channel, the dictionaries of every size
        are stacked, ``membership_c`` numbering them across sizes (largest size's first);
        ``dict1_c``/``dict2_c`` are zero-padded to the largest size P, (K_total, P, P), so one
        stride serves every node (a location never reaches the padding);
        ``tau_c`` (N,) int32: the loaded τ of each node's size (what a level-of-detail
        fraction multiplies). Everything else (statistics, bound, directions, neighbours) as
        for a fixed-size material; :attr:`meta` adds ``adaptive``, ``smallest`` and sets
        ``patch`` to P and ``n_points`` to N."""
        tree = self.coded.tree
        big, small = tree.sizes[0], tree.sizes[-1]
        out = self.layers[big].arrays(neighbours)
        nodes = {p: tree.points(p) for p in tree.sizes}
        first = {}  # global number of each size's first node
        n = 0
        for p in tree.sizes:
            first[p], n = n, n + nodes[p].size
        cells = np.empty((tree.height // small, tree.width // small), dtype=np.int32)
        for p in tree.sizes:
            k = p // small
            rb = nodes[p] % (tree.height // p)
            cb = nodes[p] // (tree.height // p)
            ids = first[p] + np.arange(nodes[p].size, dtype=np.int32)
            for dr in range(k):  # each node paints its k x k cells
                for dc in range(k):
                    cells[rb * k + dr, cb * k + dc] = ids
        out["cells"] = np.ascontiguousarray(cells.T).ravel()  # release order: row fastest
        out["node_patch"] = np.concatenate(
            [np.full(nodes[p].size, p, dtype=np.int32) for p in tree.sizes])
        layer_arrays = {p: dict(out) if p == big else self.layers[p].arrays(neighbours=False)
                        for p in tree.sizes}  # fmt: skip
        for ch in ("Y", "U", "V"):
            member, offsets, values, locations, tau = [], [np.zeros(1, np.int64)], [], [], []
            dicts: list[list[np.ndarray]] = [[], [], [], []]
            n_dict = nnz = 0
            for p in tree.sizes:
                a = layer_arrays[p]
                o = a[f"offsets_{ch}"].astype(np.int64)
                take = nodes[p]
                member.append(a[f"membership_{ch}"][take] + n_dict)
                counts = o[take + 1] - o[take]
                offsets.append(nnz + np.cumsum(counts))
                nnz += int(counts.sum())
                idx = coefficient_indices(o[take], counts)
                values.append(a[f"values_{ch}"][idx])
                locations.append(a[f"locations_{ch}"][idx])
                tau.append(np.full(take.size, self.layers[p].tau[ch], dtype=np.int32))
                for j in range(4):
                    d = a[f"dict{j + 1}_{ch}"]
                    if j < 2:  # pad the spatial modes to the largest size
                        d = np.pad(d, ((0, 0), (0, big - p), (0, big - p)))
                    dicts[j].append(d)
                n_dict += a[f"dict1_{ch}"].shape[0]
            if nnz >= 2**31:
                raise BTFInputError(f"channel {ch}: {nnz} coefficients exceed int32 offsets")
            out[f"membership_{ch}"] = np.concatenate(member).astype(np.int32)
            out[f"offsets_{ch}"] = np.concatenate(offsets).astype(np.int32)
            out[f"values_{ch}"] = np.concatenate(values).astype(np.float32)
            out[f"locations_{ch}"] = np.concatenate(locations).astype(np.uint32)
            out[f"tau_{ch}"] = np.concatenate(tau)
            for j in range(4):
                out[f"dict{j + 1}_{ch}"] = np.ascontiguousarray(
                    np.concatenate(dicts[j]), dtype=np.float32)
        return out

    @property
    def flat_meta(self) -> dict[str, Any]:
        """:attr:`meta` for :meth:`arrays`: ``patch`` the largest size (the stride of the
        padded spatial dictionaries), ``n_points`` the nodes, ``adaptive`` True,
        ``smallest`` the size of the cells, ``nnz`` the whole tree's coefficients,
        ``tau_by_size`` each size's loaded τ (``tau`` stays the largest size's)."""
        tree = self.coded.tree
        return {**self.meta, "patch": tree.sizes[0], "n_rb": tree.height // tree.sizes[0],
                "n_points": tree.n_nodes, "adaptive": True, "smallest": tree.sizes[-1],
                "nnz": {ch: sum(rt.meta["nnz"][ch] for rt in self.layers.values())
                        for ch in ("Y", "U", "V")},
                "tau_by_size": {p: dict(rt.tau) for p, rt in self.layers.items()},
                "n_dictionaries": {ch: sum(rt.meta["n_dictionaries"][ch]
                                           for rt in self.layers.values())
                                   for ch in ("Y", "U", "V")}}  # fmt: skip

    def evaluate(self, wi: np.ndarray, wo: np.ndarray, uv: np.ndarray | None = None,
                 texel: np.ndarray | None = None, *, tau: TauSpec | np.ndarray = None,
                 backend: str = "auto", **kwargs: Any) -> np.ndarray:  # fmt: skip
        """:meth:`RuntimeBTF.evaluate` (same arguments), each query in its node's layer:
        the queries of one size go to that layer's runtime together, in one batch (angular
        weights, kernels and the inverse preprocessing as for a fixed-size material)."""
        # checked here, not only in the layers that get queries: one answer for any batch
        backend = self.layers[self.coded.tree.sizes[0]]._select_backend(backend)
        wi, wo = np.asarray(wi), np.asarray(wo)
        row, col = query_texels(uv, texel, self.coded.height, self.coded.width)
        if wi.ndim != 2 or wi.shape != wo.shape or wi.shape[0] != row.size:
            raise BTFInputError(f"wi {wi.shape} and wo {wo.shape} must be (n, 3) with n = "
                                f"{row.size} texels")  # fmt: skip
        small = self.coded.tree.sizes[-1]
        which = self.sizes[row // small, col // small]
        out = np.empty((row.size, 3), dtype=np.float32)
        for p, rt in self.layers.items():
            m = which == p
            if not m.any():
                continue
            t = tau[m] if isinstance(tau, np.ndarray) else tau
            texels = np.stack([row[m], col[m]], axis=1)
            out[m] = rt.evaluate(wi[m], wo[m], texel=texels, tau=t, backend=backend,
                                 **kwargs)  # fmt: skip
        return out

    def image(self, light: np.ndarray, view: np.ndarray, size: tuple[int, int] | None = None,
              **kwargs: Any) -> np.ndarray:  # fmt: skip
        """:meth:`RuntimeBTF.image`: an (H, W, 3) image at one light and view direction."""
        return RuntimeBTF.image(self, light, view, size, **kwargs)  # type: ignore[arg-type]
