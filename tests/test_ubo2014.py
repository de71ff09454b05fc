"""UBO2014 ``.btf`` reader/writer: round trips against dense products written from the spec.

The references below recompute every value straight from the factor matrices with the
formulas of ``shared/specs/ubo-btf-format.md`` §1.10 (float64, view-major ``lv = v·nL + l``,
``xy = row·W + col``), independently of the reader's code path.
"""

import struct

import numpy as np
import pytest

from sparsebtf.data.directions import from_angles
from sparsebtf.errors import BTFInputError, FileFormatError
from sparsebtf.formats.ubo2014 import read_ubo2014
from sparsebtf.formats.ubo2014_write import write_ubo2014

H, W, NL, NV = 8, 6, 7, 5
EPS = 1e-5
NP_DT = {"half": np.float16, "float": np.float32, "double": np.float64}

LIGHTS = from_angles(
    np.radians([0, 15, 30, 30, 45, 60, 75]), np.radians([0, 10, 100, 220, 300, 45, 170])
)
VIEWS = from_angles(np.radians([0, 20, 40, 55, 70]), np.radians([0, 90, 180, 270, 30]))


def yuv_to_rgb(y, u, v):
    return np.stack([y + 1.13983 * v, y - 0.39465 * u - 0.5806 * v, y + 2.03211 * u], axis=-1)


def to_dense(q):
    """(nV·nL, H·W) channel matrix → (H, W, L, V)."""
    return q.reshape(NV, NL, H, W).transpose(2, 3, 1, 0)


def dfmf_factors(rng, ks=(3, 2, 1), dtype="half"):
    sp = [(rng.uniform(-0.5, 0.5, (H * W, k))).astype(NP_DT[dtype]) for k in ks]
    an = [(rng.uniform(-0.5, 0.5, (NL * NV, k))).astype(NP_DT[dtype]) for k in ks]
    return sp, an


def dfmf_reference(sp, an, model=11, mean=None, t=None):
    q = [to_dense(an[c].astype(np.float64) @ sp[c].astype(np.float64).T) for c in range(3)]
    if model == 0:
        return np.stack(q, axis=-1)
    if model == 1:
        return yuv_to_rgb(*q)
    if model == 3:
        return np.einsum("...i,ij->...j", np.stack(q, axis=-1), t) + mean
    if model == 4:
        y, co, cg = q
        return np.stack([y + co - cg, y + cg, y - co - cg], axis=-1)
    if model == 12:
        return np.exp(np.stack(q, axis=-1)) - EPS
    y = np.exp(q[0]) - EPS
    if model == 9:
        return yuv_to_rgb(y, q[1], q[2])
    if model == 10:
        return yuv_to_rgb(
            y,
            np.sign(q[1]) * EPS * np.exp(np.abs(q[1])),
            np.sign(q[2]) * EPS * np.exp(np.abs(q[2])),
        )
    assert model == 11
    return yuv_to_rgb(y, q[1] * (y + EPS), q[2] * (y + EPS))


def fmf_factors(rng, k=3, dtype="half"):
    sp = rng.uniform(-0.5, 0.5, (H * W, k)).astype(NP_DT[dtype])
    an = rng.uniform(-0.5, 0.5, (3 * NL * NV, k)).astype(NP_DT[dtype])
    return sp, an


def fmf_reference(sp, an, drr=True):
    q = an.astype(np.float64) @ sp.astype(np.float64).T  # rows (v·nL + l)·3 + c
    dense = q.reshape(NV, NL, 3, H, W).transpose(3, 4, 1, 0, 2)
    return np.exp(dense) - EPS if drr else dense


def check_all_accessors(btf, ref, tol=2e-5):
    assert btf.shape == (H, W, NL, NV, 3)
    got = btf.to_array()
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, ref, rtol=tol, atol=tol)
    np.testing.assert_allclose(btf.angular_image(4, 3), ref[:, :, 4, 3], rtol=tol, atol=tol)
    np.testing.assert_allclose(btf.patch(2, 1, 4), ref[2:6, 1:5], rtol=tol, atol=tol)
    r, c, li, vi = [7, 0, 3], [5, 2], [6, 0, 2], [4, 1]
    np.testing.assert_allclose(
        btf.read(r, c, li, vi), ref[np.ix_(r, c, li, vi, [0, 1, 2])], rtol=tol, atol=tol
    )


@pytest.mark.parametrize("rotations", [True, False])
@pytest.mark.parametrize("dtype", ["half", "float", "double"])
def test_dfmf_round_trip(tmp_path, dtype, rotations):
    rng = np.random.default_rng(1)
    sp, an = dfmf_factors(rng, dtype=dtype)
    path = tmp_path / "a.btf"
    write_ubo2014(path, sp, an, H, W, LIGHTS, VIEWS, "DFMF", dtype, rotations=rotations)
    assert path.read_bytes()[:10] == b"!DFMF08FCR" if rotations else b"!DFMF08FC"
    btf = read_ubo2014(path)
    assert btf.layout == "DFMF" and btf.color_model == 11 and btf.ranks == [3, 2, 1]
    assert btf.attrs["n_rotations"] == (2 if rotations else 0)
    assert all(isinstance(m, np.memmap) for pair in btf.factors for m in pair)
    assert btf.lights.equals(LIGHTS) and btf.views.equals(VIEWS)
    check_all_accessors(btf, dfmf_reference(sp, an))


@pytest.mark.parametrize("rotations", [True, False])
@pytest.mark.parametrize("dtype", ["half", "float", "double"])
def test_fmf_round_trip_with_height_map(tmp_path, dtype, rotations):
    rng = np.random.default_rng(2)
    sp, an = fmf_factors(rng, dtype=dtype)
    hm = rng.uniform(0, 1, (3, 4)).astype(np.float16)  # hmH=3 rows of hmW=4: non-square on purpose
    path = tmp_path / "b.btf"
    write_ubo2014(
        path, sp, an, H, W, LIGHTS, VIEWS, "FMF", dtype, rotations=rotations, height_map=hm
    )
    assert path.read_bytes()[:10] == b"!FMF12FCER" if rotations else b"!FMF12FCE"
    btf = read_ubo2014(path)
    assert btf.layout == "FMF" and btf.drr and btf.ranks == [3]
    assert np.array_equal(btf.height_map, hm.astype(np.float32))
    check_all_accessors(btf, fmf_reference(sp, an))


@pytest.mark.parametrize(
    ("header_version", "drr"), [(None, False), (0, False), (1, True), (1, False), (2, False)]
)
def test_fmf_header_variants(tmp_path, header_version, drr):
    rng = np.random.default_rng(3)
    sp, an = fmf_factors(rng, k=2, dtype="float")
    path = tmp_path / "c.btf"
    write_ubo2014(
        path, sp, an, H, W, LIGHTS, VIEWS, "FMF", "float", False,
        drr=drr, fmf_header_version=header_version,
    )  # fmt: skip
    btf = read_ubo2014(path)
    assert btf.height_map is None and btf.drr == drr
    check_all_accessors(btf, fmf_reference(sp, an, drr=drr))


@pytest.mark.parametrize("model", [0, 1, 3, 4, 9, 10, 12])
def test_dfmf_colour_models(tmp_path, model):
    rng = np.random.default_rng(4)
    sp, an = dfmf_factors(rng, ks=(2, 3, 2), dtype="double")
    mean = np.array([0.1, -0.2, 0.3], dtype=np.float32)
    t = rng.uniform(-1, 1, (3, 3)).astype(np.float32)
    path = tmp_path / "d.btf"
    write_ubo2014(
        path, sp, an, H, W, LIGHTS, VIEWS, "DFMF", "double",
        color_model=model, color_mean=mean, color_transform=t,
    )  # fmt: skip
    ref = dfmf_reference(sp, an, model, mean.astype(np.float64), t.astype(np.float64))
    check_all_accessors(read_ubo2014(path), ref, tol=1e-6)  # float32 output


@pytest.mark.parametrize("version", [1, 2, 3, 4])
def test_header_versions_and_cosine_flag(tmp_path, version):
    rng = np.random.default_rng(5)
    sp, an = dfmf_factors(rng, dtype="float")
    path = tmp_path / "e.btf"
    flag = 1 if version > 1 else 0
    write_ubo2014(
        path, sp, an, H, W, LIGHTS, VIEWS, dtype="float",
        version=version, cosine_flag=flag, xml="<m/>",
    )  # fmt: skip
    ref = dfmf_reference(sp, an)
    btf = read_ubo2014(path)
    assert btf.attrs["version"] == version and btf.cosine_flag == flag
    if version > 2:
        assert btf.attrs["xml"] == "<m/>"
    check_all_accessors(btf, ref)  # default: never divide (btf-extractor behaviour)
    divided = read_ubo2014(path, divide_cosine=True)
    cos = np.cos(LIGHTS.theta)[None, None, :, None, None]
    check_all_accessors(divided, ref / cos if flag else ref)


@pytest.mark.parametrize("rotations", [True, False])
def test_size_byte_that_looks_like_rotation_marker(tmp_path, rotations):
    # Version 3, 66-byte XML: Size = 338 = 0x152, whose first byte is "R". Without rotations
    # the file then starts with "!DFMF08FCR" too; the reader must still find the right layout.
    rng = np.random.default_rng(9)
    sp, an = dfmf_factors(rng, dtype="float")
    path = tmp_path / "r.btf"
    write_ubo2014(path, sp, an, H, W, LIGHTS, VIEWS, dtype="float", rotations=rotations,
                  version=3, xml="x" * 66)  # fmt: skip
    assert path.read_bytes()[:10] == b"!DFMF08FCR"
    btf = read_ubo2014(path)
    assert btf.attrs["n_rotations"] == (2 if rotations else 0)
    check_all_accessors(btf, dfmf_reference(sp, an))


def test_pixel_convention_row_major_top_row_first(tmp_path):
    # A single bright texel at storage index xy = row·W + col must land at [row, col].
    sp = [np.zeros((H * W, 1)) for _ in range(3)]
    sp[0][2 * W + 5, 0] = 1.0
    an = [np.ones((NL * NV, 1)) for _ in range(3)]
    path = tmp_path / "p.btf"
    write_ubo2014(path, sp, an, H, W, LIGHTS, VIEWS, dtype="float", color_model=0)
    img = read_ubo2014(path).angular_image(0, 0)
    assert img[2, 5, 0] == 1.0 and np.count_nonzero(img) == 1


def test_angular_index_is_view_major(tmp_path):
    # U row lv = v·nL + l holds value lv; reading (light l, view v) must give that number.
    sp = [np.ones((H * W, 1)) for _ in range(3)]
    an = [np.arange(NL * NV, dtype=np.float64)[:, None] for _ in range(3)]
    path = tmp_path / "q.btf"
    write_ubo2014(path, sp, an, H, W, LIGHTS, VIEWS, dtype="float", color_model=0)
    btf = read_ubo2014(path)
    assert btf.read([0], [0], [3], [2])[0, 0, 0, 0, 0] == 2 * NL + 3


# -- bad input ------------------------------------------------------------------------------------


@pytest.fixture
def good(tmp_path):
    rng = np.random.default_rng(6)
    sp, an = dfmf_factors(rng)
    path = tmp_path / "good.btf"
    offsets = write_ubo2014(path, sp, an, H, W, LIGHTS, VIEWS)
    read_ubo2014(path)  # sanity: the unmodified file is fine
    return path, offsets


def rewrite(path, data):
    bad = path.with_name("bad.btf")
    bad.write_bytes(bytes(data))
    return bad


def expect_error(path, *words):
    with pytest.raises(FileFormatError) as e:
        read_ubo2014(path)
    msg = str(e.value)
    assert str(path) in msg
    for w in words:
        assert w in msg, msg
    return msg


@pytest.mark.parametrize("magic", [b"DFMF08FCR!", b"!DFMF09FCR", b"!BDIF06R2!", b"\0" * 10])
def test_wrong_magic(good, magic):
    path, _ = good
    data = bytearray(path.read_bytes())
    data[:10] = magic
    expect_error(rewrite(path, data), "magic")


def test_unknown_colour_model(good):
    path, off = good
    data = bytearray(path.read_bytes())
    data[off["color_model"] : off["color_model"] + 4] = struct.pack("<i", 2)  # LAB: unsupported
    expect_error(rewrite(path, data), "ColorModel", "2")
    data[off["color_model"] : off["color_model"] + 4] = struct.pack("<i", 77)
    expect_error(rewrite(path, data), "ColorModel", "77")


@pytest.mark.parametrize("cut", [1, 2, 100, 0.5, 0.1, 0.02])
def test_truncated(good, cut):
    path, _ = good
    data = path.read_bytes()
    n = cut if isinstance(cut, int) else int(len(data) * (1 - cut))
    expect_error(rewrite(path, data[: len(data) - n]), "truncated")


def test_trailing_bytes(good):
    path, _ = good
    expect_error(rewrite(path, path.read_bytes() + b"\0"), "trailing")


@pytest.mark.parametrize("delta", [4, -4, 1])
def test_header_size_mismatch(good, delta):
    path, off = good
    data = bytearray(path.read_bytes())
    (size,) = struct.unpack_from("<I", data, off["size"])
    struct.pack_into("<I", data, off["size"], size + delta)
    expect_error(rewrite(path, data), "'Size'")


def test_header_version_out_of_range(good):
    path, off = good
    data = bytearray(path.read_bytes())
    struct.pack_into("<I", data, off["size"] + 4, 5)
    expect_error(rewrite(path, data), "'Version'", "5")


def test_inconsistent_direction_counts(good):
    path, off = good
    data = bytearray(path.read_bytes())
    # View 1's light count (after view 0's θ, φ, count and light list) becomes NL − 1,
    # and its list one entry shorter.
    at = off["view_count"] + 4 + (12 + 8 * NL) + 8
    struct.pack_into("<I", data, at, NL - 1)
    del data[at + 4 : at + 12]
    expect_error(rewrite(path, data), "inconsistent direction counts", "view 1 light count")


def test_view_count_disagrees_with_matrix_rows(tmp_path):
    # Directions written for 4 views but factors sized for 5: the matrix 'rows' field disagrees.
    rng = np.random.default_rng(7)
    sp, an = dfmf_factors(rng)
    path = tmp_path / "v.btf"
    off = write_ubo2014(path, sp, an, H, W, LIGHTS, VIEWS)
    data = bytearray(path.read_bytes())
    struct.pack_into("<I", data, off["view_count"], NV - 1)
    at = off["view_count"] + 4 + (NV - 1) * (12 + 8 * NL)
    del data[at : at + 12 + 8 * NL]
    expect_error(rewrite(path, data), "rows", "inconsistent direction counts")


def test_fmf_k0_differs_from_k(tmp_path):
    rng = np.random.default_rng(8)
    sp, an = fmf_factors(rng)
    path = tmp_path / "k.btf"
    off = write_ubo2014(path, sp, an, H, W, LIGHTS, VIEWS, "FMF", rotations=False)
    data = bytearray(path.read_bytes())
    struct.pack_into("<I", data, off["payload"] + 1 + 4 + 8, 2)  # hv, DRR, 0x0 height map
    expect_error(rewrite(path, data), "'K0'")


def test_missing_file(tmp_path):
    expect_error(tmp_path / "nope.btf", "cannot open")


def test_full_size_file_is_read_lazily(tmp_path):
    # 400×400 texels, the 151×151 UBO2014 dome, rank 1: a 1.1 MB file standing for a 44 GB
    # BTF. Images and patches come from the memory maps; the whole BTF is never built.
    from sparsebtf.data.directions import ubo2014

    d = ubo2014()
    rng = np.random.default_rng(10)
    n, m = 400 * 400, 151 * 151
    sp = [rng.uniform(0, 0.1, (n, 1)).astype(np.float16) for _ in range(3)]
    an = [rng.uniform(-1, 0, (m, 1)).astype(np.float16) for _ in range(3)]
    path = tmp_path / "big.btf"
    write_ubo2014(path, sp, an, 400, 400, d, d)
    btf = read_ubo2014(path)
    assert btf.shape == (400, 400, 151, 151, 3) and btf.lights.equals(d, atol=1e-6)
    q = [an[c][150 * 151 + 7].astype(np.float64) @ sp[c].astype(np.float64).T for c in range(3)]
    y = np.exp(q[0]) - EPS
    ref = yuv_to_rgb(y, q[1] * (y + EPS), q[2] * (y + EPS)).reshape(400, 400, 3)
    np.testing.assert_allclose(btf.angular_image(7, 150), ref, rtol=2e-5, atol=2e-5)
    assert btf.patch(398, 0, 2).shape == (2, 2, 151, 151, 3)
    with pytest.raises(BTFInputError, match="refusing"):
        btf.to_array()


@pytest.mark.parametrize(("layout", "model"), [("DFMF", 11), ("DFMF", 12), ("FMF", None)])
def test_angular_rows_kept_once_read_give_the_same_values(tmp_path, monkeypatch, layout, model):
    """Each channel's angular factor is converted and reordered light-major once, then read
    from there: the values of gathering the file's rows per read, bit for bit."""
    import pickle

    from sparsebtf.formats import ubo2014

    rng = np.random.default_rng(9)
    if layout == "DFMF":
        sp, an = dfmf_factors(rng, dtype="half")
        write_ubo2014(tmp_path / "e.btf", sp, an, H, W, LIGHTS, VIEWS, "DFMF", "half",
                      color_model=model)  # fmt: skip
    else:
        sp, an = fmf_factors(rng, dtype="half")
        write_ubo2014(tmp_path / "e.btf", sp, an, H, W, LIGHTS, VIEWS, "FMF", "half")
    kept = read_ubo2014(tmp_path / "e.btf")
    requests = [(slice(None),) * 4, (slice(2, 6), slice(1, 5), slice(None), slice(None)),
                ([7, 0, 3], [5, 2], [6, 0, 2], [4, 1])]  # fmt: skip
    got = [kept.read(*r) for r in requests]
    assert kept.__dict__["_angular_rows"]  # the rows were kept
    assert "_angular_rows" not in pickle.loads(pickle.dumps(kept)).__dict__
    monkeypatch.setattr(ubo2014, "memory_budget", lambda: 0)  # too large to keep: gathered
    gathered = read_ubo2014(tmp_path / "e.btf")
    for r, g in zip(requests, got, strict=True):
        assert np.array_equal(gathered.read(*r), g)
    assert not gathered.__dict__.get("_angular_rows")
