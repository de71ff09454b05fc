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

__all__ = ["READERS", "build_corpus", "exercise", "mutate", "run_case", "write_case"]

#: The readers fuzzed, in report order.
READERS = ("ubo2014", "ubo2003", "dense", "model", "coded", "release")

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
    from .points.preprocessing import Standardization

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
    stats = Standardization("shared", mean, std)
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
    """Valid seed files for every reader in ``folder`` (a few KB each), made by our writers.

    Returns reader → files; the coded files' model is ``folder/model.h5`` and the release files
    are named as the authors named theirs, so the reader is known from the name.
    """
    from .data.dense_file import write_dense
    from .formats.ubo2003 import write_ubo2003_zip
    from .formats.ubo2014_write import write_ubo2014
    from .storage import save_coded, save_model

    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    lights, views = _directions()
    nl, nv, h, w = len(lights), len(views), 3, 5
    out: dict[str, list[Path]] = {r: [] for r in READERS}

    def factors(k: int, rows: int, scale: float = 0.3) -> np.ndarray:
        return rng.normal(0, scale, (rows, k))

    p = d / "dfmf.btf"
    write_ubo2014(p, [factors(2, h * w) for _ in range(3)], [factors(2, nl * nv) for _ in range(3)],
                  h, w, lights, views, "DFMF", "half")  # fmt: skip
    out["ubo2014"].append(p)
    p = d / "fmf.btf"
    write_ubo2014(p, factors(2, h * w), factors(2, 3 * nl * nv), h, w, lights, views, "FMF",
                  "float", height_map=rng.uniform(0, 1, (2, 3)))  # fmt: skip
    out["ubo2014"].append(p)
    p = d / "dfmf_v1.btf"
    write_ubo2014(p, [factors(1, h * w) for _ in range(3)], [factors(1, nl * nv) for _ in range(3)],
                  h, w, lights, views, "DFMF", "double", rotations=False, version=1)  # fmt: skip
    out["ubo2014"].append(p)

    data = np.asarray(_btf(1).to_array(), dtype=np.float64)
    for kind in ("jpeg", "hdr"):
        p = write_ubo2003_zip(d / f"ubo2003_{kind}.zip", data, lights, views, kind=kind)
        out["ubo2003"].append(p)
    deflated = d / "ubo2003_deflated.zip"
    with zipfile.ZipFile(out["ubo2003"][1]) as zi, zipfile.ZipFile(
        deflated, "w", zipfile.ZIP_DEFLATED
    ) as zo:
        for info in zi.infolist():
            zo.writestr(info.filename, zi.read(info))
    out["ubo2003"].append(deflated)

    out["dense"].append(write_dense(d / "dense.h5", _btf(2)))
    out["dense"].append(write_dense(d / "dense16.h5", _btf(3), dtype="float16"))
    out["dense"].append(_legacy_copy(out["dense"][0], d / "dense_v1.h5"))

    model = _model()
    out["model"].append(save_model(model, d / "model.h5"))
    out["model"].append(_legacy_copy(out["model"][0], d / "model_v1.h5"))
    coded = _coded(model)
    coded.params["model_file"] = str(d / "model.h5")
    out["coded"].append(save_coded(coded, d / "coded.h5"))
    out["coded"].append(save_coded(coded, d / "coded_v2.h5", schema=2))
    out["coded"].append(_legacy_copy(out["coded"][1], d / "coded_v1.h5"))

    out["release"] = _release_files(d / "release", model, coded)
    return out


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
