"""Model file: the K orthonormal dictionaries per channel, in HDF5 (schema in ``docs/format.md``).

Layout (``format="sparsebtf-model"``, ``schema_version=2``; schema 1 lacks the checksums)::

    /                         attrs: format, schema_version, content_hash, library_version,
                              patch, channels (JSON list), params_json, provenance_json,
                              training_json (all required from schema 2)
    /dictionaries/<CH>        attrs: n_dictionaries (K), mode_sizes (N,) int64 (checked against
                              the datasets from schema 2)
    /dictionaries/<CH>/modeN  (K, m_n, m_n) float64 (float32 / float16 when that type holds
                              every value exactly; shuffle + deflate filters, lossless);
                              [k, row, col]: row = sample index
                              (texel offset or direction), col = atom index (paper Eq. 4/5)
    /lights, /views           direction tables (xyz, theta, phi), as in the dense file
    /patches/<p>/<CH>/modeN   schema 3 only: the ensemble at another patch size p (adaptive
                              patch sizes), laid out as /dictionaries/<CH>; root attribute
                              patch_sizes (JSON list, largest first). A model of one size is
                              written in schema 2, as before.

Dictionaries are stored so that their float64 values come back bit for bit: in float64, or in
the narrowest of float16 / float32 that represents every value exactly (a model rounded to
float32, like the bundled one, takes half the bytes). So :attr:`Model.content_hash` — the
address coded files refer to, always computed on float64 values — is recomputed exactly on
load; a mismatch means the file was corrupted. (The
release stores binary16 dictionaries; Table 4 of the paper counts 2 bytes per entry, which
:mod:`sparsebtf.storage.accounting` follows regardless of the file's dtype.) Schema 2 adds the
fletcher32 checksum to every dataset and HDF5 structures with metadata checksums
(:mod:`sparsebtf._hdf5`); every dataset is checked for dtype, shape, size and finiteness before
it is used.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import h5py
import numpy as np

from .._atomic import atomic_output
from .._h5check import (
    as_str,
    checked_dataset,
    read_array,
    read_int_attr,
    read_json_attr,
    read_str_attr,
    require,
)
from .._hdf5 import create, create_dataset, write_str_attr
from .._semantic import (
    ORTHONORMAL_TOLERANCE,
    ORTHONORMAL_TOLERANCE_FP16,
    check_orthonormal,
    validate_model_dictionaries,
)
from .._version import library_version
from ..data.dense_file import read_directions, write_directions
from ..errors import BTFInputError, FileFormatError
from ..model import Model, dictionaries_hash
from ..points.grid import MAX_PATCH
from ..points.preprocessing import STD_MODES, TRANSFORMS
from ._common import check_geometry, check_str_param, check_tau_param, open_checked, to_json

__all__ = ["MODEL_FORMAT", "MODEL_SCHEMA_PATCHES", "MODEL_SCHEMA_VERSION", "exact_dtype",
           "load_model", "save_model"]

MODEL_FORMAT = "sparsebtf-model"
MODEL_SCHEMA_VERSION = 2
#: The schema of a model with several patch sizes (``/patches``): older readers refuse it.
MODEL_SCHEMA_PATCHES = 3
_SUPPORTED = (1, 2, 3)


def save_model(model: Model, path: str | os.PathLike[str]) -> Path:
    """Write ``model`` to ``path`` (HDF5, atomically: an interrupted write leaves no file).

    Every mode is stored in the narrowest of float16 / float32 / float64 that holds its values
    exactly (:func:`exact_dtype`), so the content hash that coded files refer to is preserved
    exactly, with HDF5's built-in lossless ``shuffle`` + ``deflate`` filters (any HDF5 reader
    has them). Returns the path written; ``model.file`` remembers it.
    """
    target = Path(path)
    ensembles = {model.patch: model.dictionaries, **model.patches}
    for p, ens in ensembles.items():
        for ch in model.channels:
            sizes = tuple(int(m.shape[1]) for m in ens[ch])
            what = f"model channel {ch}" + (f", patch {p}" if model.patches else "")
            check_geometry(sizes, p, len(model.lights), len(model.views), what, BTFInputError)
            mats = ens[ch]
            half = all(exact_dtype(m) == "<f2" for m in mats)
            try:  # what load_model refuses is not written
                check_orthonormal(mats, what,
                                  ORTHONORMAL_TOLERANCE_FP16 if half else ORTHONORMAL_TOLERANCE)
            except FileFormatError as e:
                raise BTFInputError(str(e)) from None
    with atomic_output(target) as tmp, create(tmp) as f:
        write_str_attr(f, "format", MODEL_FORMAT)
        f.attrs["schema_version"] = MODEL_SCHEMA_PATCHES if model.patches else MODEL_SCHEMA_VERSION
        write_str_attr(f, "content_hash", model.content_hash)
        write_str_attr(f, "library_version", library_version())
        f.attrs["patch"] = int(model.patch)
        write_str_attr(f, "channels", json.dumps(list(model.channels)))
        write_str_attr(f, "params_json", to_json(model.params))
        write_str_attr(f, "provenance_json", to_json(model.provenance))
        write_str_attr(f, "training_json", to_json(model.training))
        _write_ensembles(f.create_group("dictionaries"), model.dictionaries, model.channels)
        if model.patches:
            write_str_attr(f, "patch_sizes", json.dumps(list(model.patch_sizes)))
            extra = f.create_group("patches")
            for p in sorted(model.patches, reverse=True):
                _write_ensembles(extra.create_group(str(p)), model.patches[p], model.channels)
        write_directions(f.create_group("lights"), model.lights)
        write_directions(f.create_group("views"), model.views)
    model.file = str(target.resolve())
    return target


def _write_ensembles(root: h5py.Group, ensembles: dict[str, list[np.ndarray]],
                     channels: tuple[str, ...]) -> None:  # fmt: skip
    for ch in channels:
        mats = ensembles[ch]
        g = root.create_group(ch)
        g.attrs["n_dictionaries"] = int(mats[0].shape[0])
        g.attrs["mode_sizes"] = np.array([m.shape[1] for m in mats], dtype=np.int64)
        for n, m in enumerate(mats, start=1):
            a = np.asarray(m, dtype="<f8")
            create_dataset(g, f"mode{n}", data=a.astype(exact_dtype(a)), compress=True)


def exact_dtype(values: np.ndarray) -> str:
    """The narrowest of ``<f2``, ``<f4``, ``<f8`` whose cast gives back ``values`` exactly
    (as float64 bit patterns, so the content hash cannot change)."""
    a = np.asarray(values, dtype="<f8")
    with np.errstate(over="ignore"):
        for dt in ("<f2", "<f4"):
            if np.array_equal(a.astype(dt).astype("<f8").view("<u8"), a.view("<u8")):
                return dt
    return "<f8"


def load_model(path: str | os.PathLike[str]) -> Model:
    """Read a model file written by :func:`save_model`.

    Raises :class:`~sparsebtf.errors.FileFormatError` (naming the file and field) for a file
    that is not HDF5 or is truncated, has the wrong ``format``, an unsupported
    ``schema_version``, a missing or misshapen dataset, dictionaries whose recomputed
    content hash differs from the stored one (corruption), dictionaries that are not
    orthonormal (:func:`sparsebtf._semantic.check_orthonormal`) or direction tables that are
    not distinct unit vectors.
    """
    p = Path(path)
    with open_checked(p, MODEL_FORMAT, _SUPPORTED) as f:
        where = str(p)
        schema = read_int_attr(f, "schema_version", where)
        _check_root(f, schema, where)
        stored_hash = read_str_attr(f, "content_hash", where)
        patch = read_int_attr(f, "patch", where, 1, MAX_PATCH)
        root = require(f, "dictionaries", where)
        channels = _channel_list(f, root, where)
        tolerance: dict[str, float] = {}
        dictionaries = _read_ensembles(root, channels, f"{where}/dictionaries", tolerance,
                                       schema)  # fmt: skip
        patches = _read_patches(f, channels, patch, where, tolerance, schema)
        lights = read_directions(require(f, "lights", where), f"{where}/lights")
        views = read_directions(require(f, "views", where), f"{where}/views")
        params = read_json_attr(f, "params_json", where)
        check_tau_param(params, "tau_train", where)
        check_str_param(params, "std_mode", where, STD_MODES)
        check_str_param(params, "preprocessing", where, TRANSFORMS)
        provenance = read_json_attr(f, "provenance_json", where)
        training = read_json_attr(f, "training_json", where)

    for size, ens, at in ((patch, dictionaries, "dictionaries"),
                          *((q, e, f"patches/{q}") for q, e in patches.items())):  # fmt: skip
        for ch, mats in ens.items():
            check_geometry(
                tuple(m.shape[1] for m in mats), size, len(lights), len(views),
                f"{where}/{at}/{ch}", FileFormatError,
            )
    found = dictionaries_hash(dictionaries)
    for q, ens in patches.items():
        validate_model_dictionaries(ens, f"{where}/patches/{q}", tolerance)
    if patches:
        try:
            found = Model(dictionaries, patch, lights, views, patches=patches).content_hash
        except BTFInputError as e:
            raise FileFormatError(f"{where}: {e}") from None
    if found != stored_hash:
        raise FileFormatError(
            f"{where}: dictionaries are corrupted: their content hash is {found[:12]}…, but the "
            f"file records {stored_hash[:12]}…"
        )
    validate_model_dictionaries(dictionaries, f"{where}/dictionaries", tolerance)
    _check_tau_dictionaries(params, {ch: m[0].shape[0] for ch, m in dictionaries.items()}, where)
    try:
        model = Model(
            dictionaries=dictionaries, patch=patch, lights=lights, views=views,
            params=params, provenance=provenance, training=training, patches=patches,
        )
    except BTFInputError as e:
        raise FileFormatError(f"{where}: {e}") from None
    model.file = str(p.resolve())
    return model


#: Root attributes every model file carries from schema 2 on (schema 1 files may lack them:
#: no channel order, no parameters). Without ``params_json`` a model of several training
#: levels would lose its per-dictionary τ_l silently, so from schema 2 a missing one is damage.
REQUIRED_ROOT = ("library_version", "channels", "params_json", "provenance_json",
                 "training_json")  # fmt: skip


def _check_root(f: h5py.File, schema: int, where: str) -> None:
    """Refuse a schema >= 2 model that lacks an attribute of :data:`REQUIRED_ROOT`."""
    if schema < 2:
        return
    for key in REQUIRED_ROOT:
        if key not in f.attrs:
            raise FileFormatError(
                f"{where}: missing attribute {key!r}, which every schema-2 model file carries "
                f"(this file says schema {schema}); the file is damaged or was edited"
            )


def _check_group_attrs(g: h5py.Group, mats: list[np.ndarray], where: str) -> None:
    """A channel group's ``n_dictionaries`` and ``mode_sizes`` (schema >= 2 writes both):
    they must state the K and mode sizes of its datasets."""
    k = read_int_attr(g, "n_dictionaries", where, 1, 2**32)
    if k != mats[0].shape[0]:
        raise FileFormatError(
            f"{where}: attribute 'n_dictionaries' is {k}, but its datasets hold "
            f"{mats[0].shape[0]} dictionaries; the file is damaged"
        )
    raw = np.asarray(g.attrs["mode_sizes"]) if "mode_sizes" in g.attrs else None
    want = [int(m.shape[1]) for m in mats]
    if raw is None or raw.dtype.kind not in "iu" or raw.shape != (len(want),) or (
            [int(v) for v in raw] != want):  # fmt: skip
        found = "nothing" if raw is None else f"{raw.tolist()} ({raw.dtype})"
        raise FileFormatError(
            f"{where}: attribute 'mode_sizes' must be {want} (its datasets' sizes), found "
            f"{found}; the file is damaged"
        )


def _read_ensembles(root: h5py.Group, channels: list[str], where: str,
                    tolerance: dict[str, float],
                    schema: int = 2) -> dict[str, list[np.ndarray]]:  # fmt: skip
    """One ensemble per channel from ``root``/<CH>/mode1..modeN (float64); ``tolerance``
    gets each channel's orthonormality tolerance (looser where a mode is stored in fp16)."""
    dictionaries: dict[str, list[np.ndarray]] = {}
    for ch in channels:
        g = require(root, ch, where)
        gw = f"{where}/{ch}"
        if not isinstance(g, h5py.Group):
            raise FileFormatError(f"{gw}: expected a group of datasets mode1..modeN")
        names = sorted(
            (k for k in g if k.startswith("mode") and k[4:].isdigit()), key=lambda k: int(k[4:])
        )
        if [int(k[4:]) for k in names] != list(range(1, len(names) + 1)) or not names:
            raise FileFormatError(
                f"{gw}: expected datasets mode1..modeN, found {sorted(g.keys())}"
            )
        mats = []
        tolerance.setdefault(ch, ORTHONORMAL_TOLERANCE)
        for k in names:
            ds = checked_dataset(g, k, gw, kinds="f", shape=(None, None, None))
            if ds.shape[1] != ds.shape[2] or min(ds.shape) < 1:
                raise FileFormatError(
                    f"{gw}/{k}: expected shape (K, m, m) with K, m >= 1, found {ds.shape}"
                )
            if ds.dtype.itemsize == 2:
                tolerance[ch] = ORTHONORMAL_TOLERANCE_FP16
            mats.append(read_array(g, k, gw, kinds="f", finite=True).astype(np.float64))
        if len({m.shape[0] for m in mats}) != 1:
            raise FileFormatError(
                f"{gw}: modes disagree on the number of dictionaries "
                f"{[m.shape[0] for m in mats]}"
            )
        if schema >= 2:
            _check_group_attrs(g, mats, gw)
        dictionaries[ch] = mats
    return dictionaries


def _read_patches(f: h5py.File, channels: list[str], patch: int, where: str,
                  tolerance: dict[str, float],
                  schema: int) -> dict[int, dict[str, list[np.ndarray]]]:
    """The ensembles at other patch sizes (``/patches``, schema 3), checked against the
    root's ``patch_sizes``; none in a model of one size."""
    if "patches" not in f and "patch_sizes" not in f.attrs:
        return {}
    try:
        sizes = json.loads(read_str_attr(f, "patch_sizes", where))
    except (ValueError, RecursionError):
        sizes = None
    group = require(f, "patches", where)
    if (not isinstance(sizes, list) or patch not in sizes
            or not all(isinstance(p, int) and not isinstance(p, bool) for p in sizes)):
        raise FileFormatError(f"{where}: attribute 'patch_sizes' must be a JSON list of "
                              f"integers holding the patch {patch}, found {str(sizes)[:80]}")
    others = sorted((p for p in sizes if p != patch), reverse=True)
    if not isinstance(group, h5py.Group) or sorted(group.keys()) != sorted(map(str, others)):
        found = sorted(group.keys()) if isinstance(group, h5py.Group) else "a dataset"
        raise FileFormatError(f"{where}/patches: expected one group per other patch size "
                              f"{others}, found {found}")  # fmt: skip
    return {p: _read_ensembles(group[str(p)], channels, f"{where}/patches/{p}", tolerance,
                               schema) for p in others}  # fmt: skip


def _check_tau_dictionaries(params: dict, ks: dict[str, int], where: str) -> None:
    """``tau_dictionaries`` (several training levels), when present: per channel one integer
    >= 1 per dictionary."""
    value = params.get("tau_dictionaries")
    if value is None:
        return
    ok = isinstance(value, dict) and set(value) == set(ks) and all(
        isinstance(v, list) and len(v) == ks[ch]
        and all(isinstance(t, int) and not isinstance(t, bool) and t >= 1 for t in v)
        for ch, v in value.items()
    )  # fmt: skip
    if not ok:
        want = ", ".join(f"{ch}: {k}" for ch, k in ks.items())
        raise FileFormatError(
            f"{where}: attribute 'params_json': 'tau_dictionaries' must map each channel to "
            f"one integer >= 1 per dictionary ({want}), found {str(value)[:80]}"
        )


def _channel_list(f: h5py.File, root: h5py.Group, where: str) -> list[str]:
    """Channels in the stored order (attr ``channels``), else the groups under the root."""
    if "channels" in f.attrs:
        try:
            channels = json.loads(as_str(f.attrs["channels"]))
        except (ValueError, TypeError, RecursionError):
            raise FileFormatError(f"{where}: attribute 'channels' is not a JSON list") from None
        if (
            not isinstance(channels, list)
            or not channels
            or not all(isinstance(c, str) and c for c in channels)
        ):
            raise FileFormatError(f"{where}: attribute 'channels' is not a JSON list of names")
        return channels
    if not isinstance(root, h5py.Group):
        raise FileFormatError(f"{where}/dictionaries: expected a group")
    return list(root.keys())
