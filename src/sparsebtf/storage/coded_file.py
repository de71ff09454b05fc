"""Coded BTF file: the sparse coefficients of one material, in HDF5 (schema in ``docs/format.md``).

Layout (``format="sparsebtf-coded"``, ``schema_version=3``, or 5 with a highlight store in
``/highlights``, :mod:`.highlight_file`; 2 and 1 are read too)::

    /                       attrs: format, schema_version, model_hash, library_version, name,
                            height, width, patch, channels (JSON list), params_json, attrs_json
    /codes/<CH>             attrs: mode_sizes (N,) int64, n_points, nnz, location_bytes (3|4),
                            n_dictionaries (K; unknown at write time: max(membership) + 1);
                            each checked against the data (required from schema 3)
    /codes/<CH>/membership  (P,) uint8 (K <= 255) or uint16     dictionary of each point (m)
    /codes/<CH>/counts      (P,) uint16 (or uint32 if a count > 65535)   coefficients per point (z)
    /codes/<CH>/location_table, table_sizes, usage, value_bytes [, rank]   schema 3:
                            :mod:`.coded_streams` (its first layout: location_gaps, values)
    /codes/<CH>/values      schema 1–2: (NNZ,) float16 (float32 only if a value overflows)
    /codes/<CH>/locations   schema 1–2: (NNZ, 3) uint8, or (NNZ, 4) when ∏m >= 2^24:
                            little-endian bytes of the column-major linear index
                            l1 + m1·l2 + m1·m2·l3 + …
    /codes/<CH>/errors      (P,) float32    residual MSE per tensor entry (diagnostic)
    /stats/mean, /stats/std (L, V, C) float32; attrs mode ("shared" | "per_channel"), eps (the
                            log offset)
    /stats/bound            (L, V) float16: largest ln(x + offset) over texels and R, G, B of each
                            angular image, rounded up; decoders clamp to it. Schema 3: always
                            there, or ``stats@clamp = "none"`` says the statistics have none
                            (release imports); schemas 1–2 without it: no clamp
    /lights, /views         direction tables, as in the dense file

Points are in release order (``point = row_block + n_row_blocks·col_block``). Schema 3
stores each dictionary's locations once with a bit per point using them, the values as byte
planes in that order, and every dataset of ``codes/`` and ``stats/`` with HDF5's built-in
``shuffle`` + ``deflate`` filters (lossless; no plugin needed); the reader gives them back,
like schemas 1–2 store them, by decreasing magnitude (ties by increasing location), so
truncating τ is a prefix read. ``params_json`` ``"objective"`` records a coding objective
other than the paper's ("linear" or "display"; absent: "log"). Schema 2 added the fletcher32
checksum to every dataset and HDF5 structures with metadata checksums
(:mod:`sparsebtf._hdf5`): a flipped bit in any dataset is reported as corruption naming the
dataset. The reader checks every attribute and dataset (dtype, shape, size against the file
and the memory budget, finiteness) before using it.
"""

from __future__ import annotations

import io
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import h5py
import numpy as np

from .._atomic import atomic_output
from .._h5check import (
    checked_dataset,
    read_array,
    read_float_attr,
    read_int_attr,
    read_json_attr,
    read_str_attr,
    require,
)
from .._hdf5 import LIBVER, CompressedGroup, create, create_dataset, write_str_attr
from .._semantic import check_same_directions, validate_coded
from .._version import library_version
from ..data.dense_file import read_directions, write_directions
from ..errors import BTFInputError, FileFormatError, ModelMismatchError
from ..learning.coding import SparseCodes
from ..learning.cost import location_width
from ..learning.objective import OBJECTIVES
from ..model import CodedBTF, Model, model_text
from ..points.grid import MAX_PATCH
from ..points.preprocessing import RELEASE_LOG_OFFSET, STD_MODES, Standardization
from ._common import check_geometry, check_str_param, check_tau_param, open_checked, to_json
from .coded_schema import NO_CLAMP, check_required
from .coded_streams import read_streams, stored_values, write_streams
from .highlight_file import HIGHLIGHT_SCHEMAS, read_highlights, store_schema, write_highlights
from .locations import pack_locations, unpack_locations
from .model_file import exact_dtype

if TYPE_CHECKING:
    from ..patch_tree import AdaptiveCodedBTF

__all__ = [
    "CODED_FORMAT",
    "CODED_SCHEMA_VERSION",
    "WRITABLE_SCHEMAS",
    "coded_image",
    "load_coded",
    "save_coded",
]

CODED_FORMAT = "sparsebtf-coded"
CODED_SCHEMA_VERSION = 3
#: The schema of a material coded with adaptive patch sizes (:mod:`.adaptive_file`).
ADAPTIVE_SCHEMA = 4
_SUPPORTED = (1, 2, 3, ADAPTIVE_SCHEMA, *HIGHLIGHT_SCHEMAS)
#: Schema 4's reader and writers, registered by :mod:`.adaptive_file` (imported with the
#: package): this module does not import the one above it.
ADAPTIVE_IO: dict[str, Callable[..., Any]] = {}
#: Schemas :func:`save_coded` can write (2: the uncompressed Table 4 layout, for old readers).
WRITABLE_SCHEMAS = (2, 3)
_MAX_SIDE = 2**20  # texels per side


# --------------------------------------------------------------------------- writing


def _check_coded(coded: CodedBTF) -> None:
    """Refuse (before anything is written) what :func:`load_coded` would refuse."""
    name = coded.name
    if not coded.channels:
        raise BTFInputError(f"{name}: no coded channels to save")
    p = coded.patch
    if p < 1 or coded.height % p or coded.width % p:
        raise BTFInputError(
            f"{name}: size {coded.height}x{coded.width} is not a multiple of the patch {p}"
        )
    if coded.stats.transform != "log_yuv":
        raise BTFInputError(
            f"{name}: coded with preprocessing {coded.stats.transform!r}; the coded file format "
            "stores log-YUV statistics only (that preprocessing is an evaluation baseline)"
        )
    nl, nv = len(coded.lights), len(coded.views)
    if coded.stats.mean.shape[:2] != (nl, nv):
        raise BTFInputError(
            f"{name}: statistics are {coded.stats.mean.shape[:2]} (lights, views) but the "
            f"direction tables have {nl} x {nv}"
        )
    for ch in coded.channels:
        c = coded.codes[ch]
        check_geometry(c.mode_sizes, p, nl, nv, f"{name}, channel {ch}", BTFInputError)
        if c.n_points != coded.n_points:
            raise BTFInputError(
                f"{name}, channel {ch}: {c.n_points} coded points, but a {coded.height}x"
                f"{coded.width} texture in {p}x{p} patches has {coded.n_points}"
            )
        if c.n_points and (int(c.membership.min()) < 0 or int(c.counts.min()) < 0):
            raise BTFInputError(f"{name}, channel {ch}: negative membership or count")
        k = coded.dictionary_count(ch)
        if k is not None and c.n_points and int(c.membership.max()) >= k:
            raise BTFInputError(
                f"{name}, channel {ch}: membership {int(c.membership.max())} but only {k} "
                f"dictionaries"
            )
        if not np.all(np.isfinite(c.values)):
            raise BTFInputError(
                f"{name}, channel {ch}: {int((~np.isfinite(c.values)).sum())} NaN/Inf values"
            )
    # the K each channel's file records (:func:`written_k`), as the reader will check it
    ks = {ch: written_k(coded.dictionary_count(ch), coded.codes[ch]) for ch in coded.channels}
    try:  # the reader's semantic checks, so that no file is written that cannot be read
        validate_coded(coded, name, ks)
    except FileFormatError as e:
        raise BTFInputError(str(e)) from None


def save_coded(
    coded: CodedBTF, path: str | os.PathLike[str], *, schema: int = CODED_SCHEMA_VERSION
) -> Path:
    """Write ``coded`` to ``path`` (HDF5, atomically: an interrupted write leaves no file).

    Values are rounded to binary16 (round-to-nearest-even, as the release's ``.bin`` files);
    a channel with a finite value beyond ±65504 is kept in float32 instead, with a warning.
    ``schema`` 3 (default) stores each dictionary's locations once with a usage bit per point
    and the values as byte planes (:mod:`.coded_streams`), and compresses every dataset of
    ``codes/`` and ``stats/`` losslessly; ``schema`` 2 packs locations to 3 bytes (4 when
    ∏m ≥ 2^24), uncompressed, as the paper's Table 4 counts them. Both decode to the same
    values in the same order. The file of the attached model (if it was saved or loaded from
    one) is recorded as ``params["model_file"]`` unless one is set already, so the coded file
    finds its model. Returns the path written.
    """
    if not isinstance(coded, CodedBTF):  # adaptive patch sizes: schema 4
        return ADAPTIVE_IO["save"](coded, path)  # type: ignore[no-any-return]
    _check_schema(schema)
    _check_coded(coded)
    target = Path(path)
    with atomic_output(target) as tmp, create(tmp) as f:
        write_coded(f, coded, _file_params(coded), schema)
    return target


def coded_image(coded: CodedBTF, schema: int = CODED_SCHEMA_VERSION) -> bytes:
    """The bytes :func:`save_coded` would write for ``coded``, made in memory (to measure the
    stored size without touching the disk)."""
    if not isinstance(coded, CodedBTF):  # adaptive patch sizes: schema 4
        return ADAPTIVE_IO["image"](coded)  # type: ignore[no-any-return]
    _check_schema(schema)
    _check_coded(coded)
    buf = io.BytesIO()
    with h5py.File(buf, "w", libver=LIBVER) as f:
        write_coded(f, coded, _file_params(coded), schema)
    return buf.getvalue()


def _check_schema(schema: int) -> None:
    if schema not in WRITABLE_SCHEMAS:
        raise BTFInputError(
            f"coded files are written in schema {' or '.join(map(str, WRITABLE_SCHEMAS))}, "
            f"not {schema}"
        )


def _file_params(coded: CodedBTF) -> dict:
    """``coded.params`` with the attached model's file recorded (when it has one)."""
    params = dict(coded.params)
    if not params.get("model_file") and coded.model is not None and coded.model.file:
        params["model_file"] = coded.model.file
    return params


def write_coded(f: h5py.File, coded: CodedBTF, params: dict, schema: int) -> None:
    """The content of a coded file into the open, empty HDF5 file ``f`` (see
    :func:`save_coded`; also used to measure the stored size without a file). A material
    with a highlight store is schema 5, 6 with lobes, 7 compact, 8 tinted (:mod:`.highlight_file`):
    schema 3 and the store."""
    store = coded.highlight_store
    if store is not None and schema != CODED_SCHEMA_VERSION:
        raise BTFInputError(f"{coded.name}: a highlight store is written in schema "
                            f"{store_schema(store)} (schema 3 and the store), not {schema}")
    write_root(f, coded, params, store_schema(store) if store is not None else schema)
    root = f.create_group("codes")
    for ch in coded.channels:
        k = coded.dictionary_count(ch)
        _write_codes(root.create_group(ch), coded.codes[ch], k, schema, coded.name, ch)
    write_shared(f, coded, schema)
    if store is not None:
        write_highlights(f, store, coded.patch ** 2 * len(coded.lights) * len(coded.views))


def write_root(f: h5py.File, coded: Any, params: dict, schema: int) -> None:
    """The root attributes of a coded file (``coded``: a coded BTF, or an adaptive one)."""
    write_str_attr(f, "format", CODED_FORMAT)
    f.attrs["schema_version"] = int(schema)
    write_str_attr(f, "model_hash", coded.model_hash)
    write_str_attr(f, "library_version", library_version())
    write_str_attr(f, "name", coded.name)
    f.attrs["height"] = int(coded.height)
    f.attrs["width"] = int(coded.width)
    f.attrs["patch"] = int(coded.patch)
    write_str_attr(f, "channels", json.dumps(list(coded.channels)))
    write_str_attr(f, "params_json", to_json(params))
    write_str_attr(f, "attrs_json", to_json(coded.attrs))


def write_shared(f: h5py.File, coded: CodedBTF, schema: int) -> None:
    """The statistics and direction tables of ``coded`` (every schema; 4 as 3)."""
    st = f.create_group("stats")
    if schema >= 3:  # every dataset of the group compressed, whoever adds it
        st = CompressedGroup(st.id)
    write_str_attr(st, "mode", coded.stats.mode)
    st.attrs["eps"] = float(coded.stats.log_offset)  # the attribute keeps its name
    for name in ("mean", "std"):
        a = np.asarray(getattr(coded.stats, name), dtype="<f4")
        # schema 3: binary16 when that holds every value exactly (the encoders' statistics)
        create_dataset(st, name, data=a.astype(exact_dtype(a)) if schema >= 3 else a)
    if coded.stats.bound is not None:
        # Exact: the bound is a multiple of 1/32 (round_up_bound), which binary16 holds.
        create_dataset(st, "bound", data=np.asarray(coded.stats.bound, dtype="<f2"))
    elif schema >= 3:  # say so: a schema-3 file without a bound is otherwise a damaged one
        write_str_attr(st, *NO_CLAMP)
    write_directions(f.create_group("lights"), coded.lights)
    write_directions(f.create_group("views"), coded.views)


def written_k(k: int | None, c: SparseCodes) -> int:
    """The ``n_dictionaries`` a channel's file records: K, or when K is unknown to the writer
    the fewest dictionaries the memberships use (a lower bound: the reader checks the
    memberships against it, and against the model's K when it is attached)."""
    if k is not None:
        return k
    return int(c.membership.max()) + 1 if c.n_points else 1


def _write_codes(
    g: h5py.Group, c: SparseCodes, k: int | None, schema: int, name: str, ch: str
) -> None:
    sizes = tuple(int(m) for m in c.mode_sizes)
    packed = schema >= 3
    g.attrs["mode_sizes"] = np.array(sizes, dtype=np.int64)
    g.attrs["n_points"] = c.n_points
    g.attrs["nnz"] = c.nnz
    g.attrs["location_bytes"] = location_width(sizes)
    k_eff = written_k(k, c)
    g.attrs["n_dictionaries"] = k_eff
    m_dtype = "<u1" if k_eff <= 255 else "<u2" if k_eff <= 65535 else "<u4"
    create_dataset(g, "membership", data=np.asarray(c.membership).astype(m_dtype),
                   compress=packed)  # fmt: skip
    big = c.n_points and int(c.counts.max()) > 65535
    create_dataset(g, "counts", data=np.asarray(c.counts).astype("<u4" if big else "<u2"),
                   compress=packed)  # fmt: skip
    if packed:
        write_streams(g, c, f"{name}, channel {ch}")
    else:
        create_dataset(g, "values", data=stored_values(c.values, f"{name}, channel {ch}"))
        create_dataset(g, "locations", data=pack_locations(c.locations, sizes))
    create_dataset(g, "errors", data=np.asarray(c.errors).astype("<f4"), compress=packed)


# --------------------------------------------------------------------------- reading


def load_coded(path: str | os.PathLike[str], model: Model | None = None, *,
               adaptive: bool = False) -> CodedBTF | AdaptiveCodedBTF:  # fmt: skip
    """Read a coded file written by :func:`save_coded`; attach ``model`` if given.

    Schema 4 (adaptive patch sizes) is read, as an :class:`~sparsebtf.patch_tree.
    AdaptiveCodedBTF`, with ``adaptive=True`` only; else it is one line naming its readers.

    Values come back as float32 (the stored binary16 values, exactly), locations as int32
    multi-indices in the stored per-point order (decreasing magnitude), errors as float64.

    Raises
    ------
    FileFormatError
        Not HDF5 or truncated; wrong ``format``; unsupported ``schema_version``; a missing
        dataset (named); inconsistent shapes; values that cannot be right
        (:func:`sparsebtf._semantic.validate_coded`: statistics, counts, memberships beyond
        K, locations outside the data point or repeated within a point, directions); mode
        sizes differing from the given model's.
    ModelMismatchError
        ``model`` is not the model the file was coded with (both hashes are named).
    """
    p = Path(path)
    where = str(p)
    with open_checked(p, CODED_FORMAT, _SUPPORTED) as f:
        schema = read_int_attr(f, "schema_version", where)
        if schema == ADAPTIVE_SCHEMA:  # read, or refused in one line, by :mod:`.adaptive_file`
            return ADAPTIVE_IO["read"](f, where, model, adaptive)  # type: ignore[no-any-return]
        check_required(f, schema, where)  # no field of the schema it claims left to a default
        model_hash = read_str_attr(f, "model_hash", where)
        name = read_str_attr(f, "name", where) if "name" in f.attrs else p.stem
        height = read_int_attr(f, "height", where, 1, _MAX_SIDE)
        width = read_int_attr(f, "width", where, 1, _MAX_SIDE)
        patch = read_int_attr(f, "patch", where, 1, MAX_PATCH)
        params = read_json_attr(f, "params_json", where)
        check_tau_param(params, "tau", where)
        check_str_param(params, "model_file", where)
        check_str_param(params, "objective", where, OBJECTIVES)
        attrs = read_json_attr(f, "attrs_json", where)
        root = require(f, "codes", where)
        channels = _channels(f, root, where)
        if patch < 1 or height % patch or width % patch:
            raise FileFormatError(
                f"{where}: size {height}x{width} is not a multiple of the patch {patch}"
            )
        n_points = (height // patch) * (width // patch)
        codes: dict[str, SparseCodes] = {}
        ks: dict[str, int] = {}
        for ch in channels:
            g = require(root, ch, f"{where}/codes")
            if not isinstance(g, h5py.Group):
                raise FileFormatError(f"{where}/codes/{ch}: expected a group, found a dataset")
            codes[ch], k = _read_codes(g, f"{where}/codes/{ch}", n_points, schema)
            if k is not None:
                ks[ch] = k
        stats = _read_stats(require(f, "stats", where), f"{where}/stats")
        lights = read_directions(require(f, "lights", where), f"{where}/lights")
        views = read_directions(require(f, "views", where), f"{where}/views")
        store = (read_highlights(f, where, n_points, patch, len(lights), len(views), schema)
                 if schema in HIGHLIGHT_SCHEMAS else None)  # fmt: skip

    nl, nv = len(lights), len(views)
    if stats.mean.shape[:2] != (nl, nv):
        raise FileFormatError(
            f"{where}/stats: (lights, views) = {stats.mean.shape[:2]} but the direction tables "
            f"have {nl} x {nv}"
        )
    for ch, c in codes.items():
        check_geometry(c.mode_sizes, patch, nl, nv, f"{where}/codes/{ch}", FileFormatError)
    coded = CodedBTF(
        codes=codes,
        stats=stats,
        height=height,
        width=width,
        patch=patch,
        lights=lights,
        views=views,
        model_hash=model_hash,
        params=params,
        name=name,
        attrs=attrs,
        source=where,
        highlights=store,
    )
    validate_coded(coded, where, ks)
    if model is not None:
        attach_model(coded, model, where)
    return coded


def attach_model(coded: CodedBTF, model: Model, where: str) -> None:
    """Attach ``model`` to ``coded`` after checking it is the one the codes index: content
    hash, channels, mode sizes, K and the direction tables (``where`` names the file)."""
    if model.content_hash != coded.model_hash:
        raise ModelMismatchError(
            f"{where}: coded with {model_text(coded.model_hash, coded.model_file)}, but the "
            f"given model is {model_text(model.content_hash, model.file)}; load the model "
            "this BTF was coded with"
        )
    for ch, c in coded.codes.items():
        if ch not in model.dictionaries:
            raise FileFormatError(
                f"{where}: channel {ch} is coded, but its model has only {model.channels}"
            )
        model_sizes = tuple(int(m.shape[1]) for m in model.dictionaries[ch])
        if tuple(int(m) for m in c.mode_sizes) != model_sizes:
            raise FileFormatError(
                f"{where}/codes/{ch}: mode sizes {tuple(c.mode_sizes)} disagree with the model's "
                f"{model_sizes}"
            )
        _check_membership(c, model.n_dictionaries(ch), f"{where}/codes/{ch}", "the model's K")
    for group, mine, theirs in (("lights", coded.lights, model.lights),
                                ("views", coded.views, model.views)):  # fmt: skip
        check_same_directions(mine.xyz, theirs.xyz, f"{where}/{group}/xyz", "the model's")
    coded.attach(model)


def _check_membership(c: SparseCodes, k: int | None, where: str, source: str) -> None:
    if k is not None and c.n_points and int(c.membership.max()) >= k:
        bad = int(np.argmax(c.membership >= k))
        raise FileFormatError(
            f"{where}/membership: point {bad} uses dictionary {int(c.membership[bad])}, but "
            f"{source} is {k}"
        )


def _channels(f: h5py.File, root: h5py.Group, where: str) -> list[str]:
    if "channels" not in f.attrs:
        return list(root.keys())
    try:
        channels = json.loads(read_str_attr(f, "channels", where))
    except (ValueError, RecursionError):
        raise FileFormatError(f"{where}: attribute 'channels' is not a JSON list") from None
    if (
        not isinstance(channels, list)
        or not channels
        or not all(isinstance(c, str) and c for c in channels)
    ):
        raise FileFormatError(f"{where}: attribute 'channels' must be a non-empty list of names")
    return channels


def _mode_sizes(g: h5py.Group, where: str) -> tuple[int, ...]:
    """The ``mode_sizes`` attribute: 4 or 5 positive integers whose product fits 4 bytes."""
    if "mode_sizes" not in g.attrs:
        raise FileFormatError(f"{where}: missing attribute 'mode_sizes'")
    raw = np.asarray(g.attrs["mode_sizes"])
    if raw.dtype.kind not in "iu" or raw.ndim != 1 or raw.size not in (4, 5):
        raise FileFormatError(
            f"{where}: attribute 'mode_sizes' must be 4 or 5 integers, found {raw.dtype} "
            f"{raw.shape}"
        )
    sizes = tuple(int(m) for m in raw)
    if min(sizes) < 1 or int(np.prod(sizes, dtype=object)) > 2**32:
        raise FileFormatError(
            f"{where}: attribute 'mode_sizes' is {sizes}; expected positive sizes whose product "
            "is at most 2^32"
        )
    return sizes


def _read_codes(
    g: h5py.Group, where: str, n_points: int, schema: int
) -> tuple[SparseCodes, int | None]:
    sizes = _mode_sizes(g, where)
    k = _dictionary_count(g, where)
    membership = read_array(g, "membership", where, kinds="u", shape=(n_points,))
    counts = read_array(g, "counts", where, kinds="u", shape=(n_points,)).astype(np.int64)
    errors = read_array(g, "errors", where, kinds="f", shape=(n_points,))
    total = int(counts.sum(dtype=np.int64))
    if schema >= 3:
        values, locations = read_streams(g, where, sizes, membership, counts, total)
    else:
        values, locations = _read_packed(g, where, sizes, total)
    # after the data agree among themselves (their own messages are the more telling)
    _check_size_attrs(g, where, {
        "n_points": (n_points, "the texture's grid (schema 4: its tree's nodes)"),
        "nnz": (total, "the sum of 'counts'"),
        "location_bytes": (location_width(sizes), "the width 'mode_sizes' needs"),
    })  # fmt: skip
    try:
        codes = SparseCodes(
            sizes,
            membership.astype(np.int64),
            counts,
            values.astype(np.float32),
            locations,
            errors.astype(np.float64),
        )
    except BTFInputError as e:
        raise FileFormatError(f"{where}: {e}") from None
    return codes, k


def _dictionary_count(g: h5py.Group, where: str) -> int | None:
    """``n_dictionaries`` (K): required from schema 3 (:mod:`.coded_schema`; the writer always
    records it), checked against the memberships by :func:`~sparsebtf._semantic.validate_coded`
    and against the model's K when one is attached; older files may lack it."""
    if "n_dictionaries" not in g.attrs:
        return None
    return read_int_attr(g, "n_dictionaries", where, 1, 2**32)


def _check_size_attrs(g: h5py.Group, where: str, expected: dict[str, tuple[int, str]]) -> None:
    """The channel's counts (``n_points``, ``nnz``, ``location_bytes``) must equal what its
    data give: a count that disagrees is damage, even where the reader need not use it.
    Required from schema 3 (:mod:`.coded_schema`); checked when present in older files."""
    for key, (want, source) in expected.items():
        if key not in g.attrs:
            continue
        found = read_int_attr(g, key, where)
        if found != want:
            raise FileFormatError(
                f"{where}: attribute {key!r} is {found}, but {source} gives {want}; the file "
                "is damaged"
            )


def _read_packed(
    g: h5py.Group, where: str, sizes: tuple[int, ...], total: int
) -> tuple[np.ndarray, np.ndarray]:
    """Schemas 1–2: (NNZ,) values and (NNZ, w) packed locations, in magnitude order."""
    values_ds = checked_dataset(g, "values", where, kinds="f", shape=(None,))
    if total != values_ds.shape[0]:
        raise FileFormatError(
            f"{where}: counts sum to {total} coefficients but 'values' holds {values_ds.shape[0]}"
        )
    width = location_width(sizes)
    loc_ds = checked_dataset(g, "locations", where, kinds="u", shape=(None, None))
    if loc_ds.shape != (total, width) or loc_ds.dtype.itemsize != 1:
        raise FileFormatError(
            f"{where}/locations: expected ({total}, {width}) uint8 (one packed location per "
            f"value), found {loc_ds.shape} {loc_ds.dtype}"
        )
    values = read_array(g, "values", where, kinds="f", finite=True)
    packed = read_array(g, "locations", where, kinds="u")
    try:
        return values, unpack_locations(packed, sizes)
    except BTFInputError as e:
        raise FileFormatError(f"{where}: {e}") from None


def _read_stats(g: h5py.Group, where: str) -> Standardization:
    mean = read_array(g, "mean", where, kinds="f", shape=(None, None, None), finite=True)
    std = read_array(g, "std", where, kinds="f", shape=(None, None, None), finite=True)
    mode = read_str_attr(g, "mode", where)
    if mode not in STD_MODES:
        raise FileFormatError(f"{where}: attribute 'mode' is {mode!r}, expected one of {STD_MODES}")
    if mean.shape != std.shape:
        raise FileFormatError(
            f"{where}: 'mean' is {mean.shape} but 'std' is {std.shape}; they must agree"
        )
    log_offset = read_float_attr(g, "eps", where, default=RELEASE_LOG_OFFSET, positive=True)
    bound = None
    clamp = read_str_attr(g, NO_CLAMP[0], where) if NO_CLAMP[0] in g.attrs else None
    if clamp is not None and (clamp != NO_CLAMP[1] or "bound" in g):
        raise FileFormatError(
            f"{where}: attribute {NO_CLAMP[0]!r} is {clamp!r}; the only value is "
            f"{NO_CLAMP[1]!r}, in a file without a 'bound' dataset"
        )
    if "bound" in g:
        bound = read_array(g, "bound", where, kinds="f", shape=mean.shape[:2], finite=True)
        bound = bound.astype(np.float32)  # its values are checked with the other statistics
    try:
        return Standardization(
            mode=mode,  # type: ignore[arg-type]
            mean=mean.astype(np.float64),
            std=std.astype(np.float64),
            log_offset=log_offset,
            bound=bound,
        )
    except BTFInputError as e:
        raise FileFormatError(f"{where}: {e}") from None


def load_coded_with_model(path: str | os.PathLike[str], model_path: str | os.PathLike[str]
                          | None = None, *, adaptive: bool = False
                          ) -> CodedBTF | AdaptiveCodedBTF:  # fmt: skip
    """Read a coded file with its model attached.

    The model is ``model_path`` (a model file, or the name of a bundled model such as
    ``"release"``), else found from the file: a bundled model whose content hash is the one
    the codes name, else the model file recorded at encoding (``params["model_file"]``). The
    content hash is checked either way (:class:`~sparsebtf.errors.ModelMismatchError` for the
    wrong model).
    """
    from .bundled import find_model

    coded = load_coded(path, adaptive=adaptive)
    model = find_model(coded, model_path, str(path))
    if not isinstance(coded, CodedBTF):  # adaptive patch sizes (``adaptive``)
        return ADAPTIVE_IO["attach"](coded, model, str(path))  # type: ignore[no-any-return]
    attach_model(coded, model, str(path))
    return coded
