"""Coded file of adaptive patch sizes: schema 4 of ``sparsebtf-coded`` (``docs/format.md`` §3).

Layout (what differs from schema 3; root attributes, ``stats``, ``lights`` and ``views`` are
schema 3's, ``patch`` is the largest size)::

    /                       attrs: ... schema_version = 4, patch_sizes (S,) int64, largest first
    /tree/nodes             (N, 3) uint16 (uint32 above 65535 texels): (row, col, size) of each
                            node in texels; by decreasing size, within a size by the release
                            numbering of that size's grid (row_block + n_row_blocks·col_block)
    /sizes/<s>/<CH>         schema 3's codes group of the nodes of size s, in the table's order
                            (n_points = those nodes; a size without nodes has n_points 0)

Every texel lies in exactly one node; the reader refuses in one line a tree that overlaps,
misses texels, leaves the texture or its size's grid, or uses a size the file (or the model)
lacks. In memory the codes of each size become a layer on the whole grid of that size
(:class:`~sparsebtf.patch_tree.AdaptiveCodedBTF`).
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from .._atomic import atomic_output
from .._h5check import read_array, read_int_attr, read_json_attr, read_str_attr, require
from .._hdf5 import LIBVER, create, create_dataset
from .._semantic import validate_coded
from ..data.dense_file import read_directions
from ..errors import BTFInputError, FileFormatError, ModelMismatchError
from ..learning.cost import channel_storage
from ..learning.objective import OBJECTIVES
from ..model import CodedBTF, Model, model_text
from ..patch_tree import AdaptiveCodedBTF, PatchTree, expand_points
from ..points.grid import PatchGrid, check_nested
from ._common import check_geometry, check_str_param, check_tau_param
from .accounting import _combine, _model_file_bytes, stored_bytes
from .coded_file import (
    ADAPTIVE_IO,
    ADAPTIVE_SCHEMA,
    _channels,
    _check_coded,
    _file_params,
    _read_codes,
    _read_stats,
    _write_codes,
    attach_model,
    write_root,
    write_shared,
)
from .coded_schema import check_required

__all__ = ["adaptive_image", "adaptive_report", "attach_adaptive", "save_adaptive"]

_MAX_SIDE = 2**20


def _check(coded: AdaptiveCodedBTF) -> None:
    """What the reader refuses is not written: each layer as a coded file's, the tree."""
    coded.tree.check(coded.name)
    for layer in coded.layers.values():
        _check_coded(layer)


def _write(f: h5py.File, coded: AdaptiveCodedBTF) -> None:
    first = coded.first
    write_root(f, coded, _file_params(first), ADAPTIVE_SCHEMA)
    f.attrs["patch_sizes"] = np.array(coded.tree.sizes, dtype=np.int64)
    nodes = coded.tree.nodes
    wide = nodes.size and int(nodes.max()) > 65535
    create_dataset(f.create_group("tree"), "nodes", data=nodes.astype("<u4" if wide else "<u2"),
                   compress=True)  # fmt: skip
    sizes = f.create_group("sizes")
    for p in coded.tree.sizes:
        g = sizes.create_group(str(p))
        layer = coded.layers[p]
        for ch, c in coded.node_codes(p).items():
            _write_codes(g.create_group(ch), c, layer.dictionary_count(ch), 3, coded.name, ch)
    write_shared(f, first, 3)


def save_adaptive(coded: AdaptiveCodedBTF, path: str | os.PathLike[str]) -> Path:
    """Write ``coded`` in schema 4 (atomically); :func:`~.coded_file.save_coded` calls this
    for an adaptive material."""
    _check(coded)
    target = Path(path)
    with atomic_output(target) as tmp, create(tmp) as f:
        _write(f, coded)
    return target


def adaptive_image(coded: AdaptiveCodedBTF) -> bytes:
    """The bytes :func:`save_adaptive` would write, made in memory."""
    _check(coded)
    buf = io.BytesIO()
    with h5py.File(buf, "w", libver=LIBVER) as f:
        _write(f, coded)
    return buf.getvalue()


def _read(f: h5py.File, where: str, model: Model | None, adaptive: bool) -> AdaptiveCodedBTF:
    """Schema 4 from the open file ``f`` (:func:`~.coded_file.load_coded`); one line for a
    reader of one patch size (``adaptive`` False)."""
    if not adaptive:
        raise FileFormatError(
            f"{where}: coded with adaptive patch sizes (schema {ADAPTIVE_SCHEMA}); this "
            "reader takes one patch size (adaptive files are read by sparsebtf decode, eval, "
            "lookup, info and view, and by sparsebtf.decode and "
            "sparsebtf.runtime.AdaptiveRuntimeBTF.from_file)"
        )
    check_required(f, ADAPTIVE_SCHEMA, where)
    model_hash = read_str_attr(f, "model_hash", where)
    name = read_str_attr(f, "name", where)
    height = read_int_attr(f, "height", where, 1, _MAX_SIDE)
    width = read_int_attr(f, "width", where, 1, _MAX_SIDE)
    patch = read_int_attr(f, "patch", where, 1, _MAX_SIDE)
    raw = np.asarray(f.attrs.get("patch_sizes", []))
    if raw.ndim != 1 or raw.dtype.kind not in "iu" or raw.size < 1:
        raise FileFormatError(f"{where}: attribute 'patch_sizes' must be a list of integers, "
                              f"found {raw.dtype} {raw.shape}")  # fmt: skip
    try:
        sizes = check_nested([int(v) for v in raw])
    except BTFInputError as e:
        raise FileFormatError(f"{where}: attribute 'patch_sizes': {e}") from None
    if patch != sizes[0]:
        raise FileFormatError(f"{where}: attribute 'patch' is {patch}, but the largest of "
                              f"'patch_sizes' is {sizes[0]}")  # fmt: skip
    params = read_json_attr(f, "params_json", where)
    check_tau_param(params, "tau", where)
    check_str_param(params, "model_file", where)
    check_str_param(params, "objective", where, OBJECTIVES)
    attrs = read_json_attr(f, "attrs_json", where)
    nodes = read_array(require(f, "tree", where), "nodes", f"{where}/tree", kinds="u",
                       shape=(None, 3))  # fmt: skip
    tree = PatchTree.from_nodes(height, width, sizes, nodes, f"{where}/tree/nodes",
                                FileFormatError)  # fmt: skip
    root = require(f, "sizes", where)
    if not isinstance(root, h5py.Group) or sorted(root.keys()) != sorted(map(str, sizes)):
        found = sorted(root.keys()) if isinstance(root, h5py.Group) else "a dataset"
        raise FileFormatError(f"{where}/sizes: expected one group per patch size "
                              f"{list(sizes)}, found {found}")  # fmt: skip
    stats = _read_stats(require(f, "stats", where), f"{where}/stats")
    lights = read_directions(require(f, "lights", where), f"{where}/lights")
    views = read_directions(require(f, "views", where), f"{where}/views")
    counts = tree.counts()
    layers = {}
    for p in sizes:
        g = root[str(p)]
        gw = f"{where}/sizes/{p}"
        if not isinstance(g, h5py.Group):
            raise FileFormatError(f"{gw}: expected a group of channels, found a dataset")
        channels = _channels(f, g, where)
        codes, ks = {}, {}
        points = tree.points(p)
        n_grid = PatchGrid(height, width, p).n_points
        for ch in channels:
            c, k = _read_codes(require(g, ch, gw), f"{gw}/{ch}", counts[p], 3)
            check_geometry(c.mode_sizes, p, len(lights), len(views), f"{gw}/{ch}",
                           FileFormatError)  # fmt: skip
            codes[ch] = expand_points(c, points, n_grid)
            if k is not None:
                ks[ch] = k
        layer = CodedBTF(codes, stats, height, width, p, lights, views, model_hash, params,
                         name, attrs, source=where)  # fmt: skip
        validate_coded(layer, gw, ks)
        layers[p] = layer
    if stats.mean.shape[:2] != (len(lights), len(views)):
        raise FileFormatError(f"{where}/stats: (lights, views) = {stats.mean.shape[:2]} but "
                              f"the direction tables have {len(lights)} x {len(views)}")
    coded = AdaptiveCodedBTF(tree, layers)
    if model is not None:
        attach_adaptive(coded, model, where)
    return coded


def attach_adaptive(coded: AdaptiveCodedBTF, model: Model, where: str) -> AdaptiveCodedBTF:
    """Attach ``model`` after the checks of :func:`~.coded_file.attach_model` for every size,
    and one line for a node size the model has no ensemble for."""
    if model.content_hash != coded.model_hash:
        raise ModelMismatchError(
            f"{where}: coded with {model_text(coded.model_hash, coded.model_file)}, but the "
            f"given model is {model_text(model.content_hash, model.file)}; load the model "
            "this BTF was coded with"
        )
    for p in coded.tree.sizes:
        if p not in model.patch_sizes:
            raise FileFormatError(
                f"{where}: nodes of size {p}, but its model has patch sizes "
                f"{list(model.patch_sizes)}"
            )
        attach_model(coded.layers[p], model.for_patch(p), where)
    coded.model = model
    return coded


def adaptive_report(coded: AdaptiveCodedBTF, model: Model | None = None,
                    file_path: str | os.PathLike[str] | None = None) -> dict[str, Any]:  # fmt: skip
    """:func:`~.accounting.storage_report`'s keys for an adaptive material: Table 4 bytes of
    every node (coefficients, a membership and a count byte per node and channel) plus
    ``bytes_tree`` (one bit per split flag, :meth:`PatchTree.tree_bytes`) in
    ``bytes_table4_material``; the dictionaries of every size; ``nodes`` per size."""
    m = model if model is not None else coded.model
    counts = coded.tree.counts()
    per: dict[str, dict[str, Any]] = {}
    for ch in coded.channels:
        entries = []
        for p, layer in coded.layers.items():
            c = layer.codes[ch]
            k = layer.dictionary_count(ch, m.for_patch(p) if m is not None else None) or 1
            entries.append(channel_storage(c.nnz, counts[p], k, c.mode_sizes))
        total = {key: sum(e[key] for e in entries)
                 for key in ("nnz", "n_points", "bytes_values", "bytes_locations",
                             "bytes_coefficients", "bytes_dictionaries", "bytes_membership",
                             "bytes_counts")}  # fmt: skip
        per[ch] = total
    parts = stored_bytes(file_path if file_path is not None else adaptive_image(coded))
    st = coded.stats
    out = _combine(per, coded.height, coded.width, len(coded.lights), len(coded.views),
                   4 * (int(st.mean.size) + int(st.std.size)), parts)  # fmt: skip
    tree = coded.tree.tree_bytes()
    out["bytes_tree"] = tree
    out["bytes_table4_material"] += tree
    out["bytes_total"] += tree
    out["mib_total"] = out["bytes_total"] / 2**20
    out["compression_ratio"] = out["bytes_raw"] / out["bytes_total"]
    out["compression_ratio_table4_material"] = out["bytes_raw"] / out["bytes_table4_material"]
    out["nodes"] = {str(p): n for p, n in counts.items()}
    out["file_bytes"] = Path(file_path).stat().st_size if file_path is not None else None
    out["bytes_model_file"] = _model_file_bytes(m, coded.model_hash)
    return out


ADAPTIVE_IO.update(read=_read, save=save_adaptive, image=adaptive_image, attach=attach_adaptive)
