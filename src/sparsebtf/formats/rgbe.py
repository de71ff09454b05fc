"""Radiance RGBE (``.hdr``) images in numpy: the ATRIUM HDR members of UBO2003-style zips.

Format (``shared/specs/ubo-btf-format.md`` §3.3): a magic line (``#?RADIANCE`` or ``#?RGBE``),
``KEY=value`` lines up to a blank line, a resolution line of two ``±Y/±X n`` pairs in any of the
8 orders, then flat or new-style RLE scanlines (each starting with bytes 2, 2 and a big-endian
15-bit width). ``f = m · 2^(e − 136)`` (no +0.5, like FreeImage), divided by ``EXPOSURE`` when
the header has one. Images come back with row 0 at the top and column 0 at the left.

The decoder checks the resolution against the bytes present (:func:`min_encoded_bytes`: even
run-length coded, a scanline of n pixels takes at least 4 + 8·⌈n/127⌉ bytes) and against the
memory budget before it allocates anything.
"""

from __future__ import annotations

import re

import numpy as np

from .._limits import check_allocation
from ..errors import BTFInputError, FileFormatError

__all__ = ["decode_rgbe", "encode_rgbe", "hdr_size", "min_encoded_bytes", "read_header"]

_RES_RE = re.compile(rb"^([-+])([XY]) (\d{1,9}) ([-+])([XY]) (\d{1,9})$")
#: Largest side accepted (Radiance's RLE width field has 15 bits; flat files are not bounded,
#: but no measured BTF image comes near this).
_MAX_SIDE = 1 << 20
#: Bytes per pixel the decoder holds at once (RGBE bytes, float64 and float32 RGB).
_DECODE_BYTES_PER_PIXEL = 4 + 24 + 8 + 12


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
    if not (1 <= int(n1) <= _MAX_SIDE and 1 <= int(n2) <= _MAX_SIDE):
        raise FileFormatError(
            f"{where}: resolution line {line[:40]!r}: each size must be in 1..{_MAX_SIDE}"
        )
    return s1.decode(), a1.decode(), int(n1), s2.decode(), a2.decode(), int(n2)


def read_header(buf: bytes, where: str) -> tuple[dict[str, str], float, tuple, int]:
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
            if not (exposure > 0 and np.isfinite(exposure)):
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
    _, exposure, res, pos = read_header(data, where)
    n_slow, n_fast = res[2], res[5]
    need = min_encoded_bytes(n_slow, n_fast)
    if len(data) - pos < need:
        raise FileFormatError(
            f"{where}: pixel data truncated: resolution {n_slow}x{n_fast} needs at least {need} "
            f"bytes, the file has {len(data) - pos} (a damaged header or a truncated file)"
        )
    check_allocation(
        n_slow * n_fast * _DECODE_BYTES_PER_PIXEL, f"{where}: decoding", FileFormatError
    )
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


def min_encoded_bytes(n_slow: int, n_fast: int) -> int:
    """Fewest pixel-data bytes ``n_slow`` scanlines of ``n_fast`` pixels can take: flat
    scanlines take 4 bytes a pixel; new-style RLE (8 ≤ n_fast < 32768) at least a 4-byte head
    and, per channel, one 2-byte run per 127 pixels."""
    flat = 4 * n_fast
    rle = 4 + 4 * 2 * -(-n_fast // 127) if 8 <= n_fast < 32768 else flat
    return n_slow * min(flat, rle)


def hdr_size(data: bytes, where: str, size: int | None = None) -> tuple[int, int]:
    """(height, width) of a Radiance file from its header (the first bytes of the file).

    ``size`` is the file's full length: a resolution that length cannot hold is refused.
    """
    _, _, res, pos = read_header(data, where)
    if size is not None:
        need = min_encoded_bytes(res[2], res[5])
        if size - pos < need:
            raise FileFormatError(
                f"{where}: resolution line claims {res[2]}x{res[5]} pixels, which need at "
                f"least {need} bytes, but the image has {size - pos} bytes after its header"
            )
    sizes = {res[1]: res[2], res[4]: res[5]}
    return sizes["Y"], sizes["X"]

