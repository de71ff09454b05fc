"""The format registry: every format with a writer round-trips, and the one table drives
``open_btf``, the command line's output checks, ``write_btf`` and the fuzz harness."""

import numpy as np
import pytest

from sparsebtf.cli._args import OUTPUT_FORMATS, output_format
from sparsebtf.cli.main import main
from sparsebtf.errors import SparseBTFError
from sparsebtf.formats import registry
from sparsebtf.formats.registry import FORMATS, Format, registered, writer_for
from sparsebtf.fuzzing import READERS
from sparsebtf.open import open_btf

SOURCE = "synth:felt:8:0:tiny13"


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.parametrize("fmt", [f for f in FORMATS if f.writer is not None], ids=lambda f: f.kind)
@pytest.mark.parametrize("dtype", ["float32", "float16"])
def test_every_writer_round_trips(fmt, dtype, tmp_path):
    ref = open_btf(SOURCE)
    path = tmp_path / f"x{fmt.extensions[0]}"
    assert writer_for(path) is fmt
    fmt.writer(str(path), ref, dtype)
    back = open_btf(path)
    want = ref.to_array()
    if dtype == "float16":  # both writers store binary16 then: the values rounded once
        want = want.astype(np.float16).astype(np.float32)
    assert np.array_equal(back.to_array(), want)
    assert back.lights.equals(ref.lights) and back.views.equals(ref.views)
    if fmt.nbytes is not None:  # the size announced is the file's, within 1% and a header
        size = path.stat().st_size
        assert abs(fmt.nbytes(ref, dtype) - size) <= 0.01 * size + 8192


def test_writer_for_refuses_extensions_without_a_writer():
    with pytest.raises(SparseBTFError, match=r"unknown extension '\.zip'; give \.h5"):
        writer_for("x.zip")


def test_output_formats_come_from_the_registry():
    assert OUTPUT_FORMATS is registry.OUTPUT_FORMATS
    table, names = OUTPUT_FORMATS["btf"]
    assert table == {".h5": "dense", ".hdf5": "dense", ".btf": "ubo2014"}
    assert names == ".h5 (our dense file) or .btf (a UBO2014 file)"
    assert READERS == registry.fuzz_readers()
    assert set(READERS) == {"ubo2014", "ubo2003", "dense", "model", "coded", "release"}


def _write_as_dense(path, btf, dtype="float32", **options):
    from sparsebtf.data.dense_file import write_dense

    write_dense(path, btf, dtype=dtype)


def _read_as_dense(path, model_path=None):
    from sparsebtf.data.dense_file import DenseFileBTF

    return DenseFileBTF(path)


def test_a_registered_format_is_accepted_by_open_btf_and_the_cli(tmp_path, capsys):
    out = tmp_path / "x.tbtf"
    code, _, err = run(["convert", SOURCE, "-o", out], capsys)
    assert code == 2 and "unknown extension '.tbtf'" in err and not out.exists()
    extra = Format("test-btf", (".tbtf",), "a test format", ("btf",), _read_as_dense,
                   _write_as_dense)  # fmt: skip
    with registered(extra):
        assert output_format(out, "btf") == "test-btf"
        assert "or .tbtf (a test format)" in OUTPUT_FORMATS["btf"][1]
        code, _, err = run(["convert", SOURCE, "-o", out], capsys)
        assert code == 0, err
        assert np.array_equal(open_btf(out).to_array(), open_btf(SOURCE).to_array())
    assert extra not in FORMATS
    with pytest.raises(SparseBTFError, match="unknown extension"):
        output_format(out, "btf")


def test_register_refuses_a_kind_twice():
    with pytest.raises(ValueError, match="already registered"):
        registry.register(Format("dense", (".x",), "x"))


def _header(path):
    """Everything of a dense file but its values: root attributes, /btf's layout and filters,
    the direction tables."""
    import h5py

    with h5py.File(path, "r") as f:
        ds = f["btf"]
        out = {"attrs": {k: f.attrs[k] for k in sorted(f.attrs)},
               "btf": (ds.shape, str(ds.dtype), ds.chunks, ds.fletcher32, ds.compression,
                       sorted(ds.attrs))}  # fmt: skip
        for g in ("lights", "views"):
            out[g] = ({k: f[g].attrs[k] for k in f[g].attrs},
                      {k: (f[g][k][()].tobytes(), f[g][k].fletcher32) for k in f[g]})  # fmt: skip
        out["members"] = sorted(f)
        return out


def test_capture_and_write_dense_write_the_same_header(tmp_path):
    """The capture's file and write_dense's copy of it (same name, attributes, directions):
    one header writer, identical header attributes and datasets."""
    from sparsebtf.data.capture import capture
    from sparsebtf.data.dense_file import write_dense
    from sparsebtf.llvm import configure

    if not configure().ok:
        pytest.skip("capture renders with Mitsuba's LLVM backend")
    scene = tmp_path / "plane.py"
    scene.write_text("def scene(seed):\n    return {'type': 'scene', 'plane': {'type': "
                     "'rectangle', 'bsdf': {'type': 'diffuse'}}}\n")  # fmt: skip
    captured = capture(str(scene), tmp_path / "c.h5", size=8, directions="tiny13", spp=1,
                       progress=False)  # fmt: skip
    with open_btf(captured) as b:
        copy = write_dense(tmp_path / "d.h5", b)
    assert _header(captured) == _header(copy)


def test_build_corpus_runs_every_registered_corpus_maker(tmp_path):
    from sparsebtf.fuzzing import build_corpus

    def maker(folder, shared):
        assert "model" in shared  # the built-in makers ran first and shared their model
        p = folder / "x.tst"
        p.write_bytes(b"seed")
        return [p]

    with registered(Format("tst", (".tst",), "a test format", corpus=maker)):
        files = build_corpus(tmp_path)
    assert files["tst"] == [tmp_path / "x.tst"]
    assert set(files) == {*READERS, "tst"}
