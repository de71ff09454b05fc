"""The command line end to end on tiny shapes (13 directions, 8x8 texels, 4x4 patches)."""

import json

import numpy as np
import pytest

from sparsebtf.cli.main import main
from sparsebtf.data.dense_file import DenseFileBTF, write_dense

from .conftest import smooth_btf


@pytest.fixture
def files(tmp_path):
    paths = []
    for s in range(3):
        p = tmp_path / f"m{s}.h5"
        write_dense(p, smooth_btf(s))
        paths.append(str(p))
    return tmp_path, paths


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_train_encode_decode_eval_info(files, capsys):
    tmp, paths = files
    model = tmp / "model.h5"
    code, out, _ = run(
        [
            "train",
            *paths[:2],
            "-o",
            model,
            "--dicts",
            "2",
            "--tau-train",
            "16,4,4",
            "--patch",
            "4",
            "--sample",
            "1",
            "--iters",
            "2",
            "--json",
        ],
        capsys,
    )
    assert code == 0
    summary = json.loads(out)
    assert summary["channels"] == ["Y", "U", "V"] and summary["mode_sizes"] == [4, 4, 13, 13]

    coded = tmp / "c.h5"
    code, out, _ = run(
        ["encode", paths[2], "-m", model, "-o", coded, "--tau", "32,8,8", "--json"], capsys
    )
    assert code == 0
    rep = json.loads(out)
    assert rep["nnz"] == {"Y": 4 * 32, "U": 4 * 8, "V": 4 * 8}

    code, out, _ = run(
        ["eval", coded, "--reference", paths[2], "--json", "--ssim-images", "4"], capsys
    )
    assert code == 0
    ev = json.loads(out)
    for key in (
        "mse_rgb",
        "psnr_rgb",
        "ssim",
        "mse_log",
        "mse_display",
        "nnz",
        "bytes_coefficients",
        "bytes_dictionaries",
        "bytes_stats",
        "bytes_total",
        "compression_ratio",
        "file_bytes",
    ):
        assert key in ev
    assert 0 < ev["mse_rgb"] < 0.05 and 0 < ev["ssim"] <= 1

    recon = tmp / "r.h5"
    code, out, _ = run(
        ["decode", coded, "-o", recon, "--images", "0:0,5:7", "--png", tmp / "png"], capsys
    )
    assert code == 0
    assert len(list((tmp / "png").glob("*.png"))) == 2
    with DenseFileBTF(recon) as r:
        rec = r.to_array()
    ref = smooth_btf(2).to_array()
    assert np.mean((rec - ref) ** 2) == pytest.approx(ev["mse_rgb"], rel=1e-3)

    for f, kind in ((paths[0], "btf"), (model, "model"), (coded, "coded")):
        code, out, _ = run(["info", f, "--json"], capsys)
        assert code == 0 and json.loads(out)["kind"] == kind
    code, out, _ = run(["info", paths[0]], capsys)
    assert "value range" in out and "13" in out


def test_synth_command_and_info(tmp_path, capsys):
    out_h5 = tmp_path / "stone.h5"
    png = tmp_path / "stone.png"
    code, out, _ = run(
        [
            "synth",
            "--class",
            "stone",
            "--size",
            "12",
            "--directions",
            "tiny13",
            "-o",
            out_h5,
            "--preview",
            png,
        ],
        capsys,
    )
    assert code == 0 and out_h5.exists() and png.exists()
    code, out, _ = run(["info", out_h5, "--json"], capsys)
    info = json.loads(out)
    assert info["shape"] == [12, 12, 13, 13, 3]
    assert info["directions"]["lights"]["name"] == "tiny13"
    lo, hi = info["value_range"]
    assert 0 <= lo < hi


def test_errors_are_one_line(files, capsys):
    tmp, paths = files
    code, _, err = run(["info", tmp / "missing.h5"], capsys)
    assert code == 2 and err.startswith("sparsebtf: error:") and "no such file" in err
    code, _, err = run(["synth", "--class", "velvet", "-o", tmp / "x.h5"], capsys)
    assert code == 2 and "unknown material class" in err
    model = tmp / "model.h5"
    run(
        [
            "train",
            *paths[:2],
            "-o",
            model,
            "--dicts",
            "2",
            "--tau-train",
            "16,4,4",
            "--patch",
            "4",
            "--sample",
            "1",
            "--iters",
            "1",
        ],
        capsys,
    )
    code, _, err = run(
        ["encode", paths[2], "-m", model, "-o", tmp / "c.h5", "--tau", "8,4,4"], capsys
    )
    assert code == 2 and "below the training sparsity" in err
    code, _, err = run(
        ["train", paths[0], "-o", tmp / "bad_model.h5", "--crop", "0:5,0:8", "--patch", "4"], capsys
    )
    assert code == 2 and "not a multiple of the patch size" in err
    assert not (tmp / "bad_model.h5").exists()


def test_ubo2014_btf_file_through_the_cli(tmp_path, capsys):
    from sparsebtf.data.directions import tiny
    from sparsebtf.formats.ubo2014_write import write_ubo2014

    rng = np.random.default_rng(0)
    d = tiny(7)
    h = w = 8
    sp = [rng.standard_normal((h * w, 2)).astype(np.float32) * 0.1 for _ in range(3)]
    an = [rng.standard_normal((49, 2)).astype(np.float32) * 0.1 for _ in range(3)]
    path = tmp_path / "tiny.btf"
    write_ubo2014(path, sp, an, h, w, d, d, "DFMF", "float")
    code, out, _ = run(["info", path, "--json"], capsys)
    assert code == 0
    info = json.loads(out)
    assert info["shape"] == [8, 8, 7, 7, 3] and info["format"] == "ubo2014-btf"
    dense = tmp_path / "tiny.h5"
    from sparsebtf.open import open_btf

    btf = open_btf(path)
    write_dense(dense, btf)
    with DenseFileBTF(dense) as f:
        assert np.allclose(f.to_array(), btf.to_array())


def test_convert_with_crop(files, capsys):
    tmp, paths = files
    out = tmp / "crop.h5"
    code, _, _ = run(["convert", paths[0], "-o", out, "--crop", "2:6,0:4"], capsys)
    assert code == 0
    with DenseFileBTF(out) as f:
        assert np.array_equal(f.to_array(), smooth_btf(0).data[2:6, 0:4])
    code, _, err = run(["convert", paths[0], "-o", tmp / "bad.h5", "--crop", "2-6"], capsys)
    assert code == 2 and "R0:R1,C0:C1" in err


def test_synth_preview_of_any_btf(files, capsys):
    tmp, paths = files
    png = tmp / "sheet.png"
    code, _, _ = run(["synth", "--from", paths[1], "--preview", png], capsys)
    assert code == 0 and png.exists() and png.stat().st_size > 1000
    code, _, err = run(["synth", "--preview", png], capsys)
    assert code == 2 and "--class" in err


def test_ubo2003_zip_through_the_cli(tmp_path, capsys):
    from sparsebtf.data.directions import from_angles
    from sparsebtf.formats.ubo2003 import write_ubo2003_zip

    d = from_angles(np.radians([0, 30, 30]), np.radians([0, 0, 180]))
    data = smooth_btf(1, size=8).data[:, :, :3, :3] * 0.5 + 0.1
    path = tmp_path / "tiny.zip"
    write_ubo2003_zip(path, data, d, d, kind="hdr")
    code, out, _ = run(["info", path, "--json"], capsys)
    assert code == 0
    info = json.loads(out)
    assert info["shape"] == [8, 8, 3, 3, 3] and info["format"] == "ubo2003-zip"
    dense = tmp_path / "z.h5"
    code, _, _ = run(["convert", path, "-o", dense], capsys)
    assert code == 0
    with DenseFileBTF(dense) as f:
        assert np.allclose(f.to_array(), data, rtol=0.02, atol=1e-3)
