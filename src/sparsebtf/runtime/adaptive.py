"""Decoding adaptive patch sizes (:mod:`sparsebtf.patch_tree`), layer by layer.

A material coded with adaptive patch sizes holds one layer of codes per size, each a fixed-size
coded BTF that is empty outside the nodes of its size. Every texel is read from the layer of
the node that covers it, by the fixed-size decoders: :class:`AdaptiveDecodedBTF` (the lazy
dense decode, Eq. 4 / Eq. 5 per layer) and :class:`AdaptiveRuntimeBTF` (the runtime's
queries, Eq. 5 / Eq. 6, by either backend: a layer is an ordinary fixed-size coded BTF, so
its NumPy reference and its numba kernels serve the queries routed to it as they are). Cost: a
dense read decodes the requested block once per size that has nodes in it (up to the number
of sizes times a fixed-size read); a query costs what it costs in the layer of its node. The
renderer arrays (Mitsuba plugin, WebGL viewer) do not carry the tree yet: they refuse
adaptive materials in one line.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..data.btf import BTF, Index
from ..errors import BTFInputError
from ..model import TauSpec
from ..patch_tree import AdaptiveCodedBTF
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


class AdaptiveRuntimeBTF:
    """:class:`~sparsebtf.runtime.decoder.RuntimeBTF`'s queries on an adaptive material: each
    query answered by the runtime of its node's layer, on the backend asked for (``tau`` per
    channel applies to every node, a fraction to each size's coded τ)."""

    def __init__(self, coded: AdaptiveCodedBTF, tau: TauSpec = None,
                 dtype: type = np.float32) -> None:  # fmt: skip
        coded.require_model()
        self.coded = coded
        self.layers = {p: RuntimeBTF(layer, tau, dtype) for p, layer in coded.layers.items()}
        self.sizes = coded.tree.size_map()
        first = self.layers[coded.tree.sizes[0]]
        self.meta: dict[str, Any] = {**first.meta, "patch_sizes": list(coded.tree.sizes),
                                     "nodes": coded.tree.counts()}  # fmt: skip

    @classmethod
    def from_file(cls, path: Any, model: Any = None, tau: TauSpec = None,
                  dtype: type = np.float32) -> AdaptiveRuntimeBTF:  # fmt: skip
        from ..storage import load_coded_with_model

        coded = load_coded_with_model(path, model, adaptive=True)
        if not isinstance(coded, AdaptiveCodedBTF):
            raise BTFInputError(f"{path}: coded with one patch size; use RuntimeBTF")
        return cls(coded, tau, dtype)

    def arrays(self, neighbours: bool = True) -> dict[str, np.ndarray]:
        raise BTFInputError(
            f"{self.coded.label}: coded with adaptive patch sizes; the renderer arrays (Mitsuba "
            "plugin, WebGL viewer) do not carry a patch tree yet: render a material coded with "
            "one patch size"
        )

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
