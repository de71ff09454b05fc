"""A coded BTF in the authors' release layout (the inverse of :mod:`.release`'s reader), for the
authors' OptiX renderer and for :func:`.release.import_release`.

A folder gets, for a material NAME coded with residual threshold ε:

* ``Coeffs_BTF_<NAME>_<ε>_<CH>.bin`` per channel Y, U, V — 16-bit little-endian words: int16
  dims (4), uint16 LNZ (4 per non-zero, 0-based, l1 fastest), int16 membership M (P), int16
  NNZ (P), fp16 values (N = ΣNNZ); points in our (the release's) numbering, each point's
  coefficients in column-major scan order of the coefficient tensor (the authors' order);
* ``<NAME>_mean_std.bin`` — float64 means then stds, index ``view·L + light``;
* ``bonn_angles.bin`` — float64 rows φ, elevation (radians), index (1-based);
  ``xyz_loc.bin`` — float64 rows x, y, z, index (1-based).

The dictionaries are not written: the layout's ensembles are the release's own (K = 8, 10×10
patches, the 151 UBO2014 directions; our bundled model ``release``), which every user has. So
only a coded file on that model is representable; anything else is refused in one line before
a file is written. What the layout drops: the values' precision below fp16 (relative 2^-11),
the per-point residuals and the clamp bound of schema-3 files (decoders of the release do not
clamp).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from .._atomic import atomic_output
from ..data.btf import RELEASE_LOG_OFFSET
from ..errors import BTFInputError
from ..learning.codes import RELEASE_EPS
from ..model import CodedBTF
from .release import MODE_SIZES

__all__ = ["FP16_MAX", "check_exportable", "check_name", "export_release", "release_files"]

#: The largest finite fp16 value: coefficients beyond it do not fit the release's values.
FP16_MAX = 65504.0
#: The release's ensembles per channel.
RELEASE_K = 8
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9.+-]*$")


def _eps_text(eps: float) -> str:
    """ε as the authors' file names write it (1e-05)."""
    return f"{eps:g}"


def release_files(coded: CodedBTF, name: str | None = None) -> list[str]:
    """The file names :func:`export_release` writes for ``coded`` (material ``name``)."""
    n = name or coded.name
    eps = _eps_text(float(coded.params.get("eps", RELEASE_EPS)))
    return [*(f"Coeffs_BTF_{n}_{eps}_{ch}.bin" for ch in coded.codes), f"{n}_mean_std.bin",
            "bonn_angles.bin", "xyz_loc.bin"]  # fmt: skip


def check_name(name: str | None, option: str = "name") -> None:
    """The rule of the material name given to :func:`export_release` (``option``: how the
    caller spells it, ``--name`` on the command line): None takes the coded file's name, an
    empty or blank one is a mistake, not a request for the default."""
    if name is not None and not name.strip():
        raise BTFInputError(f"{option} must not be empty, got {name!r}: give the material name "
                            f"for the file names, or leave {option} out for the coded file's")


def check_exportable(coded: CodedBTF, release_hash: str, name: str | None = None) -> None:
    """One line (:class:`BTFInputError`) unless ``coded`` fits the release layout: coded on
    the release's ensembles (model ``release_hash``), shared log-YUV statistics with log offset
    1e-5, 10×10 patches on 151×151 directions, channels Y/U/V, K = 8, values within fp16."""
    where = coded.label
    if coded.highlight_store is not None:
        raise BTFInputError(f"{where}: has a highlight store (encode --highlights), which the "
                            "release layout cannot hold; encode it without one")
    check_name(name)
    n = name or coded.name
    if not _NAME_RE.match(n):
        raise BTFInputError(f"{where}: material name {n!r} cannot be a release file name "
                            "(letters, digits, '.', '+', '-'; give --name)")  # fmt: skip
    if coded.model_hash != release_hash:
        raise BTFInputError(
            f"{where}: coded on model {coded.model_hash[:12]}, not the release's ensembles "
            f"({release_hash[:12]}); the release layout holds no dictionaries, so only a file "
            "coded with -m release can be exported"
        )
    for ch, c in coded.codes.items():
        if ch not in ("Y", "U", "V"):
            raise BTFInputError(f"{where}: channel {ch!r}; the release layout holds Y, U, V")
        if tuple(c.mode_sizes) != MODE_SIZES:
            raise BTFInputError(f"{where}: channel {ch} mode sizes {tuple(c.mode_sizes)}, the "
                                f"release layout's are {MODE_SIZES}")  # fmt: skip
        if c.membership.size and int(c.membership.max()) >= RELEASE_K:
            raise BTFInputError(
                f"{where}: channel {ch} uses dictionary "
                f"{int(c.membership.max())}; the release has K = {RELEASE_K}"
            )
        if c.counts.size and int(c.counts.max()) > np.iinfo(np.int16).max:
            raise BTFInputError(
                f"{where}: channel {ch} keeps {int(c.counts.max())} "
                "coefficients in a point; NNZ is int16 (at most 32767)"
            )
        big = np.abs(c.values) > FP16_MAX
        if big.any():
            raise BTFInputError(f"{where}: channel {ch} value {float(c.values[big][0]):g} "
                                f"exceeds fp16's range (±{FP16_MAX:g})")  # fmt: skip
    st = coded.stats
    if st.mode != "shared" or st.transform != "log_yuv":
        raise BTFInputError(
            f"{where}: statistics {st.mode}/{st.transform}; the release layout "
            "holds one mean and std per angular image (shared, log-YUV)"
        )
    if not np.isclose(st.log_offset, RELEASE_LOG_OFFSET, rtol=1e-9, atol=0):
        raise BTFInputError(
            f"{where}: log offset {st.log_offset:g}; the release's decoders use "
            f"{RELEASE_LOG_OFFSET:g} (encode with --log-offset 1e-5)"
        )
    if coded.patch != MODE_SIZES[0] or coded.height % coded.patch or coded.width % coded.patch:
        raise BTFInputError(
            f"{where}: {coded.height}x{coded.width} texels in {coded.patch}x"
            f"{coded.patch} patches; the release layout needs 10x10 patches"
        )
    if not coded.lights.equals(coded.views):
        raise BTFInputError(f"{where}: lights and views differ; the release has one direction "
                            "table")  # fmt: skip


def _coefficient_words(c: object) -> np.ndarray:
    """One channel's words (see the module docstring), each point's non-zeros in column-major
    scan order: ``l1 + m1·l2 + m1·m2·l3 + m1·m2·m3·l4`` increasing."""
    sizes = np.asarray(c.mode_sizes, dtype=np.int64)  # type: ignore[attr-defined]
    counts = np.asarray(c.counts, dtype=np.int64)  # type: ignore[attr-defined]
    loc = np.asarray(c.locations, dtype=np.int64)  # type: ignore[attr-defined]
    strides = np.concatenate([[1], np.cumprod(sizes[:-1])])
    scan = loc @ strides
    owner = np.repeat(np.arange(counts.size), counts)
    order = np.lexsort((scan, owner))
    return np.concatenate([
        sizes.astype("<i2").view("<u2"),
        loc[order].astype("<u2").ravel(),
        np.asarray(c.membership).astype("<i2").view("<u2"),  # type: ignore[attr-defined]
        counts.astype("<i2").view("<u2"),
        np.asarray(c.values)[order].astype("<f2").view("<u2"),  # type: ignore[attr-defined]
    ])  # fmt: skip


def export_release(
    coded: CodedBTF,
    folder: str | os.PathLike[str],
    release_hash: str,
    name: str | None = None,
) -> list[Path]:
    """Write ``coded`` into ``folder`` in the release layout; returns the files written.

    Everything is checked first (:func:`check_exportable`), then each file is written
    atomically. ``release_hash`` is the content hash of the release's ensembles (the bundled
    model ``release``); ``name`` replaces the material name in the file names.
    """
    check_exportable(coded, release_hash, name)
    d = Path(folder)
    n = name or coded.name
    eps = _eps_text(float(coded.params.get("eps", RELEASE_EPS)))
    blobs: dict[str, bytes] = {}
    for ch, c in coded.codes.items():
        blobs[f"Coeffs_BTF_{n}_{eps}_{ch}.bin"] = _coefficient_words(c).astype("<u2").tobytes()
    st = coded.stats
    # index view·L + light: transpose (L, V) to (V, L) before flattening
    ms = np.concatenate([st.mean[..., 0].T.ravel(), st.std[..., 0].T.ravel()])
    blobs[f"{n}_mean_std.bin"] = ms.astype("<f8").tobytes()
    dirs = coded.lights
    idx = np.arange(1, len(dirs) + 1, dtype=np.float64)
    angles = np.concatenate([dirs.phi, dirs.elevation, idx])
    blobs["bonn_angles.bin"] = angles.astype("<f8").tobytes()
    xyz = np.asarray(dirs.xyz, dtype=np.float64)
    blobs["xyz_loc.bin"] = np.concatenate([xyz.T.ravel(), idx]).astype("<f8").tobytes()
    written = []
    for fname, blob in blobs.items():
        with atomic_output(d / fname) as tmp:
            tmp.write_bytes(blob)
        written.append(d / fname)
    return written
