"""``sparsebtf render``: coded vs reference side by side, JSON numbers, clear errors."""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

from sparsebtf import llvm
from sparsebtf.cli.main import main
from sparsebtf.codec import encode

from .conftest import smooth_btf, tiny_model

if importlib.util.find_spec("mitsuba") is None or importlib.util.find_spec("drjit") is None:
    pytest.skip("mitsuba/drjit not installed (pip install mitsuba drjit)", allow_module_level=True)
_status = llvm.configure()
if not _status.ok:
    pytest.skip(f"Dr.Jit LLVM backend unusable here: {_status.message()}", allow_module_level=True)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    from sparsebtf.data.dense_file import write_dense
    from sparsebtf.storage import save_coded, save_model

    d = tmp_path_factory.mktemp("render")
    model = tiny_model()
    save_model(model, d / "model.h5")
    btf = smooth_btf(9)
    coded = encode(btf, model, tau=(100, 20, 20), eps=0.0, progress=False)
    coded.params["model_file"] = str(d / "model.h5")
    save_coded(coded, d / "m.coded.h5")
    write_dense(d / "m.h5", btf, progress=False)
    write_dense(d / "wrong.h5", smooth_btf(3, size=12), progress=False)
    return d


def test_render_with_reference_writes_png_and_json(files, capsys):
    out = files / "cmp.png"
    raw = files / "raw.npz"
    rc = main(["render", str(files / "m.coded.h5"), "-o", str(out), "--image-size", "40x32",
               "--spp", "4", "--reference", str(files / "m.h5"), "--uv-scale", "2",
               "--interpolation", "barycentric", "--save-raw", str(raw), "--json"])  # fmt: skip
    assert rc == 0
    res = json.loads(capsys.readouterr().out)
    assert res["variant"] == "llvm_ad_rgb" and res["size"] == [40, 32]
    assert 0 < res["mse"] and res["ssim"] > 0.9
    # PSNR with the project's fixed peak 1.0, not the reference render's largest value.
    assert res["peak"] == 1.0 and res["psnr"] == pytest.approx(-10 * np.log10(res["mse"]))
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    arrays = np.load(raw)
    assert arrays["render"].shape == (32, 40, 3) and arrays["reference"].shape == (32, 40, 3)
    assert np.all(np.isfinite(arrays["render"]))
    a, b = arrays["render"].astype(np.float64), arrays["reference"].astype(np.float64)
    assert np.mean((a - b) ** 2) == pytest.approx(res["mse"], rel=1e-6)


def test_render_sampling_option(files, capsys):
    """--sampling cosine|btf: both render; with --reference the two renders of each pair share
    their sampling, so coded and reference stay close (correlated noise) either way."""
    scores = {}
    for sampling in ("cosine", "btf"):
        rc = main(["render", str(files / "m.coded.h5"), "-o", str(files / f"{sampling}.png"),
                   "--image-size", "24", "--spp", "4", "--sampling", sampling, "--reference",
                   str(files / "m.h5"), "--lod", "off", "--json"])  # fmt: skip
        assert rc == 0
        res = json.loads(capsys.readouterr().out)
        assert res["sampling"] == sampling and f"sampling={sampling}" in res["plugin"]
        scores[sampling] = (res["mse"], res["ssim"])
    # Radiance under the sky's sun lobe is far above 1: the fixed-peak PSNR is low here, so
    # closeness is judged by SSIM.
    assert all(s > 0.95 for _, s in scores.values()), scores
    with pytest.raises(SystemExit) as exc:
        main(["render", str(files / "m.coded.h5"), "-o", str(files / "x.png"), "--sampling",
              "importance"])  # fmt: skip
    assert exc.value.code == 2 and "--sampling" in capsys.readouterr().err


def test_render_lod_option(files, capsys):
    """--lod auto (default) gives the plugin the scene's camera; --lod off renders at --tau."""
    images = {}
    for lod in ("auto", "off"):
        raw = files / f"lod-{lod}.npz"
        rc = main(["render", str(files / "m.coded.h5"), "-o", str(files / f"lod-{lod}.png"),
                   "--image-size", "16", "--spp", "2", "--lod", lod, "--uv-scale", "4",
                   "--save-raw", str(raw), "--json"])  # fmt: skip
        assert rc == 0
        res = json.loads(capsys.readouterr().out)
        assert res["lod"] == lod and f"lod={lod}]" in res["plugin"]
        images[lod] = np.load(raw)["render"]
    assert np.abs(images["auto"] - images["off"]).max() > 0


def test_render_alone_cloth(files, capsys):
    out = files / "cloth.png"
    rc = main(["render", str(files / "m.coded.h5"), "-o", str(out), "--scene", "cloth",
               "--image-size", "24", "--spp", "2", "--tau", "0.25"])  # fmt: skip
    assert rc == 0
    assert "wrote" in capsys.readouterr().out and out.stat().st_size > 0


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--reference", "{d}/m.h5", "--max-gib", "1e-6"], "GiB"),
        (["--reference", "{d}/wrong.h5"], "does not match"),
        (["--image-size", "big"], "--image-size"),
        (["--envmap", "{d}/sky.png"], ".exr or .hdr"),
        (["--tau", "0,1,1"], "tau"),
    ],
)
def test_render_errors_are_clear(files, capsys, extra, message):
    args = [a.format(d=files) for a in extra]
    rc = main(["render", str(files / "m.coded.h5"), "-o", str(files / "x.png"),
               "--image-size", "8", "--spp", "1", *args])  # fmt: skip
    assert rc == 2
    assert message in capsys.readouterr().err
    assert not (files / "x.png").exists()


def test_render_refuses_nonfinite_pixels(files, tmp_path, capsys):
    """A file without a bound (one that says so: schema 3 requires the bound or
    ``stats@clamp = "none"``) whose values overflow on decode: one line and no image."""
    import h5py

    from sparsebtf._semantic import STAT_BOUND

    p = tmp_path / "old.coded.h5"
    p.write_bytes((files / "m.coded.h5").read_bytes())
    with h5py.File(p, "r+") as f:
        del f["stats/bound"]
        f["stats"].attrs["clamp"] = np.bytes_(b"none")
        for ch in "YUV":  # schema 3: the values' little-endian bytes, one row each
            planes = f[f"codes/{ch}/value_bytes"]
            v = np.ascontiguousarray(planes[()].T).view("<f2")[:, 0]
            big = (np.sign(v) * np.float16(60000)).astype("<f2")
            planes[...] = big.view(np.uint8).reshape(-1, 2).T
        s = f["stats/std"]
        s[...] = np.full(s.shape, STAT_BOUND, s.dtype)
    out = tmp_path / "bad.png"
    args = ["render", str(p), "-m", str(files / "model.h5"), "-o", str(out), "--image-size",
            "16", "--spp", "1"]  # fmt: skip
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "non-finite pixels" in err[0]
    assert not out.exists()
    # The same values with the bound every new file has: a finite render.
    with h5py.File(p, "r+") as f:
        del f["stats"].attrs["clamp"]
        f["stats"].create_dataset("bound", data=np.zeros((13, 13), np.float16))
    assert main(args) == 0 and out.exists()
