"""``sparsebtf export-release``: a coded file in the authors' release layout, read back by
``import-release`` to the same codes, statistics and (unclamped) decoded values."""

import dataclasses
import json

import numpy as np
import pytest

from sparsebtf.cli.main import main
from sparsebtf.data.btf import ArrayBTF
from sparsebtf.data.dense_file import write_dense
from sparsebtf.errors import BTFInputError
from sparsebtf.runtime.dense import coded_btf_view
from sparsebtf.storage import load_coded, load_coded_with_model, save_coded
from sparsebtf.storage.bundled import load_bundled
from sparsebtf.storage.release import import_release, read_angles
from sparsebtf.storage.release_write import check_exportable, export_release

from .test_bundled import ubo_btf


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def coded_file(tmp_path_factory):
    """Two 10x10 patches (20x10 texels) on the 151 UBO2014 directions, coded on the bundled
    release model with the release's log offset."""
    d = tmp_path_factory.mktemp("export")
    a, b = ubo_btf(10, 0), ubo_btf(10, 1)
    data = np.concatenate([a.to_array(), b.to_array()], axis=0)
    write_dense(d / "u.h5", ArrayBTF(data, a.lights, a.views, name="ubo"))
    assert main(["encode", str(d / "u.h5"), "-m", "release", "--log-offset", "release",
                 "-o", str(d / "c.h5")]) == 0  # fmt: skip
    return d / "c.h5"


def test_export_then_import_gives_the_same_codes_and_decode(coded_file, tmp_path, capsys):
    out = tmp_path / "out"
    code, text, _ = run(["export-release", coded_file, out, "--json"], capsys)
    assert code == 0, text
    report = json.loads(text)
    assert report["import_with"].endswith("-m release --size 20x10")
    assert report["clamp_bound_dropped"] is True
    names = sorted(p.name for p in out.iterdir())
    assert names == ["Coeffs_BTF_ubo_1e-05_U.bin", "Coeffs_BTF_ubo_1e-05_V.bin",
                     "Coeffs_BTF_ubo_1e-05_Y.bin", "bonn_angles.bin", "ubo_mean_std.bin",
                     "xyz_loc.bin"]  # fmt: skip
    code, text, _ = run(["import-release", out, "-m", "release", "--size", "20x10",
                         "--coded-dir", tmp_path / "back"], capsys)  # fmt: skip
    assert code == 0, text
    a = load_coded_with_model(coded_file)
    b = load_coded_with_model(tmp_path / "back" / "ubo.coded.h5")
    # exact: the coded file's values are binary16 already, the statistics float64 in both
    for ch in ("Y", "U", "V"):
        ca, cb = a.codes[ch], b.codes[ch]
        assert np.array_equal(ca.membership, cb.membership)
        assert np.array_equal(ca.counts, cb.counts)
        assert np.array_equal(ca.values, cb.values)
        assert np.array_equal(ca.locations, cb.locations)
    assert np.array_equal(a.stats.mean, b.stats.mean) and np.array_equal(a.stats.std, b.stats.std)
    assert b.stats.bound is None  # the layout has no clamp bound
    unclamped = dataclasses.replace(a, stats=dataclasses.replace(a.stats, bound=None))
    assert np.array_equal(coded_btf_view(unclamped).to_array(), coded_btf_view(b).to_array())
    assert read_angles(out / "bonn_angles.bin").equals(a.lights, atol=1e-12)


def test_export_of_the_official_files_reproduces_them(official, tmp_path):
    """The authors' coefficients and statistics imported, then exported: the same bytes; the
    direction files within float32 rounding (the authors computed theirs in single precision)."""
    model = load_bundled()
    _, coded, _ = import_release(official, model=model)
    assert coded
    for c in coded.values():
        for p in export_release(c, tmp_path, model.content_hash):
            mine, theirs = p.read_bytes(), (official / p.name).read_bytes()
            if p.name.startswith("Coeffs_BTF_") or p.name.endswith("_mean_std.bin"):
                assert mine == theirs, p.name
            else:
                assert len(mine) == len(theirs)
                diff = np.abs(np.frombuffer(mine, "<f8") - np.frombuffer(theirs, "<f8"))
                assert diff.max() < (1e-12 if p.name == "bonn_angles.bin" else 2e-7), p.name


def test_unrepresentable_coded_files_are_refused(coded_file, tmp_path, capsys):
    c = load_coded(coded_file)
    h = c.model_hash
    with pytest.raises(BTFInputError, match="not the release's ensembles"):
        check_exportable(c, "0" * 64)
    with pytest.raises(BTFInputError, match="log offset"):
        offset = dataclasses.replace(c.stats, log_offset=1e-3)
        check_exportable(dataclasses.replace(c, stats=offset), h)
    with pytest.raises(BTFInputError, match="cannot be a release file name"):
        check_exportable(c, h, name="a/b")
    big = dataclasses.replace(c.codes["U"], values=c.codes["U"].values * 1e5)
    with pytest.raises(BTFInputError, match="fp16"):
        check_exportable(dataclasses.replace(c, codes={**c.codes, "U": big}), h)
    # a file on another model: one line, nothing written
    other = tmp_path / "other.h5"
    save_coded(dataclasses.replace(c, model_hash="1" * 64), other)
    code, _, err = run(["export-release", other, tmp_path / "out"], capsys)
    assert code != 0 and len(err.strip().splitlines()) == 1 and "release" in err
    assert not (tmp_path / "out").exists()


def test_an_empty_name_is_refused_by_the_library_too(coded_file, tmp_path):
    """The command line's rule (``--name ""``) is the library's: an empty or blank name is a
    mistake, not the default (None takes the coded file's name)."""
    coded = load_coded(coded_file)
    release = load_bundled("release").content_hash
    for name in ("", "   "):
        with pytest.raises(BTFInputError, match="name must not be empty"):
            export_release(coded, tmp_path / "out", release, name=name)
    assert not (tmp_path / "out").exists()
