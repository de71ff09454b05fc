"""Write Bonn UBO2014 ``.btf`` files: from raw factor matrices (synthetic fixtures for tests),
or any BTF exactly (:func:`write_btf_ubo2014`, ``sparsebtf convert -o X.btf``).

Every branch the reader (:mod:`sparsebtf.formats.ubo2014`) decodes can be written: DFMF and
FMF layouts, half/float/double, with or without rotations, the colour models, DRR, header
versions (layout: ``shared/specs/ubo-btf-format.md`` §1).
"""

from __future__ import annotations

import os
import struct
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..data.directions import DirectionSet
from ..errors import BTFInputError
from .ubo2014 import _DTYPE_NAMES, _SCALARS

__all__ = ["ubo2014_bytes", "write_btf_ubo2014", "write_ubo2014"]


def _mat(a: np.ndarray, dt: np.dtype) -> bytes:
    return np.ascontiguousarray(np.asarray(a, dtype=np.float64).astype(dt)).tobytes()


def write_ubo2014(
    path: str | os.PathLike[str],
    spatial: np.ndarray | Sequence[np.ndarray],
    angular: np.ndarray | Sequence[np.ndarray],
    height: int,
    width: int,
    lights: DirectionSet,
    views: DirectionSet,
    layout: str = "DFMF",
    dtype: str = "half",
    rotations: bool = True,
    height_map: np.ndarray | None = None,
    color_model: int = 11,
    color_mean: Sequence[float] = (0.0, 0.0, 0.0),
    color_transform: np.ndarray | None = None,
    drr: bool = True,
    fmf_header_version: int | None = 2,
    version: int = 4,
    cosine_flag: int = 0,
    xml: str = "",
    n_rotations: int = 2,
) -> dict[str, int]:
    """Write a UBO2014 ``.btf`` file from its raw factor matrices (test fixtures).

    Parameters
    ----------
    spatial, angular : DFMF — three SxV_c (H·W × K_c) and three U_c (nL·nV × K_c) (sequences or
        (3, n, K) arrays); FMF — one SxV (H·W × K) and one U (3·nL·nV × K, rows ``lv·3 + c``).
        Angular rows follow the file's ``lv = view·nL + light``; spatial rows ``row·W + col``.
    height, width : texture size. lights, views : direction tables, written per view.
    layout : "DFMF" or "FMF". dtype : "half", "float" or "double" payload scalars.
    rotations : write the ``R`` magic and ``n_rotations`` identity frames.
    height_map : (hmH, hmW) heights (FMF with header version 2 only).
    color_model : DFMF ``ColorModel``; color_mean, color_transform : model-3 fields.
    drr : FMF log domain flag. fmf_header_version : 0..2, or None for ``!FMF06FC`` (no extended
        header). version : meta block version 1..4. cosine_flag, xml : header fields.

    Returns
    -------
    Byte offsets of some fields (``size``, ``color_model``, ``view_count``, ``payload``), for
    tests that corrupt files.
    """
    if layout not in ("DFMF", "FMF"):
        raise BTFInputError(f"layout must be 'DFMF' or 'FMF', got {layout!r}")
    if dtype not in _DTYPE_NAMES:
        raise BTFInputError(f"dtype must be one of {sorted(_DTYPE_NAMES)}, got {dtype!r}")
    if not 1 <= version <= 4:
        raise BTFInputError(f"version must be 1..4, got {version}")
    s = _DTYPE_NAMES[dtype]
    dt = _SCALARS[s]
    nl, nv, npix = len(lights), len(views), height * width
    if layout == "DFMF":
        sp = [np.asarray(x) for x in spatial]
        an = [np.asarray(x) for x in angular]
        if len(sp) != 3 or len(an) != 3:
            raise BTFInputError("DFMF needs three spatial and three angular factors")
        for c in range(3):
            if (
                sp[c].shape[0] != npix
                or an[c].shape[0] != nl * nv
                or (sp[c].shape[1] != an[c].shape[1])
            ):
                raise BTFInputError(
                    f"channel {c}: SxV {sp[c].shape} / U {an[c].shape} do not fit "
                    f"{npix} texels and {nl * nv} directions"
                )
        magic = b"!DFMF08FC"
    else:
        sp = [np.asarray(spatial)]
        an = [np.asarray(angular)]
        if (
            sp[0].shape[0] != npix
            or an[0].shape[0] != 3 * nl * nv
            or (sp[0].shape[1] != an[0].shape[1])
        ):
            raise BTFInputError(
                f"FMF: SxV {sp[0].shape} / U {an[0].shape} do not fit {npix} texels and "
                f"3x{nl * nv} directions"
            )
        if fmf_header_version is None:
            magic = b"!FMF06FC"
        elif 0 <= fmf_header_version <= 2:
            magic = b"!FMF12FCE"
        else:
            raise BTFInputError(f"fmf_header_version must be 0..2 or None: {fmf_header_version}")
        if height_map is not None and fmf_header_version != 2:
            raise BTFInputError("a height map needs fmf_header_version=2")
    if rotations:
        magic += b"R"

    offsets: dict[str, int] = {}
    out = bytearray(magic)
    # Meta block; Size counts itself and every version-dependent field (§1.3).
    meta = bytearray(struct.pack("<I", version))
    for text in (b"synthetic", b"sensor", b"light"):
        meta += text.ljust(80, b"\0")
    meta += struct.pack("<f3f", 10.0, 1.0, 1.0, 1.0)
    if version > 1:
        meta += struct.pack("<I", cosine_flag)
    if version > 2:
        xb = xml.encode()
        meta += struct.pack("<I", len(xb)) + xb
    if version > 3:
        meta += struct.pack("<I", 3)
        for name in (
            (b"R", b"G", b"B") if layout == "FMF" or color_model == 0 else (b"Y", b"U", b"V")
        ):
            meta += struct.pack("<I", len(name)) + name
    offsets["size"] = len(out)
    out += struct.pack("<I", len(meta) + 4) + meta

    offsets["view_count"] = len(out)
    out += struct.pack("<I", nv)
    light_block = np.stack([lights.theta, lights.phi], axis=1).astype("<f4").tobytes()
    for v in range(nv):
        out += struct.pack("<ffI", views.theta[v], views.phi[v], nl) + light_block
    out += struct.pack("<II", width, height)
    if rotations:
        out += struct.pack("<I", n_rotations)
        out += np.tile(np.eye(3, dtype="<f4").ravel(), n_rotations).tobytes()

    offsets["payload"] = len(out)
    if layout == "DFMF":
        out += struct.pack("<I", max(a.shape[1] for a in an))
        offsets["color_model"] = len(out)
        t = np.eye(3) if color_transform is None else np.asarray(color_transform)
        out += struct.pack("<i", color_model)
        out += np.asarray(color_mean, dtype="<f4").tobytes() + t.astype("<f4").tobytes()
        for c in range(3):
            k = an[c].shape[1]
            out += struct.pack("<BIII", s, k, nl * nv, npix)
            out += _mat(np.ones(k), dt) + _mat(an[c], dt) + _mat(sp[c], dt)
    else:
        if fmf_header_version is not None:
            out += struct.pack("<B", fmf_header_version)
            if fmf_header_version >= 1:
                out += struct.pack("<I", int(drr))
            if fmf_header_version >= 2:
                hm = np.zeros((0, 0)) if height_map is None else np.asarray(height_map)
                out += struct.pack("<II", hm.shape[1], hm.shape[0]) + _mat(hm, np.dtype("<f2"))
        k = an[0].shape[1]
        out += struct.pack("<IBIII", k, s, k, 3 * nl * nv, npix)
        out += _mat(np.ones(k), dt) + _mat(an[0], dt) + _mat(sp[0], dt)
    Path(path).write_bytes(bytes(out))
    return offsets


def _exact_rank(height: int, width: int, n_lights: int, n_views: int) -> int:
    """K of the exact factorisation :func:`write_btf_ubo2014` writes: the smaller side."""
    return min(height * width, n_lights * n_views)


def ubo2014_bytes(
    height: int, width: int, n_lights: int, n_views: int, dtype: str = "float"
) -> int:
    """Bytes of the file :func:`write_btf_ubo2014` writes for this shape (header included)."""
    item = _DTYPE_NAMES[dtype]
    npix, nlv = height * width, n_lights * n_views
    k = _exact_rank(height, width, n_lights, n_views)
    meta = 4 + 3 * 80 + 16 + 4 + 4 + 4 + 3 * (4 + 1)  # version 4, no XML, channels Y, U, V
    header = len(b"!DFMF08FC") + 4 + meta + 4 + n_views * (12 + 8 * n_lights) + 8
    payload = 4 + 4 + 12 + 36 + 3 * (13 + item * k * (1 + nlv + npix))
    return header + payload


def write_btf_ubo2014(path: str | os.PathLike[str], btf: Any, dtype: str = "float") -> None:
    """Write ``btf`` as a UBO2014 ``.btf`` that reads back to the same values (exactly for
    ``dtype="float"``; ``"half"`` rounds to binary16): DFMF, colour model 0 (RGB), one factor
    the identity and the other the data, whichever side (H·W texels or L·V directions) is
    smaller, so K = min(H·W, L·V) and the file is about the raw data's size.

    The whole BTF is read into memory (refused above ``$SPARSEBTF_MAX_MEMORY_GB``) and the
    file is written atomically.
    """
    from .._atomic import atomic_output
    from .._limits import check_allocation

    h, w, nl, nv = btf.height, btf.width, len(btf.lights), len(btf.views)
    check_allocation(2 * ubo2014_bytes(h, w, nl, nv, dtype), f"writing {path} (UBO2014)")
    rgb = btf.to_array()  # (H, W, L, V, 3)
    # Rows of the file's matrices: texel row·W + col; direction view·nL + light.
    m = np.ascontiguousarray(rgb.transpose(0, 1, 3, 2, 4)).reshape(h * w, nv * nl, 3)
    k = _exact_rank(h, w, nl, nv)
    spatial, angular = [], []
    for c in range(3):
        if k == h * w:  # SxV = I, U = data^T
            spatial.append(np.eye(k, dtype=np.float32))
            angular.append(m[:, :, c].T)
        else:  # U = I, SxV = data
            spatial.append(m[:, :, c])
            angular.append(np.eye(k, dtype=np.float32))
    with atomic_output(path) as tmp:
        write_ubo2014(tmp, spatial, angular, h, w, btf.lights, btf.views, "DFMF", dtype,
                      rotations=False, color_model=0)  # fmt: skip
