"""Valid seed files for every reader, made by our own writers (a few KB each): the corpus of
the fuzz harness (:mod:`sparsebtf.testing.mutation`, :mod:`sparsebtf.testing.semantic`). Each
registered format's corpus maker (:mod:`sparsebtf.formats.registry`) is a ``corpus_*``
function here; :func:`build_corpus` runs them all.
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path
from typing import Any

import h5py
import numpy as np

__all__ = [
    "build_corpus", "corpus_coded", "corpus_dense", "corpus_model", "corpus_release",
    "corpus_ubo2003", "corpus_ubo2014",
]  # fmt: skip

def _directions(n_l: int = 3, n_v: int = 2) -> tuple[Any, Any]:
    from ..data.directions import from_angles

    lights = from_angles(np.radians([0.0, 30.0, 60.0][:n_l]), np.radians([0.0, 90.0, 180.0][:n_l]))
    views = from_angles(np.radians([15.0, 45.0][:n_v]), np.radians([0.0, 270.0][:n_v]))
    return lights, views


def _btf(seed: int = 0, size: int = 4) -> Any:
    from ..data.btf import ArrayBTF

    rng = np.random.default_rng(seed)
    lights, views = _directions()
    data = rng.uniform(0.05, 0.9, (size, size, len(lights), len(views), 3)).astype(np.float32)
    return ArrayBTF(data, lights, views, name=f"fuzz{seed}")


def _model(seed: int = 0) -> Any:
    from ..learning.ensemble import random_orthonormal
    from ..model import CHANNELS, Model

    rng = np.random.default_rng(seed)
    lights, views = _directions()
    sizes = (2, 2, len(lights), len(views))
    dicts = {ch: [np.stack([random_orthonormal(m, rng) for _ in range(2)]) for m in sizes]
             for ch in CHANNELS}  # fmt: skip
    return Model(dicts, 2, lights, views, params={"n_dictionaries": 2})


def _coded(model: Any, seed: int = 0) -> Any:
    from ..learning.coding import SparseCodes
    from ..model import CodedBTF
    from ..points.preprocessing import Standardization, round_up_bound

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
    from ..formats.registry import FORMATS

    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True)
    shared: dict[str, Any] = {}
    # a built-in format names its maker in this module (the registry imports no test tooling)
    makers = {f.kind: f.corpus if callable(f.corpus) else globals()[f.corpus]
              for f in FORMATS if f.corpus is not None}  # fmt: skip
    return {kind: make(d, shared) for kind, make in makers.items()}


def corpus_ubo2014(d: Path, shared: dict[str, Any]) -> list[Path]:
    """Bonn files: DFMF (half), FMF (float, with a height map), a version-1 DFMF (double)."""
    from ..formats.ubo2014_write import write_ubo2014

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
    from ..formats.ubo2003 import write_ubo2003_zip

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
    from ..data.dense_file import write_dense

    first = write_dense(d / "dense.h5", _btf(2))
    return [first, write_dense(d / "dense16.h5", _btf(3), dtype="float16"),
            _legacy_copy(first, d / "dense_v1.h5")]  # fmt: skip


def _shared_model(d: Path, shared: dict[str, Any]) -> Any:
    if "model" not in shared:
        from ..storage import save_model

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
    from ..storage import save_coded

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
