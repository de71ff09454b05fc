"""The public API, ``import sparsebtf as sb``: every name resolves lazily, ``encode``'s one
``target`` (τ, size, ratio; one or many BTFs) dispatches to the codec's encoders, ``save_btf``
writes by extension and reads back, ``load_model`` takes a name or a file, and the README's
Python example runs as written."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

import sparsebtf as sb
from sparsebtf.errors import BTFInputError, FileFormatError, SparseBTFError

from .conftest import readme_python_api_blocks, smooth_btf, tiny_model

ROOT = Path(__file__).resolve().parents[1]
SRC = Path(sb.__file__).resolve().parents[1]
NAMES = ("open_btf", "save_btf", "load_model", "train", "encode", "decode", "RuntimeBTF",
         "blend", "capture")  # fmt: skip


@pytest.fixture(scope="module")
def model():
    return tiny_model()


@pytest.fixture(scope="module")
def btf():
    return smooth_btf(5)


def _same_codes(a, b) -> None:
    assert a.channels == b.channels
    for ch in a.channels:
        ca, cb = a.codes[ch], b.codes[ch]
        np.testing.assert_array_equal(ca.membership, cb.membership)
        np.testing.assert_array_equal(ca.counts, cb.counts)
        np.testing.assert_array_equal(ca.values, cb.values)
        np.testing.assert_array_equal(ca.locations, cb.locations)


def _one_line(e: pytest.ExceptionInfo) -> str:
    text = str(e.value)
    assert "\n" not in text and text
    return text


# -- the names -----------------------------------------------------------------------------


def test_all_names_resolve_documented():
    assert set(NAMES) <= set(sb.__all__)
    for name in sb.__all__:
        obj = getattr(sb, name)
        assert callable(obj), name
        assert obj.__doc__ and obj.__doc__.strip(), f"{name} has no docstring"
        assert obj is getattr(sb, name)  # resolved once, then a plain attribute
    from sparsebtf.codec.train import train
    from sparsebtf.data.capture import capture
    from sparsebtf.open import open_btf
    from sparsebtf.runtime import RuntimeBTF, blend

    assert (sb.train, sb.capture, sb.open_btf, sb.RuntimeBTF, sb.blend) == (
        train, capture, open_btf, RuntimeBTF, blend)  # fmt: skip
    from sparsebtf import decode, encode  # from-imports resolve too

    assert (encode, decode) == (sb.encode, sb.decode)
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        sb.nope  # noqa: B018


def test_dir_lists_the_api_not_the_plumbing():
    names = dir(sb)
    assert set(sb.__all__) <= set(names)
    assert not {"TYPE_CHECKING", "Any", "importlib", "_LAZY"} & set(names)
    assert names == sorted(names)


def test_import_loads_no_torch_mitsuba_or_dask():
    heavy = ("torch", "mitsuba", "drjit", "dask", "distributed", "numba", "h5py")
    code = ("import sys, sparsebtf; "
            f"print(','.join(m for m in {heavy!r} if m in sys.modules))")  # fmt: skip
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(SRC)})  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == ""


# -- encode's target -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("target", "parsed"),
    [
        (None, ("tau", (885, 64, 64))),
        ((300, 40, 40), ("tau", (300, 40, 40))),
        ({"Y": 300, "U": 40, "V": 40}, ("tau", {"Y": 300, "U": 40, "V": 40})),
        ("885,64,64", ("tau", "885,64,64")),
        ("0.25", ("tau", "0.25")),
        ("1.2MB", ("bytes", 1_200_000)),
        ("300KiB", ("bytes", 300 * 1024)),
        ("250000B", ("bytes", 250_000)),
        (" 2 gb ", ("bytes", 2 * 10**9)),
        ("50x", ("ratio", 50.0)),
        ("12.5X", ("ratio", 12.5)),
    ],
)
def test_target_spellings(target, parsed):
    from sparsebtf.api import parse_target

    assert parse_target(target) == parsed


@pytest.mark.parametrize("bad", [64, 1.5, np.int64(64), True, "50y", "abc", "-3x", "0B", "0x",
                                 object()])  # fmt: skip
def test_bad_target_is_one_line(model, btf, bad):
    with pytest.raises(BTFInputError) as e:
        sb.encode(btf, model, target=bad)
    assert "target" in _one_line(e)


def test_bare_number_names_the_spellings(model, btf):
    with pytest.raises(BTFInputError, match=r"ambiguous.*'64B'.*'64x'"):
        sb.encode(btf, model, target=64)


def test_target_tau_is_codec_encode(model, btf):
    from sparsebtf.codec import encode

    coded = sb.encode(btf, model, target=(16, 4, 4), eps=1e-4)
    _same_codes(coded, encode(btf, model, tau=(16, 4, 4), eps=1e-4))
    assert coded.coded_tau == {"Y": 16, "U": 4, "V": 4}


def test_target_size_and_ratio_are_the_coded_file(model, btf):
    from sparsebtf.codec import encode_to_size
    from sparsebtf.learning.cost import raw_bytes
    from sparsebtf.storage.coded_file import coded_image

    by_size = sb.encode(btf, model, target="30000B")
    _same_codes(by_size, encode_to_size(btf, model, target_bytes=30000, budget="stored",
                                        per_material=True))  # fmt: skip
    assert 0.99 * 30000 <= len(coded_image(by_size)) <= 30000
    by_ratio = sb.encode(btf, model, target="2x")
    _same_codes(by_ratio, encode_to_size(btf, model, target_ratio=2, budget="stored",
                                         per_material=True))  # fmt: skip
    assert len(coded_image(by_ratio)) <= raw_bytes(btf.n_values) / 2
    # the Table 4 budget is an option away
    paper = sb.encode(btf, model, target="2x", budget="paper")
    _same_codes(paper, encode_to_size(btf, model, target_ratio=2, per_material=True))


def test_many_btfs_yield_one_coded_each(model):
    btfs = [smooth_btf(6), smooth_btf(7)]
    out = sb.encode(btfs, model, target=(16, 4, 4))
    assert isinstance(out, Iterator)
    coded = list(out)
    assert [c.name for c in coded] == [b.name for b in btfs]
    for c, b in zip(coded, btfs, strict=True):
        _same_codes(c, sb.encode(b, model, target=(16, 4, 4)))
    sized = list(sb.encode((b for b in btfs), model, target="30000B"))  # any iterable
    for c, b in zip(sized, btfs, strict=True):
        _same_codes(c, sb.encode(b, model, target="30000B"))


def test_many_btfs_refuse_a_bad_tau_at_once(model):
    # the many-BTF encode is an iterator; its τ is still checked before it is returned
    with pytest.raises(BTFInputError):
        sb.encode([smooth_btf(6)], model, target="0,0,0")


def test_options_the_encoder_does_not_take(model, btf):
    with pytest.raises(BTFInputError, match="'eps' does not apply to a ratio target") as e:
        sb.encode(btf, model, target="2x", eps=1e-3)
    _one_line(e)
    with pytest.raises(BTFInputError, match=r"target=\.\.\., not tau="):
        sb.encode(btf, model, tau=(16, 4, 4))
    with pytest.raises(BTFInputError, match="'crop' does not apply"):
        sb.encode(btf, model, target=(16, 4, 4), crop=(slice(0, 4), slice(0, 4)))


def test_encode_a_path_and_a_model_file(model, btf, tmp_path):
    from sparsebtf.storage import save_model

    sb.save_btf(btf, tmp_path / "b.h5")
    save_model(model, tmp_path / "m.h5")
    coded = sb.encode(str(tmp_path / "b.h5"), tmp_path / "m.h5", target="16,4,4")
    _same_codes(coded, sb.encode(btf, model, target=(16, 4, 4)))


# -- save_btf, decode ----------------------------------------------------------------------


@pytest.mark.parametrize("name", ["b.h5", "b.HDF5", "b.btf"])
def test_save_btf_round_trips_by_extension(btf, tmp_path, name):
    path = sb.save_btf(btf, tmp_path / name)
    assert Path(path) == tmp_path / name
    back = sb.open_btf(path)
    np.testing.assert_array_equal(back.to_array(), btf.to_array())


def test_save_btf_float16(btf, tmp_path):
    sb.save_btf(btf, tmp_path / "b.h5", dtype="float16")
    back = sb.open_btf(tmp_path / "b.h5").to_array()
    np.testing.assert_array_equal(back, btf.to_array().astype(np.float16).astype(np.float32))


def test_save_coded_and_decode(model, btf, tmp_path):
    from sparsebtf.runtime import coded_btf_view

    coded = sb.encode(btf, model, target=(16, 4, 4))
    path = sb.save_btf(coded, tmp_path / "b.coded.h5")
    want = coded_btf_view(coded).to_array()
    np.testing.assert_array_equal(sb.decode(coded).to_array(), want)
    # from the file, with the model given (a Model or its file), through open_btf too
    from sparsebtf.storage import save_model

    save_model(model, tmp_path / "m.h5")
    for m in (model, tmp_path / "m.h5"):
        np.testing.assert_allclose(sb.decode(path, m).to_array(), want, rtol=2e-3, atol=1e-6)
    decoded = sb.open_btf(path, tmp_path / "m.h5").to_array()
    np.testing.assert_array_equal(decoded, sb.decode(path, model).to_array())
    # a decoded BTF is a BTF: written dense and read back
    sb.save_btf(sb.decode(coded), tmp_path / "d.h5")
    np.testing.assert_array_equal(sb.open_btf(tmp_path / "d.h5").to_array(), want)


def test_save_btf_refusals_leave_no_file(model, btf, tmp_path):
    coded = sb.encode(btf, model, target=(16, 4, 4))
    cases = [(btf, "b.png", r"cannot write a BTF as \.png; give \.h5"),
             (btf, "b", "without an extension"),
             (coded, "b.btf", r"decode it first"),
             (coded, "b.zip", r"cannot write a coded BTF as \.zip"),
             (model, "m.h5", "not a Model"),
             (btf, "b.h5", "dtype must be")]  # fmt: skip
    for obj, name, why in cases:
        with pytest.raises(BTFInputError, match=why) as e:
            sb.save_btf(obj, tmp_path / name, **({"dtype": "int8"} if "dtype" in why else {}))
        _one_line(e)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(SparseBTFError, match="decode: coded must be a coded BTF"):
        sb.decode(object())  # type: ignore[arg-type]
    with pytest.raises(BTFInputError, match="encode: btf_or_btfs must be a BTF, a path"):
        sb.encode(3.5, model)  # type: ignore[call-overload]


# -- load_model ------------------------------------------------------------------------------


def test_load_model_by_name_and_path(model, tmp_path):
    from sparsebtf.storage import save_model

    release = sb.load_model("release")
    assert release.channels == ("Y", "U", "V")
    assert {ch: release.n_dictionaries(ch) for ch in release.channels} == {"Y": 8, "U": 8,
                                                                           "V": 8}
    assert sb.load_model().content_hash == release.content_hash
    save_model(model, tmp_path / "m.h5")
    assert sb.load_model(tmp_path / "m.h5").content_hash == model.content_hash
    assert sb.load_model(str(tmp_path / "m.h5")).content_hash == model.content_hash
    with pytest.raises(FileFormatError, match="no bundled model of that name") as e:
        sb.load_model(tmp_path / "missing.h5")
    _one_line(e)


# -- the README ------------------------------------------------------------------------------


def test_readme_block_uses_the_one_import():
    block = readme_python_api_blocks()[0]
    imports = [ln for ln in block.splitlines() if re.match(r"\s*(import|from) ", ln)]
    assert imports == ["import sparsebtf as sb"]


@pytest.mark.slow
def test_readme_python_api_block_runs(readme_python_run):
    """The block runs as written (the session's one run of the README's Python blocks, this
    one first: conftest.readme_python_run)."""
    cwd, r = readme_python_run
    assert r.returncode == 0, r.stderr[-4000:]
    # "50x": the coded file is raw fp16 bytes / 50, as `ls -l` shows it
    raw = 20 * 20 * 151 * 151 * 3 * 2
    size = (cwd / "stone.coded.h5").stat().st_size
    assert size <= raw / 50 and raw / size == pytest.approx(50, rel=0.01)
    assert len(r.stdout.splitlines()) == 2 + 3  # nnz, error, one line per material
