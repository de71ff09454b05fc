"""The authors' released files (shared/official) imported as our model and coded files."""

import json
import shutil

import numpy as np
import pytest

from sparsebtf.cli.main import main
from sparsebtf.errors import FileFormatError
from sparsebtf.learning.coding import sparse_code
from sparsebtf.runtime import decode_points, decode_points_eq5
from sparsebtf.storage import load_coded, load_model, save_coded, save_model
from sparsebtf.storage.release import (
    import_release,
    read_coefficients,
    read_dictionaries,
    read_mean_std,
)


@pytest.fixture(scope="module")
def release(request):
    from .conftest import shared_dir

    d = shared_dir()
    if d is None:
        pytest.skip("the authors' release (shared/official) is not available")
    return import_release(d / "official")


def test_dictionaries_orthonormal(official):
    for ch in "YUV":
        mat, extra = read_dictionaries(official / f"DictEnsOrth4D{ch}.mat")
        b, _ = read_dictionaries(official / f"DictEnsOrth4D{ch}.bin")
        assert sum(extra["EnsHist"]) == 2880
        for u_mat, u_bin in zip(mat, b, strict=True):
            eye = np.eye(u_mat.shape[1])
            assert np.abs(np.einsum("kji,kjl->kil", u_mat, u_mat) - eye).max() < 1e-12
            # fp16 copy: orthonormal at half-precision level (spec: <= 6.7e-4)
            assert np.abs(np.einsum("kji,kjl->kil", u_bin, u_bin) - eye).max() < 1e-3
            assert np.abs(u_mat - u_bin).max() < 5e-4


def test_coefficients_and_memberships(release):
    _, coded, notes = release
    assert set(coded) == {"carpet07", "felt05"}
    assert any("no Y coefficients" in n for n in notes)
    hist = {
        ("carpet07", "U"): [14, 1583, 1, 0, 0, 2, 0, 0],
        ("carpet07", "V"): [898, 518, 184, 0, 0, 0, 0, 0],
        ("felt05", "U"): [0, 1599, 1, 0, 0, 0, 0, 0],
        ("felt05", "V"): [78, 0, 1522, 0, 0, 0, 0, 0],
    }
    for (mat, ch), h in hist.items():
        codes = coded[mat].codes[ch]
        assert codes.n_points == 1600 and np.all(codes.counts == 64)
        assert np.bincount(codes.membership, minlength=8).tolist() == h
        _, vals = codes.point(7)
        assert np.all(np.diff(np.abs(vals)) <= 0)
    assert np.isclose(coded["carpet07"].stats.mean.min(), -1.361, atol=1e-3)


def test_eq4_equals_eq5_on_imported_point(release):
    _, coded, _ = release
    c = coded["felt05"]
    for ch in ("U", "V"):
        eq5 = decode_points_eq5(c, ch, [5, 900], [0, 77], [3, 150])
        eq4 = decode_points(c, ch, [5, 900], slice(None), slice(None))[:, :, :, [0, 77]][
            ..., [3, 150]
        ]
        assert np.allclose(eq4, eq5, atol=1e-10)


def test_reencoding_reproduces_membership_and_coefficients(release):
    model, coded, _ = release
    c = coded["carpet07"]
    codes = c.codes["U"]
    pts = [0, 1599]
    x = decode_points(c, "U", pts)
    again = sparse_code(x, model.dictionaries["U"], tau=64, eps=0.0, dtype=np.float64)
    assert np.array_equal(again.membership, codes.membership[pts])
    for j, p in enumerate(pts):
        loc_a, val_a = again.point(j)
        loc_b, val_b = codes.point(p)
        order_a = np.lexsort(loc_a.T)
        order_b = np.lexsort(loc_b.T)
        assert np.array_equal(loc_a[order_a], loc_b[order_b])
        assert np.allclose(val_a[order_a], val_b[order_b], atol=1e-6 * np.abs(val_b).max())


def test_imported_files_round_trip(release, tmp_path):
    model, coded, _ = release
    save_model(model, tmp_path / "m.h5")
    save_coded(coded["felt05"], tmp_path / "f.h5")
    back = load_coded(tmp_path / "f.h5", load_model(tmp_path / "m.h5"))
    assert back.channels == ("U", "V")
    assert np.array_equal(back.codes["V"].locations, coded["felt05"].codes["V"].locations)


def test_import_and_lookup_commands(official, tmp_path, capsys):
    assert main(["import-release", str(official), "-o", str(tmp_path / "m.h5"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["coded"]) == {"carpet07", "felt05"}
    coded = out["coded"]["carpet07"]
    assert (
        main(["lookup", coded, "--texel", "15,27", "--light", "3", "--view", "40", "--json"]) == 0
    )
    val = json.loads(capsys.readouterr().out)
    assert set(val["standardized"]) == {"U", "V"} and val["rgb"] is None
    assert val["point"] == 15 // 10 + 40 * (27 // 10) and val["in_patch"] == [5, 7]
    # log = standardized · σ + μ with the release's shared statistics (index view·151 + light)
    raw = np.fromfile(official / "carpet07_mean_std.bin", dtype="<f8")
    j = 40 * 151 + 3
    assert val["log"]["U"] == pytest.approx(val["standardized"]["U"] * raw[22801 + j] + raw[j])


def test_release_bad_files(official, tmp_path):
    bad = tmp_path / "DictEnsOrth4DU.bin"
    bad.write_bytes((official / "DictEnsOrth4DU.bin").read_bytes()[:-2])
    with pytest.raises(FileFormatError, match="732830 bytes, expected 732832"):
        read_dictionaries(bad)
    coeffs = tmp_path / "Coeffs_BTF_x_1e-05_U.bin"
    coeffs.write_bytes((official / "Coeffs_BTF_felt05_1e-05_U.bin").read_bytes()[:-4])
    with pytest.raises(FileFormatError, match="do not fit 4"):
        read_coefficients(coeffs)
    raw = bytearray((official / "Coeffs_BTF_felt05_1e-05_U.bin").read_bytes())
    n = 102400
    raw[2 * (4 + 4 * n) : 2 * (4 + 4 * n) + 2] = (9).to_bytes(2, "little", signed=True)
    coeffs.write_bytes(bytes(raw))
    with pytest.raises(FileFormatError, match=r"membership M\[0\] = 9"):
        read_coefficients(coeffs)
    ms = tmp_path / "x_mean_std.bin"
    ms.write_bytes(b"\0" * 100)
    with pytest.raises(FileFormatError, match="expected 364816"):
        read_mean_std(ms)
    shutil.copy(official / "DictEnsOrth4DV.mat", tmp_path / "DictEnsOrth4DV.mat")
    mats, _ = read_dictionaries(tmp_path / "DictEnsOrth4DV.mat")
    assert len(mats) == 4
    with pytest.raises(FileFormatError, match="not a folder"):
        import_release(tmp_path / "nope")
