"""Semantic validation: well-formed files that say impossible things are refused at read, in
one line naming the file, the field, the index and expected vs found (issue 20). One test per
defect found by trying the tool; the fuzz over many such cases is tests/test_fuzz.py."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from sparsebtf._semantic import (
    ORTHONORMAL_TOLERANCE,
    ORTHONORMAL_TOLERANCE_FP16,
    STAT_BOUND,
    orthonormality_error,
)
from sparsebtf.cli.info import describe
from sparsebtf.cli.main import main
from sparsebtf.data.dense_file import DenseFileBTF, write_dense
from sparsebtf.errors import FileFormatError
from sparsebtf.fuzzing import _directions, build_corpus
from sparsebtf.learning.ensemble import DictionaryEnsemble, random_orthonormal
from sparsebtf.model import dictionaries_hash
from sparsebtf.storage import load_coded, load_coded_with_model, load_model, release

from .conftest import smooth_btf


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("valid")
    build_corpus(folder)
    return folder


def _copy(corpus: Path, name: str, tmp_path: Path) -> Path:
    dst = tmp_path / name
    shutil.copy(corpus / name, dst)
    return dst


def _set(path: Path, field: str, edit) -> None:
    """Overwrite dataset ``field`` of ``path`` with ``edit(values)`` (same shape and dtype)."""
    with h5py.File(path, "r+") as f:
        ds = f[field]
        ds[...] = edit(ds[()].copy())


def _one_line(excinfo: pytest.ExceptionInfo, *parts: str) -> str:
    text = str(excinfo.value)
    assert "\n" not in text
    for p in parts:
        assert p in text, text
    return text


# --------------------------------------------------------------------------- coded files


def test_coded_eps_out_of_range(corpus, tmp_path):
    p = _copy(corpus, "coded.h5", tmp_path)
    with h5py.File(p, "r+") as f:
        f["stats"].attrs["eps"] = float(2**62)  # decoded to -4.6e18 everywhere before
    with pytest.raises(FileFormatError) as e:
        load_coded(p)
    _one_line(e, str(p), "stats@eps", "4.6116", "expected 1e-12 <= eps <= 1000")


def test_coded_repeated_locations_within_a_point(corpus, tmp_path):
    p = _copy(corpus, "coded_v2.h5", tmp_path)  # schema 2: packed locations
    _set(p, "codes/Y/locations", lambda b: np.zeros_like(b))
    with pytest.raises(FileFormatError) as e:
        load_coded(p)
    _one_line(e, "codes/Y/locations", "point 0 repeats location (0, 0, 0, 0)",
              "coefficients 0 and 1", "expected distinct")  # fmt: skip


def test_coded_location_outside_the_data_point(corpus, tmp_path):
    p = _copy(corpus, "coded_v2.h5", tmp_path)  # schema 2: packed locations
    _set(p, "codes/U/locations", lambda b: np.full_like(b, 255))
    with pytest.raises(FileFormatError) as e:
        load_coded(p)
    _one_line(e, "codes/U", "outside the 24 entries of a data point")


def test_coded_counts_differ_from_values(corpus, tmp_path):
    p = _copy(corpus, "coded.h5", tmp_path)
    _set(p, "codes/V/counts", lambda c: c + np.array([1, 0, 0, 0], c.dtype))
    with pytest.raises(FileFormatError) as e:
        load_coded(p)
    _one_line(e, "codes/V", "counts sum to 13", "holds 12")


def test_coded_membership_beyond_k(corpus, tmp_path):
    # schema 2 (in schema 3 the dictionary's missing location table is found first: a
    # 'table_sizes' error, tests/test_schema3.py)
    p = _copy(corpus, "coded_v2.h5", tmp_path)
    _set(p, "codes/Y/membership", lambda m: np.array([0, 1, 2, 0], m.dtype))
    with pytest.raises(FileFormatError) as e:
        load_coded(p)
    _one_line(e, "codes/Y/membership", "point 2 uses dictionary 2", "K = 2")


def test_coded_values_out_of_order(corpus, tmp_path):
    # Truncating to τ reads a prefix: a point whose values are not by decreasing |v| would
    # silently keep the wrong coefficients.
    p = _copy(corpus, "coded_v2.h5", tmp_path)  # schema 2 keeps the stored order
    _set(p, "codes/U/values", lambda v: v[::-1].copy())
    with pytest.raises(FileFormatError) as e:
        load_coded(p)
    _one_line(e, "codes/U/values", "point 0", "expected decreasing magnitudes")


@pytest.mark.parametrize(
    ("value", "expected"),
    [(1e30, f"0 < std <= {STAT_BOUND:g}"), (0.0, "0 < std"), (-1.0, "0 < std"),
     (np.inf, "NaN/Inf")],
)  # fmt: skip
def test_coded_std_implausible(corpus, tmp_path, value, expected):
    p = _copy(corpus, "coded.h5", tmp_path)
    _set(p, "stats/std", lambda s: np.where(np.arange(s.size).reshape(s.shape) == 3, value, s))
    with pytest.raises(FileFormatError) as e:
        load_coded(p)
    _one_line(e, "stats/std", "index (1, 1, 0)", expected)


def test_coded_mean_implausible(corpus, tmp_path):
    p = _copy(corpus, "coded.h5", tmp_path)
    _set(p, "stats/mean", lambda s: s - 1e6)
    with pytest.raises(FileFormatError) as e:
        load_coded(p)
    _one_line(e, "stats/mean", "index (0, 0, 0)", f"-{STAT_BOUND:g} <= mean")


def test_coded_directions_must_be_the_models(corpus, tmp_path):
    # Codes index the model's directions: a permuted (but valid) table would pair every
    # decoded value with the wrong direction.
    p = _copy(corpus, "coded.h5", tmp_path)
    for key in ("xyz", "theta", "phi"):  # the whole table, its angles agreeing with xyz
        _set(p, f"lights/{key}", lambda x: x[::-1].copy())
    load_coded(p)  # a valid table on its own
    with pytest.raises(FileFormatError) as e:
        load_coded_with_model(p, corpus / "model.h5")
    _one_line(e, "lights/xyz", "row 0", "but the model's is", "same directions in the same order")
    with pytest.raises(FileFormatError) as e:  # info reads it with the same checks
        describe(str(p), model_path=str(corpus / "model.h5"))
    _one_line(e, "lights/xyz", "row 0", "but the model's is")


# --------------------------------------------------------------------------- direction tables


@pytest.mark.parametrize("name", ["coded.h5", "model.h5", "dense.h5"])
@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda x: x * 1e-8, "row 0 has length 1e-08"),  # gave 13 identical directions
        (lambda x: x * 1e30, "row 0 has length 1e+30"),  # gave "13×13 … covers 13×13"
        (lambda x: np.concatenate([x[:1], x[:1], x[2:]]), "rows 0 and 1 are the same direction"),
        (lambda x: x * np.array([1, 1, -1]), "row 0 points below the surface"),
    ],
)
def test_direction_tables_unit_distinct_upper(corpus, tmp_path, name, edit, message):
    p = _copy(corpus, name, tmp_path)
    _set(p, "views/xyz", edit)
    read = {"coded.h5": load_coded, "model.h5": load_model, "dense.h5": DenseFileBTF}[name]
    with pytest.raises(FileFormatError) as e:
        read(p)
    _one_line(e, str(p), "views/xyz", message)


# --------------------------------------------------------------------------- dictionaries


def _rehash(path: Path) -> None:
    """Recompute a model file's content hash (a well-formed file, not a corrupted one)."""
    with h5py.File(path, "r+") as f:
        dicts = {ch: [f[f"dictionaries/{ch}/mode{n}"][()].astype(np.float64) for n in range(1, 5)]
                 for ch in f["dictionaries"]}  # fmt: skip
        f.attrs["content_hash"] = np.bytes_(dictionaries_hash(dicts).encode())


def test_model_dictionaries_must_be_orthonormal(corpus, tmp_path):
    p = _copy(corpus, "model.h5", tmp_path)
    _set(p, "dictionaries/U/mode3", lambda u: u * np.array([1.0, 1.01])[:, None, None])
    _rehash(p)
    with pytest.raises(FileFormatError) as e:
        load_model(p)
    _one_line(e, "dictionaries/U/mode3", "dictionary 1 is not orthonormal",
              f"expected <= {ORTHONORMAL_TOLERANCE:g}")  # fmt: skip


def test_bundled_model_within_the_tolerance():
    from sparsebtf.storage.bundled import load_bundled

    m = load_bundled("release")
    worst = max(float(orthonormality_error(u).max()) for ch in m.channels
                for u in m.dictionaries[ch])  # fmt: skip
    assert 0 < worst < ORTHONORMAL_TOLERANCE / 100  # float32 rounding: 8e-8


def _release_bin(path: Path, rng: np.random.Generator) -> tuple[int, tuple[int, ...]]:
    """An fp16 DictEnsOrth4D .bin file at the release's layout (K = 8, small modes)."""
    k, sizes = 8, (10, 10, 20, 20)
    mats = [np.stack([random_orthonormal(m, rng) for _ in range(k)]) for m in sizes]
    words = np.concatenate([np.ascontiguousarray(u.transpose(0, 2, 1)).ravel() for u in mats])
    path.write_bytes(words.astype("<f2").tobytes())
    return k, sizes


def test_release_dictionaries_with_overwritten_words(tmp_path):
    rng = np.random.default_rng(3)
    p = tmp_path / "DictEnsOrth4DY.bin"
    k, sizes = _release_bin(p, rng)
    mats, _ = release.read_dictionaries(p, k, sizes)  # binary16 rounding is within tolerance
    assert max(float(orthonormality_error(u).max()) for u in mats) < ORTHONORMAL_TOLERANCE_FP16
    words = np.fromfile(p, "<f2")
    hit = rng.choice(words.size, 100, replace=False)
    words[hit] = rng.uniform(-0.3, 0.3, 100).astype("<f2")  # 100 words overwritten
    words.tofile(p)
    with pytest.raises(FileFormatError) as e:
        release.read_dictionaries(p, k, sizes)
    _one_line(e, str(p), "is not orthonormal", f"expected <= {ORTHONORMAL_TOLERANCE_FP16:g}")


def test_release_statistics_and_repeated_locations(corpus, tmp_path):
    src = corpus / "release"
    ms = tmp_path / "fuzz_mean_std.bin"
    a = np.fromfile(src / "fuzz_mean_std.bin", "<f8")
    a[a.size // 2 + 1] = 1e30  # a standard deviation
    a.tofile(ms)
    with pytest.raises(FileFormatError) as e:
        release.read_mean_std(ms, 3, 2)
    _one_line(e, str(ms), "std", "1e+30")
    co = tmp_path / "Coeffs_BTF_fuzz_1e-05_V.bin"
    raw = np.fromfile(src / co.name, "<u2")
    raw[4 + 4 : 4 + 8] = raw[4:8]  # point 0's second location = its first
    raw.tofile(co)
    with pytest.raises(FileFormatError) as e:
        release.read_coefficients(co, n_points=4, n_dictionaries=2)
    _one_line(e, str(co), "point 0 repeats location")


# --------------------------------------------------------------------------- UBO2014 header


@pytest.mark.parametrize("field", ["color_mean", "color_transform"])
@pytest.mark.parametrize("value", [np.nan, np.inf, 1e30])
def test_ubo2014_colour_header(tmp_path, field, value):
    from sparsebtf.formats.ubo2014 import read_ubo2014
    from sparsebtf.formats.ubo2014_write import write_ubo2014

    rng = np.random.default_rng(0)
    lights, views = _directions()
    n = len(lights) * len(views)
    args = {"color_mean": np.zeros(3), "color_transform": np.eye(3)}
    args[field] = np.array(args[field], dtype=np.float64)
    args[field].flat[1] = value
    p = tmp_path / "pca.btf"
    write_ubo2014(p, [rng.normal(size=(6, 1)) for _ in range(3)],
                  [rng.normal(size=(n, 1)) for _ in range(3)], 2, 3, lights, views, "DFMF",
                  "float", color_model=3, drr=False, **args)  # fmt: skip
    with pytest.raises(FileFormatError) as e:
        read_ubo2014(p)
    name = "ColorMean" if field == "color_mean" else "ColorTransform"
    _one_line(e, str(p), f"header field '{name}'", "entry 1", "expected a finite number")


# --------------------------------------------------------------------------- checkpoints


@pytest.fixture
def checkpoint(tmp_path):
    rng = np.random.default_rng(1)
    x = rng.normal(size=(12, 2, 2, 3, 2))
    kw = dict(n_dictionaries=2, tau=3, max_iter=1, init="random", dtype="float64",
              progress=False)  # fmt: skip
    ck = tmp_path / "ck.npz"
    DictionaryEnsemble(checkpoint=ck, **kw).fit(x)
    return ck, x, kw


@pytest.mark.parametrize("damage", ["truncate", "flip"])
def test_damaged_checkpoint_is_one_line(checkpoint, damage):
    ck, x, kw = checkpoint
    data = bytearray(ck.read_bytes())
    if damage == "truncate":
        del data[len(data) // 2 :]  # raised zipfile.BadZipFile before
    else:
        data[len(data) // 3] ^= 0x10
    ck.write_bytes(bytes(data))
    with pytest.raises(FileFormatError) as e:
        DictionaryEnsemble(checkpoint=ck, **{**kw, "max_iter": 2}).fit(x)
    _one_line(e, str(ck), "delete it to start over")


def test_checkpoint_hash_and_contents(checkpoint):
    from sparsebtf.checkpoints import checkpoint_digest

    ck, x, kw = checkpoint
    with np.load(ck) as f:
        arrays = {k: f[k] for k in f.files if k != "sha256"}
        stored = str(f["sha256"])
    assert stored == checkpoint_digest(arrays)
    # Edited without the hash: damaged.
    arrays["objective"] = arrays["objective"] * 2
    np.savez(ck, sha256=np.asarray(stored), **arrays)
    with pytest.raises(FileFormatError, match="is damaged: its arrays hash to"):
        DictionaryEnsemble(checkpoint=ck, **kw).fit(x)
    # Edited with a fresh hash, but impossible: refused by the content checks.
    arrays["mode1"] = arrays["mode1"] * 3
    np.savez(ck, sha256=np.asarray(checkpoint_digest(arrays)), **arrays)
    with pytest.raises(FileFormatError) as e:
        DictionaryEnsemble(checkpoint=ck, **kw).fit(x)
    _one_line(e, "mode2", "dictionary 0 is not orthonormal")


def test_train_resume_on_truncated_checkpoint(tmp_path, capsys):
    src = tmp_path / "m.h5"
    write_dense(src, smooth_btf(0))
    ck = tmp_path / "ck"
    opts = ["--patch", "4", "--dicts", "2", "--tau-train", "16,4,4", "--sample", "1",
            "--checkpoint-dir", str(ck)]  # fmt: skip
    assert main(["train", str(src), "-o", str(tmp_path / "a.h5"), *opts, "--iters", "1"]) == 0
    npz = ck / "train_Y.npz"
    npz.write_bytes(npz.read_bytes()[:-100])
    capsys.readouterr()
    code = main(["train", str(src), "-o", str(tmp_path / "b.h5"), *opts, "--iters", "2",
                 "--resume"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith(f"sparsebtf: error: checkpoint {npz} is damaged")
    assert "Traceback" not in err and not (tmp_path / "b.h5").exists()


# --------------------------------------------------------------------------- non-finite results


def test_eval_and_lookup_refuse_nonfinite_results(corpus, tmp_path, capsys):
    # Valid statistics and values, but values near binary16's maximum with σ at its bound
    # decode past the float range: eval printed MSE inf / PSNR -inf / SSIM nan and lookup
    # Infinity, both with exit 0. (Schema 2: its values are a float16 dataset to edit.)
    p = _copy(corpus, "coded_v2.h5", tmp_path)
    _set(p, "codes/Y/values", lambda v: np.sign(v) * np.float16(60000))
    _set(p, "stats/std", lambda s: np.full_like(s, STAT_BOUND))
    model = str(corpus / "model.h5")
    capsys.readouterr()
    # With the bound kept with the statistics every value stays finite (at most the
    # brightest of its angular image): the same file decodes, exit 0.
    assert main(["eval", str(p), "--reference", str(corpus / "dense.h5"), "-m", model,
                 "--ssim-images", "1", "--json"]) == 0  # fmt: skip
    assert json.loads(capsys.readouterr().out)["max_decoded"] < 1e3
    with h5py.File(p, "r+") as f:  # a file written before bounds existed
        del f["stats/bound"]
    code = main(["eval", str(p), "--reference", str(corpus / "dense.h5"), "-m", model])
    # (NumPy's overflow warnings before the line are another issue's: issue 20, item 4.)
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2 and err.startswith("sparsebtf: error: eval: the result mse_rgb is inf")
    assert "--allow-nonfinite" in err
    look = ["lookup", str(p), "--texel", "0,0", "--light", "0", "--view", "0", "-m", model]
    assert main([*look, "--allow-nonfinite", "--json"]) == 0
    if json.loads(capsys.readouterr().out)["log"]["Y"] < 0:  # exp(-huge) = 0 is finite:
        _set(p, "codes/Y/values", lambda v: -v)  # the other sign overflows
    code = main(look)
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2 and err.startswith("sparsebtf: error: lookup: the result rgb[0] is inf")
    code = main([*look, "--allow-nonfinite", "--json"])
    assert code == 0 and "Infinity" in capsys.readouterr().out
    # The unmutated file: finite results, exit 0.
    code = main(["lookup", str(corpus / "coded.h5"), "--texel", "0,0", "--light", "0",
                 "--view", "0", "-m", model])  # fmt: skip
    assert code == 0


def test_check_finite_result_names_the_field():
    from sparsebtf.cli._output import check_finite_result
    from sparsebtf.errors import SparseBTFError

    check_finite_result({"a": 1.0, "b": [1, 2.0], "c": "inf", "d": None}, "x")
    with pytest.raises(SparseBTFError, match=r"^x: the result a\.b\[1\] is nan \(2 non-finite"):
        check_finite_result({"a": {"b": [1.0, float("nan")]}, "c": np.array([np.inf])}, "x")
    check_finite_result({"a": float("nan")}, "x", allow=True)
    # The PSNR of identical images is +inf exactly; NaN never is.
    check_finite_result({"psnr_rgb": float("inf")}, "eval", exact=("psnr_rgb",))
    with pytest.raises(SparseBTFError, match="psnr_rgb is nan"):
        check_finite_result({"psnr_rgb": float("nan")}, "eval", exact=("psnr_rgb",))


def test_writers_refuse_what_readers_refuse(tmp_path):
    from sparsebtf.errors import BTFInputError
    from sparsebtf.fuzzing import _coded, _model
    from sparsebtf.storage import save_coded, save_model

    model = _model()
    model.dictionaries["Y"][0] = model.dictionaries["Y"][0] * 1.5
    with pytest.raises(BTFInputError, match="model channel Y/mode1: dictionary 0 is not orth"):
        save_model(model, tmp_path / "m.h5")
    coded = _coded(_model())
    coded.codes["U"].locations[1] = coded.codes["U"].locations[0]
    with pytest.raises(BTFInputError, match="codes/U/locations: point 0 repeats location"):
        save_coded(coded, tmp_path / "c.h5")
    assert not list(tmp_path.iterdir())  # nothing written


def test_encode_with_a_model_of_huge_directions(corpus, tmp_path, capsys):
    # Said "has 13×13 (tiny13) … model covers 13×13 (tiny13) only" before.
    m = _copy(corpus, "model.h5", tmp_path)
    _set(m, "views/xyz", lambda x: x * 1e30)
    code = main(["encode", str(corpus / "dense.h5"), "-m", str(m), "-o", str(tmp_path / "c.h5")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert f"{m}/views/xyz: row 0 has length 1e+30; expected a unit vector" in err
