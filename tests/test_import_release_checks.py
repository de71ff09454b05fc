"""``import-release`` refuses incomplete or implausible input in one line, before writing
anything (issue 47): statistics a coded file cannot store, a missing channel or statistics
file, a ``--size`` that does not fit the coefficient files. The CLI and
:func:`~sparsebtf.storage.release.import_release` share one rule.

The folders are synthetic: the release's layout (10×10 patches, 151 UBO2014 directions,
K = 8) with identity dictionaries, so the tests need none of the authors' files."""

import re
from pathlib import Path

import numpy as np
import pytest

from sparsebtf.cli.main import main
from sparsebtf.errors import FileFormatError
from sparsebtf.storage.release import import_release, read_coefficients, read_mean_std

L = 151
MODES = (10, 10, L, L)


def _coefficients(n_points: int, per_point: int = 2, seed: int = 0) -> bytes:
    """One channel's words: ``per_point`` non-zeros per point, memberships 0…7."""
    rng = np.random.default_rng(seed)
    n = n_points * per_point
    lnz = np.stack([rng.integers(0, m, n) for m in MODES], axis=1)
    member = rng.integers(0, 8, n_points)
    counts = np.full(n_points, per_point)
    values = rng.uniform(-1, 1, n)
    return np.concatenate([
        np.asarray(MODES, "<i2").view("<u2"), lnz.astype("<u2").ravel(),
        member.astype("<i2").view("<u2"), counts.astype("<i2").view("<u2"),
        values.astype("<f2").view("<u2"),
    ]).astype("<u2").tobytes()  # fmt: skip


def _mean_std(std: float = 0.5) -> np.ndarray:
    return np.concatenate([np.full(L * L, -1.0), np.full(L * L, std)])


def release_folder(d: Path, n_points: int = 2, channels: str = "YUV", stats: bool = True,
                   dictionaries: bool = True) -> Path:  # fmt: skip
    """A release folder of one material ``mat`` with ``n_points`` points (20x10 texels)."""
    d.mkdir(parents=True, exist_ok=True)
    if dictionaries:
        eye = np.concatenate([np.tile(np.eye(m).ravel(), 8) for m in MODES]).astype("<f2")
        for ch in "YUV":
            (d / f"DictEnsOrth4D{ch}.bin").write_bytes(eye.tobytes())
    for i, ch in enumerate(channels):
        (d / f"Coeffs_BTF_mat_1e-05_{ch}.bin").write_bytes(_coefficients(n_points, seed=i))
    if stats:
        (d / "mat_mean_std.bin").write_bytes(_mean_std().astype("<f8").tobytes())
    return d


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def _import(folder: Path, out: Path, capsys, size: str = "20x10"):
    """``import-release folder -o out/m.h5 --size …``: (exit code, stderr, files in out/)."""
    out.mkdir(exist_ok=True)
    code, _, err = run(["import-release", folder, "-o", out / "m.h5", "--size", size], capsys)
    return code, err, sorted(p.name for p in out.iterdir())


def _one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("sparsebtf: error: "), err
    return lines[0]


def test_a_complete_folder_imports(tmp_path, capsys):
    """The synthetic folder is valid: the refusals below are each one change away from it."""
    code, err, names = _import(release_folder(tmp_path / "rel"), tmp_path / "out", capsys)
    assert code == 0, err
    assert names == ["m.h5", "mat.coded.h5"]
    # the chroma-only release (the authors published no Y coefficients) still imports
    code, err, names = _import(release_folder(tmp_path / "uv", channels="UV"),
                               tmp_path / "out_uv", capsys)  # fmt: skip
    assert code == 0, err
    assert names == ["m.h5", "mat.coded.h5"]


def test_a_write_failing_part_way_leaves_no_file_of_the_run(tmp_path, capsys, monkeypatch):
    """The model file is written first; when a coded file cannot be written after it (a full
    disk), the model file goes too: no half-written set of outputs."""
    import sparsebtf.storage as storage
    from sparsebtf.errors import OutputError

    def full_disk(_coded, path, *_args, **_kw):  # what save_coded raises on a full disk
        raise OutputError(f"no space left on device while writing {path}; nothing was written")

    monkeypatch.setattr(storage, "save_coded", full_disk)
    code, err, names = _import(release_folder(tmp_path / "rel"), tmp_path / "out", capsys)
    assert code == 2 and "no space left on device" in _one_error_line(err)
    assert names == []  # the model file written before it is gone too


def test_a_system_error_is_one_line_not_a_traceback(tmp_path, capsys, monkeypatch):
    """An OSError no check anticipated (a lost mount mid-write) ends the command in one line
    that names it, exit 2."""
    import sparsebtf.storage as storage

    def lost(*_args, **_kw):
        raise OSError(5, "Input/output error", str(tmp_path / "out" / "mat.coded.h5"))

    monkeypatch.setattr(storage, "save_coded", lost)
    code, err, names = _import(release_folder(tmp_path / "rel"), tmp_path / "out", capsys)
    assert code == 2 and "Input/output error" in _one_error_line(err) and "mat.coded.h5" in err
    assert names == []


@pytest.mark.parametrize("std", [5e-324, 1e-40, 0.0, 41.0])
def test_std_that_the_coded_file_cannot_store_is_refused(tmp_path, capsys, std):
    """σ = 5e-324 passes σ > 0 in float64 but is stored (float32) as 0.0, which decode refuses;
    1e-40 would be stored as a float32 subnormal, not within float32 rounding."""
    d = release_folder(tmp_path / "rel")
    ms = _mean_std()
    ms[L * L + 7] = std
    (d / "mat_mean_std.bin").write_bytes(ms.astype("<f8").tobytes())
    code, err, names = _import(d, tmp_path / "out", capsys)
    assert code == 2 and names == []
    line = _one_error_line(err)
    assert "mat_mean_std.bin/std" in line and f"{std!r}" in line
    with pytest.raises(FileFormatError, match="std"):
        import_release(d, height=20, width=10)
    with pytest.raises(FileFormatError, match="std"):
        read_mean_std(d / "mat_mean_std.bin")


@pytest.mark.parametrize("missing", ["U", "V"])
def test_missing_channel_coefficients_are_refused(tmp_path, capsys, missing):
    d = release_folder(tmp_path / "rel", channels="YUV".replace(missing, ""))
    code, err, names = _import(d, tmp_path / "out", capsys)
    assert code == 2 and names == []
    line = _one_error_line(err)
    assert f"Coeffs_BTF_mat_1e-05_{missing}.bin" in line and "missing" in line
    with pytest.raises(FileFormatError, match=re.escape(f"Coeffs_BTF_mat_1e-05_{missing}.bin")):
        import_release(d, height=20, width=10)


def test_coefficients_without_their_dictionaries_are_refused(tmp_path, capsys):
    d = release_folder(tmp_path / "rel")
    (d / "DictEnsOrth4DV.bin").unlink()
    code, err, names = _import(d, tmp_path / "out", capsys)
    assert code == 2 and names == []
    line = _one_error_line(err)
    assert "Coeffs_BTF_mat_1e-05_V.bin" in line and "DictEnsOrth4DV" in line


def test_missing_statistics_file_is_refused(tmp_path, capsys):
    d = release_folder(tmp_path / "rel", stats=False)
    code, err, names = _import(d, tmp_path / "out", capsys)
    assert code == 2 and names == []
    line = _one_error_line(err)
    assert "mat_mean_std.bin" in line and "missing" in line
    with pytest.raises(FileFormatError, match=re.escape("mat_mean_std.bin")):
        import_release(d, height=20, width=10)


@pytest.mark.parametrize("size", ["10x10", "20x20", "210x10", "400x400"])
def test_size_that_does_not_fit_names_the_size(tmp_path, capsys, size):
    """6 points (60x10 texels) on file: another --size is named, with the point count that
    fits, never as a negative count (at 210x10, 21 points, the reader took values for NNZ and
    said "NNZ[19] = -19684 is negative")."""
    d = release_folder(tmp_path / "rel", n_points=6)
    code, err, names = _import(d, tmp_path / "out", capsys, size=size)
    assert code == 2 and names == []
    line = _one_error_line(err)
    h, w = size.split("x")
    assert f"{h}x{w}" in line and "6 points" in line and "30x20" in line, line
    assert not re.search(r"(^|[\s=(])-\d", line), line
    with pytest.raises(FileFormatError, match=f"{h}x{w}.*6 points"):
        import_release(d, height=int(h), width=int(w))
    with pytest.raises(FileFormatError, match="6 points"):
        read_coefficients(d / "Coeffs_BTF_mat_1e-05_U.bin", n_points=int(h) * int(w) // 100)


def test_size_fits_and_a_damaged_file_keeps_its_message(tmp_path, capsys):
    d = release_folder(tmp_path / "rel", n_points=40)
    code, err, _ = _import(d, tmp_path / "out", capsys, size="400x10")
    assert code == 0, err
    assert import_release(d, height=80, width=50)[1]["mat"].n_points == 40
    f = d / "Coeffs_BTF_mat_1e-05_U.bin"
    f.write_bytes(f.read_bytes()[:-4])  # no point count fits the truncated file
    with pytest.raises(FileFormatError, match="do not fit 4 "):
        read_coefficients(f, n_points=40)


def test_coefficients_without_model_or_output_write_nothing_and_say_so(tmp_path, capsys):
    """A folder with statistics but no coefficient files, coded against -m release and no -o:
    nothing to write, so an error rather than a silent exit 0."""
    d = release_folder(tmp_path / "rel", channels="", dictionaries=False)
    out = tmp_path / "out"
    out.mkdir()
    code, _, err = run(["import-release", d, "-m", "release", "--coded-dir", out, "--size",
                        "20x10"], capsys)  # fmt: skip
    assert code == 2 and list(out.iterdir()) == []
    line = _one_error_line(err)
    assert "Coeffs_BTF_" in line


def test_api_refuses_the_same_with_a_model(tmp_path):
    """A folder without dictionaries (as export-release writes) read against a model: the same
    refusals, from the same code."""
    from sparsebtf.storage.bundled import load_bundled

    model = load_bundled("release")
    d = release_folder(tmp_path / "rel", channels="YV", dictionaries=False)
    with pytest.raises(FileFormatError, match=re.escape("Coeffs_BTF_mat_1e-05_U.bin: missing")):
        import_release(d, model=model, height=20, width=10)
    d = release_folder(tmp_path / "rel2", stats=False, dictionaries=False)
    with pytest.raises(FileFormatError, match=re.escape("mat_mean_std.bin: missing")):
        import_release(d, model=model, height=20, width=10)


def test_ambiguous_coefficient_files_are_refused(tmp_path, capsys):
    d = release_folder(tmp_path / "rel")
    (d / "Coeffs_BTF_mat_0.001_U.bin").write_bytes((d / "Coeffs_BTF_mat_1e-05_U.bin").read_bytes())
    code, err, names = _import(d, tmp_path / "out", capsys)
    assert code == 2 and names == []
    assert "two U coefficient files for mat" in _one_error_line(err)
    d = release_folder(tmp_path / "rel2")
    (d / "Coeffs_BTF_mat_1e-05_V.bin").rename(d / "Coeffs_BTF_mat_0.001_V.bin")
    with pytest.raises(FileFormatError, match="different ε"):
        import_release(d, height=20, width=10)


@pytest.mark.parametrize("hw", [(25, 10), (0, 10), (20, -10)])
def test_api_size_must_be_whole_patches(tmp_path, hw):
    """The CLI's --size rule, in the API (25x10 was read as 2 points)."""
    from sparsebtf.errors import BTFInputError

    d = release_folder(tmp_path / "rel")
    with pytest.raises(BTFInputError, match=f"size {hw[0]}x{hw[1]}"):
        import_release(d, height=hw[0], width=hw[1])
