"""Bonn UBO2003 and ATRIUM BTF zip archives as lazy BTFs.

Layout: ``shared/specs/ubo-btf-format.md`` §3. An archive holds one image per (light, view)
pair, named ``…/tv{θv:03d}_pv{φv:03d}/{index:05d} tl{θl:03d} pl{φl:03d} tv{θv:03d}
pv{φv:03d}.{jpg|hdr}`` with integer-degree angles and a single space (or underscore) between
fields. Directory prefixes and the 5-digit counter are ignored; the angles are taken from the
``tl``/``pl``/``tv``/``pv`` fields of the base name, and the light and view sets are the
distinct angle pairs found, each ordered by (θ, φ) with φ in [0°, 360°).

* ``.jpg`` members (UBO2003, ATRIUM LDR): 8-bit gamma-encoded RGB, converted to linear with
  an inverse gamma of 2.2, ``(u / 255) ** 2.2``.
* ``.hdr`` members (ATRIUM HDR): Radiance RGBE, decoded in numpy by :mod:`.rgbe`. Images are
  returned with row 0 at the top and column 0 at the left per the Radiance convention
  (``-Y H +X W`` is the standard order); BX's 256×256-only header hack is not reproduced (its
  output equals ``np.rot90`` of ours for ``+X 256 -Y 256`` files).

Images are decoded only when a read needs them; the last few decoded images are cached. Every
member read is guarded: a damaged archive (bad CRC, truncated or corrupt compressed data, an
unsupported compression) is a :class:`FileFormatError` naming the archive and the member, and
an image's size is checked against its member's bytes and the memory budget before decoding.
"""

from __future__ import annotations

import io
import re
import struct
import zipfile
import zlib
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path
from typing import IO

import numpy as np

from .._limits import check_allocation
from ..data.btf import BTF, Index
from ..data.directions import DirectionSet, from_angles
from ..errors import BTFInputError, FileFormatError
from .rgbe import decode_rgbe, encode_rgbe, hdr_size

__all__ = [
    "UBO2003BTF",
    "decode_rgbe",
    "encode_rgbe",
    "read_ubo2003_zip",
    "write_ubo2003_zip",
]

GAMMA = 2.2
_IMAGE_EXT = {".jpg": "jpeg", ".jpeg": "jpeg", ".hdr": "hdr"}
_NAME_RE = re.compile(
    r"(?:^|[ _])tl(\d{1,3})[ _]pl(\d{1,3})[ _]tv(\d{1,3})[ _]pv(\d{1,3})\.(?:jpe?g|hdr)$",
    re.IGNORECASE,
)
#: What reading a damaged zip member can raise (CRC and size checks, truncated or corrupt
#: DEFLATE/BZIP2/LZMA streams, encrypted or unsupported members).
_ZIP_ERRORS = (
    OSError, EOFError, zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, RuntimeError,
    NotImplementedError, ValueError, KeyError, struct.error, LookupError,
)  # fmt: skip
#: A JPEG can hold at most this many pixels per byte (an empty 8×8 block still takes a few
#: bits; measured BTF images hold under 10). A larger claim is a damaged header.
_JPEG_PIXELS_PER_BYTE = 1024
#: Bytes the JPEG path holds per pixel (uint8 RGB and float32 RGB).
_JPEG_BYTES_PER_PIXEL = 3 + 12

Angles = tuple[int, int, int, int]


# ---------------------------------------------------------------------------------------------
# Image sizes without decoding
# ---------------------------------------------------------------------------------------------
def _jpeg_size(f: IO[bytes], where: str, size: int | None = None) -> tuple[int, int]:
    """(height, width) from a JPEG's SOF marker, reading only the segment headers.

    ``size`` is the member's byte count: more pixels than that many bytes can hold (see
    ``_JPEG_PIXELS_PER_BYTE``) or a zero size is a damaged header.
    """
    if f.read(2) != b"\xff\xd8":
        raise FileFormatError(f"{where}: not a JPEG file (no SOI marker)")
    while True:
        b = f.read(1)
        while b == b"\xff":
            b = f.read(1)
        if not b:
            raise FileFormatError(f"{where}: JPEG has no frame header (SOF)")
        marker = b[0]
        if marker in (0x01, *range(0xD0, 0xD8)):
            continue
        seg = f.read(2)
        if len(seg) < 2:
            raise FileFormatError(f"{where}: JPEG truncated")
        length = int.from_bytes(seg, "big")
        if marker in (0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF):
            sof = f.read(5)
            if len(sof) < 5:
                raise FileFormatError(f"{where}: JPEG frame header truncated")
            h, w = int.from_bytes(sof[1:3], "big"), int.from_bytes(sof[3:5], "big")
            if h < 1 or w < 1:
                raise FileFormatError(f"{where}: JPEG frame header gives a {h}x{w} image")
            if size is not None and h * w > _JPEG_PIXELS_PER_BYTE * size:
                raise FileFormatError(
                    f"{where}: JPEG frame header claims {h}x{w} pixels, more than its {size} "
                    "bytes can hold; the image is damaged"
                )
            return h, w
        if length < 2:
            raise FileFormatError(f"{where}: bad JPEG segment length {length}")
        skipped = f.read(length - 2)
        if len(skipped) < length - 2:
            raise FileFormatError(f"{where}: JPEG truncated")


def _hdr_size(f: IO[bytes], where: str, size: int | None = None) -> tuple[int, int]:
    """(height, width) of a Radiance file from its header only."""
    return hdr_size(f.read(65536), where, size)


def _member_size(
    zf: zipfile.ZipFile, info: zipfile.ZipInfo, kind: str, where: str
) -> tuple[int, int]:
    """An image member's (height, width) from its header; damaged members are named."""
    size_of = _hdr_size if kind == "hdr" else _jpeg_size
    try:
        with zf.open(info) as f:
            return size_of(f, where, info.file_size)
    except _ZIP_ERRORS as exc:
        raise FileFormatError(f"{where}: cannot read ({type(exc).__name__}: {exc})") from None


def _decode_jpeg(data: bytes, where: str) -> np.ndarray:
    """JPEG bytes → (H, W, 3) float32 linear RGB (inverse gamma 2.2)."""
    import imageio.v3 as iio

    try:
        u8 = np.asarray(iio.imread(data, extension=".jpg"))
    except MemoryError:
        raise
    except Exception as exc:
        raise FileFormatError(f"{where}: cannot decode JPEG ({exc})") from exc
    if u8.ndim == 2:
        u8 = np.repeat(u8[:, :, None], 3, axis=2)
    if u8.ndim != 3 or u8.shape[2] < 3:
        raise FileFormatError(f"{where}: JPEG has unsupported shape {u8.shape}")
    return ((u8[:, :, :3].astype(np.float32) / 255.0) ** GAMMA).astype(np.float32)


# ---------------------------------------------------------------------------------------------
# Reader
# ---------------------------------------------------------------------------------------------
def _parse_member(name: str, where: str) -> Angles:
    base = name.rsplit("/", 1)[-1]
    m = _NAME_RE.search(base)
    if m is None:
        raise FileFormatError(
            f"{where}: member {name!r}: file name does not parse as "
            "'tlAAA plBBB tvCCC pvDDD.ext' (integer degrees, space or underscore separated)"
        )
    vals = tuple(int(g) for g in m.groups())
    for field, val, lim in zip(("tl", "pl", "tv", "pv"), vals, (90, 359, 90, 359), strict=True):
        if val > lim:
            raise FileFormatError(
                f"{where}: member {name!r}: field {field} = {val}° is outside [0°, {lim}°]"
            )
    return vals  # type: ignore[return-value]


def _dirset(pairs: Sequence[tuple[int, int]], name: str) -> DirectionSet:
    arr = np.asarray(pairs, dtype=np.float64).reshape(-1, 2)
    return from_angles(np.radians(arr[:, 0]), np.radians(arr[:, 1]), name=name)


class UBO2003BTF(BTF):
    """A lazy BTF over a UBO2003 / ATRIUM zip: one image member per (light, view) pair.

    Attributes
    ----------
    path : the archive.
    kind : ``"jpeg"`` or ``"hdr"``.
    light_angles, view_angles : the (θ°, φ°) integer pairs of each light / view, in order.
    members : (L, V) array of member names.
    """

    def __init__(
        self,
        path: Path,
        kind: str,
        members: np.ndarray,
        light_angles: list[tuple[int, int]],
        view_angles: list[tuple[int, int]],
        size: tuple[int, int],
        cache_size: int = 8,
        name: str | None = None,
    ) -> None:
        super().__init__(
            size[0],
            size[1],
            _dirset(light_angles, "ubo2003-lights"),
            _dirset(view_angles, "ubo2003-views"),
            name=name or path.stem,
            attrs={"source": str(path), "format": f"ubo2003-{kind}"},
        )
        self.path = path
        self.kind = kind
        self.members = members
        self.light_angles = list(light_angles)
        self.view_angles = list(view_angles)
        self.cache_size = max(int(cache_size), 0)
        self._cache: OrderedDict[tuple[int, int], np.ndarray] = OrderedDict()
        self.decoded = 0  # number of images decoded so far (for tests / diagnostics)

    def image(self, light: int, view: int) -> np.ndarray:
        """The decoded (H, W, 3) float32 linear image of one (light, view) pair (cached)."""
        key = (int(light), int(view))
        hit = self._cache.get(key)
        if hit is not None:
            self._cache.move_to_end(key)
            return hit
        member = str(self.members[key])
        where = f"{self.path}: member {member!r}"
        try:
            with zipfile.ZipFile(self.path) as zf:
                info = zf.getinfo(member)
                check_allocation(info.file_size, where, FileFormatError)
                data = zf.read(info)
        except _ZIP_ERRORS as exc:
            raise FileFormatError(f"{where}: cannot read ({type(exc).__name__}: {exc})") from None
        # The header's size is checked before decoding: a damaged one must not allocate.
        size_of = _hdr_size if self.kind == "hdr" else _jpeg_size
        got = size_of(io.BytesIO(data), where, len(data))
        if got != (self.height, self.width):
            raise FileFormatError(
                f"{where}: image is {got[0]}x{got[1]}, the archive's images are "
                f"{self.height}x{self.width}"
            )
        if self.kind == "jpeg":
            check_allocation(got[0] * got[1] * _JPEG_BYTES_PER_PIXEL, where, FileFormatError)
        img = decode_rgbe(data, where) if self.kind == "hdr" else _decode_jpeg(data, where)
        if img.shape[:2] != (self.height, self.width):
            raise FileFormatError(
                f"{where}: image is {img.shape[0]}x{img.shape[1]}, "
                f"the archive's images are {self.height}x{self.width}"
            )
        self.decoded += 1
        if self.cache_size:
            self._cache[key] = img
            while len(self._cache) > self.cache_size:
                self._cache.popitem(last=False)
        return img

    def read(self, rows: Index, cols: Index, lights: Index, views: Index) -> np.ndarray:
        """Values at the outer product of the indices: (h, w, l, v, 3) float32."""
        r, c, li, vi = self.indices(rows, cols, lights, views)
        out = np.empty((r.size, c.size, li.size, vi.size, 3), dtype=np.float32)
        rc = np.ix_(r, c)
        for j, v in enumerate(vi):
            for i, lt in enumerate(li):
                out[:, :, i, j, :] = self.image(int(lt), int(v))[rc]
        return out


def read_ubo2003_zip(path: str | Path, cache_size: int = 8, check_sizes: bool = True) -> UBO2003BTF:
    """Open a UBO2003 / ATRIUM zip as a lazy :class:`UBO2003BTF`.

    Only member names (and, with ``check_sizes``, each image's header) are read here; pixels
    are decoded on demand. Members that are not ``.jpg``/``.jpeg``/``.hdr`` files are ignored.

    Raises
    ------
    FileFormatError : not a zip; an image member whose name does not parse; mixed JPEG and HDR
        members; a duplicate (θl, φl, θv, φv); a missing (light, view) pair; images of
        different sizes; a corrupt HDR header or JPEG.
    """
    p = Path(path)
    where = str(p)
    if p.exists() and not p.is_file():
        raise FileFormatError(f"{where}: not a regular file (a folder, FIFO or device)")
    try:
        zf = zipfile.ZipFile(p)
    except _ZIP_ERRORS as exc:
        raise FileFormatError(f"{where}: not a readable zip archive ({exc})") from None
    with zf:
        found: dict[Angles, str] = {}
        kinds: dict[str, str] = {}
        for info in zf.infolist():
            if not info.filename or info.filename.endswith("/"):
                continue
            ext = Path(info.filename).suffix.lower()
            if ext not in _IMAGE_EXT:
                continue
            angles = _parse_member(info.filename, where)
            kinds.setdefault(_IMAGE_EXT[ext], info.filename)
            if angles in found:
                raise FileFormatError(
                    f"{where}: duplicate image for (θl, φl, θv, φv) = {angles}: "
                    f"members {found[angles]!r} and {info.filename!r}"
                )
            found[angles] = info.filename
        if not found:
            raise FileFormatError(f"{where}: no .jpg or .hdr image members")
        if len(kinds) > 1:
            raise FileFormatError(
                f"{where}: mixes JPEG and HDR members ({kinds['jpeg']!r}, {kinds['hdr']!r})"
            )
        kind = next(iter(kinds))
        lights = sorted({(a[0], a[1]) for a in found})
        views = sorted({(a[2], a[3]) for a in found})
        missing = [(*lt, *vw) for vw in views for lt in lights if (*lt, *vw) not in found]
        if missing:
            shown = ", ".join(str(m) for m in missing[:5])
            more = f" and {len(missing) - 5} more" if len(missing) > 5 else ""
            raise FileFormatError(
                f"{where}: {len(missing)} of {len(lights) * len(views)} images missing for "
                f"(θi, φi, θv, φv) = {shown}{more}"
            )
        members = np.empty((len(lights), len(views)), dtype=object)
        for i, lt in enumerate(lights):
            for j, vw in enumerate(views):
                members[i, j] = found[(*lt, *vw)]
        first = str(members[0, 0])
        size = _member_size(zf, zf.getinfo(first), kind, f"{where}: member {first!r}")
        if check_sizes:
            for name in members.ravel():
                s = _member_size(zf, zf.getinfo(str(name)), kind, f"{where}: member {name!r}")
                if s != size:
                    raise FileFormatError(
                        f"{where}: member {name!r} is {s[0]}x{s[1]} but member {first!r} is "
                        f"{size[0]}x{size[1]}; all images must have the same size"
                    )
    return UBO2003BTF(p, kind, members, lights, views, size, cache_size=cache_size)


# ---------------------------------------------------------------------------------------------
# Writer (synthetic archives for tests)
# ---------------------------------------------------------------------------------------------
def _int_angles(ds: DirectionSet, what: str) -> list[tuple[int, int]]:
    """Integer-degree (θ, φ ∈ [0, 360)) pairs of a set; refuses non-integer angles."""
    th = np.degrees(ds.theta)
    ph = np.mod(np.degrees(ds.phi), 360.0)
    out = []
    for k, (t, f) in enumerate(zip(th, ph, strict=True)):
        ti, fi = round(t), round(f) % 360
        if abs(t - ti) > 1e-6 or min(abs(f - fi), 360 - abs(f - fi)) > 1e-6:
            raise BTFInputError(
                f"{what} direction {k} ({t:.4f}°, {f:.4f}°) is not at integer degrees; "
                "UBO2003 names store integer angles"
            )
        out.append((ti, fi))
    if len(set(out)) != len(out):
        raise BTFInputError(f"{what} directions repeat at integer-degree precision")
    return out


def _encode_jpeg(img: np.ndarray, quality: int) -> bytes:
    import imageio.v3 as iio

    u8 = np.round(np.clip(img, 0.0, 1.0) ** (1.0 / GAMMA) * 255.0).astype(np.uint8)
    return bytes(iio.imwrite("<bytes>", u8, extension=".jpg", quality=quality, subsampling=0))


def write_ubo2003_zip(
    path: str | Path,
    data: np.ndarray,
    lights: DirectionSet,
    views: DirectionSet,
    kind: str = "jpeg",
    *,
    rle: bool = True,
    order: str = "-Y +X",
    quality: int = 100,
    sep: str = " ",
    prefix: str = "MAT",
    exposure: float | None = None,
) -> Path:
    """Write an (H, W, L, V, 3) linear array as a UBO2003 (``jpeg``) or ATRIUM (``hdr``) zip.

    Members are named ``{prefix}/tv{θv:03d}_pv{φv:03d}/{view:05d}{sep}tl…{sep}pv….ext``.
    JPEGs are gamma-encoded (1/2.2) 8-bit at ``quality`` without chroma subsampling; HDR
    members use :func:`encode_rgbe` with ``rle``, ``order`` and ``exposure``. Angles must be
    integer degrees. Returns the path.
    """
    arr = np.asarray(data, dtype=np.float64)
    if arr.ndim != 5 or arr.shape[4] != 3:
        raise BTFInputError(f"data must have shape (H, W, L, V, 3), got {arr.shape}")
    if arr.shape[2] != len(lights) or arr.shape[3] != len(views):
        raise BTFInputError(
            f"data has {arr.shape[2]} lights x {arr.shape[3]} views, the direction sets "
            f"{len(lights)} x {len(views)}"
        )
    if kind not in ("jpeg", "hdr"):
        raise BTFInputError(f"kind must be 'jpeg' or 'hdr', got {kind!r}")
    if sep not in (" ", "_"):
        raise BTFInputError(f"sep must be ' ' or '_', got {sep!r}")
    la, va = _int_angles(lights, "light"), _int_angles(views, "view")
    ext = "jpg" if kind == "jpeg" else "hdr"
    p = Path(path)
    with zipfile.ZipFile(p, "w", compression=zipfile.ZIP_STORED) as zf:
        for j, (tv, pv) in enumerate(va):
            folder = f"{prefix}/tv{tv:03d}_pv{pv:03d}" if prefix else f"tv{tv:03d}_pv{pv:03d}"
            for i, (tl, pl) in enumerate(la):
                fname = sep.join(
                    (f"{j:05d}", f"tl{tl:03d}", f"pl{pl:03d}", f"tv{tv:03d}", f"pv{pv:03d}")
                )
                img = arr[:, :, i, j, :]
                blob = (
                    _encode_jpeg(img, quality)
                    if kind == "jpeg"
                    else encode_rgbe(img, rle=rle, order=order, exposure=exposure)
                )
                zf.writestr(f"{folder}/{fname}.{ext}", blob)
    return p
