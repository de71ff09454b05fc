"""Bonn UBO2003 and ATRIUM BTF zip archives as lazy BTFs.

Layout: ``shared/specs/ubo-btf-format.md`` §3. An archive holds one image per (light, view)
pair, named ``…/tv{θv:03d}_pv{φv:03d}/{index:05d} tl{θl:03d} pl{φl:03d} tv{θv:03d}
pv{φv:03d}.{jpg|hdr}`` with integer-degree angles and a single space (or underscore) between
fields. Directory prefixes and the 5-digit counter are ignored; the angles are taken from the
``tl``/``pl``/``tv``/``pv`` fields of the base name, and the light and view sets are the
distinct angle pairs found, each ordered by (θ, φ) with φ in [0°, 360°).

* ``.jpg`` members (UBO2003, ATRIUM LDR): 8-bit gamma-encoded RGB, converted to linear with
  an inverse gamma of 2.2, ``(u / 255) ** 2.2``.
* ``.hdr`` members (ATRIUM HDR): Radiance RGBE, decoded here in numpy: magic line, ``KEY=value``
  lines up to a blank line, a resolution line in any of the 8 orders, flat or new-style RLE
  scanlines. ``f = m · 2^(e − 136)`` (no +0.5, like FreeImage), divided by ``EXPOSURE`` when the
  header has one. Images are returned with row 0 at the top and column 0 at the left per the
  Radiance convention (``-Y H +X W`` is the standard order); BX's 256×256-only header hack is
  not reproduced (its output equals ``np.rot90`` of ours for ``+X 256 -Y 256`` files).

Images are decoded only when a read needs them; the last few decoded images are cached.
"""

from __future__ import annotations

import re
import zipfile
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path
from typing import IO

import numpy as np

from ..data.btf import BTF, Index
from ..data.directions import DirectionSet, from_angles
from ..errors import BTFInputError, FileFormatError

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
_RES_RE = re.compile(rb"^([-+])([XY]) (\d+) ([-+])([XY]) (\d+)$")

Angles = tuple[int, int, int, int]


# ---------------------------------------------------------------------------------------------
# Radiance RGBE
# ---------------------------------------------------------------------------------------------
def _rgbe_to_float(rgbe: np.ndarray) -> np.ndarray:
    """(..., 4) uint8 RGBE → (..., 3) float32 with f = m·2^(e−136), 0 where e = 0."""
    e = rgbe[..., 3].astype(np.int32)
    scale = np.where(e > 0, np.ldexp(1.0, e - 136), 0.0)
    return (rgbe[..., :3].astype(np.float64) * scale[..., None]).astype(np.float32)


def _float_to_rgbe(img: np.ndarray) -> np.ndarray:
    """(..., 3) non-negative floats → (..., 4) uint8 RGBE (mantissa truncated, like rgbe.c)."""
    x = np.maximum(np.asarray(img, dtype=np.float64), 0.0)
    v = x.max(axis=-1)
    m, e = np.frexp(v)
    ok = v >= 1e-32
    scale = np.where(ok, m * 256.0 / np.where(ok, v, 1.0), 0.0)
    out = np.zeros((*x.shape[:-1], 4), dtype=np.uint8)
    out[..., :3] = np.clip(np.floor(x * scale[..., None]), 0, 255).astype(np.uint8)
    out[..., 3] = np.where(ok, np.clip(e + 128, 0, 255), 0).astype(np.uint8)
    return out


def _parse_resolution(line: bytes, where: str) -> tuple[str, str, int, str, str, int]:
    """Parse ``-Y 256 +X 256`` style lines: (sign1, axis1, n1, sign2, axis2, n2)."""
    m = _RES_RE.match(line.strip())
    if m is None or m.group(2) == m.group(5):
        raise FileFormatError(f"{where}: bad Radiance resolution line {line[:40]!r}")
    s1, a1, n1, s2, a2, n2 = m.groups()
    if int(n1) < 1 or int(n2) < 1:
        raise FileFormatError(f"{where}: resolution line {line[:40]!r} has a zero size")
    return s1.decode(), a1.decode(), int(n1), s2.decode(), a2.decode(), int(n2)


def _read_header(buf: bytes, where: str) -> tuple[dict[str, str], float, tuple, int]:
    """Parse a Radiance header: (KEY=value dict, exposure, resolution tuple, data offset)."""
    pos = 0

    def line() -> bytes:
        nonlocal pos
        end = buf.find(b"\n", pos)
        if end < 0:
            raise FileFormatError(f"{where}: Radiance header is truncated (no end of line)")
        out = buf[pos:end]
        pos = end + 1
        return out

    magic = line().rstrip(b"\r")
    if magic not in (b"#?RADIANCE", b"#?RGBE"):
        raise FileFormatError(
            f"{where}: not a Radiance HDR file (magic {magic[:16]!r}, "
            "expected '#?RADIANCE' or '#?RGBE')"
        )
    keys: dict[str, str] = {}
    exposure = 1.0
    for _ in range(10000):
        text = line().rstrip(b"\r")
        if not text.strip():
            break
        if text.startswith(b"#"):
            continue
        if b"=" not in text:
            raise FileFormatError(f"{where}: bad Radiance header line {text[:40]!r}")
        k, v = text.decode("latin-1").split("=", 1)
        k, v = k.strip(), v.strip()
        keys[k] = v
        if k == "EXPOSURE":
            try:
                exposure *= float(v)
            except ValueError as exc:
                raise FileFormatError(
                    f"{where}: header field EXPOSURE={v!r} is not a number"
                ) from exc
            if not exposure > 0:
                raise FileFormatError(f"{where}: header field EXPOSURE={v!r} must be positive")
    else:
        raise FileFormatError(f"{where}: Radiance header has no end (no blank line)")
    fmt = keys.get("FORMAT", "32-bit_rle_rgbe")
    if fmt != "32-bit_rle_rgbe":
        raise FileFormatError(f"{where}: header field FORMAT={fmt!r} is not 32-bit_rle_rgbe")
    res = _parse_resolution(line().rstrip(b"\r"), where)
    return keys, exposure, res, pos


def _orient(raw: np.ndarray, res: tuple) -> np.ndarray:
    """Map scanline-ordered pixels (n_slow, n_fast, c) to image order (row top, col left)."""
    s1, a1, _, s2, _, _ = res
    if a1 == "X":  # scanlines are columns
        raw = raw.transpose(1, 0, 2)
        ys, xs = s2, s1
    else:
        ys, xs = s1, s2
    if ys == "+":  # increasing Y: bottom row first
        raw = raw[::-1]
    if xs == "-":  # decreasing X: right column first
        raw = raw[:, ::-1]
    return raw


def decode_rgbe(data: bytes, where: str = "<hdr>") -> np.ndarray:
    """Decode a Radiance ``.hdr`` file to (H, W, 3) float32 linear RGB (top row first)."""
    _, exposure, res, pos = _read_header(data, where)
    n_slow, n_fast = res[2], res[5]
    buf = np.frombuffer(data, dtype=np.uint8)
    out = np.empty((n_slow, n_fast, 4), dtype=np.uint8)
    for s in range(n_slow):
        head = buf[pos : pos + 4]
        if head.size < 4:
            raise FileFormatError(f"{where}: pixel data truncated at scanline {s} of {n_slow}")
        rle = 8 <= n_fast < 32768 and head[0] == 2 and head[1] == 2 and head[2] < 128
        if not rle:
            end = pos + 4 * n_fast
            if end > buf.size:
                raise FileFormatError(f"{where}: pixel data truncated at scanline {s} of {n_slow}")
            out[s] = buf[pos:end].reshape(n_fast, 4)
            pos = end
            continue
        width = (int(head[2]) << 8) | int(head[3])
        if width != n_fast:
            raise FileFormatError(f"{where}: RLE scanline {s} has width {width}, expected {n_fast}")
        pos += 4
        for ch in range(4):
            i = 0
            row = out[s, :, ch]
            while i < n_fast:
                if pos >= buf.size:
                    raise FileFormatError(f"{where}: RLE data truncated at scanline {s}")
                count = int(buf[pos])
                pos += 1
                if count > 128:
                    count -= 128
                    if i + count > n_fast or pos >= buf.size:
                        raise FileFormatError(f"{where}: bad RLE run in scanline {s}")
                    row[i : i + count] = buf[pos]
                    pos += 1
                else:
                    if count == 0 or i + count > n_fast or pos + count > buf.size:
                        raise FileFormatError(f"{where}: bad RLE run in scanline {s}")
                    row[i : i + count] = buf[pos : pos + count]
                    pos += count
                i += count
    img = _orient(_rgbe_to_float(out), res)
    if exposure != 1.0:
        img = img / np.float32(exposure)
    return np.ascontiguousarray(img, dtype=np.float32)


def _rle_channel(values: np.ndarray) -> bytes:
    """New-style RLE of one channel of one scanline (runs ≥ 4 coded as runs)."""
    out = bytearray()
    n = values.size
    i = 0
    while i < n:
        j = i
        while j < n and j - i < 127 and values[j] == values[i]:
            j += 1
        if j - i >= 4:
            out += bytes((128 + j - i, int(values[i])))
            i = j
            continue
        # literal run until the next run of ≥ 4 or 128 bytes
        k = i
        while k < n and k - i < 128:
            r = k
            while r < n and r - k < 4 and values[r] == values[k]:
                r += 1
            if r - k >= 4:
                break
            k += 1
        out += bytes((k - i,)) + values[i:k].tobytes()
        i = k
    return bytes(out)


def encode_rgbe(
    img: np.ndarray, rle: bool = True, order: str = "-Y +X", exposure: float | None = None
) -> bytes:
    """Encode (H, W, 3) non-negative floats as a Radiance ``.hdr`` file.

    ``order`` is the resolution line's axis order, e.g. ``"-Y +X"`` (standard) or ``"+X -Y"``;
    pixels are laid out so :func:`decode_rgbe` returns ``img``. ``rle`` selects new-style RLE
    scanlines (only possible for scanline lengths 8..32767; flat otherwise). ``exposure`` is
    written as ``EXPOSURE=`` and the stored values are multiplied by it.
    """
    a = np.asarray(img, dtype=np.float64)
    if a.ndim != 3 or a.shape[2] != 3:
        raise BTFInputError(f"HDR image must have shape (H, W, 3), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise BTFInputError("HDR image values must be finite")
    parts = order.split()
    if (
        len(parts) != 2
        or {p[1:] for p in parts} != {"X", "Y"}
        or any(p[0] not in "+-" for p in parts)
    ):
        raise BTFInputError(f"resolution order must be like '-Y +X', got {order!r}")
    h, w = a.shape[:2]
    if exposure is not None:
        a = a * exposure
    sizes = {"Y": h, "X": w}
    res = (
        parts[0][0],
        parts[0][1],
        sizes[parts[0][1]],
        parts[1][0],
        parts[1][1],
        sizes[parts[1][1]],
    )
    # Inverse of _orient.
    raw = a
    s1, a1, _, s2, _, _ = res
    ys, xs = (s2, s1) if a1 == "X" else (s1, s2)
    if xs == "-":
        raw = raw[:, ::-1]
    if ys == "+":
        raw = raw[::-1]
    if a1 == "X":
        raw = raw.transpose(1, 0, 2)
    rgbe = _float_to_rgbe(raw)
    head = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n"
    if exposure is not None:
        head += f"EXPOSURE={exposure!r}\n".encode()
    head += f"\n{res[0]}{res[1]} {res[2]} {res[3]}{res[4]} {res[5]}\n".encode()
    body = bytearray(head)
    n_fast = rgbe.shape[1]
    for s in range(rgbe.shape[0]):
        if rle and 8 <= n_fast < 32768:
            body += bytes((2, 2, n_fast >> 8, n_fast & 255))
            for ch in range(4):
                body += _rle_channel(np.ascontiguousarray(rgbe[s, :, ch]))
        else:
            body += rgbe[s].tobytes()
    return bytes(body)


# ---------------------------------------------------------------------------------------------
# Image sizes without decoding
# ---------------------------------------------------------------------------------------------
def _jpeg_size(f: IO[bytes], where: str) -> tuple[int, int]:
    """(height, width) from a JPEG's SOF marker, reading only the segment headers."""
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
            return int.from_bytes(sof[1:3], "big"), int.from_bytes(sof[3:5], "big")
        if length < 2:
            raise FileFormatError(f"{where}: bad JPEG segment length {length}")
        skipped = f.read(length - 2)
        if len(skipped) < length - 2:
            raise FileFormatError(f"{where}: JPEG truncated")


def _hdr_size(f: IO[bytes], where: str) -> tuple[int, int]:
    """(height, width) of a Radiance file from its header only."""
    data = f.read(65536)
    res = _read_header(data, where)[2]
    sizes = {res[1]: res[2], res[4]: res[5]}
    return sizes["Y"], sizes["X"]


def _decode_jpeg(data: bytes, where: str) -> np.ndarray:
    """JPEG bytes → (H, W, 3) float32 linear RGB (inverse gamma 2.2)."""
    import imageio.v3 as iio

    try:
        u8 = np.asarray(iio.imread(data, extension=".jpg"))
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
                data = zf.read(member)
        except (OSError, zipfile.BadZipFile, KeyError) as exc:
            raise FileFormatError(f"{where}: cannot read ({exc})") from exc
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
    try:
        zf = zipfile.ZipFile(p)
    except (OSError, zipfile.BadZipFile) as exc:
        raise FileFormatError(f"{where}: not a readable zip archive ({exc})") from exc
    with zf:
        found: dict[Angles, str] = {}
        kinds: dict[str, str] = {}
        for info in zf.infolist():
            if info.is_dir():
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
        size_of = _hdr_size if kind == "hdr" else _jpeg_size
        first = str(members[0, 0])
        with zf.open(first) as f:
            size = size_of(f, f"{where}: member {first!r}")
        if check_sizes:
            for name in members.ravel():
                with zf.open(str(name)) as f:
                    s = size_of(f, f"{where}: member {name!r}")
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
