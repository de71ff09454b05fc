"""Encoding many BTFs in one run (``sparsebtf encode A B C -o DIR/``), in process."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sparsebtf.cli.main import main
from sparsebtf.codec import encode, encode_many, output_name
from sparsebtf.data.crop import CroppedBTF
from sparsebtf.data.dense_file import write_dense
from sparsebtf.points.statistics import combine_statistics, gather_statistics, statistic_sums
from sparsebtf.storage import save_model

from .conftest import smooth_btf, tiny_model


@pytest.fixture(scope="module")
def model():
    return tiny_model(1)


def test_output_names():
    assert output_name("/data/carpet07.btf") == "carpet07.coded.h5"
    assert output_name("stone.H5") == "stone.coded.h5"
    assert output_name("a/b.zip") == "b.coded.h5"
    assert output_name("synth:stone:40:1") == "synth_stone_40_1.coded.h5"


def test_statistics_by_view_ranges_equal_one_pass():
    btf = smooth_btf(4, size=8)
    for mode in ("shared", "per_channel"):
        whole = gather_statistics(btf, mode)
        parts = [statistic_sums(btf, v) for v in [(0, 5), (5, 6), (6, 13)]]
        split = combine_statistics(parts, mode)
        assert np.array_equal(whole.mean, split.mean) and np.array_equal(whole.std, split.std)
    with pytest.raises(ValueError, match="consecutive"):
        combine_statistics(parts[1:])


def test_each_of_many_equals_its_own_encode(model):
    btfs = [smooth_btf(20 + s, size=size) for s, size in enumerate((16, 8, 12))]
    window = (slice(0, 8), slice(4, 8))
    many = list(encode_many(btfs, model, tau=(16, 4, 4), crop=window, progress=False))
    for btf, got in zip(btfs, many, strict=True):
        want = encode(CroppedBTF(btf, *window), model, tau=(16, 4, 4), progress=False)
        assert got.name == btf.name and (got.height, got.width) == (8, 4)
        for ch in want.codes:
            assert np.array_equal(got.codes[ch].values, want.codes[ch].values)
            assert np.array_equal(got.codes[ch].locations, want.codes[ch].locations)
            assert np.array_equal(got.codes[ch].membership, want.codes[ch].membership)


@pytest.fixture
def files(tmp_path, model):
    paths = []
    for s in range(2):
        p = tmp_path / f"in{s}.h5"
        write_dense(p, smooth_btf(30 + s))
        paths.append(str(p))
    save_model(model, tmp_path / "model.h5")
    return tmp_path, paths


def test_cli_folder_output_and_json(files, capsys):
    tmp, paths = files
    code = main(["encode", *paths, "-m", str(tmp / "model.h5"), "-o", str(tmp / "out"),
                 "--tau", "16,4,4", "--json"])  # fmt: skip
    assert code == 0
    files_out = json.loads(capsys.readouterr().out)["files"]
    assert [f["output"] for f in files_out] == [str(tmp / "out" / f"in{s}.coded.h5")
                                               for s in range(2)]  # fmt: skip
    assert all((tmp / "out" / f"in{s}.coded.h5").exists() for s in range(2))


@pytest.mark.parametrize(
    ("inputs", "output", "message"),
    [
        (["in0.h5", "in1.h5"], "both.h5", "2 inputs need an output folder"),
        (["in0.h5", "in0.h5"], "out/", "would both be written to"),
        (["in0.h5"], "in0.h5", "would overwrite the input"),
    ],
)
def test_cli_refuses_clashing_outputs(files, capsys, inputs, output, message):
    tmp, _ = files
    argv = ["encode", *(str(tmp / i) for i in inputs), "-m", str(tmp / "model.h5"),
            "-o", str(tmp / output) + ("/" if output.endswith("/") else "")]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("sparsebtf: error: ") and message in err and err.count("\n") == 1
