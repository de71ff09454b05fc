"""Hostile inputs for every reader: small valid files made by our own writers, seeded byte-level
mutations of them, and the operation each reader's user runs. Used by ``tests/test_fuzz.py``
(a few hundred cases per reader, in process) and ``benchmarks/fuzz.py`` (thousands, each in a
subprocess with a memory cap and a time limit).

A reader passes a case when it either accepts the mutated file or raises a
:class:`~sparsebtf.errors.SparseBTFError`; any other exception, a crash, a hang or a memory
blow-up is a defect. Every case is a pure function of ``(reader, seed)``, so a failure found by
the benchmark is replayed with :func:`run_case`.
"""

from __future__ import annotations

import io
import os
import zipfile
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from .formats.registry import fuzz_readers

__all__ = ["READERS", "build_corpus", "exercise", "mutate", "run_case", "write_case"]

#: The readers fuzzed, in report order: the registered formats that have a corpus maker.
READERS = fuzz_readers()

#: Interesting 32-bit words for size and count fields.
_WORDS = (0, 1, 2, 3, 0x7F, 0xFF, 0x7FFF, 0xFFFF, 0x10000, 0x7FFFFFFF, 0x80000000, 0x80000003,
          0xFFFFFFFE, 0xFFFFFFFF)  # fmt: skip


# --------------------------------------------------------------------------- the corpus


def _directions(n_l: int = 3, n_v: int = 2) -> tuple[Any, Any]:
    from .data.directions import from_angles

    lights = from_angles(np.radians([0.0, 30.0, 60.0][:n_l]), np.radians([0.0, 90.0, 180.0][:n_l]))
    views = from_angles(np.radians([15.0, 45.0][:n_v]), np.radians([0.0, 270.0][:n_v]))
    return lights, views


def _btf(seed: int = 0, size: int = 4) -> Any:
    from .data.btf import ArrayBTF

    rng = np.random.default_rng(seed)
    lights, views = _directions()
    data = rng.uniform(0.05, 0.9, (size, size, len(lights), len(views), 3)).astype(np.float32)
    return ArrayBTF(data, lights, views, name=f"fuzz{seed}")


def _model(seed: int = 0) -> Any:
    from .learning.ensemble import random_orthonormal
    from .model import CHANNELS, Model

    rng = np.random.default_rng(seed)
    lights, views = _directions()
    sizes = (2, 2, len(lights), len(views))
    dicts = {ch: [np.stack([random_orthonormal(m, rng) for _ in range(2)]) for m in sizes]
             for ch in CHANNELS}  # fmt: skip
    return Model(dicts, 2, lights, views, params={"n_dictionaries": 2})


def _coded(model: Any, seed: int = 0) -> Any:
    from .learning.coding import SparseCodes
    from .model import CodedBTF
    from .points.preprocessing import Standardization, round_up_bound

    rng = np.random.default_rng(seed)
    sizes = model.mode_sizes
    n_pts, tau = 4, 3
    codes = {}
    for ch in model.channels:
        lin = np.concatenate([rng.choice(int(np.prod(sizes)), tau, replace=False)
                              for _ in range(n_pts)])  # fmt: skip
        mag = np.sort(rng.uniform(0.1, 2.0, (n_pts, tau)), axis=1)[:, ::-1].ravel()
        codes[ch] = SparseCodes(
            sizes, rng.integers(0, 2, n_pts), np.full(n_pts, tau),
            (mag * rng.choice([-1, 1], mag.size)).astype(np.float32),
            np.stack(np.unravel_index(lin, sizes), 1).astype(np.int32), rng.uniform(0, 1e-3, n_pts),
        )  # fmt: skip
    nl, nv = len(model.lights), len(model.views)
    mean, std = rng.uniform(-2, -1, (nl, nv, 1)), rng.uniform(0.3, 0.8, (nl, nv, 1))
    bound = round_up_bound(mean[..., 0] + 2 * std[..., 0])
    stats = Standardization("shared", mean, std, bound=bound)
    params = {"tau": dict.fromkeys(model.channels, tau), "n_dictionaries": 2}
    return CodedBTF(codes, stats, 4, 4, 2, model.lights, model.views, model.content_hash,
                    params, "fuzz", {}, model)  # fmt: skip


def _legacy_copy(src: Path, dst: Path) -> Path:
    """``src`` rewritten as a schema-1 file: no checksums, HDF5's earliest structures and
    variable-length strings (what every file written before schema 2 looks like)."""

    def attrs(a: Any, b: Any) -> None:
        for k, v in a.attrs.items():
            b.attrs[k] = v.decode() if isinstance(v, bytes) else v

    with h5py.File(src, "r") as fi, h5py.File(dst, "w", libver="earliest") as fo:
        attrs(fi, fo)
        fo.attrs["schema_version"] = 1

        def copy(name: str, obj: Any) -> None:
            if isinstance(obj, h5py.Group):
                attrs(obj, fo.create_group(name))
            else:
                attrs(obj, fo.create_dataset(name, data=obj[()]))

        fi.visititems(copy)
    return dst


def build_corpus(folder: str | os.PathLike[str]) -> dict[str, list[Path]]:
    """Valid seed files for every reader in ``folder`` (a few KB each), made by our writers:
    each registered format's corpus maker (:mod:`sparsebtf.formats.registry`), in turn.

    Returns reader → files; the coded files' model is ``folder/model.h5`` and the release files
    are named as the authors named theirs, so the reader is known from the name.
    """
    from .formats.registry import FORMATS

    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True)
    shared: dict[str, Any] = {}
    return {f.kind: f.corpus(d, shared) for f in FORMATS if f.corpus is not None}


def corpus_ubo2014(d: Path, shared: dict[str, Any]) -> list[Path]:
    """Bonn files: DFMF (half), FMF (float, with a height map), a version-1 DFMF (double)."""
    from .formats.ubo2014_write import write_ubo2014

    rng = np.random.default_rng(0)
    lights, views = _directions()
    nl, nv, h, w = len(lights), len(views), 3, 5

    def factors(k: int, rows: int, scale: float = 0.3) -> np.ndarray:
        return rng.normal(0, scale, (rows, k))

    out = []
    p = d / "dfmf.btf"
    write_ubo2014(p, [factors(2, h * w) for _ in range(3)], [factors(2, nl * nv) for _ in range(3)],
                  h, w, lights, views, "DFMF", "half")  # fmt: skip
    out.append(p)
    p = d / "fmf.btf"
    write_ubo2014(p, factors(2, h * w), factors(2, 3 * nl * nv), h, w, lights, views, "FMF",
                  "float", height_map=rng.uniform(0, 1, (2, 3)))  # fmt: skip
    out.append(p)
    p = d / "dfmf_v1.btf"
    write_ubo2014(p, [factors(1, h * w) for _ in range(3)], [factors(1, nl * nv) for _ in range(3)],
                  h, w, lights, views, "DFMF", "double", rotations=False, version=1)  # fmt: skip
    out.append(p)
    return out


def corpus_ubo2003(d: Path, shared: dict[str, Any]) -> list[Path]:
    """Zip archives of JPEG and of Radiance HDR images, and the HDR one deflated."""
    from .formats.ubo2003 import write_ubo2003_zip

    lights, views = _directions()
    data = np.asarray(_btf(1).to_array(), dtype=np.float64)
    out = [write_ubo2003_zip(d / f"ubo2003_{kind}.zip", data, lights, views, kind=kind)
           for kind in ("jpeg", "hdr")]  # fmt: skip
    deflated = d / "ubo2003_deflated.zip"
    with zipfile.ZipFile(out[1]) as zi, zipfile.ZipFile(deflated, "w", zipfile.ZIP_DEFLATED) as zo:
        for info in zi.infolist():
            zo.writestr(info.filename, zi.read(info))
    out.append(deflated)
    return out


def corpus_dense(d: Path, shared: dict[str, Any]) -> list[Path]:
    """Dense files: float32, float16, and a schema-1 copy."""
    from .data.dense_file import write_dense

    first = write_dense(d / "dense.h5", _btf(2))
    return [first, write_dense(d / "dense16.h5", _btf(3), dtype="float16"),
            _legacy_copy(first, d / "dense_v1.h5")]  # fmt: skip


def _shared_model(d: Path, shared: dict[str, Any]) -> Any:
    if "model" not in shared:
        from .storage import save_model

        shared["model"] = _model()
        save_model(shared["model"], d / "model.h5")
    return shared["model"]


def _shared_coded(d: Path, shared: dict[str, Any]) -> Any:
    if "coded" not in shared:
        shared["coded"] = _coded(_shared_model(d, shared))
        shared["coded"].params["model_file"] = str(d / "model.h5")
    return shared["coded"]


def corpus_model(d: Path, shared: dict[str, Any]) -> list[Path]:
    """The model file (``model.h5``, the coded files' model) and a schema-1 copy."""
    _shared_model(d, shared)
    return [d / "model.h5", _legacy_copy(d / "model.h5", d / "model_v1.h5")]


def corpus_coded(d: Path, shared: dict[str, Any]) -> list[Path]:
    """Coded files: schema 3 (today's), schema 2, and a schema-1 copy of the schema-2 one."""
    from .storage import save_coded

    coded = _shared_coded(d, shared)
    out = [save_coded(coded, d / "coded.h5"), save_coded(coded, d / "coded_v2.h5", schema=2)]
    return [*out, _legacy_copy(out[1], d / "coded_v1.h5")]


def corpus_release(d: Path, shared: dict[str, Any]) -> list[Path]:
    """The authors' five file kinds (in ``d/release``)."""
    coded = _shared_coded(d, shared)
    return _release_files(d / "release", _shared_model(d, shared), coded)


def _release_files(d: Path, model: Any, coded: Any) -> list[Path]:
    """The authors' five file kinds at the corpus's small geometry (K = 2, 2×2×3×2)."""
    d.mkdir(parents=True, exist_ok=True)
    y = model.dictionaries["Y"]
    words = np.concatenate([np.ascontiguousarray(m.transpose(0, 2, 1)).ravel() for m in y])
    (d / "DictEnsOrth4DY.bin").write_bytes(words.astype("<f2").tobytes())
    with h5py.File(d / "DictEnsOrth4DU.mat", "w", userblock_size=512) as f:
        for n, m in enumerate(model.dictionaries["U"], start=1):
            f.create_dataset(f"DictDim{n}", data=np.ascontiguousarray(m.transpose(0, 2, 1)))
        f.create_dataset("EnsHist", data=np.array([[2.0, 2.0]]))
        f.create_dataset("TrainTime", data=np.array([[12.5]]))
    c = coded.codes["V"]
    body = [np.asarray(c.mode_sizes, "<i2").view("<u2"), c.locations.astype("<u2").ravel(),
            c.membership.astype("<i2").view("<u2"), c.counts.astype("<i2").view("<u2"),
            c.values.astype("<f2").view("<u2")]  # fmt: skip
    (d / "Coeffs_BTF_fuzz_1e-05_V.bin").write_bytes(np.concatenate(body).astype("<u2").tobytes())
    st = coded.stats
    ms = np.concatenate([st.mean[..., 0].T.ravel(), st.std[..., 0].T.ravel()]).astype("<f8")
    (d / "fuzz_mean_std.bin").write_bytes(ms.tobytes())
    ang = np.concatenate([model.lights.phi, model.lights.elevation, np.arange(len(model.lights))])
    (d / "bonn_angles.bin").write_bytes(ang.astype("<f8").tobytes())
    return sorted(p for p in d.iterdir() if p.is_file())


# --------------------------------------------------------------------------- mutations


def mutate(data: bytes, rng: np.random.Generator) -> bytes:
    """One to three random edits: bit flips, byte and word overwrites with boundary values,
    truncation, deletion, duplication or insertion of a span."""
    b = bytearray(data)
    for _ in range(int(rng.integers(1, 4))):
        n = len(b)
        op = int(rng.integers(9)) if n else 8
        pos = int(rng.integers(n)) if n else 0
        if op <= 2:  # the most common damage: flipped bits
            for _ in range(int(rng.integers(1, 9))):
                i = int(rng.integers(n))
                b[i] ^= 1 << int(rng.integers(8))
        elif op == 3:
            b[pos] = int(rng.choice([0x00, 0x01, 0x7F, 0x80, 0xFF, int(rng.integers(256))]))
        elif op in (4, 5):  # a size or count field: an aligned little-endian word
            width = 8 if op == 5 else 4
            pos -= pos % width
            word = int(rng.choice(_WORDS)) if op == 4 else int(rng.choice(_WORDS)) << 16
            b[pos : pos + width] = word.to_bytes(8, "little")[:width][: max(0, n - pos)]
        elif op == 6:
            del b[int(rng.integers(n)) :]
        elif op == 7:
            span = int(rng.integers(1, min(n, 512) + 1))
            chunk = bytes(b[pos : pos + span])
            if rng.integers(2):
                del b[pos : pos + span]
            else:
                b[pos:pos] = chunk
        else:
            b[pos:pos] = rng.integers(0, 256, int(rng.integers(1, 64)), dtype=np.uint8).tobytes()
    return bytes(b)


def _mutate_member(data: bytes, rng: np.random.Generator) -> bytes:
    """The archive ``data`` rewritten with one member mutated (its CRC recomputed)."""
    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(data)) as zi:
        infos = zi.infolist()
        victim = int(rng.integers(len(infos)))
        with zipfile.ZipFile(out, "w", infos[0].compress_type) as zo:
            for i, info in enumerate(infos):
                blob = zi.read(info)
                zo.writestr(info.filename, mutate(blob, rng) if i == victim else blob)
    return out.getvalue()


def write_case(corpus: dict[str, list[Path]], reader: str, seed: int, folder: Path) -> Path:
    """Write case ``seed`` of ``reader`` (a mutated copy of one corpus file) into ``folder``."""
    rng = np.random.default_rng([READERS.index(reader), seed])
    files = corpus[reader]
    src = files[int(rng.integers(len(files)))]
    target = folder / src.name
    folder.mkdir(parents=True, exist_ok=True)
    tmp = target.with_suffix(target.suffix + ".tmp")
    if src.suffix == ".zip" and rng.integers(2):
        # Half the zip cases damage one image inside a valid archive (correct CRCs), so the
        # JPEG and Radiance parsers are reached, not only the archive's own checks.
        tmp.write_bytes(_mutate_member(src.read_bytes(), rng))
    else:
        tmp.write_bytes(mutate(src.read_bytes(), rng))
    os.replace(tmp, target)
    return target


# --------------------------------------------------------------------------- what users run


def _scan(btf: Any) -> None:
    for block in btf.iter_blocks():
        np.isfinite(block).sum()


def exercise(reader: str, path: Path, corpus_dir: Path) -> None:
    """What a user of ``reader`` runs on ``path``: ``sparsebtf info`` (value scan included),
    plus a full decode for coded files; the release readers at the corpus geometry."""
    from .cli.info import describe

    if reader in ("ubo2014", "ubo2003", "dense", "model"):
        describe(path)
    elif reader == "coded":
        from .runtime import RuntimeBTF, coded_btf_view
        from .storage import load_coded_with_model

        describe(path, model_path=str(corpus_dir / "model.h5"))
        coded = load_coded_with_model(path, corpus_dir / "model.h5")
        _scan(coded_btf_view(coded))
        RuntimeBTF(coded, tau=0.5).arrays(neighbours=False)  # what the viewer and the renderer load
    elif reader == "release":
        _release(path)
    else:  # pragma: no cover
        raise ValueError(reader)


def _release(path: Path) -> None:
    from .storage import release

    sizes = (2, 2, 3, 2)
    name = path.name
    if name.startswith("DictEnsOrth4D"):
        release.read_dictionaries(path, 2, sizes)
    elif name.startswith("Coeffs_BTF_"):
        release.read_coefficients(path, n_points=4, n_dictionaries=2)
    elif name.endswith("_mean_std.bin"):
        release.read_mean_std(path, 3, 2)
    else:
        release.read_angles(path)


def run_case(
    corpus: dict[str, list[Path]], reader: str, seed: int, folder: Path, corpus_dir: Path
) -> str:
    """Run one case in this process: ``"accepted"`` or ``"error"`` (a clean project error);
    anything else propagates (a defect)."""
    from .errors import SparseBTFError

    path = write_case(corpus, reader, seed, folder)
    try:
        exercise(reader, path, corpus_dir)
    except SparseBTFError:
        return "error"
    return "accepted"


def sizes(corpus: dict[str, list[Path]]) -> dict[str, int]:
    """The largest seed file per reader (mutations add at most a few hundred bytes)."""
    return {r: max(p.stat().st_size for p in files) for r, files in corpus.items()}


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
#   to the unmutated file's when the field is one the reader does not use (theta/phi columns,
#   the angle file's index row);
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
_UNIT, _CHORD, _BOUND, _EPS = 1e-6, 1e-4, 40.0, (1e-12, 1.0)
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


def _stats_ok(mean: np.ndarray, std: np.ndarray, eps: float, bound: Any = None) -> bool:
    ok = bool(
        np.isfinite(mean).all() and np.isfinite(std).all() and np.all(np.abs(mean) <= _BOUND)
        and np.all(std > 0) and np.all(std <= _BOUND) and np.isfinite(eps)
        and _EPS[0] <= eps <= _EPS[1]
    )  # fmt: skip
    if ok and bound is not None:  # decoded values never above exp(bound); black is ln(eps)
        ok = bool(np.isfinite(bound).all() and np.all(bound <= _BOUND)
                  and np.all(bound >= np.log(eps) - 1e-2))  # fmt: skip
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
    from .learning.ensemble import DictionaryEnsemble

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
    from .data.directions import DirectionSet
    from .formats.ubo2014_write import write_ubo2014

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
    from .data.validate import check_finite

    out: list[np.ndarray] = []
    if kind in ("ubo2014", "dense"):
        from .open import open_btf

        btf = open_btf(path)
        out += [btf.lights.xyz, btf.views.xyz]
        for block in btf.iter_blocks():
            check_finite(block, str(path))
            out.append(block)
    elif kind == "model":
        from .storage import load_model

        m = load_model(path)
        out += [m.lights.xyz, m.views.xyz]
        out += [u for ch in m.channels for u in m.dictionaries[ch]]
    elif kind == "coded":
        from .runtime import RuntimeBTF, coded_btf_view
        from .storage import load_coded_with_model

        coded = load_coded_with_model(path, corpus["dir"] / "model.h5")
        view = coded_btf_view(coded)
        for block in view.iter_blocks():
            check_finite(block, str(path))
            out.append(block)
        arrays = RuntimeBTF(coded, tau=0.5).arrays(neighbours=False)
        out += [np.asarray(v) for _, v in sorted(arrays.items())]
    elif kind == "release":
        from .storage import release

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
        from .learning.partitions import ArraySource

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
            from .errors import SparseBTFError

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
    from .model import dictionaries_hash

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
    ok = all(_directions_ok(f[g]["xyz"][()]) for g in ("lights", "views"))
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
    from .learning.ensemble import checkpoint_digest

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
    from .errors import SparseBTFError

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
