"""Tests of the UBO2003 / ATRIUM zip reader and writer (tiny synthetic archives)."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

from sparsebtf.data.directions import from_angles, tiny
from sparsebtf.errors import FileFormatError
from sparsebtf.formats.ubo2003 import (
    decode_rgbe,
    encode_rgbe,
    read_ubo2003_zip,
    write_ubo2003_zip,
)

H = W = 8


def _smooth(h: int, w: int, n_l: int, n_v: int, seed: int = 0) -> np.ndarray:
    """A smooth positive (h, w, L, V, 3) array in (0.05, 0.95) (JPEG-friendly)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w] / max(h, w)
    base = 0.5 + 0.2 * np.sin(3 * x + 2 * y)[:, :, None, None, None]
    amp = rng.uniform(0.3, 1.0, size=(1, 1, n_l, n_v, 3))
    return np.clip(base * amp + 0.05, 0.05, 0.95)


def _hdr_data(n_l: int, n_v: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(0.0, 1.0, size=(H, W, n_l, n_v, 3)) * 10.0 ** rng.uniform(
        -3, 3, size=(1, 1, n_l, n_v, 1)
    )


def _rgbe_close(got: np.ndarray, want: np.ndarray) -> None:
    """Equal to RGBE precision: error ≤ 2^-7 of each pixel's largest channel."""
    scale = want.max(axis=-1, keepdims=True)
    assert np.all(np.abs(got - want) <= scale * 2.0**-7 + 1e-30)


@pytest.fixture(scope="module")
def dirs() -> tuple:
    return tiny(7), tiny(7)


@pytest.fixture(scope="module")
def hdr_archive(tmp_path_factory: pytest.TempPathFactory, dirs: tuple) -> tuple[Path, np.ndarray]:
    data = _hdr_data(7, 7)
    path = tmp_path_factory.mktemp("hdr") / "CEILING_HDR.zip"
    write_ubo2003_zip(path, data, *dirs, kind="hdr")
    return path, data


@pytest.fixture(scope="module")
def jpeg_archive(tmp_path_factory: pytest.TempPathFactory, dirs: tuple) -> tuple[Path, np.ndarray]:
    data = _smooth(H, W, 7, 7)
    path = tmp_path_factory.mktemp("jpg") / "UBO_TEST8.zip"
    write_ubo2003_zip(path, data, *dirs, kind="jpeg")
    return path, data


# -- RGBE codec ---------------------------------------------------------------------------------
@pytest.mark.parametrize("rle", [True, False])
@pytest.mark.parametrize(
    "order",
    ["-Y +X", "+Y +X", "-Y -X", "+Y -X", "+X -Y", "+X +Y", "-X -Y", "-X +Y"],
)
def test_rgbe_round_trip_all_orders(rle: bool, order: str) -> None:
    rng = np.random.default_rng(3)
    img = rng.uniform(0, 5, size=(9, 13, 3))  # non-square, so orientation errors show
    img[2, 3] = 0.0
    img[4:, 5:] = 1.25  # long runs for RLE
    blob = encode_rgbe(img, rle=rle, order=order)
    ax1, ax2 = order.split()
    sizes = {"Y": 9, "X": 13}
    assert f"\n{ax1} {sizes[ax1[1]]} {ax2} {sizes[ax2[1]]}\n".encode() in blob
    got = decode_rgbe(blob)
    assert got.shape == (9, 13, 3) and got.dtype == np.float32
    _rgbe_close(got, img)
    assert np.all(got[2, 3] == 0)


def test_rgbe_rle_is_smaller_and_flat_is_four_bytes_per_pixel() -> None:
    img = np.full((10, 20, 3), 0.75)
    flat = encode_rgbe(img, rle=False)
    rle = encode_rgbe(img, rle=True)
    header = flat[: flat.index(b"+X 20\n") + 6]
    assert len(flat) == len(header) + 10 * 20 * 4
    assert len(rle) < len(flat)
    assert rle[len(header) : len(header) + 4] == bytes((2, 2, 0, 20))
    np.testing.assert_allclose(decode_rgbe(rle), decode_rgbe(flat))


def test_rgbe_mantissa_convention_and_exposure() -> None:
    # 0.5 = 128 · 2^(128 − 136): exactly representable, no +0.5 mantissa offset.
    blob = b"#?RGBE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1 +X 1\n" + bytes((128, 64, 0, 128))
    np.testing.assert_array_equal(decode_rgbe(blob)[0, 0], [0.5, 0.25, 0.0])
    img = np.full((2, 3, 3), 0.5)
    got = decode_rgbe(encode_rgbe(img, exposure=4.0))
    np.testing.assert_allclose(got, img, rtol=1e-6)


@pytest.mark.parametrize(
    ("blob", "match"),
    [
        (b"#?JPEG\n\n-Y 1 +X 1\n\x00\x00\x00\x00", "magic"),
        (b"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 1 +X 1\n\x00\x00\x00\x00", "FORMAT"),
        (b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1 +Y 1\n\x00\x00\x00\x00", "resolution"),
        (b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 2\n\x00\x00\x00\x00", "truncated"),
        (b"#?RADIANCE\nEXPOSURE=abc\n\n-Y 1 +X 1\n\x00\x00\x00\x00", "EXPOSURE"),
        (b"#?RADIANCE\nnonsense\n\n-Y 1 +X 1\n\x00\x00\x00\x00", "header line"),
    ],
)
def test_rgbe_bad_headers(blob: bytes, match: str) -> None:
    with pytest.raises(FileFormatError, match=match):
        decode_rgbe(blob, "x.hdr")


# -- archives -----------------------------------------------------------------------------------
def test_hdr_archive_round_trip(hdr_archive: tuple, dirs: tuple) -> None:
    path, data = hdr_archive
    btf = read_ubo2003_zip(path)
    assert btf.kind == "hdr"
    assert btf.shape == (H, W, 7, 7, 3)
    assert btf.lights.equals(dirs[0]) and btf.views.equals(dirs[1])
    _rgbe_close(btf.to_array(), data)


def test_jpeg_archive_round_trip(jpeg_archive: tuple, dirs: tuple) -> None:
    path, data = jpeg_archive
    btf = read_ubo2003_zip(path)
    assert btf.kind == "jpeg"
    assert btf.lights.equals(dirs[0]) and btf.views.equals(dirs[1])
    got = btf.to_array()
    assert got.dtype == np.float32 and got.shape == data.shape
    # 8-bit quantisation in gamma space + JPEG at quality 100, no chroma subsampling.
    err = np.abs(got - data)
    assert err.max() < 0.03
    assert err.mean() < 0.005
    # linear, not gamma-encoded: a gamma-space reading would be far off
    assert np.abs(got ** (1 / 2.2) - data).mean() > 0.05


def test_directions_parsed_from_names(tmp_path: Path) -> None:
    lights = from_angles(np.radians([75, 0, 15, 15]), np.radians([345, 0, 300, 0]))
    views = from_angles(np.radians([30, 0]), np.radians([30, 0]))
    data = _hdr_data(4, 2)
    path = write_ubo2003_zip(tmp_path / "a.zip", data, lights, views, kind="hdr", sep="_")
    btf = read_ubo2003_zip(path)
    # ordered by (θ, φ): input order is permuted
    assert btf.light_angles == [(0, 0), (15, 0), (15, 300), (75, 345)]
    assert btf.view_angles == [(0, 0), (30, 30)]
    np.testing.assert_allclose(np.degrees(btf.lights.theta), [0, 15, 15, 75], atol=1e-9)
    np.testing.assert_allclose(np.degrees(btf.lights.phi), [0, 0, -60, -15], atol=1e-9)
    perm_l, perm_v = [1, 3, 2, 0], [1, 0]
    assert btf.lights.equals(from_angles(lights.theta[perm_l], lights.phi[perm_l]))
    _rgbe_close(btf.to_array(), data[:, :, perm_l][:, :, :, perm_v])


def test_accessors_consistent_and_lazy(hdr_archive: tuple) -> None:
    path, data = hdr_archive
    btf = read_ubo2003_zip(path, cache_size=2)
    assert btf.decoded == 0
    img = btf.angular_image(3, 5)
    assert btf.decoded == 1
    _rgbe_close(img, data[:, :, 3, 5])
    btf.angular_image(3, 5)
    assert btf.decoded == 1  # cached
    p = btf.patch(2, 3, 4)
    assert p.shape == (4, 4, 7, 7, 3)
    _rgbe_close(p, data[2:6, 3:7])
    np.testing.assert_array_equal(p[:, :, 3, 5], img[2:6, 3:7])
    a = btf.abrdf(1, 6)
    np.testing.assert_array_equal(a, btf.read([1], [6], slice(None), slice(None))[0, 0])
    np.testing.assert_array_equal(btf.view_block(4)[..., 2, :], btf.angular_image(2, 4))
    sub = btf.read([7, 0], slice(None, None, 2), [6, 0], [1])
    _rgbe_close(sub, data[[7, 0]][:, ::2][:, :, [6, 0]][:, :, :, [1]])


def test_rle_and_flat_archives_agree(tmp_path: Path, dirs: tuple) -> None:
    data = _hdr_data(7, 7, seed=5)
    a = write_ubo2003_zip(tmp_path / "rle.zip", data, *dirs, kind="hdr", rle=True)
    b = write_ubo2003_zip(tmp_path / "flat.zip", data, *dirs, kind="hdr", rle=False, order="+X -Y")
    assert a.stat().st_size != b.stat().st_size
    np.testing.assert_array_equal(read_ubo2003_zip(a).to_array(), read_ubo2003_zip(b).to_array())


def test_non_image_members_ignored(hdr_archive: tuple, tmp_path: Path) -> None:
    src, data = hdr_archive
    dst = tmp_path / "extra.zip"
    dst.write_bytes(src.read_bytes())
    with zipfile.ZipFile(dst, "a") as zf:
        zf.writestr("MAT/readme.txt", "hello")
        zf.writestr("MAT/tv000_pv000/", "")
    _rgbe_close(read_ubo2003_zip(dst).angular_image(0, 0), data[:, :, 0, 0])


# -- bad input ----------------------------------------------------------------------------------
def _copy_with(src: Path, dst: Path, drop: str | None = None, add: dict | None = None) -> Path:
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for info in zin.infolist():
            if drop is not None and info.filename.endswith(drop):
                continue
            zout.writestr(info, zin.read(info))
        for name, blob in (add or {}).items():
            zout.writestr(name, blob)
    return dst


def test_not_a_zip(tmp_path: Path) -> None:
    p = tmp_path / "bad.zip"
    p.write_bytes(b"not a zip at all")
    with pytest.raises(FileFormatError, match=r"bad\.zip.*not a readable zip"):
        read_ubo2003_zip(p)


def test_unparsable_member_name(hdr_archive: tuple, tmp_path: Path) -> None:
    dst = _copy_with(hdr_archive[0], tmp_path / "n.zip", add={"MAT/oops tl0x0.hdr": b""})
    with pytest.raises(FileFormatError, match=r"n\.zip.*'MAT/oops tl0x0\.hdr'.*does not parse"):
        read_ubo2003_zip(dst)


def test_angle_out_of_range(hdr_archive: tuple, tmp_path: Path) -> None:
    dst = _copy_with(
        hdr_archive[0], tmp_path / "r.zip", add={"x/00000 tl095 pl000 tv000 pv000.hdr": b""}
    )
    with pytest.raises(FileFormatError, match=r"field tl = 95"):
        read_ubo2003_zip(dst)


def test_missing_image(hdr_archive: tuple, tmp_path: Path) -> None:
    dst = _copy_with(hdr_archive[0], tmp_path / "m.zip", drop="tl040 pl120 tv040 pv300.hdr")
    with pytest.raises(FileFormatError, match=r"m\.zip.*1 of 49.*\(40, 120, 40, 300\)"):
        read_ubo2003_zip(dst)


def test_duplicate_image(hdr_archive: tuple, tmp_path: Path) -> None:
    with zipfile.ZipFile(hdr_archive[0]) as zf:
        blob = zf.read(zf.namelist()[0])
    dst = _copy_with(
        hdr_archive[0], tmp_path / "d.zip", add={"other/99999_tl000_pl000_tv000_pv000.hdr": blob}
    )
    with pytest.raises(FileFormatError, match=r"duplicate.*\(0, 0, 0, 0\).*99999"):
        read_ubo2003_zip(dst)


def test_extra_image_makes_pairs_missing(hdr_archive: tuple, tmp_path: Path) -> None:
    with zipfile.ZipFile(hdr_archive[0]) as zf:
        blob = zf.read(zf.namelist()[0])
    dst = _copy_with(
        hdr_archive[0], tmp_path / "e.zip", add={"x/00000 tl010 pl000 tv000 pv000.hdr": blob}
    )
    with pytest.raises(
        FileFormatError, match=r"6 of 56 images missing for \(θi, φi, θv, φv\) = \(10, 0, 40, 0\)"
    ):
        read_ubo2003_zip(dst)


def test_mixed_kinds(hdr_archive: tuple, tmp_path: Path) -> None:
    dst = _copy_with(
        hdr_archive[0],
        tmp_path / "k.zip",
        drop="tl000 pl000 tv000 pv000.hdr",
        add={"x/00000 tl000 pl000 tv000 pv000.jpg": b"\xff\xd8"},
    )
    with pytest.raises(FileFormatError, match="mixes JPEG and HDR"):
        read_ubo2003_zip(dst)


@pytest.mark.parametrize("kind", ["hdr", "jpeg"])
def test_images_of_different_sizes(kind: str, tmp_path: Path, dirs: tuple) -> None:
    data = _smooth(H, W, 7, 7)
    src = write_ubo2003_zip(tmp_path / "s.zip", data, *dirs, kind=kind)
    other = write_ubo2003_zip(tmp_path / "o.zip", _smooth(6, 5, 7, 7), *dirs, kind=kind)
    ext = "hdr" if kind == "hdr" else "jpg"
    victim = f"tl040 pl060 tv040 pv120.{ext}"
    with zipfile.ZipFile(other) as zf:
        (name,) = [n for n in zf.namelist() if n.endswith(victim)]
        blob = zf.read(name)
    dst = _copy_with(src, tmp_path / "z.zip", drop=victim, add={name: blob})
    with pytest.raises(FileFormatError, match=r"z\.zip.*tl040 pl060 tv040 pv120.*6x5.*8x8"):
        read_ubo2003_zip(dst)
    # without the up-front check the mismatch is caught when the image is decoded
    btf = read_ubo2003_zip(dst, check_sizes=False)
    with pytest.raises(FileFormatError, match=r"tl040 pl060 tv040 pv120.*6x5"):
        btf.to_array()


def test_corrupt_hdr_header(hdr_archive: tuple, tmp_path: Path) -> None:
    with zipfile.ZipFile(hdr_archive[0]) as zf:
        (name,) = [n for n in zf.namelist() if n.endswith("tl040 pl180 tv000 pv000.hdr")]
        blob = zf.read(name)
    bad = blob.replace(b"-Y 8 +X 8", b"-Y 8 +Q 8")
    dst = _copy_with(hdr_archive[0], tmp_path / "c.zip", drop=name, add={name: bad})
    with pytest.raises(FileFormatError, match=r"c\.zip.*tl040 pl180 tv000 pv000.*resolution"):
        read_ubo2003_zip(dst)
    bad_magic = b"#?NOPE" + blob[10:]
    dst2 = _copy_with(hdr_archive[0], tmp_path / "c2.zip", drop=name, add={name: bad_magic})
    btf = read_ubo2003_zip(dst2, check_sizes=False)  # header of [0, 0] only is read eagerly
    with pytest.raises(FileFormatError, match=r"tl040 pl180 tv000 pv000.*magic"):
        btf.to_array()


def test_rgbe_rle_hand_built_and_wide_scanlines() -> None:
    # One 8-pixel RLE scanline: R a run of 8×10, G 8 literals, B a run of 0, E a run of 128.
    g = bytes(range(1, 9))
    blob = (
        b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1 +X 8\n"
        + bytes((2, 2, 0, 8))
        + bytes((128 + 8, 10))
        + bytes((8,))
        + g
        + bytes((128 + 8, 0))
        + bytes((128 + 8, 128))
    )
    got = decode_rgbe(blob)
    np.testing.assert_array_equal(got[0, :, 0], np.full(8, 10 / 256))
    np.testing.assert_array_equal(got[0, :, 1], np.arange(1, 9) / 256)
    np.testing.assert_array_equal(got[0, :, 2], 0)
    # Wide rows exercise literal runs of 128 bytes and runs of 127.
    rng = np.random.default_rng(9)
    img = rng.uniform(0, 1, size=(3, 400, 3))
    img[1] = 0.3
    _rgbe_close(decode_rgbe(encode_rgbe(img, rle=True)), img)
