"""Corruption is detected: a flipped bit anywhere in a coded, model or dense file is reported
(checksums on every dataset, checksummed HDF5 structures), naming the dataset; schema-1 files
(no checksums) still load and say so."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from sparsebtf.cli.info import describe
from sparsebtf.cli.main import main
from sparsebtf.data.dense_file import DenseFileBTF
from sparsebtf.errors import FileFormatError
from sparsebtf.fuzzing import _legacy_copy, build_corpus
from sparsebtf.storage import load_coded, load_model


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("integrity")
    build_corpus(folder)
    return folder


def _datasets(path: Path) -> list[str]:
    names: list[str] = []
    with h5py.File(path, "r") as f:
        f.visititems(lambda n, o: names.append(n) if isinstance(o, h5py.Dataset) else None)
    return names


def _flip_in_data(path: Path, name: str, out: Path, rng: np.random.Generator) -> Path:
    """Copy ``path`` to ``out`` with one bit flipped inside dataset ``name``'s stored data."""
    with h5py.File(path, "r") as f:
        info = f[name].id.get_chunk_info(int(rng.integers(f[name].id.get_num_chunks())))
    raw = bytearray(path.read_bytes())
    raw[info.byte_offset + int(rng.integers(info.size))] ^= 1 << int(rng.integers(8))
    out.write_bytes(bytes(raw))
    return out


def test_flipped_bit_in_every_dataset_of_a_coded_file_is_named(corpus: Path, tmp_path: Path):
    coded, model = corpus / "coded.h5", load_model(corpus / "model.h5")
    names = _datasets(coded)
    # Values, locations, membership, counts, errors of every channel, the statistics and
    # the direction tables.
    assert {"codes/Y/value_bytes", "codes/V/location_table", "codes/V/usage",
            "codes/U/membership", "codes/Y/counts", "codes/U/errors", "stats/mean",
            "stats/std", "lights/xyz", "views/phi"} <= set(names)
    rng = np.random.default_rng(0)
    for i, name in enumerate(names):
        for trial in range(3):
            bad = _flip_in_data(coded, name, tmp_path / f"c{i}_{trial}.h5", rng)
            with pytest.raises(FileFormatError, match=rf"/{name}: checksum mismatch"):
                load_coded(bad, model)


def test_flipped_bits_anywhere_are_refused_or_harmless(corpus: Path, tmp_path: Path) -> None:
    """A flip in any byte of a coded file: an error, or (unused bytes) the very same codes."""
    src = corpus / "coded.h5"
    model = load_model(corpus / "model.h5")
    ref = load_coded(src, model)
    data = src.read_bytes()
    rng = np.random.default_rng(1)
    outcomes = {"error": 0, "same": 0}
    for k, pos in enumerate(rng.choice(len(data), 150, replace=False)):
        raw = bytearray(data)
        raw[int(pos)] ^= 1 << int(rng.integers(8))
        p = tmp_path / f"flip{k}.h5"
        p.write_bytes(bytes(raw))
        try:
            got = load_coded(p, model)
        except FileFormatError:
            outcomes["error"] += 1
            continue
        outcomes["same"] += 1
        assert (got.height, got.width, got.patch, got.name) == (ref.height, ref.width,
                                                                ref.patch, ref.name)  # fmt: skip
        assert got.params == ref.params and got.stats.log_offset == ref.stats.log_offset
        np.testing.assert_array_equal(got.stats.mean, ref.stats.mean)
        for ch in ref.channels:
            a, b = got.codes[ch], ref.codes[ch]
            for field in ("membership", "counts", "values", "locations", "errors"):
                np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert outcomes["error"] > 100


def test_flipped_bit_in_stats_eps_attribute_is_detected(corpus: Path, tmp_path: Path) -> None:
    src = corpus / "coded.h5"
    with h5py.File(src, "r") as f:
        eps = np.float64(f["stats"].attrs["eps"]).tobytes()
    raw = bytearray(src.read_bytes())
    at = raw.find(eps)
    assert at > 0
    raw[at + 2] ^= 0x10  # the attribute now holds another finite number
    bad = tmp_path / "eps.h5"
    bad.write_bytes(bytes(raw))
    with pytest.raises(FileFormatError, match=r"eps\.h5.*(checksum|damaged)"):
        load_coded(bad)


def test_nan_eps_makes_eval_fail(corpus: Path, tmp_path: Path, capsys) -> None:
    bad = tmp_path / "nan_eps.h5"
    bad.write_bytes((corpus / "coded.h5").read_bytes())
    with h5py.File(bad, "a") as f:  # a consistent rewrite: the checksums still match
        f["stats"].attrs["eps"] = np.nan
    with pytest.raises(FileFormatError, match=r"stats: attribute 'eps' is nan"):
        load_coded(bad)
    code = main(["eval", str(bad), "--reference", "synth:stone:4", "-m",
                 str(corpus / "model.h5")])  # fmt: skip
    assert code == 2
    assert "attribute 'eps' is nan" in capsys.readouterr().err


def test_nan_values_written_by_another_tool_are_refused(corpus: Path, tmp_path: Path) -> None:
    bad = tmp_path / "nan_values.h5"
    bad.write_bytes((corpus / "coded.h5").read_bytes())
    with h5py.File(bad, "a") as f:
        v = f["codes/U/value_bytes"][()]
        v[:, 1] = np.array([np.nan], "<f2").view(np.uint8)
        f["codes/U/value_bytes"][...] = v
    with pytest.raises(FileFormatError, match=r"codes/U/value_bytes: 1 NaN/Inf values"):
        load_coded(bad)


def test_model_and_dense_flips_are_named(corpus: Path, tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    bad = _flip_in_data(corpus / "model.h5", "dictionaries/U/mode4", tmp_path / "m.h5", rng)
    with pytest.raises(FileFormatError, match=r"dictionaries/U/mode4: checksum mismatch"):
        load_model(bad)
    bad = _flip_in_data(corpus / "dense.h5", "btf", tmp_path / "d.h5", rng)
    with pytest.raises(FileFormatError, match=r"/btf: checksum mismatch"):
        DenseFileBTF(bad).to_array()


def test_schema_1_files_still_load_and_say_they_have_no_checksum(corpus: Path) -> None:
    model = load_model(corpus / "model_v1.h5")
    coded = load_coded(corpus / "coded_v1.h5", model)
    ref = load_coded(corpus / "coded.h5", model)
    np.testing.assert_array_equal(coded.codes["Y"].values, ref.codes["Y"].values)
    with DenseFileBTF(corpus / "dense_v1.h5") as old, DenseFileBTF(corpus / "dense.h5") as new:
        np.testing.assert_array_equal(old.to_array(), new.to_array())
    for name in ("coded_v1.h5", "model_v1.h5", "dense_v1.h5"):
        assert "no checksums" in describe(corpus / name, scan=False)["integrity"]
    for name in ("coded.h5", "model.h5", "dense.h5"):
        assert describe(corpus / name, scan=False)["integrity"].startswith("fletcher32")


def test_writers_checksum_every_dataset(corpus: Path) -> None:
    for name in ("coded.h5", "model.h5", "dense.h5"):
        # Superblock version 3 (HDF5 1.10 structures, checksummed metadata).
        assert (corpus / name).read_bytes()[8] == 3
        with h5py.File(corpus / name, "r") as f:
            assert int(f.attrs["schema_version"]) == (3 if name == "coded.h5" else 2)
            for ds in _datasets(corpus / name):
                assert f[ds].fletcher32, f"{name}:{ds}"


def test_info_json_reports_integrity(corpus: Path, capsys) -> None:
    assert main(["info", str(corpus / "coded_v1.h5"), "--json"]) == 0
    assert "no checksums" in json.loads(capsys.readouterr().out)["integrity"]


def test_legacy_copy_is_schema_1(corpus: Path, tmp_path: Path) -> None:
    old = _legacy_copy(corpus / "coded_v2.h5", tmp_path / "old.h5")
    with h5py.File(old, "r") as f:
        assert int(f.attrs["schema_version"]) == 1 and not f["codes/Y/values"].fletcher32
