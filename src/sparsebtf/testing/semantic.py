"""Semantic fuzzing: well-formed files that say impossible things, judged by an oracle of the
formats' rules (see the comment below). Seed files come from
:mod:`sparsebtf.testing.corpus`."""

from __future__ import annotations

import os
import zipfile
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from .corpus import _directions, build_corpus

__all__ = [
    "SEMANTIC_KINDS", "SEMANTIC_OUTCOMES", "build_semantic_corpus", "run_semantic_case",
    "semantic_exercise", "write_semantic_case",
]  # fmt: skip

# =========================================================================== semantic fuzzing
#
# Well-formed files that say impossible things: one field of a valid file set to a boundary or
# impossible value (0, −1, huge, NaN, ±inf, tiny, a duplicated row, a permutation, a sign
# flip), written with the file's own structure intact (HDF5 datasets rewritten in place, a
# model's content hash and a checkpoint's SHA-256 recomputed, release words overwritten). Each
# case is judged against the format's rules by an oracle written here, apart from the readers'
# validators (:mod:`sparsebtf._semantic`), from the mutated file's raw values:
#
# * ``rejected``: the rules are broken and the reader raised a project error (correct);
# * ``correct``: the rules hold and the reader accepted the file with finite results, equal
#   to the unmutated file's when the field is one the reader does not use for its results
#   (theta/phi columns: checked against ``xyz``, never used; the angle file's index row);
# * ``silent_wrong``: accepted although the rules are broken, or accepted with results that
#   differ from the unmutated file's where the field is unused (must be 0);
# * ``false_rejection``: refused although the rules hold (reported; a stricter rule than the
#   format's is a defect too, but not a wrong output).

#: The file kinds of the semantic fuzz, in report order.
SEMANTIC_KINDS = ("ubo2014", "dense", "model", "coded", "release", "checkpoint")
SEMANTIC_OUTCOMES = ("rejected", "correct", "silent_wrong", "false_rejection")

#: Value edits applied to the chosen entries of a field.
_OPS = ("zero", "minus_one", "huge", "nan", "inf", "neg_inf", "tiny", "duplicate", "permute",
        "negate", "scale")  # fmt: skip

# The format's rules (docs/format.md §1–3, §7), restated for the oracle.
_UNIT, _CHORD, _BOUND, _OFFSETS = 1e-6, 1e-4, 40.0, (1e-12, 1.0)
_ORTHO, _ORTHO16, _COLOR = 1e-4, 2e-3, 1e4

#: Fields per kind: (name, unused by the reader).
_FIELDS: dict[str, tuple[tuple[str, bool], ...]] = {
    "ubo2014": (("ColorMean", False), ("ColorTransform", False), ("lights", False),
                ("views", False)),
    "dense": (("lights/xyz", False), ("views/xyz", False), ("lights/theta", True),
              ("views/phi", True), ("btf", False)),
    "model": (("dictionaries/Y/mode1", False), ("dictionaries/U/mode3", False),
              ("dictionaries/V/mode4", False), ("lights/xyz", False), ("views/xyz", False),
              ("lights/phi", True)),
    "coded": (("stats/mean", False), ("stats/std", False), ("stats@eps", False),
              ("stats/bound", False),
              ("codes/Y/membership", False), ("codes/Y/counts", False),
              ("codes/U/values", False), ("codes/V/locations", False), ("codes/Y/errors", False),
              ("lights/xyz", False), ("views/xyz", False), ("views/theta", True)),
    "release": (("DictEnsOrth4DY.bin", False), ("DictEnsOrth4DU.mat", False),
                ("Coeffs:LNZ", False), ("Coeffs:M", False), ("Coeffs:NNZ", False),
                ("Coeffs:values", False), ("mean_std:mean", False), ("mean_std:std", False),
                ("bonn_angles:phi", False), ("bonn_angles:elevation", False),
                ("bonn_angles:index", True)),
    "checkpoint": (("iteration", False), ("objective", False), ("passes", False),
                   ("ranking", False), ("mode0", False), ("mode2", False), ("bytes", False)),
}  # fmt: skip


def _edit(a: np.ndarray, op: str, rng: np.random.Generator, rows: bool = False) -> np.ndarray:
    """``a`` with one value edit: entries (or, with ``rows``, whole rows of a 2-D table)."""
    out = np.array(a, copy=True)
    flat = out.reshape(len(out), -1) if rows and out.ndim >= 2 else out.reshape(-1)
    n = len(flat)
    if n == 0:
        return out
    i = int(rng.integers(n))
    many = rng.choice(n, size=int(rng.integers(1, min(n, 4) + 1)), replace=False)
    kind = out.dtype.kind
    info = np.iinfo(out.dtype) if kind in "iu" else None
    if op == "duplicate" and n > 1:
        j = int((i + 1 + rng.integers(n - 1)) % n)
        flat[j] = flat[i]
    elif op == "permute" and n > 1:
        flat[...] = flat[rng.permutation(n)]
    elif kind in "US":  # text: labels from the right set, or not
        flat[many] = {"zero": "", "negate": "partial", "scale": "full"}.get(op, "bogus")
    elif op == "negate":
        flat[many] = -flat[many] if kind != "u" else flat[many]
    elif op == "scale":
        with np.errstate(all="ignore"):
            flat[many] = (flat[many] * rng.choice([0.5, 2.0, 1e-8, 1e8])).astype(out.dtype)
    else:
        value = {"zero": 0, "minus_one": -1, "tiny": 1e-8, "huge": 1e30, "nan": np.nan,
                 "inf": np.inf, "neg_inf": -np.inf}.get(op, 0)  # fmt: skip
        if info is not None:
            value = {"minus_one": info.max, "huge": info.max, "nan": info.max, "inf": info.max,
                     "neg_inf": info.min, "tiny": 1}.get(op, value)  # fmt: skip
        with np.errstate(all="ignore"):
            flat[many] = np.array(value).astype(out.dtype)
    return out


# -- the oracle: the format's rules on raw values -------------------------------------------


def _directions_ok(xyz: np.ndarray) -> bool:
    v = np.asarray(xyz, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
        return False
    if np.any(np.abs(np.sqrt((v * v).sum(axis=1)) - 1) > _UNIT) or np.any(v[:, 2] < -_UNIT):
        return False
    for i in range(len(v)):
        if np.any(np.sqrt(((v[i + 1 :] - v[i]) ** 2).sum(axis=1)) <= _CHORD):
            return False
    return True


def _angles_xyz(theta: np.ndarray, phi: np.ndarray) -> np.ndarray | None:
    """Unit vectors of polar/azimuth angles (radians), or None when θ is outside [0, 90°]."""
    if not (np.isfinite(theta).all() and np.isfinite(phi).all()):
        return None
    if np.any(theta < -1e-12) or np.any(theta > np.pi / 2 + 1e-9):
        return None
    if np.any(np.abs(phi) > 4 * np.pi):  # an azimuth, in radians
        return None
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], 1)


def _angles_ok(group: h5py.Group) -> bool:
    """A direction table's stored θ/φ (radians) give back its ``xyz`` within 1e-5 (the
    readers take directions from ``xyz``; a copy that disagrees is damage)."""
    v = np.asarray(group["xyz"][()], dtype=np.float64)
    with np.errstate(all="ignore"):
        v = v / np.linalg.norm(v, axis=1, keepdims=True)
        angles = {"theta": np.arccos(np.clip(v[:, 2], -1, 1)), "phi": np.arctan2(v[:, 1], v[:, 0])}
    for key in angles:
        if key in group:
            a = np.asarray(group[key][()], dtype=np.float64)
            if a.shape != (len(v),) or not np.isfinite(a).all():
                return False
            theta = a if key == "theta" else angles["theta"]
            phi = a if key == "phi" else angles["phi"]
            with np.errstate(all="ignore"):
                back = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                                 np.cos(theta)], 1)  # fmt: skip
            if not np.all(np.abs(back - v) <= 1e-5):
                return False
    return True


def _stats_ok(mean: np.ndarray, std: np.ndarray, log_offset: float, bound: Any = None) -> bool:
    ok = bool(
        np.isfinite(mean).all() and np.isfinite(std).all() and np.all(np.abs(mean) <= _BOUND)
        and np.all(std > 0) and np.all(std <= _BOUND) and np.isfinite(log_offset)
        and _OFFSETS[0] <= log_offset <= _OFFSETS[1]
    )  # fmt: skip
    if ok and bound is not None:  # decoded values never above exp(bound); black is ln(offset)
        ok = bool(np.isfinite(bound).all() and np.all(bound <= _BOUND)
                  and np.all(bound >= np.log(log_offset) - 1e-2))  # fmt: skip
    return ok


def _orthonormal(u: np.ndarray, tol: float) -> bool:
    a = np.asarray(u, dtype=np.float64)
    if not np.isfinite(a).all():
        return False
    return all(np.abs(m.T @ m - np.eye(m.shape[0])).max() <= tol for m in a)


def _codes_ok(sizes: tuple[int, ...], member: np.ndarray, counts: np.ndarray, values: np.ndarray,
              linear: np.ndarray, k: int, sorted_values: bool = True) -> bool:  # fmt: skip
    """Counts sum to the values, memberships < K, locations inside and distinct per point,
    values finite (and by decreasing |v| within a point when stored so)."""
    counts = counts.astype(np.int64)
    if np.any(counts < 0) or counts.sum() != len(values) or len(linear) != len(values):
        return False
    if np.any(member.astype(np.int64) >= k) or np.any(member.astype(np.int64) < 0):
        return False
    if not np.isfinite(values).all() or np.any(linear >= int(np.prod(sizes))):
        return False
    start = 0
    for c in counts:
        lin, val = linear[start : start + c], np.abs(values[start : start + c].astype(float))
        if len(set(lin.tolist())) != len(lin) or (sorted_values and np.any(np.diff(val) > 0)):
            return False
        start += c
    return True


# -- the corpus and the users' operation ------------------------------------------------------


def _checkpoint_setup() -> tuple[Any, np.ndarray]:
    from ..learning.ensemble import DictionaryEnsemble

    rng = np.random.default_rng(5)
    x = rng.normal(size=(12, 2, 2, 3, 2))
    ens = DictionaryEnsemble(n_dictionaries=2, tau=3, max_iter=1, init="random",
                             dtype="float64", progress=False)  # fmt: skip
    return ens, x


def build_semantic_corpus(folder: str | os.PathLike[str]) -> dict[str, Any]:
    """The byte-level corpus (:func:`build_corpus`) plus a training checkpoint, and each
    seed's result (what :func:`semantic_exercise` returns on the unmutated file)."""
    d = Path(folder)
    corpus: dict[str, Any] = {"files": build_corpus(d), "dir": d}
    ens, x = _checkpoint_setup()
    ens.checkpoint = str(d / "train_Y.npz")
    ens.fit(x)
    corpus["checkpoint"] = d / "train_Y.npz"
    corpus["ubo2014_args"] = _ubo2014_args()
    _write_ubo2014_case(corpus, d / "semantic_seed.btf", {})
    corpus["originals"] = {
        (kind, field): semantic_exercise(kind, _seed_file(corpus, kind, field), corpus)
        for kind in SEMANTIC_KINDS for field, unused in _FIELDS[kind] if unused
    }
    return corpus


def _seed_file(corpus: dict[str, Any], kind: str, field: str) -> Path:
    files = corpus["files"]
    if kind == "checkpoint":
        return corpus["checkpoint"]
    if kind == "release":
        stem = field.split(":")[0]
        names = {"Coeffs": "Coeffs_BTF_fuzz_1e-05_V.bin", "mean_std": "fuzz_mean_std.bin",
                 "bonn_angles": "bonn_angles.bin"}  # fmt: skip
        return corpus["dir"] / "release" / names.get(stem, stem or "DictEnsOrth4DY.bin")
    if kind == "ubo2014":
        return corpus["dir"] / "semantic_seed.btf"
    if kind == "coded":
        # schema 2: its fields are the codes themselves (schema 3 stores the same codes as
        # location tables; the semantic checks run on the codes after reading, whatever the
        # schema, and tests/test_schema3.py covers damaged tables and gaps)
        return next(p for p in files["coded"] if p.name == "coded_v2.h5")
    return files[kind][0]


def _ubo2014_args() -> dict[str, Any]:
    rng = np.random.default_rng(7)
    lights, views = _directions()
    nl, nv, h, w = len(lights), len(views), 3, 5
    spatial = [rng.normal(0, 0.3, (h * w, 2)) for _ in range(3)]
    angular = [rng.normal(0, 0.3, (nl * nv, 2)) for _ in range(3)]
    t = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    return {"spatial": spatial, "angular": angular, "height": h, "width": w,
            "theta_l": lights.theta, "phi_l": lights.phi, "theta_v": views.theta,
            "phi_v": views.phi, "color_mean": np.array([0.2, 0.3, 0.1]), "color_transform": t}


def _write_ubo2014_case(corpus: dict[str, Any], path: Path, edits: dict[str, np.ndarray]) -> None:
    from ..data.directions import DirectionSet
    from ..formats.ubo2014_write import write_ubo2014

    a = {**corpus["ubo2014_args"], **edits}

    def dirs(theta: np.ndarray, phi: np.ndarray) -> DirectionSet:
        # Written as given (no checks): the file's angle table is what is fuzzed.
        with np.errstate(all="ignore"):
            st = np.sin(theta)
            xyz = np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=1)
        return DirectionSet(xyz=xyz, theta=theta, phi=phi, name="fuzz")

    write_ubo2014(path, a["spatial"], a["angular"], a["height"], a["width"],
                  dirs(a["theta_l"], a["phi_l"]), dirs(a["theta_v"], a["phi_v"]), "DFMF",
                  "float", color_model=3, color_mean=a["color_mean"],
                  color_transform=a["color_transform"], drr=False)  # fmt: skip


def semantic_exercise(kind: str, path: Path, corpus: dict[str, Any]) -> list[np.ndarray]:
    """What a user's command does with a file of ``kind``, returning its numeric results;
    non-finite results raise (as every command does: ``decode`` and ``write_dense`` refuse
    NaN/inf, ``eval`` and ``lookup`` refuse them without ``--allow-nonfinite``)."""
    from ..data.validate import check_finite

    out: list[np.ndarray] = []
    if kind in ("ubo2014", "dense"):
        from ..open import open_btf

        btf = open_btf(path)
        out += [btf.lights.xyz, btf.views.xyz]
        for block in btf.iter_blocks():
            check_finite(block, str(path))
            out.append(block)
    elif kind == "model":
        from ..storage import load_model

        m = load_model(path)
        out += [m.lights.xyz, m.views.xyz]
        out += [u for ch in m.channels for u in m.dictionaries[ch]]
    elif kind == "coded":
        from ..runtime import RuntimeBTF, coded_btf_view
        from ..storage import load_coded_with_model

        coded = load_coded_with_model(path, corpus["dir"] / "model.h5")
        view = coded_btf_view(coded)
        for block in view.iter_blocks():
            check_finite(block, str(path))
            out.append(block)
        arrays = RuntimeBTF(coded, tau=0.5).arrays(neighbours=False)
        out += [np.asarray(v) for _, v in sorted(arrays.items())]
    elif kind == "release":
        from ..storage import release

        name = path.name
        if name.startswith("DictEnsOrth4D"):
            out += release.read_dictionaries(path, 2, (2, 2, 3, 2))[0]
        elif name.startswith("Coeffs_BTF_"):
            c = release.read_coefficients(path, n_points=4, n_dictionaries=2)
            out += [c.membership, c.counts, c.values, c.locations]
        elif name.endswith("_mean_std.bin"):
            s = release.read_mean_std(path, 3, 2)
            out += [s.mean, s.std]
        else:
            out.append(release.read_angles(path).xyz)
    elif kind == "checkpoint":
        from ..learning.partitions import ArraySource

        ens, x = _checkpoint_setup()
        ens.checkpoint = str(path)
        state = ens._resume(ArraySource(x))
        assert state is not None
        out += [*state.dicts, np.array(state.objective), np.array(state.iteration)]
    else:  # pragma: no cover
        raise ValueError(kind)
    for a in out:
        a = np.asarray(a)
        if a.dtype.kind == "f" and not np.isfinite(a).all():
            from ..errors import SparseBTFError

            raise SparseBTFError(f"{path}: non-finite result")
    return out


# -- writing one case and judging it ----------------------------------------------------------


def write_semantic_case(
    corpus: dict[str, Any], kind: str, seed: int, folder: Path
) -> tuple[Path, str, bool, bool]:
    """Case ``seed`` of ``kind``: (file, description, the format's rules hold, field unused)."""
    rng = np.random.default_rng([1000 + SEMANTIC_KINDS.index(kind), seed])
    field, unused = _FIELDS[kind][int(rng.integers(len(_FIELDS[kind])))]
    op = _OPS[int(rng.integers(len(_OPS)))]
    folder.mkdir(parents=True, exist_ok=True)
    src = _seed_file(corpus, kind, field)
    target = folder / src.name
    if kind != "ubo2014":
        target.write_bytes(src.read_bytes())
    legal = {"ubo2014": _case_ubo2014, "dense": _case_h5, "model": _case_h5, "coded": _case_h5,
             "release": _case_release, "checkpoint": _case_checkpoint}[kind](
        corpus, kind, field, op, rng, target)  # fmt: skip
    return target, f"{kind} {field} {op}", legal, unused


def _case_ubo2014(corpus: dict[str, Any], kind: str, field: str, op: str,
                  rng: np.random.Generator, target: Path) -> bool:  # fmt: skip
    a = corpus["ubo2014_args"]
    edits: dict[str, np.ndarray] = {}
    if field == "ColorMean":
        edits["color_mean"] = _edit(a["color_mean"].astype(np.float32), op, rng)
    elif field == "ColorTransform":
        edits["color_transform"] = _edit(a["color_transform"].astype(np.float32), op, rng)
    else:
        t, p = ("theta_l", "phi_l") if field == "lights" else ("theta_v", "phi_v")
        pair = _edit(np.stack([a[t], a[p]], 1).astype(np.float32), op, rng, rows=op in (
            "duplicate", "permute"))  # fmt: skip
        edits[t], edits[p] = pair[:, 0].astype(np.float64), pair[:, 1].astype(np.float64)
    _write_ubo2014_case(corpus, target, edits)
    mean = edits.get("color_mean", a["color_mean"])
    tr = edits.get("color_transform", a["color_transform"])
    ok = all(np.isfinite(x).all() and np.all(np.abs(x) <= _COLOR) for x in (mean, tr))
    for t, p in (("theta_l", "phi_l"), ("theta_v", "phi_v")):
        theta = np.asarray(edits.get(t, a[t]), np.float32).astype(np.float64)
        xyz = _angles_xyz(theta, np.asarray(edits.get(p, a[p]), np.float32).astype(np.float64))
        ok = ok and xyz is not None and _directions_ok(xyz)
    return bool(ok)


def _case_h5(corpus: dict[str, Any], kind: str, field: str, op: str,
             rng: np.random.Generator, target: Path) -> bool:  # fmt: skip
    from ..model import dictionaries_hash

    rows = op in ("duplicate", "permute") and field.endswith("xyz")
    with h5py.File(target, "r+") as f:
        if "@" in field:
            group, attr = field.split("@")
            f[group].attrs[attr] = _edit(np.array([f[group].attrs[attr]], np.float64), op, rng)[0]
        elif field == "btf":
            ds = f["btf"]
            ds[...] = _edit(ds[()], op, rng)
        else:
            ds = f[field]
            ds[...] = _edit(ds[()], op, rng, rows=rows)
        if kind == "model":
            dicts = {ch: [f[f"dictionaries/{ch}/mode{n}"][()].astype(np.float64)
                          for n in range(1, 5)] for ch in f["dictionaries"]}  # fmt: skip
            f.attrs["content_hash"] = np.bytes_(dictionaries_hash(dicts).encode())
        return _h5_legal(f, kind, corpus["dir"] / "model.h5")


def _h5_legal(f: h5py.File, kind: str, model: Path) -> bool:
    ok = all(_directions_ok(f[g]["xyz"][()]) and _angles_ok(f[g]) for g in ("lights", "views"))
    if kind == "coded":  # the codes index the model's directions, in its order
        with h5py.File(model, "r") as m:
            ok = ok and all(np.abs(f[g]["xyz"][()] - m[g]["xyz"][()]).max() <= _UNIT
                            for g in ("lights", "views"))  # fmt: skip
    if kind == "dense":
        return ok and bool(np.isfinite(f["btf"][()]).all())
    if kind == "model":
        for ch in f["dictionaries"]:
            for n in range(1, 5):
                ds = f[f"dictionaries/{ch}/mode{n}"]
                ok = ok and _orthonormal(ds[()], _ORTHO16 if ds.dtype.itemsize == 2 else _ORTHO)
        return ok
    st = f["stats"]
    ok = ok and _stats_ok(st["mean"][()], st["std"][()], float(st.attrs["eps"]),
                          st["bound"][()] if "bound" in st else None)
    for ch in f["codes"]:
        g = f["codes"][ch]
        sizes = tuple(int(m) for m in g.attrs["mode_sizes"])
        b = g["locations"][()].astype(np.int64)
        linear = sum(b[:, i] << (8 * i) for i in range(b.shape[1]))
        err = g["errors"][()]
        ok = ok and _codes_ok(sizes, g["membership"][()], g["counts"][()], g["values"][()],
                              linear, int(g.attrs["n_dictionaries"]))  # fmt: skip
        ok = ok and not np.any(np.isinf(err)) and not np.any(err < 0)
    return bool(ok)


def _case_release(corpus: dict[str, Any], kind: str, field: str, op: str,
                  rng: np.random.Generator, target: Path) -> bool:  # fmt: skip
    sizes, k, n_pts = (2, 2, 3, 2), 2, 4
    name = target.name
    if name.endswith(".mat"):
        n = int(rng.integers(1, 5))
        with h5py.File(target, "r+") as f:
            ds = f[f"DictDim{n}"]
            ds[...] = _edit(ds[()], op, rng)
            return all(_orthonormal(f[f"DictDim{i}"][()], _ORTHO) for i in range(1, 5))
    if name.startswith("DictEnsOrth4D"):
        words = _edit(np.fromfile(target, "<f2"), op, rng)
        words.tofile(target)
        off, ok = 0, True
        for m in sizes:
            block = words[off : off + k * m * m].astype(np.float64).reshape(k, m, m)
            off += k * m * m
            ok = ok and _orthonormal(block, _ORTHO16)
        return ok
    if name.startswith("Coeffs_BTF_"):
        raw = np.fromfile(target, "<u2")
        nnz = (raw.size - 4 - 2 * n_pts) // 5
        part = field.split(":")[1]
        lo, hi = {"LNZ": (4, 4 + 4 * nnz), "M": (4 + 4 * nnz, 4 + 4 * nnz + n_pts),
                  "NNZ": (4 + 4 * nnz + n_pts, 4 + 4 * nnz + 2 * n_pts),
                  "values": (4 + 4 * nnz + 2 * n_pts, raw.size)}[part]  # fmt: skip
        if part == "LNZ":
            raw[lo:hi] = _edit(raw[lo:hi].reshape(nnz, 4), op, rng,
                               rows=op in ("duplicate", "permute")).ravel()  # fmt: skip
        elif part == "values":
            raw[lo:hi] = _edit(raw[lo:hi].view("<f2"), op, rng).view("<u2")
        else:
            raw[lo:hi] = _edit(raw[lo:hi].view("<i2"), op, rng).view("<u2")
        raw.tofile(target)
        lnz = raw[4 : 4 + 4 * nnz].reshape(nnz, 4).astype(np.int64)
        if np.any(lnz >= np.array(sizes)):
            return False
        linear = lnz @ np.cumprod((1, *sizes[:-1]))
        return _codes_ok(sizes, raw[4 + 4 * nnz : 4 + 4 * nnz + n_pts].view("<i2"),
                         raw[4 + 4 * nnz + n_pts : 4 + 4 * nnz + 2 * n_pts].view("<i2"),
                         raw[4 + 4 * nnz + 2 * n_pts :].view("<f2"), linear, k,
                         sorted_values=False)  # fmt: skip
    a = np.fromfile(target, "<f8")
    if name.endswith("_mean_std.bin"):
        j = a.size // 2
        sl = slice(0, j) if field.endswith("mean") else slice(j, None)
        a[sl] = _edit(a[sl], op, rng)
        a.tofile(target)
        return _stats_ok(a[:j], a[j:], 1e-5)
    n = a.size // 3
    row = {"phi": 0, "elevation": 1, "index": 2}[field.split(":")[1]]
    a[row * n : (row + 1) * n] = _edit(a[row * n : (row + 1) * n], op, rng)
    a.tofile(target)
    xyz = _angles_xyz(np.pi / 2 - a[n : 2 * n], a[:n])
    # The index row is not used, but it is a number like every value of the file.
    return xyz is not None and _directions_ok(xyz) and bool(np.isfinite(a).all())


def _case_checkpoint(corpus: dict[str, Any], kind: str, field: str, op: str,
                     rng: np.random.Generator, target: Path) -> bool:  # fmt: skip
    from ..checkpoints import checkpoint_digest

    with np.load(target) as ck:
        arrays = {k: ck[k] for k in ck.files if k != "sha256"}
    if field == "bytes":
        data = bytearray(target.read_bytes())
        if op in ("zero", "minus_one", "huge", "tiny"):
            del data[int(rng.integers(len(data))) :]  # truncated
        else:
            for _ in range(int(rng.integers(1, 4))):
                i = int(rng.integers(len(data)))
                data[i] ^= 1 << int(rng.integers(8))
        target.write_bytes(bytes(data))
        try:  # legal only if it still holds the very same arrays (zip CRCs checked here)
            with zipfile.ZipFile(target) as z, np.load(target) as ck:
                if z.testzip() is not None:
                    return False
                got = {k: ck[k] for k in ck.files if k != "sha256"}
                same = set(got) == set(arrays) and all(
                    np.array_equal(got[k], arrays[k]) for k in arrays)  # fmt: skip
                return same and str(ck["sha256"]) == checkpoint_digest(arrays)
        except Exception:  # any failure to read it independently: not legal
            return False
    arrays[field] = _edit(np.atleast_1d(arrays[field]), op, rng).reshape(arrays[field].shape)
    with open(target, "wb") as fh:
        np.savez(fh, sha256=np.asarray(checkpoint_digest(arrays)), **arrays)
    dicts = [arrays[f"mode{n}"] for n in range(4)]
    obj, passes, ranking = arrays["objective"], arrays["passes"], arrays["ranking"]
    return bool(
        len(obj) == int(arrays["iteration"]) + 1 == len(passes)
        and np.isfinite(obj).all() and np.all(obj >= 0)
        and all(p in ("full", "partial") for p in passes.tolist())
        and ranking.min() >= 0 and ranking.max() < 2
        and all(_orthonormal(u, _ORTHO) for u in dicts)
    )  # fmt: skip


def run_semantic_case(corpus: dict[str, Any], kind: str, seed: int, folder: Path) -> dict[str, Any]:
    """Write, run and judge case ``seed`` of ``kind`` (in this process): its outcome, one of
    :data:`SEMANTIC_OUTCOMES`, with the case's description and the reader's message. Any
    exception other than a project error propagates (a defect)."""
    from ..errors import SparseBTFError

    path, what, legal, unused = write_semantic_case(corpus, kind, seed, folder)
    try:
        result = semantic_exercise(kind, path, corpus)
    except SparseBTFError as e:
        return {"kind": kind, "seed": seed, "case": what, "legal": legal, "message": str(e),
                "outcome": "false_rejection" if legal else "rejected"}  # fmt: skip
    wrong = not legal
    if legal and unused:
        original = corpus["originals"][kind, what.split()[1]]
        wrong = len(original) != len(result) or not all(
            np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)
            for a, b in zip(original, result, strict=False))  # fmt: skip
    return {"kind": kind, "seed": seed, "case": what, "legal": legal, "message": "",
            "outcome": "silent_wrong" if wrong else "correct"}  # fmt: skip
