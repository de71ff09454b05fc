"""Exhaustive field fuzzing: every dataset and every attribute of a schema-3 coded file, a
schema-5 one (with a highlight store), a schema-6 one (a store with lobes), a schema-7 one
(a compact store with lobes), a schema-8 one (a tinted compact store), a schema-4
(adaptive) coded file and a model of several training levels (τ_l), each damaged in each of
a fixed set of ways, and the users' decode judged against the undamaged file's.

Unlike the random semantic fuzz (:mod:`.semantic`), nothing here knows the format's rules:
the oracle is the output itself. A case is

* ``rejected``: the reader raised a project error (:class:`~sparsebtf.errors.SparseBTFError`);
* ``unchanged``: accepted, and every decoded number equals the undamaged file's exactly (the
  field was not needed, or its damage could not reach the output);
* ``silent_wrong``: accepted with an output that differs (the damaged field changed what a
  user gets, with exit 0);
* ``traceback``: any other exception (a defect);
* ``legal_change``: accepted with another output where the edit is a value the format allows
  (:data:`LEGAL_EDITS`: a statistic of −1 is another material's, not damage; no reader can
  tell them apart, and none should).

A reader is right on every case when the last two never happen. The cases are deterministic
and each takes milliseconds, so the whole enumeration runs as one test.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any

import h5py
import numpy as np

__all__ = [
    "FIELD_FILES", "FIELD_KINDS", "FIELD_MUTATIONS", "FIELD_OUTCOMES", "LEGAL_EDITS",
    "build_field_corpus", "field_exercise", "file_fields", "mutate_field", "run_field_case",
    "run_field_fuzz",
]  # fmt: skip

#: The seed files, in report order: a coded file (schema 3), the same with a highlight store
#: (schema 5), with a store and lobes (schema 6), with a compact store and lobes (schema 7),
#: with a tinted compact store (schema 8), an adaptive one (schema 4), the model of several
#: training levels they are coded with.
FIELD_KINDS = ("coded3", "coded5", "coded6", "coded7", "coded8", "coded4", "model")
#: The damage done to a field: deleted, one value set to −1, 2^40 or NaN (a scalar: the
#: value), one element fewer or more along the first axis (a scalar: two copies of it).
FIELD_MUTATIONS = ("delete", "minus_one", "huge", "nan", "shorter", "longer")
FIELD_OUTCOMES = ("rejected", "unchanged", "silent_wrong", "traceback", "legal_change")
#: (dataset, mutation) pairs that give a file the format allows: a log-domain mean or bound
#: of −1 (ln of 0.37) is a valid statistic, so a different output is the right one.
#: So is a highlight correction of −1, a tint's red of −1, and a lobe's first parameter (ω_x)
#: of −1.
LEGAL_EDITS = frozenset({("stats/mean", "minus_one"), ("stats/bound", "minus_one"),
                         ("highlights/rgb", "minus_one"), ("highlights/lobes", "minus_one"),
                         ("highlights/tints", "minus_one")})

_VALUES = {"minus_one": -1, "huge": 2**40, "nan": np.nan}
#: The seed file of each kind, in the corpus folder.
FIELD_FILES = {kind: f"{kind}.h5" for kind in FIELD_KINDS}


# --------------------------------------------------------------------------- the seed files


def _smooth(seed: int, size: int = 8, n_dirs: int = 13) -> Any:
    """A small positive BTF with spatial texture and smooth angular behaviour."""
    from ..data.btf import ArrayBTF
    from ..data.directions import tiny

    rng = np.random.default_rng(seed)
    d = tiny(n_dirs)
    base = rng.uniform(0.05, 0.8, (size, size, 1, 1, 3))
    cos = d.xyz[:, 2]
    ang = (0.3 + cos)[:, None] * (0.5 + cos)[None, :]
    noise = 1 + 0.1 * rng.standard_normal((size, size, n_dirs, n_dirs, 3))
    data = base * ang[None, None, :, :, None] * np.clip(noise, 0.5, None)
    return ArrayBTF(data.astype(np.float32), d, d, name=f"field{seed}")


def build_field_corpus(folder: str | os.PathLike[str]) -> dict[str, Any]:
    """The seed files in ``folder``, made by the project's own writers at tiny shapes (8×8
    texels, 4×4 and 2×2 patches, 13 directions, K = 2 at two training levels), and each
    seed's output (:func:`field_exercise` on the undamaged file)."""
    from ..codec import encode, train
    from ..codec.adaptive import encode_adaptive
    from ..storage import save_coded, save_model

    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True)
    model = train([_smooth(s) for s in range(2)], n_dictionaries=2, tau_train="4,2,2/8,3,3",
                  patch=(4, 2), sample=1.0, max_iter=1, progress=False)  # fmt: skip
    save_model(model, d / FIELD_FILES["model"])
    coded = encode(_smooth(5), model, tau=(6, 3, 3), progress=False)
    save_coded(coded, d / FIELD_FILES["coded3"])
    save_coded(replace(coded, highlights=_store(coded)), d / FIELD_FILES["coded5"])
    save_coded(replace(coded, highlights=replace(_store(coded), lobes=_lobes(coded))),
               d / FIELD_FILES["coded6"])  # fmt: skip
    save_coded(replace(coded, highlights=replace(_store(coded, compact=True), lobes=_lobes(coded))),
               d / FIELD_FILES["coded7"])  # fmt: skip
    save_coded(replace(coded, highlights=_store(coded, tinted=True)), d / FIELD_FILES["coded8"])
    adaptive = encode_adaptive(_smooth(6), model, (8, 3, 3), target_bytes=600, progress=False)
    save_coded(adaptive, d / FIELD_FILES["coded4"])
    corpus: dict[str, Any] = {"dir": d}
    corpus["originals"] = {kind: field_exercise(kind, d / FIELD_FILES[kind], corpus)
                           for kind in FIELD_KINDS}  # fmt: skip
    return corpus


def _store(coded: Any, compact: bool = False, tinted: bool = False) -> Any:
    """A highlight store at a fifth of each point's nodes (seeded); ``compact``: its
    corrections on the E5M2 grid (written in the compact code); ``tinted``: a scale an entry
    along a tint a point (the tinted compact code)."""
    from ..learning.entry_code import quantise
    from ..learning.highlights import Highlights

    rng = np.random.default_rng(7)
    per = coded.patch**2 * len(coded.lights) * len(coded.views)
    keys = [rng.choice(per, per // 5, replace=False) for _ in range(coded.n_points)]
    pts = np.repeat(np.arange(coded.n_points), per // 5)
    rgb = rng.normal(0, 0.3, (pts.size, 3))
    if tinted:
        tints = rng.uniform(0.3, 1.0, (coded.n_points, 3))
        return Highlights.from_tinted(pts, np.concatenate(keys), rgb[:, 0], tints, coded.n_points)
    return Highlights.from_nodes(pts, np.concatenate(keys), quantise(rgb) if compact else rgb,
                                 coded.n_points)  # fmt: skip


def _lobes(coded: Any) -> np.ndarray:
    """A highlight lobe on every texel (seeded): (P, p², 8) float16."""
    rng = np.random.default_rng(8)
    n = (coded.n_points, coded.patch**2)
    return np.concatenate([rng.uniform(-0.4, 0.4, (*n, 3)), np.log(rng.uniform(0.1, 0.4, (*n, 2))),
                           rng.uniform(0.1, 2, (*n, 3))], axis=2).astype(np.float16)  # fmt: skip


# --------------------------------------------------------------------------- the users' decode


def _model(corpus: dict[str, Any]) -> Any:
    """The undamaged model, loaded once (the coded cases damage only the coded file)."""
    from ..storage import load_model

    if "model" not in corpus:
        corpus["model"] = load_model(corpus["dir"] / FIELD_FILES["model"])
    return corpus["model"]


def _decoded(coded: Any) -> list[np.ndarray]:
    """Every decoded value of a coded material (its model attached)."""
    from ..patch_tree import AdaptiveCodedBTF
    from ..runtime import coded_btf_view
    from ..runtime.adaptive import decoded_view

    view = decoded_view(coded) if isinstance(coded, AdaptiveCodedBTF) else coded_btf_view(coded)
    return [np.asarray(block) for block in view.iter_blocks()]


def field_exercise(kind: str, path: Path, corpus: dict[str, Any]) -> list[np.ndarray]:
    """What a user gets from the file ``path`` of ``kind``: a coded file decoded with the
    model; a model's dictionaries, its τ_l per dictionary and training τ, and the schema-3
    coded file decoded with it."""
    from ..storage import load_coded, load_model

    if kind.startswith("coded"):
        return _decoded(load_coded(path, _model(corpus), adaptive=kind == "coded4"))
    model = load_model(path)
    out = [u for ch in model.channels for u in model.dictionaries[ch]]
    out += [np.array(model.dictionary_taus(ch)) for ch in model.channels]
    out.append(np.array(sorted(model.tau_train.items()), dtype=object))
    out.append(np.array(model.channels, dtype=object))
    out.append(np.array(sorted(model.patch_sizes)))
    return out + _decoded(load_coded(corpus["dir"] / FIELD_FILES["coded3"], model))


# --------------------------------------------------------------------------- the damage


def file_fields(path: Path) -> list[str]:
    """Every attribute and dataset of an HDF5 file: "@attr" (root), "group@attr",
    "group/dataset" (``format`` and ``schema_version`` too: a reader must refuse those)."""
    out: list[str] = []
    with h5py.File(path, "r") as f:
        out += [f"@{a}" for a in f.attrs]

        def visit(name: str, obj: Any) -> None:
            if isinstance(obj, h5py.Dataset):
                out.append(name)
            out.extend(f"{name}@{a}" for a in obj.attrs)

        f.visititems(visit)
    return out


def _damaged(value: np.ndarray, op: str) -> np.ndarray:
    """``value`` (an array) with ``op`` applied: one element set, or one more or fewer."""
    a = np.asarray(value)
    if op in ("shorter", "longer"):
        if a.ndim == 0:
            return np.stack([a, a])
        return a[:-1] if op == "shorter" else np.concatenate([a, a[-1:]])
    target = _VALUES[op]
    out = a.copy() if a.dtype.kind in "iuf" else np.zeros(a.shape, np.int64)
    with np.errstate(all="ignore"):
        cast = np.array(target).astype(out.dtype) if out.dtype.kind in "iuf" else None
    # a value the dtype cannot hold (NaN in an integer, −1 in an unsigned) widens the type
    if cast is None or not np.array_equal(cast, np.array(target), equal_nan=True):
        out = out.astype(np.float64 if op == "nan" else np.int64)
    flat = out.reshape(-1)
    if flat.size:
        flat[0] = target
    return out if a.ndim else out.reshape(())


def mutate_field(path: Path, field: str, op: str) -> None:
    """Apply ``op`` (:data:`FIELD_MUTATIONS`) to ``field`` of the file at ``path``, in place,
    the rest of the file untouched (datasets rewritten with the writers' checksum filter)."""
    from .._hdf5 import create_dataset

    with h5py.File(path, "r+") as f:
        if "@" in field:
            group, attr = field.split("@")
            obj = f[group] if group else f
            old = obj.attrs[attr]
            del obj.attrs[attr]
            if op != "delete":
                obj.attrs[attr] = _damaged(np.asarray(old), op)
            return
        old_ds = f[field]
        data, parent, name = old_ds[()], old_ds.parent, field.rsplit("/", 1)[-1]
        kept = dict(old_ds.attrs)
        del parent[name]
        if op == "delete":
            return
        new = _damaged(np.asarray(data), op)
        ds = create_dataset(parent, name, data=new) if new.ndim else parent.create_dataset(
            name, data=new)  # fmt: skip
        for k, v in kept.items():
            ds.attrs[k] = v


# --------------------------------------------------------------------------- judging


def _same(a: list[np.ndarray], b: list[np.ndarray]) -> bool:
    return len(a) == len(b) and all(
        x.shape == y.shape and x.dtype == y.dtype and np.array_equal(x, y)
        for x, y in ((np.asarray(u), np.asarray(v)) for u, v in zip(a, b, strict=True)))


def run_field_case(corpus: dict[str, Any], kind: str, field: str, op: str,
                   folder: Path) -> dict[str, Any]:  # fmt: skip
    """Damage ``field`` of the seed of ``kind`` by ``op`` in a copy under ``folder``, run the
    users' decode and judge it (:data:`FIELD_OUTCOMES`)."""
    from ..errors import SparseBTFError

    folder.mkdir(parents=True, exist_ok=True)
    path = folder / FIELD_FILES[kind]
    shutil.copyfile(corpus["dir"] / FIELD_FILES[kind], path)
    case = {"kind": kind, "field": field, "op": op, "message": ""}
    mutate_field(path, field, op)
    try:
        result = field_exercise(kind, path, corpus)
    except SparseBTFError as e:
        return {**case, "outcome": "rejected", "message": str(e)}
    except Exception as e:  # any other exception is the defect reported
        return {**case, "outcome": "traceback", "message": f"{type(e).__name__}: {e}"}
    if _same(result, corpus["originals"][kind]):
        return {**case, "outcome": "unchanged"}
    legal = (field, op) in LEGAL_EDITS
    return {**case, "outcome": "legal_change" if legal else "silent_wrong"}


def run_field_fuzz(corpus: dict[str, Any], folder: str | os.PathLike[str],
                   kinds: tuple[str, ...] = FIELD_KINDS) -> list[dict[str, Any]]:  # fmt: skip
    """Every case of every kind: each field of the seed, each of :data:`FIELD_MUTATIONS`."""
    out = []
    for kind in kinds:
        for field in file_fields(corpus["dir"] / FIELD_FILES[kind]):
            for op in FIELD_MUTATIONS:
                out.append(run_field_case(corpus, kind, field, op, Path(folder)))
    return out
