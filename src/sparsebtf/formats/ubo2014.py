"""Bonn UBO2014 ``.btf`` files (DFMF and FMF layouts) as lazy, memory-mapped BTFs.

Byte layout: ``shared/specs/ubo-btf-format.md`` §1. A file is a magic string, a meta-data
block of ``Size`` bytes, the direction table (one light list per view), the spatial size with
an optional rotations block (magic ending in ``R``), and a low-rank payload:

* ``!DFMF08FC[R]`` — one SVD per decorrelated channel (U_c: nL·nV × K_c, SxV_c: W·H × K_c),
  decoded through a colour model (UBO2014: 11, ``Ylog_UdivY_VdivY``).
* ``!FMF12FCE[R]`` / ``!FMF06FC[R]`` — one SVD for all RGB channels (U: 3·nL·nV × K, rows
  ``lv·3 + c``; SxV: W·H × K shared), optionally in the log domain (DRR) with a height map.

Angular index ``lv = view·nL + light`` (view-major, §1.10.1). Pixel convention: the file's
spatial index is ``xy = row·W + col`` with storage row 0 the top of the image (§1.10.1,
§1.10.6), so ``(row, col) = divmod(xy, W)`` — exactly our BTF's (row, col); no flip is applied
(btf-extractor's output is the vertical flip, in BGR order, of what we return).

Factors are ``np.memmap`` views of the file: an angular image or a patch touches only the
rows of U and SxV it needs, and products are summed in float32 (float64 for double files).
"""

from __future__ import annotations

import os
import struct
import threading
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from .._limits import memory_budget
from .._semantic import check_color_header, check_directions
from .._threads import thread_buffer
from ..colour import YUV_TO_RGB_RELEASE
from ..data.btf import BTF, RELEASE_LOG_OFFSET, Index, contiguous_slice
from ..data.directions import from_angles
from ..errors import BTFInputError, FileFormatError

__all__ = ["COLOR_MODELS", "UBO2014BTF", "read_ubo2014"]

# Longest first: "!DFMF08FC" is a prefix of "!DFMF08FCR" (§1.2).
_MAGICS: dict[bytes, tuple[str, bool, bool]] = {
    # magic: (layout, rotations present, FMF extended header present)
    b"!DFMF08FCR": ("DFMF", True, False),
    b"!FMF12FCER": ("FMF", True, True),
    b"!DFMF08FC": ("DFMF", False, False),
    b"!FMF12FCE": ("FMF", False, True),
    b"!FMF06FCR": ("FMF", True, False),
    b"!FMF06FC": ("FMF", False, False),
}

_SCALARS = {2: np.dtype("<f2"), 4: np.dtype("<f4"), 8: np.dtype("<f8")}
_DTYPE_NAMES = {"half": 2, "float": 4, "double": 8}

#: Colour models this reader decodes (BL's enum, §1.10.3). 2 (LAB), 5, 6 (spectral) are not.
COLOR_MODELS = {
    0: "SIMPLE",
    1: "YUV",
    3: "PCA",
    4: "YCoCg",
    9: "Ylog_UV",
    10: "Ylog_Ulog_Vlog",
    11: "Ylog_UdivY_VdivY",
    12: "SIMPLE_LOG",
}

# BT.601 analogue YUV → RGB, rows R, G, B (§1.10.3): Bonn's decoders use the same rounded
# inverse as the release's shader.
_YUV2RGB = YUV_TO_RGB_RELEASE

_META_BASE = 264  # Size of a version-1 meta block (§1.3)


class _Cursor:
    """Sequential little-endian reads with bounds checks that name the file and the field."""

    def __init__(self, f: BinaryIO, path: Path, size: int, pos: int = 0) -> None:
        self.f, self.path, self.size, self.pos = f, path, size, pos

    def take(self, n: int, field: str) -> bytes:
        self.skip(n, field)
        self.f.seek(self.pos - n)
        return self.f.read(n)

    def skip(self, n: int, field: str) -> int:
        """Advance past ``n`` bytes (a payload block); returns the block's start offset."""
        if n < 0 or self.pos + n > self.size:
            raise FileFormatError(
                f"{self.path}: truncated: field {field!r} at byte {self.pos} needs {n} bytes "
                f"but the file has {self.size} bytes"
            )
        start = self.pos
        self.pos += n
        return start

    def u8(self, field: str) -> int:
        return self.take(1, field)[0]

    def u32(self, field: str) -> int:
        return int(struct.unpack("<I", self.take(4, field))[0])

    def i32(self, field: str) -> int:
        return int(struct.unpack("<i", self.take(4, field))[0])

    def f32s(self, n: int, field: str) -> np.ndarray:
        return np.frombuffer(self.take(4 * n, field), dtype="<f4").astype(np.float64)


def _text(raw: bytes) -> str:
    return raw.split(b"\0", 1)[0].decode("latin-1")


def _factor(path: Path, offset: int, dtype: np.dtype, rows: int, k: int) -> np.ndarray:
    """A read-only memory map of a row-major (rows × k) matrix at ``offset``."""
    if rows * k == 0:  # np.memmap refuses empty maps
        return np.zeros((rows, k), dtype=dtype)
    return np.memmap(path, dtype=dtype, mode="r", offset=offset, shape=(rows, k))


def _rows(m: np.ndarray, idx: np.ndarray, dt: np.dtype) -> np.ndarray:
    """Rows ``idx`` of a (memory-mapped) factor, as ``dt``; a slice when contiguous (fast)."""
    sp = contiguous_slice(idx)
    return np.asarray(m[sp] if sp is not None else m[idx], dtype=dt)


class UBO2014BTF(BTF):
    """A lazy BTF over a UBO2014 ``.btf`` file (see :func:`read_ubo2014`).

    Attributes beyond :class:`BTF`'s: ``layout`` ("DFMF" or "FMF"), ``color_model`` (DFMF),
    ``drr`` (FMF log domain), ``height_map`` ((hmH, hmW) float32 or None), ``cosine_flag``,
    ``divide_cosine``, ``factors`` (per channel (U, SxV) memmaps for DFMF; one (U, SxV) pair
    for FMF), ``color_mean`` and ``color_transform`` (DFMF colour model 3).
    """

    layout: str
    color_model: int | None
    drr: bool
    height_map: np.ndarray | None
    color_mean: np.ndarray | None
    color_transform: np.ndarray | None
    cosine_flag: int
    divide_cosine: bool
    factors: list[tuple[np.ndarray, np.ndarray]]
    ranks: list[int]
    _acc: np.dtype

    def read(self, rows: Index, cols: Index, lights: Index, views: Index) -> np.ndarray:
        """Decoded linear RGB at the outer product of the indices: (h, w, l, v, 3) float32.

        Factors that overflow (a damaged payload) give Inf/NaN values, which consumers report
        (``info`` counts them, ``write_dense`` refuses them), without numpy warnings here.
        """
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return self._read(rows, cols, lights, views)

    def _read(self, rows: Index, cols: Index, lights: Index, views: Index) -> np.ndarray:
        r, c, li, vi = self.indices(rows, cols, lights, views)
        w, nl, nv = self.width, len(self.lights), len(self.views)
        pix = (r[:, None] * w + c[None, :]).ravel()
        # Light outer, view inner, so the result reshapes to (l, v); file index is v·nL + l.
        ang = (vi[None, :] * nl + li[:, None]).ravel()
        mine = (li[:, None] * nv + vi[None, :]).ravel()  # the same rows, light-major
        q = np.empty((pix.size, ang.size, 3), dtype=self._acc)
        # exp(·) − offset channel by channel on the way into q, where the colour model maps
        # each channel alone (DFMF 12; FMF's DRR, whose offset, Bonn's drr_eps, is
        # hard-coded by their decoders, not stored): one pass instead of three and no
        # temporaries of the whole patch
        per_channel = (self.color_model == 12) if self.layout == "DFMF" else self.drr
        local = self.__dict__.setdefault("_local", threading.local())
        val = (thread_buffer(local, pix.size * ang.size, self._acc).reshape(pix.size, ang.size)
               if per_channel else None)  # fmt: skip
        spatial: dict[int, np.ndarray] = {}  # FMF: one spatial factor for the three channels
        for ch in range(3):
            # DFMF: factor pair ch, rows view·L + light; FMF: pair 0, rows (view·L + light)·3 + ch
            k, at, stride = (ch, 0, 1) if self.layout == "DFMF" else (0, ch, 3)
            a = self._angular(k, at, stride, ang, mine)
            if k not in spatial:
                spatial[k] = _rows(self.factors[k][1], pix, self._acc)
            if val is None:
                q[..., ch] = spatial[k] @ a.T
                continue
            np.matmul(spatial[k], a.T, out=val)
            np.exp(val, out=val)
            np.subtract(val, RELEASE_LOG_OFFSET, out=q[..., ch])
        rgb = self._color_inverse(q) if self.layout == "DFMF" and not per_channel else q
        out = rgb.reshape(r.size, c.size, li.size, vi.size, 3)
        if self.divide_cosine:
            # BL removes the foreshortening term when the file says it is baked in (§1.10.5).
            out = out / self.lights.xyz[li, 2][None, None, :, None, None]
        return np.asarray(out, dtype=np.float32)

    def _angular(self, k: int, ch: int, stride: int, ang: np.ndarray, mine: np.ndarray
                 ) -> np.ndarray:  # fmt: skip
        """Angular factor ``k``'s rows of channel ``ch`` for the directions ``ang`` (file
        rows (view·L + light)·stride + ch) = ``mine`` (light·V + view), in the sums' dtype.

        The factor's rows of the channel are kept, light-major and converted, once read: a
        data point needs every direction, which in the file's view-major order is a gather
        of every row of the memory map and a conversion from binary16, per read and channel
        (a third of reading a DFMF patch). When that copy would take more than a sixteenth
        of the memory budget the rows are gathered from the file per read."""
        u = self.factors[k][0]
        cache = self.__dict__.setdefault("_angular_rows", {})
        have = cache.get((k, ch))
        if have is None:
            nl, nv = len(self.lights), len(self.views)
            if nl * nv * u.shape[1] * self._acc.itemsize > memory_budget() // 16:
                return _rows(u, ang * stride + ch, self._acc)
            rows = (np.arange(nv)[None, :] * nl + np.arange(nl)[:, None]).ravel() * stride + ch
            # two threads may both convert the first time: the same values, one kept
            have = cache.setdefault((k, ch), np.asarray(u[rows], dtype=self._acc))
        return _rows(have, mine, self._acc)

    def __getstate__(self) -> dict[str, Any]:
        # the converted rows are read again where the object lands; the threads' buffers
        # stay behind (a thread-local does not pickle)
        return {k: v for k, v in self.__dict__.items() if k not in ("_angular_rows", "_local")}

    def _color_inverse(self, q: np.ndarray) -> np.ndarray:
        """DFMF colour model → RGB (§1.10.3), Bonn's BL form (no clamping); model 12
        (exp(·) − offset on each channel) is applied channel by channel in :meth:`_read`."""
        m = self.color_model
        if m == 0:
            return q
        if m == 3:
            t = np.asarray(self.color_transform, dtype=q.dtype)
            return q @ t + np.asarray(self.color_mean, dtype=q.dtype)
        if m == 4:
            y, co, cg = q[..., 0], q[..., 1], q[..., 2]
            return np.stack([y + co - cg, y + cg, y - co - cg], axis=-1)
        if m == 1:
            yuv = q
        else:
            y = np.exp(q[..., 0]) - RELEASE_LOG_OFFSET
            if m == 9:
                u, v = q[..., 1], q[..., 2]
            elif m == 10:
                u = np.sign(q[..., 1]) * RELEASE_LOG_OFFSET * np.exp(np.abs(q[..., 1]))
                v = np.sign(q[..., 2]) * RELEASE_LOG_OFFSET * np.exp(np.abs(q[..., 2]))
            else:  # 11: U and V were divided by (Y + offset) before the SVD
                u, v = q[..., 1] * (y + RELEASE_LOG_OFFSET), q[..., 2] * (y + RELEASE_LOG_OFFSET)
            yuv = np.stack([y, u, v], axis=-1)
        return yuv @ _YUV2RGB.T.astype(q.dtype)


def read_ubo2014(path: str | os.PathLike[str], divide_cosine: bool = False) -> UBO2014BTF:
    """Open a UBO2014 ``.btf`` file as a lazy BTF; nothing beyond the headers is read.

    Parameters
    ----------
    path : the ``.btf`` file (``!DFMF08FC[R]``, ``!FMF12FCE[R]`` or ``!FMF06FC[R]``).
    divide_cosine : divide values by cos θ_light when the header's cosine flag is set (Bonn's
        MATLAB decoder does; btf-extractor never does, hence off by default).

    Returns
    -------
    A :class:`UBO2014BTF` whose light and view sets are the file's own tables, in file order.

    Raises
    ------
    FileFormatError : wrong magic, bad header ``Size``/version, unsupported colour model or scalar
        size, inconsistent direction or matrix counts, truncated payload or trailing bytes.
    """
    p = Path(path)
    try:
        fsize = p.stat().st_size
        f = p.open("rb")
    except OSError as e:
        raise FileFormatError(f"{p}: cannot open ({e})") from None
    with f:
        return _parse(f, p, fsize, divide_cosine)


def _parse(f: BinaryIO, p: Path, fsize: int, divide_cosine: bool) -> UBO2014BTF:
    head = f.read(10)
    candidates = [m for m in _MAGICS if head.startswith(m)]
    if not candidates:
        raise FileFormatError(
            f"{p}: field 'magic' is {head[:10]!r}, not a UBO2014 DFMF/FMF signature "
            "(!DFMF08FC[R], !FMF12FCE[R], !FMF06FC[R])"
        )
    # The optional "R" is ambiguous: without rotations, the byte after the magic is the low
    # byte of Size, which is "R" (0x52) when Size ≡ 82 mod 256. Try the longest match first
    # (what the C++ library does), then the shorter one; report the first failure.
    first: FileFormatError | None = None
    for magic in candidates:
        try:
            return _parse_as(f, p, fsize, divide_cosine, magic)
        except FileFormatError as e:
            first = first or e
    assert first is not None
    raise first


def _parse_as(f: BinaryIO, p: Path, fsize: int, divide_cosine: bool, magic: bytes) -> UBO2014BTF:
    layout, has_rot, extended = _MAGICS[magic]
    cur = _Cursor(f, p, fsize, len(magic))
    attrs: dict[str, Any] = {"source": str(p), "magic": magic.decode(), "layout": layout}

    # -- meta-data block (§1.3) ----------------------------------------------------------
    start = cur.pos
    size = cur.u32("Size")
    version = cur.u32("Version")
    if not 1 <= version <= 4:
        raise FileFormatError(f"{p}: header field 'Version' is {version}, expected 1..4")
    if size < _META_BASE:
        raise FileFormatError(
            f"{p}: header field 'Size' is {size}, below the minimum {_META_BASE} bytes"
        )
    end = start + size

    def within(n: int, field: str) -> None:
        # Variable-length fields must stay inside the block that Size announces.
        if cur.pos + n > end:
            raise FileFormatError(
                f"{p}: header field 'Size' ({size}) is smaller than the version-{version} "
                f"header: field {field!r} would end at byte {cur.pos + n - start}"
            )

    attrs["setup"] = _text(cur.take(80, "measurement setup"))
    attrs["sensor"] = _text(cur.take(80, "image sensor"))
    attrs["light_source"] = _text(cur.take(80, "light source"))
    attrs["ppmm"] = float(cur.f32s(1, "PPMM")[0])
    attrs["rgb_scale"] = cur.f32s(3, "RGB scale factor").tolist()
    cosine_flag = 0
    if version > 1:
        within(4, "cosine flag")
        cosine_flag = cur.u32("cosine flag")
    attrs["xml"] = ""
    names = ["R", "G", "B"]
    if version > 2:
        within(4, "XML length")
        n = cur.u32("XML length")
        within(n, "XML string")
        attrs["xml"] = cur.take(n, "XML string").decode("utf-8", "replace")
    if version > 3:
        within(4, "channel count")
        nc = cur.u32("channel count")
        names = []
        for i in range(nc):
            within(4, f"channel {i} name length")
            n = cur.u32(f"channel {i} name length")
            within(n, f"channel {i} name")
            names.append(cur.take(n, f"channel {i} name").decode("latin-1"))
    if cur.pos != end:
        raise FileFormatError(
            f"{p}: header field 'Size' is {size} but the version-{version} header has "
            f"{cur.pos - start} bytes"
        )
    if len(names) != 3:
        raise FileFormatError(
            f"{p}: header field 'channel count' is {len(names)}; only 3-channel files are supported"
        )
    attrs.update(version=version, channel_names=names, cosine_flag=cosine_flag)

    # -- direction table (§1.4): one light list per view; the first one is kept --------------
    nv = cur.u32("view count")
    if nv == 0:
        raise FileFormatError(f"{p}: field 'view count' is 0")
    # Each view takes at least 12 bytes (direction + light count): check before allocating.
    if 12 * nv > fsize - cur.pos:
        raise FileFormatError(
            f"{p}: field 'view count' is {nv}, but its table alone would need {12 * nv} bytes "
            f"and only {fsize - cur.pos} remain (a damaged header or a truncated file)"
        )
    vt = np.empty((nv, 2))
    lt: np.ndarray | None = None
    for v in range(nv):
        vt[v] = cur.f32s(2, f"view {v} direction")
        nl_v = cur.u32(f"view {v} light count")
        if lt is None:
            if nl_v == 0:
                raise FileFormatError(f"{p}: field 'view 0 light count' is 0")
            lt = cur.f32s(2 * nl_v, "view 0 light directions").reshape(nl_v, 2)
        elif nl_v != lt.shape[0]:
            raise FileFormatError(
                f"{p}: inconsistent direction counts: field 'view {v} light count' is {nl_v} "
                f"but view 0 has {lt.shape[0]} lights"
            )
        else:
            cur.skip(8 * nl_v, f"view {v} light directions")
    assert lt is not None
    nl = lt.shape[0]
    try:
        lights = from_angles(lt[:, 0], lt[:, 1], name="ubo2014-file-lights")
        views = from_angles(vt[:, 0], vt[:, 1], name="ubo2014-file-views")
    except BTFInputError as e:
        raise FileFormatError(f"{p}: field 'direction table': {e}") from None
    check_directions(lights.xyz, f"{p}: field 'view 0 light directions'")
    check_directions(views.xyz, f"{p}: field 'view directions'")

    # -- spatial size and rotations (§1.5) ------------------------------------------------
    w = cur.u32("width")
    h = cur.u32("height")
    if w == 0 or h == 0:
        raise FileFormatError(f"{p}: fields 'width'/'height' are {w}x{h}; must be positive")
    n_rot = 0
    if has_rot:
        n_rot = cur.u32("rotation count")
        cur.skip(36 * n_rot, "rotations")  # local frames: neither Bonn decoder uses them
    attrs["n_rotations"] = n_rot

    # -- payload (§1.6 / §1.7): walk the matrix headers, map nothing yet ---------------------
    blocks: list[tuple[int, np.dtype, int, int, int, int]] = []  # (K, dt, rows, cols, U, SxV)
    color_model: int | None = None
    drr = False
    height_map: np.ndarray | None = None
    color_mean = color_transform = None
    if layout == "DFMF":
        attrs["k_max"] = cur.u32("K_max")
        color_model = cur.i32("ColorModel")
        color_mean = cur.f32s(3, "ColorMean")
        color_transform = cur.f32s(9, "ColorTransform").reshape(3, 3)
        if color_model not in COLOR_MODELS:
            raise FileFormatError(
                f"{p}: field 'ColorModel' is {color_model}, not a supported colour model "
                f"({', '.join(f'{k}={v}' for k, v in COLOR_MODELS.items())})"
            )
        check_color_header(color_mean, color_transform, str(p))
        for ch in range(3):
            blocks.append(_matrix_header(cur, p, f"channel {ch} ", nl * nv, w * h))
    else:
        if extended:
            hv = cur.u8("FMF header_version")
            if hv >= 3:
                raise FileFormatError(f"{p}: field 'FMF header_version' is {hv}, expected 0..2")
            if hv >= 1:
                drr = cur.u32("DRR") != 0
            if hv >= 2:
                hmw = cur.u32("height map width")
                hmh = cur.u32("height map height")
                off = cur.skip(2 * hmw * hmh, "height map")
                if hmw * hmh:
                    # Stored as hmH rows of hmW values (the BL writer's layout, §1.7).
                    f.seek(off)
                    raw = np.frombuffer(f.read(2 * hmw * hmh), dtype="<f2")
                    height_map = raw.reshape(hmh, hmw).astype(np.float32)
        k0 = cur.u32("K0")
        blk = _matrix_header(cur, p, "", 3 * nl * nv, w * h)
        if k0 != blk[0]:
            raise FileFormatError(
                f"{p}: fields 'K0' ({k0}) and 'K' ({blk[0]}) differ; the row stride is ambiguous"
            )
        blocks.append(blk)

    # -- whole-file size check before any payload is mapped -----------------------------------
    if cur.pos != fsize:
        raise FileFormatError(
            f"{p}: {fsize - cur.pos} trailing bytes after the last matrix: the headers describe "
            f"{cur.pos} bytes but the file has {fsize}"
        )

    btf = UBO2014BTF(h, w, lights, views, name=p.stem, attrs=attrs)
    btf.layout = layout
    btf.color_model = color_model
    btf.color_mean = color_mean
    btf.color_transform = color_transform
    btf.drr = drr
    btf.height_map = height_map
    btf.cosine_flag = cosine_flag
    btf.divide_cosine = bool(divide_cosine and cosine_flag)
    btf.factors = [
        (_factor(p, uo, dt, rows, k), _factor(p, so, dt, cols, k))
        for k, dt, rows, cols, uo, so in blocks
    ]
    btf.ranks = [b[0] for b in blocks]
    # float64 files are summed in float64; half and float in float32 (never in float16).
    btf._acc = np.dtype(np.float64 if any(b[1].itemsize == 8 for b in blocks) else np.float32)
    attrs.update(
        color_model=color_model,
        drr=drr,
        ranks=btf.ranks,
        scalar_bytes=[b[1].itemsize for b in blocks],
    )
    return btf


def _matrix_header(
    cur: _Cursor, p: Path, pre: str, rows_expected: int, cols_expected: int
) -> tuple[int, np.dtype, int, int, int, int]:
    """Parse one (s, K, rows, cols, S, U, SxV) block; returns (K, dtype, rows, cols, U, SxV)."""
    # DFMF and FMF share this order; FMF's K0 was read by the caller (§1.6, §1.7).
    s = cur.u8(f"{pre}scalar size")
    k = cur.u32(f"{pre}K")
    if s not in _SCALARS:
        raise FileFormatError(f"{p}: field '{pre}scalar size' is {s}, expected 2, 4 or 8")
    rows = cur.u32(f"{pre}rows")
    cols = cur.u32(f"{pre}cols")
    if rows != rows_expected:
        raise FileFormatError(
            f"{p}: field '{pre}rows' is {rows} but the direction table gives {rows_expected} "
            "angular rows (inconsistent direction counts)"
        )
    if cols != cols_expected:
        raise FileFormatError(
            f"{p}: field '{pre}cols' is {cols} but width x height is {cols_expected}"
        )
    cur.skip(s * k, f"{pre}S")
    u_off = cur.skip(s * rows * k, f"{pre}U payload")
    sxv_off = cur.skip(s * cols * k, f"{pre}SxV payload")
    return k, _SCALARS[s], rows, cols, u_off, sxv_off
