"""Model and coded files (HDF5) and the Table 4 storage accounting."""

from __future__ import annotations

import json
import re
from pathlib import Path

import h5py
import numpy as np
import pytest

from sparsebtf.data.directions import tiny
from sparsebtf.errors import BTFInputError, FileFormatError, ModelMismatchError
from sparsebtf.learning.coding import SparseCodes
from sparsebtf.learning.tensor import reconstruct
from sparsebtf.model import CodedBTF, Model
from sparsebtf.points.preprocessing import Standardization
from sparsebtf.storage import (
    MIB,
    channel_storage,
    load_coded,
    load_model,
    location_width,
    pack_locations,
    paper_storage,
    save_coded,
    save_model,
    storage_report,
    unpack_locations,
)
from sparsebtf.storage import coded_file as coded_mod
from sparsebtf.storage import model_file as model_mod

K = 3
PATCH = 2
CH = ("Y", "U", "V")


# --------------------------------------------------------------------------- builders


def make_model(seed: int = 0, patch: int = PATCH, n_dirs: int = 7) -> Model:
    rng = np.random.default_rng(seed)
    lights, views = tiny(n_dirs), tiny(n_dirs)
    sizes = (patch, patch, len(lights), len(views))
    dicts = {
        ch: [np.stack([np.linalg.qr(rng.normal(size=(m, m)))[0] for _ in range(K)]) for m in sizes]
        for ch in CH
    }
    return Model(
        dictionaries=dicts, patch=patch, lights=lights, views=views,
        params={"n_dictionaries": K, "tau_train": {"Y": 5, "U": 3, "V": 3}, "seed": seed},
        provenance={"materials": ["a", "b"], "note": "test"},
        training={"Y": {"history": np.array([3.0, 2.5, 2.0]), "seconds": np.float64(1.5),
                        "hist": np.array([2, 1, 1])}},
    )


def make_codes(
    rng: np.random.Generator, sizes: tuple[int, ...], n_points: int, max_count: int, k: int = K
) -> SparseCodes:
    total = int(np.prod(sizes))
    counts = rng.integers(1, max_count + 1, size=n_points)
    vals, locs = [], []
    for c in counts:
        lin = rng.choice(total, size=c, replace=False)
        v = rng.normal(scale=30.0, size=c)
        order = np.argsort(-np.abs(v), kind="stable")
        vals.append(v[order])
        locs.append(np.stack(np.unravel_index(lin[order], sizes), axis=1))
    return SparseCodes(
        sizes,
        rng.integers(0, k, size=n_points),
        counts,
        np.concatenate(vals).astype(np.float32),
        np.concatenate(locs).astype(np.int32),
        rng.random(n_points) * 1e-3,
    )


def make_coded(model: Model, seed: int = 1, height: int = 4, width: int = 6,
               membership_k: int = K, params: dict | None = None) -> CodedBTF:
    rng = np.random.default_rng(seed)
    nl, nv = len(model.lights), len(model.views)
    p = model.patch
    sizes = (p, p, nl, nv)
    n_points = (height // p) * (width // p)
    codes = {ch: make_codes(rng, sizes, n_points, 9, membership_k) for ch in CH}
    stats = Standardization(
        "shared", rng.normal(-1.0, 0.2, size=(nl, nv, 1)), rng.uniform(0.5, 2.0, size=(nl, nv, 1))
    )
    return CodedBTF(
        codes=codes, stats=stats, height=height, width=width, patch=p, lights=model.lights,
        views=model.views, model_hash=model.content_hash,
        params=params if params is not None else {"tau": {"Y": 9, "U": 9, "V": 9}, "eps": 1e-5},
        name="felt-test", attrs={"source": "synthetic", "crop": [0, 4, 0, 6]},
    )


@pytest.fixture(scope="module")
def model() -> Model:
    return make_model()


@pytest.fixture()
def files(tmp_path: Path, model: Model) -> tuple[Path, Path, CodedBTF]:
    coded = make_coded(model)
    return save_model(model, tmp_path / "m.h5"), save_coded(coded, tmp_path / "c.h5"), coded


# --------------------------------------------------------------------------- round trips


def test_model_round_trip_is_exact(tmp_path: Path, model: Model) -> None:
    path = save_model(model, tmp_path / "sub" / "model.h5")
    assert path == tmp_path / "sub" / "model.h5"
    back = load_model(path)
    assert back.content_hash == model.content_hash
    assert back.channels == model.channels
    for ch in CH:
        for a, b in zip(model.dictionaries[ch], back.dictionaries[ch], strict=True):
            assert b.dtype == np.float64
            np.testing.assert_array_equal(a, b)
    assert back.patch == PATCH
    assert back.lights.equals(model.lights, atol=0) and back.views.equals(model.views, atol=0)
    assert back.lights.name == "tiny7"
    assert back.params == {"n_dictionaries": K, "tau_train": {"Y": 5, "U": 3, "V": 3}, "seed": 0}
    assert back.provenance == model.provenance
    assert back.training == {"Y": {"history": [3.0, 2.5, 2.0], "seconds": 1.5, "hist": [2, 1, 1]}}
    with h5py.File(path, "r") as f:
        # Strings are fixed-length UTF-8 (kept in the checksummed object headers): bytes in h5py.
        assert f.attrs["format"].decode() == "sparsebtf-model"
        assert int(f.attrs["schema_version"]) == 2
        assert f.attrs["content_hash"].decode() == model.content_hash
        assert f["dictionaries/U/mode3"].shape == (K, 7, 7)
        assert f["dictionaries/U/mode3"].fletcher32
        assert isinstance(f.attrs["library_version"].decode(), str)


def test_coded_round_trip(files: tuple[Path, Path, CodedBTF], model: Model) -> None:
    _, cpath, coded = files
    back = load_coded(cpath)
    assert back.model is None
    assert back.model_hash == model.content_hash
    assert (back.height, back.width, back.patch, back.name) == (4, 6, PATCH, "felt-test")
    assert back.params == {"tau": {"Y": 9, "U": 9, "V": 9}, "eps": 1e-5}
    assert back.attrs == {"source": "synthetic", "crop": [0, 4, 0, 6]}
    assert back.channels == CH
    for ch in CH:
        a, b = coded.codes[ch], back.codes[ch]
        assert b.mode_sizes == a.mode_sizes
        np.testing.assert_array_equal(b.locations, a.locations)
        np.testing.assert_array_equal(b.membership, a.membership)
        np.testing.assert_array_equal(b.counts, a.counts)
        assert b.values.dtype == np.float32
        np.testing.assert_array_equal(b.values, a.values.astype(np.float16).astype(np.float32))
        np.testing.assert_allclose(b.errors, a.errors, rtol=1e-7)
        # Per-point order (decreasing magnitude) is kept: truncation is still a prefix.
        o = b.offsets
        for i in range(b.n_points):
            mags = np.abs(a.values[o[i] : o[i + 1]])
            assert np.all(np.diff(mags) <= 0)
    np.testing.assert_allclose(back.stats.mean, coded.stats.mean, rtol=1e-7)
    np.testing.assert_allclose(back.stats.std, coded.stats.std, rtol=1e-7)
    assert back.stats.mode == "shared" and back.stats.log_offset == coded.stats.log_offset
    with h5py.File(cpath, "r") as f:
        g = f["codes/Y"]
        assert g["membership"].dtype == np.uint8
        assert g["counts"].dtype == np.uint16
        assert g["value_bytes"].dtype == np.uint8
        assert g["value_bytes"].shape == (2, coded.codes["Y"].nnz)  # binary16
        assert g["location_table"].dtype == np.uint32 and g["usage"].dtype == np.uint8
        assert g["errors"].dtype == np.float32
        assert f["stats/mean"].dtype == np.float32 and f["stats/mean"].shape == (7, 7, 1)
        assert json.loads(f.attrs["channels"]) == list(CH)


def test_load_coded_attaches_model(files: tuple[Path, Path, CodedBTF], model: Model) -> None:
    mpath, cpath, _ = files
    back = load_coded(cpath, load_model(mpath))
    assert back.model is not None and back.require_model().content_hash == model.content_hash


def test_large_counts_use_uint32(tmp_path: Path) -> None:
    model = make_model(patch=16, n_dirs=19)
    coded = make_coded(model, height=16, width=16)
    sizes = coded.codes["Y"].mode_sizes
    n = 70_000
    lin = np.arange(n)
    vals = np.linspace(5.0, 0.1, n).astype(np.float32)
    coded.codes["Y"] = SparseCodes(
        sizes, np.array([2]), np.array([n]), vals,
        np.stack(np.unravel_index(lin, sizes), axis=1).astype(np.int32), np.zeros(1),
    )
    path = save_coded(coded, tmp_path / "big.h5")
    with h5py.File(path, "r") as f:
        assert f["codes/Y/counts"].dtype == np.uint32
    back = load_coded(path, model)
    assert int(back.codes["Y"].counts[0]) == n
    np.testing.assert_array_equal(back.codes["Y"].locations, coded.codes["Y"].locations)


def test_fp16_overflow_falls_back_to_float32(tmp_path: Path, model: Model) -> None:
    coded = make_coded(model)
    coded.codes["U"].values[0] = 1e6
    with pytest.warns(UserWarning, match="overflow binary16"):
        path = save_coded(coded, tmp_path / "c.h5")
    back = load_coded(path)
    assert back.codes["U"].values[0] == np.float32(1e6)
    with h5py.File(path, "r") as f:
        assert f["codes/U/value_bytes"].shape[0] == 4 and f["codes/Y/value_bytes"].shape[0] == 2


def test_decode_one_value_with_h5py_only(files: tuple[Path, Path, CodedBTF], model: Model) -> None:
    """The docs/format.md recipe: Eq. 5 from the raw datasets, no sparsebtf reader."""
    mpath, cpath, _ = files
    point, i1, i2, light, view = 4, 1, 0, 5, 2
    with h5py.File(mpath, "r") as fm, h5py.File(cpath, "r") as fc:
        g = fc["codes/U"]
        sizes = tuple(int(m) for m in g.attrs["mode_sizes"])
        # schema 3: the point's column of its dictionary's usage matrix (docs/format.md §3)
        m = g["membership"][()].astype(np.int64)
        t = g.attrs["table_sizes"].astype(np.int64)
        k, j, n = int(m[point]), int(np.sum(m[:point] == m[point])), np.bincount(m)
        bits = np.unpackbits(g["usage"][()])
        first = int(np.sum(t[:k] * n[:k]))
        rows = np.flatnonzero(bits[first : first + t[k] * n[k]].reshape(t[k], n[k])[:, j])
        table = np.cumsum(g["location_table"][int(t[:k].sum()) :][: t[k]].astype(np.int64))
        l1, l2, l3, l4 = np.unravel_index(table[rows], sizes, order="F")
        nth = np.cumsum(bits)[first + rows * n[k] + j] - 1  # the values of those set bits
        v = g["value_bytes"][()][:, nth].T.copy().view("<f2")[:, 0].astype(np.float64)
        u1, u2, u3, u4 = (fm[f"dictionaries/U/mode{n}"][k] for n in range(1, 5))
        x = np.sum(v * u1[i1, l1] * u2[i2, l2] * u3[light, l3] * u4[view, l4])
        mu = fc["stats/mean"][light, view, 0]
        sd = fc["stats/std"][light, view, 0]
    back = load_coded(cpath, model)
    dense = back.codes["U"].dense(point)[None]
    full = reconstruct(dense, model.matrices("U", k))[0]
    assert x == pytest.approx(full[i1, i2, light, view], abs=1e-12)
    assert x * sd + mu == pytest.approx(
        full[i1, i2, light, view] * back.stats.std[light, view, 0] + back.stats.mean[light, view, 0]
    )


# --------------------------------------------------------------------------- atomicity


def test_failed_coded_write_leaves_old_file(
    tmp_path: Path, model: Model, monkeypatch: pytest.MonkeyPatch
) -> None:
    coded = make_coded(model)
    target = tmp_path / "c.h5"
    save_coded(coded, target)
    before = target.read_bytes()

    real = coded_mod._write_codes

    def failing(*args: object) -> None:
        if args[-1] == "U":  # the second channel, after Y was written
            raise RuntimeError("disk full")
        real(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(coded_mod, "_write_codes", failing)
    with pytest.raises(RuntimeError, match="disk full"):
        save_coded(make_coded(model, seed=9), target)
    assert target.read_bytes() == before
    with pytest.raises(RuntimeError):
        save_coded(coded, tmp_path / "new.h5")
    assert not (tmp_path / "new.h5").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.h5"]


def test_failed_model_write_leaves_no_file(
    tmp_path: Path, model: Model, monkeypatch: pytest.MonkeyPatch
) -> None:
    def failing(*args: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(model_mod, "write_directions", failing)
    with pytest.raises(KeyboardInterrupt):
        save_model(model, tmp_path / "m.h5")
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- bad files


def _set_attr(path: Path, key: str, value: object) -> None:
    with h5py.File(path, "a") as f:
        f.attrs[key] = value


def test_not_hdf5_and_missing(tmp_path: Path) -> None:
    bad = tmp_path / "notes.h5"
    bad.write_text("hello")
    for loader in (load_model, load_coded):
        with pytest.raises(FileFormatError, match=r"notes\.h5"):
            loader(bad)
        with pytest.raises(FileFormatError, match="no such file"):
            loader(tmp_path / "absent.h5")


def test_truncated_files(files: tuple[Path, Path, CodedBTF]) -> None:
    for path, loader in zip(files[:2], (load_model, load_coded), strict=True):
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
        with pytest.raises(FileFormatError, match=re.escape(path.name)):
            loader(path)


def test_wrong_format(files: tuple[Path, Path, CodedBTF]) -> None:
    mpath, cpath, _ = files
    with pytest.raises(FileFormatError, match="sparsebtf-coded"):
        load_model(cpath)
    with pytest.raises(FileFormatError, match="sparsebtf-model"):
        load_coded(mpath)
    _set_attr(cpath, "format", "something-else")
    with pytest.raises(FileFormatError, match="something-else"):
        load_coded(cpath)


def test_unsupported_schema_version(files: tuple[Path, Path, CodedBTF]) -> None:
    mpath, cpath, _ = files
    for path, loader in ((mpath, load_model), (cpath, load_coded)):
        _set_attr(path, "schema_version", 99)
        with pytest.raises(FileFormatError, match=r"schema_version 99 .*supports 1"):
            loader(path)


def test_corrupted_dictionary_fails_checksum_and_hash(files: tuple[Path, Path, CodedBTF]) -> None:
    mpath = files[0]
    with h5py.File(mpath, "r") as f:
        offset = f["dictionaries/V/mode3"].id.get_chunk_info(0).byte_offset
    raw = bytearray(mpath.read_bytes())
    raw[offset + 11] ^= 0x40
    mpath.with_name("flipped.h5").write_bytes(bytes(raw))
    # A flipped bit: the dataset's fletcher32 checksum names it.
    with pytest.raises(FileFormatError, match=r"dictionaries/V/mode3: checksum mismatch"):
        load_model(mpath.with_name("flipped.h5"))
    # A consistent rewrite (new checksum) is still caught by the content hash.
    with h5py.File(mpath, "a") as f:
        f["dictionaries/V/mode3"][0, 0, 0] += 1e-3
    with pytest.raises(FileFormatError, match=r"m\.h5.*corrupted"):
        load_model(mpath)


def test_wrong_model(files: tuple[Path, Path, CodedBTF], model: Model) -> None:
    other = make_model(seed=5)
    with pytest.raises(ModelMismatchError) as err:
        load_coded(files[1], other)
    assert model.content_hash[:12] in str(err.value)
    assert other.content_hash[:12] in str(err.value)


def test_missing_dataset(files: tuple[Path, Path, CodedBTF]) -> None:
    mpath, cpath, _ = files
    with h5py.File(cpath, "a") as f:
        del f["codes/U/value_bytes"]
    with pytest.raises(FileFormatError, match=r"codes/U.*'value_bytes'"):
        load_coded(cpath)
    with h5py.File(mpath, "a") as f:
        del f["lights"]
    with pytest.raises(FileFormatError, match="'lights'"):
        load_model(mpath)


def test_counts_must_sum_to_values(files: tuple[Path, Path, CodedBTF]) -> None:
    cpath = files[1]
    with h5py.File(cpath, "a") as f:
        c = f["codes/V/counts"][()]
        c[0] += 1
        f["codes/V/counts"][...] = c
    with pytest.raises(FileFormatError, match=r"codes/V: counts sum to"):
        load_coded(cpath)


def test_membership_beyond_model_k(tmp_path: Path, model: Model) -> None:
    coded = make_coded(model, params={})
    coded.codes["U"].membership[3] = K + 1
    path = save_coded(coded, tmp_path / "c.h5")  # K unknown at write time: accepted
    load_coded(path)
    with pytest.raises(FileFormatError, match=r"codes/U/membership: point 3 .* K is 3"):
        load_coded(path, model)
    # With K known at write time the writer refuses.
    coded.params["n_dictionaries"] = K
    with pytest.raises(BTFInputError, match="only 3 dictionaries"):
        save_coded(coded, tmp_path / "d.h5")


def test_mode_sizes_must_match_model(tmp_path: Path, model: Model) -> None:
    other_geometry = make_model(n_dirs=13)
    coded = make_coded(other_geometry, params={})
    coded.model_hash = model.content_hash  # claims the tiny7 model
    path = save_coded(coded, tmp_path / "c.h5")
    with pytest.raises(FileFormatError, match=r"mode sizes \(2, 2, 13, 13\) disagree"):
        load_coded(path, model)


def test_writer_refuses_bad_codes(tmp_path: Path, model: Model) -> None:
    coded = make_coded(model)
    coded.codes["Y"].values[2] = np.nan
    with pytest.raises(BTFInputError, match="NaN"):
        save_coded(coded, tmp_path / "c.h5")
    coded = make_coded(model)
    coded.height = 8  # 4x3 points expected, 2x3 coded
    with pytest.raises(BTFInputError, match="coded points"):
        save_coded(coded, tmp_path / "c.h5")
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- packing


def test_pack_locations_three_bytes_release_order() -> None:
    sizes = (10, 10, 151, 151)
    assert location_width(sizes) == 3
    loc = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1], [9, 9, 150, 150]])
    packed = pack_locations(loc, sizes)
    assert packed.dtype == np.uint8 and packed.shape == (4, 3)
    lin = packed[:, 0] + 256 * packed[:, 1].astype(int) + 65536 * packed[:, 2].astype(int)
    np.testing.assert_array_equal(lin, [1, 10, 15100, 2_280_099])
    np.testing.assert_array_equal(lin, np.ravel_multi_index(loc.T, sizes, order="F"))
    np.testing.assert_array_equal(unpack_locations(packed, sizes), loc)


def test_pack_locations_four_bytes() -> None:
    sizes = (300, 300, 200)
    assert location_width(sizes) == 4
    rng = np.random.default_rng(3)
    loc = np.stack([rng.integers(0, m, 1000) for m in sizes], axis=1)
    loc[0] = (299, 299, 199)
    packed = pack_locations(loc, sizes)
    assert packed.shape == (1000, 4)
    assert packed[0].view("<u4")[0] == 300 * 300 * 200 - 1
    np.testing.assert_array_equal(unpack_locations(packed, sizes), loc)
    assert location_width((256, 256, 256)) == 3  # exactly 2^24 entries: indices < 2^24


def test_pack_locations_rejects_out_of_range() -> None:
    with pytest.raises(BTFInputError, match="mode 3"):
        pack_locations(np.array([[0, 0, 7, 0]]), (2, 2, 7, 7))
    with pytest.raises(BTFInputError, match="outside"):
        unpack_locations(np.array([[255, 255, 0]], dtype=np.uint8), (2, 2, 7, 7))
    assert pack_locations(np.zeros((0, 4), int), (2, 2, 7, 7)).shape == (0, 3)


# --------------------------------------------------------------------------- accounting


def test_paper_table4_figure() -> None:
    r = paper_storage(400, 400, 151, 151, 10, (885, 64, 64), 8)
    assert r["bytes_total"] == 10_312_096
    assert round(r["bytes_total"] / MIB, 2) == 9.83 == round(r["mib_total"], 2)
    assert abs(r["compression_ratio"] - 2122) < 1
    assert r["bytes_raw"] == 400 * 400 * 151 * 151 * 3 * 2
    assert r["bytes_coefficients"] == 1600 * 1013 * 5 == 8_104_000
    assert r["bytes_dictionaries"] == 3 * 732_832
    assert r["bytes_membership_counts"] == 3 * 3200
    assert r["nnz"] == {"Y": 1600 * 885, "U": 102_400, "V": 102_400}
    assert r["channels"]["U"]["bytes_total"] == 1_248_032  # the release's per-channel figure
    assert paper_storage(400, 400, 151, 151, 10, {"Y": 885, "U": 64, "V": 64}, 8) == r


def test_storage_report(files: tuple[Path, Path, CodedBTF], model: Model) -> None:
    _, cpath, coded = files
    r = storage_report(coded, model, file_path=cpath)
    sizes = (2, 2, 7, 7)
    entries = K * (4 + 4 + 49 + 49)
    nnz = coded.nnz()
    assert r["nnz"] == nnz
    assert r["bytes_coefficients"] == 5 * sum(nnz.values())
    assert r["bytes_dictionaries"] == 3 * 2 * entries
    assert r["bytes_membership_counts"] == 3 * 2 * 6
    assert r["bytes_total"] == r["bytes_coefficients"] + r["bytes_dictionaries"] + 36
    assert r["bytes_raw"] == 4 * 6 * 7 * 7 * 3 * 2
    assert r["compression_ratio"] == pytest.approx(r["bytes_raw"] / r["bytes_total"])
    assert r["bytes_stats"] == 2 * 49 * 4
    assert r["file_bytes"] == cpath.stat().st_size
    # Stored bytes: the parts add up to the file's size; the per-material ratio is raw / file.
    parts = ("codes", "stats", "directions", "header")
    assert sum(r[f"bytes_stored_{p}"] for p in parts) == r["bytes_stored"] == r["file_bytes"]
    assert min(r[f"bytes_stored_{p}"] for p in parts) > 0
    assert r["compression_ratio_per_material"] == r["bytes_raw"] / cpath.stat().st_size
    assert r["compression_ratio_table4_material"] == r["bytes_raw"] / (r["bytes_total"] - r[
        "bytes_dictionaries"])
    # Without a file, the file save_coded would write is measured in memory: the same bytes.
    mem = storage_report(coded, model)
    assert {k: mem[k] for k in mem if k.startswith("bytes_stored")} == {
        k: r[k] for k in r if k.startswith("bytes_stored")}
    assert r["channels"]["Y"] == {
        **channel_storage(nnz["Y"], 6, K, sizes), "dictionary_source": "model"
    }
    # Without a model: K from params, else from the memberships (a lower bound).
    assert storage_report(coded)["file_bytes"] is None
    coded.params["n_dictionaries"] = 5
    assert storage_report(coded)["channels"]["U"]["n_dictionaries"] == 5
    del coded.params["n_dictionaries"]
    r2 = storage_report(coded)["channels"]["V"]
    assert r2["dictionary_source"] == "membership"
    assert r2["n_dictionaries"] == int(coded.codes["V"].membership.max()) + 1
    with pytest.raises(ModelMismatchError):
        storage_report(coded, make_model(seed=4))
