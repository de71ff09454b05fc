"""The bundled 'release' model: equal to a fresh conversion, used by default, found by hash."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from sparsebtf.cli.main import main
from sparsebtf.data.btf import ArrayBTF
from sparsebtf.data.dense_file import write_dense
from sparsebtf.data.directions import ubo2014
from sparsebtf.errors import ModelMismatchError
from sparsebtf.storage import load_coded, load_coded_with_model
from sparsebtf.storage.bundled import DEFAULT_MODEL, bundled_models, load_bundled, open_model

from .conftest import smooth_btf, tiny_model


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def ubo_btf(size: int = 10, seed: int = 0) -> ArrayBTF:
    """A small positive BTF on the 151 UBO2014 directions (what the bundled model covers)."""
    rng = np.random.default_rng(seed)
    d = ubo2014()
    base = rng.uniform(0.1, 0.7, (size, size, 1, 1, 3))
    ang = (0.3 + d.xyz[:, 2])[:, None] * (0.5 + d.xyz[:, 2])[None, :]
    data = base * ang[None, None, :, :, None]
    return ArrayBTF(data.astype(np.float32), d, d, name=f"ubo{seed}")


@pytest.fixture(scope="module")
def ubo_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("ubo") / "ubo.h5"
    write_dense(path, ubo_btf())
    return path


def test_bundled_model_equals_a_fresh_conversion(official):
    from sparsebtf.storage.release_bundle import compare_bundled, release_bundle

    assert compare_bundled(official) == []
    fresh = release_bundle(official)
    have = load_bundled()
    for ch in fresh.channels:
        for a, b in zip(have.dictionaries[ch], fresh.dictionaries[ch], strict=True):
            assert a.dtype == np.float64 and np.array_equal(a, b)
    # stored narrower than float64, and still exactly those values: the hash is unchanged
    import h5py

    from sparsebtf._h5check import as_str

    with h5py.File(bundled_models()[DEFAULT_MODEL].path) as f:
        assert f["dictionaries/Y/mode3"].dtype == np.float32
        assert as_str(f.attrs["content_hash"]) == fresh.content_hash  # fixed-length bytes


def test_bundled_model_metadata(capsys):
    code, out, _ = run(["models", "--json"], capsys)
    assert code == 0
    listed = json.loads(out)
    assert listed["default"] == "release"
    (m,) = [x for x in listed["models"] if x["name"] == "release"]
    assert m["content_hash"] == load_bundled().content_hash
    assert m["channels"] == ["Y", "U", "V"] and m["n_dictionaries"] == {"Y": 8, "U": 8, "V": 8}
    assert m["patch"] == 10 and m["directions"]["lights"] == {"name": "ubo2014", "count": 151}
    assert m["tau_train"] == {"Y": 256, "U": 32, "V": 32} and "MIT" in m["licence"]
    folder = bundled_models()["release"].path.parent
    assert (folder / "LICENSE-SparseBTF").read_text().startswith("MIT License")
    assert m["content_hash"] in (folder / "PROVENANCE.md").read_text()
    code, out, _ = run(["models"], capsys)
    assert code == 0 and "release" in out and "256,32,32" in out


def test_encode_without_model_uses_the_bundled_one(ubo_file, tmp_path, capsys):
    coded = tmp_path / "c.h5"
    code, out, _ = run(["encode", ubo_file, "-o", coded], capsys)
    assert code == 0 and "bundled model 'release'" in out
    c = load_coded(coded)
    assert c.model_hash == load_bundled().content_hash
    assert "model_file" not in c.params  # found by hash, not by a path into the installation
    # decode, eval, lookup, info: no -m; the coded file's hash finds the bundled model
    back = load_coded_with_model(coded)
    assert back.model is load_bundled()
    code, out, _ = run(["eval", coded, "--reference", ubo_file, "--json", "--ssim-images", "2"],
                       capsys)  # fmt: skip
    ev = json.loads(out)
    # 20 dB below the reference's largest value (PSNR itself has the fixed peak 1.0).
    assert code == 0 and ev["mse_rgb"] < ev["ssim_data_range"] ** 2 / 100
    code, out, _ = run(["lookup", coded, "--texel", "3,4", "--light", "7", "--view", "9",
                        "--json"], capsys)  # fmt: skip
    assert code == 0 and len(json.loads(out)["rgb"]) == 3
    code, out, _ = run(["info", coded, "--json"], capsys)
    assert json.loads(out)["model"] == "bundled 'release'"
    code, out, _ = run(["encode", ubo_file, "-m", "release", "-o", tmp_path / "d.h5"], capsys)
    assert code == 0 and load_coded(tmp_path / "d.h5").model_hash == c.model_hash
    code, _, err = run(["encode", ubo_file, "-m", "nosuch", "-o", tmp_path / "e.h5"], capsys)
    assert code == 2 and "no bundled model of that name (bundled: release)" in err


def test_release_coefficients_against_the_bundled_model(official):
    """The authors' carpet07/felt05 codes decode on the bundled (float32) dictionaries to the
    values they decode to on the fp64 .mat ones, within binary16 rounding."""
    from sparsebtf.runtime import decode_points
    from sparsebtf.storage.release import import_release

    _, exact, _ = import_release(official, prefer="mat")
    model, against, notes = import_release(official, model=load_bundled())
    assert model is load_bundled() and any("codes refer to model" in n for n in notes)
    points = [0, 777, 1599]
    for name in ("carpet07", "felt05"):
        assert against[name].model_hash == load_bundled().content_hash
        for ch in ("U", "V"):
            ref = decode_points(exact[name], ch, points)
            got = decode_points(against[name], ch, points)
            half_step = np.spacing(np.abs(ref).astype(np.float16)).astype(np.float64) / 2
            assert np.all(np.abs(got - ref) <= half_step)


def test_import_release_against_the_bundled_model_cli(official, tmp_path, capsys):
    code, out, _ = run(["import-release", official, "-m", "release", "--coded-dir", tmp_path,
                        "--json"], capsys)  # fmt: skip
    assert code == 0 and json.loads(out)["content_hash"] == load_bundled().content_hash
    assert not list(tmp_path.glob("*model*"))
    code, out, _ = run(["lookup", tmp_path / "felt05.coded.h5", "--texel", "15,27", "--light",
                        "3", "--view", "40"], capsys)  # fmt: skip
    assert code == 0 and "(no linear RGB: RGB needs Y, U and V" in out
    assert "no Y coefficients" in out


def test_wrong_directions_and_sizes_get_one_line(tmp_path, capsys):
    custom = tmp_path / "custom.h5"
    write_dense(custom, smooth_btf(0, size=10))
    code, _, err = run(["encode", custom, "-o", tmp_path / "x.h5"], capsys)
    assert code == 2 and err.count("\n") == 1 and err.startswith("sparsebtf: error:")
    assert "13 lights x 13 views" in err and "151 x 151 (ubo2014)" in err
    assert f"sparsebtf train {custom}" in err and not (tmp_path / "x.h5").exists()
    odd = tmp_path / "odd.h5"
    write_dense(odd, ubo_btf(size=12))
    code, _, err = run(["encode", odd, "-o", tmp_path / "y.h5"], capsys)
    assert code == 2 and err.count("\n") == 1 and "--crop 0:10,0:10" in err
    code, _, _ = run(["encode", odd, "-o", tmp_path / "y.h5", "--crop", "0:10,2:12"], capsys)
    assert code == 0


def test_ubo2003_directions_are_refused(tmp_path, capsys):
    from sparsebtf.data.directions import ubo2003

    d = ubo2003()
    data = np.full((10, 10, len(d), len(d), 3), 0.3, np.float32)
    path = tmp_path / "u3.h5"
    write_dense(path, ArrayBTF(data, d, d, name="u3"))
    code, _, err = run(["encode", path, "-o", tmp_path / "x.h5"], capsys)
    assert code == 2 and "81 lights x 81 views (ubo2003)" in err and "sparsebtf train" in err


def test_unknown_model_of_a_coded_file_names_both_ways(tmp_path):
    from sparsebtf.codec import encode
    from sparsebtf.storage import save_coded, save_model

    model = tiny_model(max_iter=1)
    coded = encode(smooth_btf(5), model, tau=(16, 4, 4))
    save_coded(coded, tmp_path / "in_memory.h5")  # the model was never saved: nothing to find
    with pytest.raises(ModelMismatchError, match=r"--model MODEL\.h5.*model_path="):
        load_coded_with_model(tmp_path / "in_memory.h5")
    save_model(model, tmp_path / "m.h5")
    save_coded(coded, tmp_path / "named.h5")  # now the coded file records the model's file
    assert load_coded_with_model(tmp_path / "named.h5").model.content_hash == model.content_hash
    assert open_model(tmp_path / "m.h5").content_hash == model.content_hash


def test_outputs_are_group_readable(tmp_path):
    from sparsebtf._atomic import atomic_output

    old = os.umask(0o022)
    try:
        with atomic_output(tmp_path / "a.txt") as tmp:
            tmp.write_text("x")
        os.umask(0o027)
        with atomic_output(tmp_path / "b.txt") as tmp:
            tmp.write_text("x")
    finally:
        os.umask(old)
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o644
    assert (tmp_path / "b.txt").stat().st_mode & 0o777 == 0o640


def test_info_into_head_has_no_traceback(ubo_file):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    r = subprocess.run(
        f"{sys.executable} -m sparsebtf.cli.main info {ubo_file} --no-scan | head -1",
        shell=True, capture_output=True, text=True, env=env, timeout=120,
    )
    assert r.stdout.startswith("kind") and "Traceback" not in r.stderr and "Broken" not in r.stderr


def test_decode_with_nothing_to_do_fails(ubo_file, tmp_path, capsys):
    code, _, err = run(["decode", tmp_path / "whatever.h5"], capsys)
    assert code == 2 and "nothing to do" in err
