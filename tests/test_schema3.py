"""Coded-file schema 3: sorted locations as gaps, compressed streams, the same codes as schema 2."""

from __future__ import annotations

import copy
import re
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from sparsebtf._hdf5 import shrinks
from sparsebtf.cli.main import main
from sparsebtf.codec import encode_levels
from sparsebtf.errors import BTFInputError, FileFormatError
from sparsebtf.learning.coding import SparseCodes
from sparsebtf.runtime import RuntimeBTF, coded_btf_view
from sparsebtf.storage import load_coded, save_coded
from sparsebtf.storage.coded_streams import canonical_codes

from .conftest import smooth_btf, tiny_model

DOCS = Path(__file__).resolve().parents[1] / "docs" / "format.md"
# Written by 02d1a95 (schema 3's first layout: per-point location gaps) and schema 2, the same
# codes (smooth_btf(5) on tiny_model() at τ = (16, 4, 4); V in an old tie order, with a rank).
FIRST_LAYOUT = Path(__file__).resolve().parent / "data" / "coded_schema3_gaps.h5"
SCHEMA2 = Path(__file__).resolve().parent / "data" / "coded_schema2.h5"
STREAMS = ("location_table", "usage", "value_bytes")
TAUS = [(16, 4, 4), (40, 8, 8), (120, 20, 20)]


@pytest.fixture(scope="module")
def model():
    return tiny_model()


@pytest.fixture(scope="module")
def levels(model):
    """One material coded at three sparsities (every level of the test)."""
    return encode_levels(smooth_btf(5), model, TAUS, eps=0.0)


def _copy(coded):
    """A shallow copy whose channel codes can be replaced (the fixture stays as it is)."""
    out = copy.copy(coded)
    out.codes = dict(coded.codes)
    return out


def _same_codes(a: SparseCodes, b: SparseCodes) -> None:
    assert np.array_equal(a.values.view(np.uint32), b.values.view(np.uint32))
    for f in ("locations", "counts", "membership"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f


def _with_ties(c: SparseCodes, flip: bool) -> SparseCodes:
    """``c`` with equal-magnitude values made on purpose (and, with ``flip``, put in the
    reverse of the rule's tie order, as an older encoder could have left them)."""
    vals = c.values.copy()
    o = c.offsets
    for i in range(c.n_points):
        if o[i + 1] - o[i] >= 4:
            vals[o[i] + 1] = -vals[o[i] + 2]  # a tie of magnitudes with opposite signs
    tied = canonical_codes(SparseCodes(c.mode_sizes, c.membership, c.counts, vals,
                                       c.locations, c.errors))  # fmt: skip
    if not flip:
        return tied
    order = np.arange(tied.nnz)
    for i in range(c.n_points):
        if o[i + 1] - o[i] >= 4:
            order[o[i] + 1], order[o[i] + 2] = order[o[i] + 2], order[o[i] + 1]
    return SparseCodes(tied.mode_sizes, tied.membership, tied.counts, tied.values[order],
                       tied.locations[order], tied.errors)  # fmt: skip


def test_schema3_decodes_to_schema2_bit_for_bit_at_every_level(levels, model, tmp_path):
    for lv, coded in enumerate(levels):
        p2 = save_coded(coded, tmp_path / f"l{lv}_v2.h5", schema=2)
        p3 = save_coded(coded, tmp_path / f"l{lv}_v3.h5")
        a, b = load_coded(p2, model), load_coded(p3, model)
        for ch in coded.channels:
            _same_codes(a.codes[ch], b.codes[ch])
        with h5py.File(p3, "r") as f:
            assert int(f.attrs["schema_version"]) == 3 and "rank" not in f["codes/Y"]
        # decoded BTF (Eq. 4) and the runtime's sums (Eq. 5) at full and reduced τ
        assert np.array_equal(coded_btf_view(a).to_array(), coded_btf_view(b).to_array())
        rng = np.random.default_rng(lv)
        uv = rng.uniform(0, 1, (64, 2))
        wi = wo = np.tile([[0.2, 0.1, 0.97]], (64, 1))
        for tau in (None, 0.5, 3):
            ra = RuntimeBTF(a, tau=tau).evaluate(wi, wo, uv=uv)
            rb = RuntimeBTF(b, tau=tau).evaluate(wi, wo, uv=uv)
            assert np.array_equal(ra, rb)


def test_files_are_smaller_and_every_dataset_compressed(levels, tmp_path):
    coded = levels[-1]
    p2 = save_coded(coded, tmp_path / "v2.h5", schema=2)
    p3 = save_coded(coded, tmp_path / "v3.h5")
    with h5py.File(p2, "r") as f2, h5py.File(p3, "r") as f3:
        for ch in coded.channels:
            old = sum(f2[f"codes/{ch}/{n}"].id.get_storage_size() for n in ("values", "locations"))
            new = sum(f3[f"codes/{ch}/{n}"].id.get_storage_size() for n in STREAMS)
            assert new < old
        for group in ("codes/Y", "codes/U", "stats"):
            for name, ds in f3[group].items():
                # compressed, unless the filters could not shrink it (a few bytes)
                want = ("gzip", True) if shrinks(ds[()]) else (None, False)
                assert (ds.compression, ds.shuffle) == want, name
                assert ds.fletcher32, name
        assert f3["codes/Y/location_table"].compression == "gzip"
        vb = f3["codes/Y/value_bytes"]
        assert vb.dtype == np.uint8 and vb.shape == (2, coded.codes["Y"].nnz)
        assert vb.chunks == (1, vb.shape[1])  # each byte plane a deflate stream of its own
        assert f3["stats/mean"].compression == "gzip"
    assert p3.stat().st_size < p2.stat().st_size


def test_runtime_magnitude_order_is_restored_with_the_tie_rule(levels, model, tmp_path):
    coded = _copy(levels[1])
    coded.codes["Y"] = _with_ties(coded.codes["Y"], flip=False)
    back = load_coded(save_coded(coded, tmp_path / "t.h5"), model)
    c = back.codes["Y"]
    with h5py.File(tmp_path / "t.h5", "r") as f:
        assert "rank" not in f["codes/Y"]  # the rule reproduces the order
    lin = c.locations.astype(np.int64) @ np.cumprod((1, *c.mode_sizes[:-1]))
    o = c.offsets
    ties = 0
    for i in range(c.n_points):
        mag = np.abs(c.values[o[i] : o[i + 1]])
        assert np.all(np.diff(mag) <= 0)  # decreasing magnitude: τ is a prefix
        same = np.diff(mag) == 0
        assert np.all(np.diff(lin[o[i] : o[i + 1]])[same] > 0)  # ties by increasing location
        ties += int(same.sum())
    assert ties >= c.n_points // 2
    want = coded.codes["Y"]
    assert np.array_equal(c.values, want.values.astype(np.float16).astype(np.float32))
    assert np.array_equal(c.locations, want.locations)
    arrays = RuntimeBTF(back).arrays(neighbours=False)
    assert np.array_equal(arrays["values_Y"], c.values)


def test_an_old_tie_order_is_kept_with_a_rank(levels, model, tmp_path):
    coded = _copy(levels[1])
    coded.codes["U"] = _with_ties(coded.codes["U"], flip=True)
    p2 = save_coded(coded, tmp_path / "old.h5", schema=2)
    assert main(["convert", str(p2), "-o", str(tmp_path / "new.h5"), "--schema", "3"]) == 0
    with h5py.File(tmp_path / "new.h5", "r") as f:
        assert int(f.attrs["schema_version"]) == 3
        assert "rank" in f["codes/U"] and "rank" not in f["codes/Y"]
    a, b = load_coded(p2, model), load_coded(tmp_path / "new.h5", model)
    for ch in coded.channels:
        _same_codes(a.codes[ch], b.codes[ch])
    # and back to schema 2: the same codes
    assert main(["convert", str(tmp_path / "new.h5"), "-o", str(tmp_path / "back.h5"),
                 "--schema", "2"]) == 0  # fmt: skip
    c = load_coded(tmp_path / "back.h5", model)
    for ch in coded.channels:
        _same_codes(a.codes[ch], c.codes[ch])


def _docs_reader() -> str:
    text = DOCS.read_text()
    m = re.search(r"<!-- schema3-reader -->\s*```python\n(.*?)```", text, re.S)
    assert m, "docs/format.md lost its schema-3 reader block"
    return m.group(1)


@pytest.mark.parametrize("with_rank", [False, True])
def test_docs_reader_reproduces_the_codes_without_sparsebtf(levels, model, tmp_path, with_rank):
    """docs/format.md's h5py + NumPy inverse, run where sparsebtf cannot be imported, reads
    every dataset of a schema-3 file and gives the codes load_coded gives."""
    coded = _copy(levels[2])
    if with_rank:
        coded.codes["V"] = _with_ties(coded.codes["V"], flip=True)
    path = save_coded(coded, tmp_path / "c.h5")
    got = _run_docs_reader(path, tmp_path / "out.npz")
    back = load_coded(path, model)
    _same_as_docs_reader(got, back)
    with h5py.File(path, "r") as f:
        names: list[str] = []
        f.visititems(lambda n, o: names.append(n) if isinstance(o, h5py.Dataset) else None)
    assert {f"raw/{n}" for n in names} <= set(got.files)  # every dataset was read
    assert {f"raw/codes/Y/{n}" for n in STREAMS} <= set(got.files)
    assert np.array_equal(got["raw/stats/mean"], back.stats.mean.astype(np.float32))
    assert ("raw/codes/V/rank" in got.files) == with_rank


def test_docs_reader_reads_the_first_layout(tmp_path):
    got = _run_docs_reader(FIRST_LAYOUT, tmp_path / "out.npz")
    assert "raw/codes/Y/location_gaps" in got.files and "raw/codes/V/rank" in got.files
    _same_as_docs_reader(got, load_coded(SCHEMA2))


def _run_docs_reader(path: Path, out: Path):
    """docs/format.md's reader run on ``path`` where sparsebtf cannot be imported → npz."""
    script = (
        "import sys\nsys.modules['sparsebtf'] = None  # any import of it fails\n"
        + _docs_reader()
        + "\ncodes, data = read_coded_v3(sys.argv[1])\n"
        "flat = {f'{ch}/{k}': v for ch, c in codes.items() for k, v in c.items()}\n"
        "flat.update({f'raw/{k}': v for k, v in data.items()})\n"
        "np.savez(sys.argv[2], **flat)\n"
    )
    r = subprocess.run([sys.executable, "-c", script, str(path), str(out)],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stderr
    return np.load(out)


def _same_as_docs_reader(got, back) -> None:
    for ch in back.channels:
        c = back.codes[ch]
        assert np.array_equal(got[f"{ch}/values"].astype(np.float32).view(np.uint32),
                              c.values.view(np.uint32))  # fmt: skip
        for f in ("locations", "counts", "membership"):
            assert np.array_equal(got[f"{ch}/{f}"], getattr(c, f)), f
        assert np.array_equal(got[f"{ch}/errors"], c.errors.astype(np.float32))


def test_first_layout_reads_as_schema2_and_converts(tmp_path):
    """A file of schema 3's first layout still loads to the codes of the same codes' schema-2
    file, bit for bit (the V rank kept), and ``convert --schema 3`` rewrites it in tables."""
    old, ref = load_coded(FIRST_LAYOUT), load_coded(SCHEMA2)
    assert int(h5py.File(FIRST_LAYOUT, "r").attrs["schema_version"]) == 3
    for ch in ref.channels:
        _same_codes(old.codes[ch], ref.codes[ch])
    assert main(["convert", str(FIRST_LAYOUT), "-o", str(tmp_path / "new.h5"),
                 "--schema", "3"]) == 0  # fmt: skip
    with h5py.File(tmp_path / "new.h5", "r") as f:
        assert set(STREAMS) <= set(f["codes/Y"]) and "location_gaps" not in f["codes/Y"]
        assert "rank" in f["codes/V"] and "rank" not in f["codes/Y"]
    new = load_coded(tmp_path / "new.h5")
    for ch in ref.channels:
        _same_codes(new.codes[ch], ref.codes[ch])


def test_damaged_gaps_are_one_clear_error(tmp_path):
    path = tmp_path / "c.h5"
    path.write_bytes(FIRST_LAYOUT.read_bytes())
    with h5py.File(path, "a") as f:
        g = f["codes/Y/location_gaps"]
        gaps = g[()]
        gaps[1] = 0
        g[...] = gaps
    with pytest.raises(FileFormatError, match=r"codes/Y/location_gaps: entry 1 is 0 \(a rep"):
        load_coded(path)
    with h5py.File(path, "a") as f:
        gaps[1] = 2**31
        f["codes/Y/location_gaps"][...] = gaps
    with pytest.raises(FileFormatError, match=r"location_gaps: entry 1 is 2147483648, beyond"):
        load_coded(path)
    gaps[:16] = 400  # each gap in range (< 2704 entries), their sum beyond them
    with h5py.File(path, "a") as f:
        f["codes/Y/location_gaps"][...] = gaps
    with pytest.raises(FileFormatError, match=r"location_gaps: entry \d+ reaches location"):
        load_coded(path)
    with h5py.File(path, "a") as f:  # 64-bit gaps beyond int64: refused, never wrapped
        del f["codes/Y/location_gaps"]
        f.create_dataset("codes/Y/location_gaps", data=np.full(gaps.size, 2**63 + 5, "<u8"))
    with pytest.raises(FileFormatError, match=r"location_gaps: entry 0 is 9223372036854775813"):
        load_coded(path)


def _rewrite(path: Path, name: str, data: np.ndarray) -> None:
    with h5py.File(path, "a") as f:
        del f[name]
        f.create_dataset(name, data=data)


def test_damaged_tables_are_one_clear_error(levels, tmp_path):
    good = save_coded(levels[0], tmp_path / "good.h5")
    with h5py.File(good, "r") as f:
        g = {n: f[f"codes/Y/{n}"][()] for n in STREAMS}
        m = f["codes/Y/membership"][()]
        t = f["codes/Y"].attrs["table_sizes"].astype(np.int64)
    k = int(np.argmax(t > 1))  # a dictionary with two entries or more
    start = int(t[:k].sum())
    cases = []
    bad = g["location_table"].copy()
    bad[start + 1] = 0
    cases.append(("location_table", bad, rf"codes/Y/location_table: entry {start + 1} is 0"))
    bad = g["location_table"].copy()
    bad[start + 1] = 2**31
    cases.append(("location_table", bad, r"location_table: entry \d+ is 2147483648, beyond"))
    bad = g["usage"].copy()
    bad[0] ^= 0x80  # the first point on dictionary 0 gains or loses its first entry
    cases.append(("usage", bad, r"codes/Y/usage: point \d+ uses \d+ table entries but its count"))
    cases.append(("usage", g["usage"][:-1], r"codes/Y/usage: expected shape"))
    for ch in ("Y", "U", "V"):  # a padding bit set, in a channel whose bits leave some
        with h5py.File(good, "r") as f:
            usage, tc = f[f"codes/{ch}/usage"][()], f[f"codes/{ch}"].attrs["table_sizes"]
            n_bits = int(np.sum(tc * np.bincount(f[f"codes/{ch}/membership"][()],
                                                 minlength=tc.size)))  # fmt: skip
        if n_bits % 8:
            usage[-1] |= 1
            cases.append((f"{ch}/usage", usage, rf"{ch}/usage: bit {8 * usage.size - 1} is "
                          rf"set beyond the {n_bits} bits"))  # fmt: skip
            break
    else:
        raise AssertionError("no channel has padding bits to damage")
    cases.append(("value_bytes", g["value_bytes"][:1], r"value_bytes: expected (shape|\(2, )"))
    nan = g["value_bytes"].copy()
    nan[:, 3] = (0x00, 0x7E)  # binary16 NaN
    cases.append(("value_bytes", nan, r"Y/value_bytes: 1 NaN/Inf values \(first at value 3\)"))
    for i, (name, data, message) in enumerate(cases):
        path = tmp_path / f"bad{i}.h5"
        path.write_bytes(good.read_bytes())
        _rewrite(path, f"codes/{name}" if "/" in name else f"codes/Y/{name}", data)
        with pytest.raises(FileFormatError, match=message):
            load_coded(path)
    attr_cases = [(t[: int(m.max())], rf"'table_sizes' lists {int(m.max())} dictionaries, "
                   r"but point \d+ is coded on"),
                  (t + 1, r"'table_sizes' sums to \d+ entries but 'location_table' holds"),
                  (np.array([[1, 2]]), r"'table_sizes' must be a list of entry counts")]
    for i, (data, message) in enumerate(attr_cases):
        path = tmp_path / f"attr{i}.h5"
        path.write_bytes(good.read_bytes())
        with h5py.File(path, "a") as f:
            f["codes/Y"].attrs["table_sizes"] = data
        with pytest.raises(FileFormatError, match=r"codes/Y: attribute " + message):
            load_coded(path)


def test_float32_values_are_four_byte_planes(levels, model, tmp_path):
    coded = _copy(levels[0])
    c = coded.codes["U"]
    vals = c.values.copy()
    vals[0] = np.float32(7e4)  # beyond binary16: the channel keeps float32
    coded.codes["U"] = canonical_codes(SparseCodes(c.mode_sizes, c.membership, c.counts, vals,
                                                   c.locations, c.errors))  # fmt: skip
    with pytest.warns(UserWarning, match="overflow binary16"):
        p3 = save_coded(coded, tmp_path / "f32.h5")
    with pytest.warns(UserWarning, match="overflow binary16"):
        p2 = save_coded(coded, tmp_path / "f32_v2.h5", schema=2)
    with h5py.File(p3, "r") as f:
        assert f["codes/U/value_bytes"].shape == (4, c.nnz)
        assert f["codes/Y/value_bytes"].shape[0] == 2
    a, b = load_coded(p2, model), load_coded(p3, model)
    for ch in coded.channels:
        _same_codes(a.codes[ch], b.codes[ch])
    assert np.float32(7e4) in b.codes["U"].values


def test_writer_refuses_repeated_locations(levels, tmp_path):
    coded = _copy(levels[0])
    c = coded.codes["Y"]
    locs = c.locations.copy()
    locs[1] = locs[0]
    coded.codes["Y"] = SparseCodes(c.mode_sizes, c.membership, c.counts, c.values, locs,
                                   c.errors)  # fmt: skip
    with pytest.raises(BTFInputError, match=r"point 0 repeats( a)? location"):
        save_coded(coded, tmp_path / "c.h5")
    assert not (tmp_path / "c.h5").exists()


def test_a_statistic_added_later_is_compressed_too(tmp_path):
    """A CompressedGroup (the coded file's stats/) compresses whatever is written into it,
    through our helper or h5py's own call, so a new statistic needs no special case."""
    from sparsebtf._hdf5 import CompressedGroup, create, create_dataset

    with create(tmp_path / "x.h5") as f:
        st = CompressedGroup(f.create_group("stats").id)
        create_dataset(st, "bound", data=np.linspace(0, 1, 500, dtype="<f4"))
        st.create_dataset("offset", data=np.arange(300, dtype="<f8").reshape(30, 10))
        st.create_dataset("empty", data=np.zeros(0, dtype="<f4"))
        st.create_dataset("tiny", data=np.array([3.5], dtype="<f4"))  # would only grow
    with h5py.File(tmp_path / "x.h5", "r") as f:
        for name in ("bound", "offset"):
            ds = f[f"stats/{name}"]
            assert (ds.compression, ds.shuffle, ds.fletcher32) == ("gzip", True, True), name
        assert f["stats/offset"][()].sum() == sum(range(300))
        assert f["stats/tiny"].compression is None and f["stats/tiny"][0] == 3.5
        assert f["stats/tiny"].fletcher32


def test_info_and_eval_totals_reconcile_with_the_file(levels, model, tmp_path, capsys):
    import json

    from sparsebtf.data.dense_file import write_dense

    mpath = save_model_file(model, tmp_path)
    coded = levels[1]
    coded.params["model_file"] = str(mpath)
    path = save_coded(coded, tmp_path / "c.h5")
    assert main(["info", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    st = info["storage"]["stored"]
    size = path.stat().st_size
    parts = ("bytes_codes", "bytes_statistics", "bytes_directions", "bytes_header")
    assert sum(st[k] for k in parts) == st["bytes_file"] == size
    assert st["ratio_per_material"] == pytest.approx(2 * smooth_btf(5).n_values / size)
    assert info["storage"]["shared"]["bytes_model_file"] == mpath.stat().st_size
    assert info["schema_version"] == 3
    ref = write_dense(tmp_path / "ref.h5", smooth_btf(5), progress=False)
    assert main(["eval", str(path), "--reference", str(ref), "--json", "--ssim-images",
                 "1"]) == 0  # fmt: skip
    ev = json.loads(capsys.readouterr().out)
    assert ev["bytes_stored"] == ev["file_bytes"] == size
    assert ev["compression_ratio_per_material"] == ev["bytes_raw"] / size
    assert main(["info", str(path)]) == 0
    text = capsys.readouterr().out
    assert any(line.startswith("storage.stored.bytes file") and f"{size:,}" in line
               for line in text.splitlines())  # fmt: skip


def save_model_file(model, folder: Path) -> Path:
    from sparsebtf.storage import save_model

    return save_model(model, folder / "model.h5")
