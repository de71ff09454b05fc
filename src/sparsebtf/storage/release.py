"""The authors' SparseBTF release (behnazkavoosi/SparseBTF, MIT) as our model and coded files.

Byte layouts (``docs/format.md`` §8):

* ``DictEnsOrth4D{Y,U,V}.bin`` — fp16, four blocks in mode order, each K column-major n×n
  matrices (``U_k[row, col]`` at ``row + n·col + n²·k``); ``.mat`` (HDF5 v7.3) holds the same
  in fp64 as ``DictDim1..4`` (read by h5py as (K, col, row)), plus ``EnsHist`` and ``TrainTime``.
* ``Coeffs_BTF_<mat>_<eps>_<CH>.bin`` — 16-bit words: int16 dims (4), uint16 LNZ (4 per
  non-zero, 0-based, l1 fastest), int16 membership M (P), int16 NNZ (P), fp16 values (N).
  The file has no point count: P comes from the BTF size (400×400 / 10² = 1600).
* ``<mat>_mean_std.bin`` — float64 means then stds, index ``view·151 + light``, one mean and
  std shared by Y, U and V (our "shared" standardisation).
* ``bonn_angles.bin`` — float64 rows φ, elevation, index (radians).

The release's patch numbering and texel convention equal ours. Coefficients are stored in
column-major scan order there; we sort each point's by decreasing magnitude on import.

Every reader checks sizes and counts against the file's length (and the memory budget) before
allocating, opens the ``.mat`` files behind the HDF5 watchdog (:mod:`sparsebtf._hdf5`), and
reports a damaged file as a :class:`FileFormatError` naming the file and the field.
:func:`import_release` reads and checks a whole folder before it returns (a material without
its U/V coefficients or statistics, statistics a coded file cannot store, a size that does not
fit: ``docs/format.md`` §8, "What import refuses"), so its callers write nothing on a refusal.
"""

from __future__ import annotations

import os
import re
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from .._h5check import HDF5_ERRORS, read_array
from .._hdf5 import open_h5, read_error
from .._limits import check_allocation
from .._semantic import (
    ORTHONORMAL_TOLERANCE,
    ORTHONORMAL_TOLERANCE_FP16,
    STAT_BOUND,
    check_codes,
    check_directions,
    check_orthonormal,
    check_statistics,
)
from ..data.directions import DirectionSet, from_angles, ubo2014
from ..errors import BTFInputError, FileFormatError, ModelMismatchError, SparseBTFError
from ..learning.coding import SparseCodes
from ..model import CodedBTF, Model
from ..points.preprocessing import Standardization

__all__ = [
    "check_same_dictionaries",
    "check_storable_statistics",
    "import_release",
    "points_that_fit",
    "read_angles",
    "read_coefficients",
    "read_dictionaries",
    "read_mean_std",
    "release_model",
]

RELEASE = "behnazkavoosi/SparseBTF (MIT), HEAD bc5d927"
MODE_SIZES = (10, 10, 151, 151)
COEFF_RE = re.compile(r"^Coeffs_BTF_(?P<mat>.+)_(?P<eps>[0-9.eE+-]+)_(?P<ch>[YUV])\.bin$")


def _regular_size(p: Path) -> int:
    """The size of a regular file (a FIFO or device would block a read), or an error."""
    if not p.exists():
        raise FileFormatError(f"{p}: no such file")
    if not p.is_file():
        raise FileFormatError(f"{p}: not a regular file (a folder, FIFO or device)")
    return p.stat().st_size


def read_dictionaries(
    path: str | os.PathLike[str],
    n_dictionaries: int = 8,
    mode_sizes: tuple[int, ...] = MODE_SIZES,
) -> tuple[list[np.ndarray], dict[str, Any]]:
    """One channel's ensemble from ``.bin`` (fp16) or ``.mat`` (fp64): (K, n, n) per mode.

    Returns the matrices (``[k, row, col]``, float64) and what else the file says
    (``EnsHist``, ``TrainTime`` from a ``.mat``). Every matrix must be orthonormal within
    :data:`~sparsebtf._semantic.ORTHONORMAL_TOLERANCE` (``.mat``) or
    :data:`~sparsebtf._semantic.ORTHONORMAL_TOLERANCE_FP16` (``.bin``).
    """
    p = Path(path)
    k = n_dictionaries
    if p.suffix == ".mat":
        mats, extra = _read_mat_dictionaries(p, k, mode_sizes)
        check_orthonormal(mats, str(p), ORTHONORMAL_TOLERANCE)
        return mats, extra
    expected = 2 * k * sum(m * m for m in mode_sizes)
    size = _regular_size(p)
    if size != expected:
        raise FileFormatError(
            f"{p}: {size} bytes, expected {expected} (fp16, K = {k}, modes {mode_sizes})"
        )
    words = np.fromfile(p, dtype="<f2").astype(np.float64)
    if not np.all(np.isfinite(words)):
        raise FileFormatError(f"{p}: {int((~np.isfinite(words)).sum())} non-finite values")
    mats, off = [], 0
    for m in mode_sizes:
        block = words[off : off + k * m * m]
        off += k * m * m
        # column-major per matrix: element (row, col) at row + m·col
        mats.append(np.ascontiguousarray(block.reshape(k, m, m).transpose(0, 2, 1)))
    check_orthonormal(mats, str(p), ORTHONORMAL_TOLERANCE_FP16)
    return mats, {}


def _read_mat_dictionaries(
    p: Path, k: int, mode_sizes: tuple[int, ...]
) -> tuple[list[np.ndarray], dict[str, Any]]:
    """``DictDim1..4`` (read by h5py as (K, col, row)), each checked before it is read."""
    f = open_h5(p)
    try:
        with f:
            mats = []
            for n, m in enumerate(mode_sizes, start=1):
                a = read_array(f, f"DictDim{n}", str(p), kinds="f", shape=(k, m, m), finite=True)
                mats.append(np.ascontiguousarray(a.astype(np.float64).transpose(0, 2, 1)))
            extra: dict[str, Any] = {}
            if "EnsHist" in f:
                hist = read_array(f, "EnsHist", str(p), finite=True)
                if hist.size > 2**16:
                    raise FileFormatError(f"{p}/EnsHist: {hist.size} entries, expected about K")
                extra["EnsHist"] = [int(v) for v in hist.ravel()]
            if "TrainTime" in f:
                t = read_array(f, "TrainTime", str(p), finite=True).ravel()
                if t.size < 1:
                    raise FileFormatError(f"{p}/TrainTime: empty")
                extra["TrainTime"] = float(t[0])
            return mats, extra
    except SparseBTFError:
        raise
    except HDF5_ERRORS as e:
        raise read_error(e, str(p)) from None


def read_coefficients(
    path: str | os.PathLike[str],
    n_points: int = 1600,
    n_dictionaries: int = 8,
    texels: tuple[int, int] | None = None,
) -> SparseCodes:
    """One channel's codes; each point's coefficients sorted by decreasing magnitude.

    The file does not say its point count: ``n_points`` (P) comes from the BTF's size
    (``texels``, H × W, named in the messages when given). When the words do not parse with
    that P but do with another, the error names the size and the point count that fits (a
    wrong size, not a damaged file)."""
    p = Path(path)
    size = _regular_size(p)
    # Words, then int32 locations, int64 membership/counts and float32 values: ~10x the file.
    check_allocation(10 * size, f"{p}: coefficients", FileFormatError)
    raw = np.fromfile(p, dtype="<u2")
    if raw.size < 4:
        raise FileFormatError(f"{p}: {size} bytes, too short for the dims header")
    dims = tuple(int(v) for v in raw[:4].view("<i2"))
    if any(d <= 0 for d in dims):
        raise FileFormatError(f"{p}: header dims {dims} are not positive")

    def misfit(why: str) -> FileFormatError:
        """``why`` P does not parse: a size error when another point count does."""
        fits = [q for q in points_that_fit(raw, n_dictionaries) if q != n_points]
        if not fits:
            return FileFormatError(f"{p}: {why}")
        points = f"{n_points} point{'s' * (n_points != 1)}"
        asked = (f"size {texels[0]}x{texels[1]} ({points} of 10x10 texels)"
                 if texels else f"a BTF of {points}")  # fmt: skip
        other = " or ".join(f"{q} point{'s' * (q != 1)} (e.g. size {size_text(q)})"
                            for q in fits[:3])  # fmt: skip
        return FileFormatError(
            f"{p}: {asked} does not fit its {raw.size} words, which parse as {other}; give "
            "that size (the release's files do not store it), or the file is damaged"
        )

    rest = raw.size - 4 - 2 * n_points
    if rest < 0 or rest % 5:
        raise misfit(f"{raw.size} words do not fit 4 + 5·N + 2·P with P = {n_points} points")
    n = rest // 5
    lnz = raw[4 : 4 + 4 * n].reshape(n, 4).astype(np.int32)
    member = raw[4 + 4 * n : 4 + 4 * n + n_points].view("<i2").astype(np.int64)
    counts = raw[4 + 4 * n + n_points : 4 + 4 * n + 2 * n_points].view("<i2").astype(np.int64)
    values = raw[4 + 4 * n + 2 * n_points :].view("<f2").astype(np.float32)
    if np.any(counts < 0):
        i = int(np.flatnonzero(counts < 0)[0])
        raise misfit(f"NNZ[{i}] = {counts[i]} is negative")
    if int(counts.sum()) != n:
        raise misfit(f"NNZ sums to {int(counts.sum())}, but the file holds {n}")
    bad = (member < 0) | (member >= n_dictionaries)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise FileFormatError(
            f"{p}: membership M[{i}] = {member[i]} is outside [0, {n_dictionaries})"
        )
    over = lnz >= np.array(dims)
    if over.any():
        i, j = (int(v[0]) for v in np.nonzero(over))
        raise FileFormatError(f"{p}: LNZ[{i}] mode {j + 1} = {lnz[i, j]} >= dims {dims[j]}")
    if not np.all(np.isfinite(values)):
        i = int(np.flatnonzero(~np.isfinite(values))[0])
        raise FileFormatError(f"{p}: value {i} is {values[i]}; values must be finite")
    # sort each point's coefficients by decreasing |v| (ties: storage order)
    owner = np.repeat(np.arange(n_points), counts)
    order = np.lexsort((np.arange(n), -np.abs(values), owner))
    errors = np.full(n_points, np.nan)  # unknown: the release does not store residuals
    try:
        codes = SparseCodes(dims, member, counts, values[order], lnz[order], errors)
    except BTFInputError as e:
        raise FileFormatError(f"{p}: {e}") from None
    check_codes(codes, str(p), n_dictionaries)
    return codes


def points_that_fit(raw: np.ndarray, n_dictionaries: int = 8, limit: int = 4) -> list[int]:
    """The point counts P (at most ``limit``, smallest first) for which a coefficient file's
    16-bit words ``raw`` parse: 4 + 5·N + 2·P words whose P counts are non-negative and sum
    to N, whose P memberships lie in [0, K), whose locations lie below the header's dims and
    whose values are finite. The sums come from one pass (prefix sums); at most 64 counts
    whose sums agree are examined further (a crafted file cannot make this slow)."""
    w = int(raw.size) - 4
    if w < 2:
        return []
    # 2·P ≡ w (mod 5)  <=>  P ≡ 3·w (mod 5)
    ps = np.arange((3 * w) % 5, w // 2 + 1, 5, dtype=np.int64)
    ps = ps[ps > 0]
    ns = (w - 2 * ps) // 5
    dims = raw[:4].view("<i2").astype(np.int64)
    signed = raw.view("<i2").astype(np.int64)
    csum = np.concatenate([[0], np.cumsum(signed)])
    start = 4 + 4 * ns + ps  # the first NNZ word
    sums = csum[start + ps] - csum[start]
    found = []
    for q, n in zip(ps[sums == ns][:64].tolist(), ns[sums == ns][:64].tolist(), strict=True):
        counts = signed[4 + 4 * n + q : 4 + 4 * n + 2 * q]
        member = signed[4 + 4 * n : 4 + 4 * n + q]
        if counts.min() < 0 or member.min() < 0 or member.max() >= n_dictionaries:
            continue
        lnz = raw[4 : 4 + 4 * n].reshape(n, 4)
        values = raw[4 + 4 * n + 2 * q :].view("<f2")
        if np.all(lnz < dims) and np.all(np.isfinite(values)):
            found.append(q)
            if len(found) == limit:
                break
    return found


def size_text(n_points: int, patch: int = 10) -> str:
    """A size ``HxW`` of ``n_points`` patches of ``patch``² texels, as near square as the count
    allows (1600 -> 400x400, 2 -> 20x10)."""
    a = max(d for d in range(1, int(np.sqrt(n_points)) + 1) if n_points % d == 0)
    return f"{patch * (n_points // a)}x{patch * a}"


#: The smallest σ a coded file stores within float32 rounding (float32's smallest normal
#: number, 1.18e-38); below it float32 is subnormal (fewer digits) or 0.
FLOAT32_NORMAL = float(np.finfo(np.float32).tiny)


def check_storable_statistics(stats: Standardization, where: str) -> None:
    """The statistics as a coded file stores them (μ, σ in float32; ``stats/`` of
    ``docs/format.md`` §3) pass the check ``decode`` applies
    (:func:`~sparsebtf._semantic.check_statistics`), and every σ is a normal float32 number
    (at least :data:`FLOAT32_NORMAL`), stored within float32 rounding: a float64 σ of 5e-324
    passes σ > 0 but is stored as 0.0, one of 1e-40 as a float32 subnormal that has lost 5 of
    its digits."""
    std = np.asarray(stats.std, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        bad = np.isfinite(std) & (std > 0) & (std < FLOAT32_NORMAL)
    if bad.any():
        first = tuple(int(x[0]) for x in np.nonzero(bad))
        stored = float(np.float32(std[first]))
        raise FileFormatError(
            f"{where}/std: {int(bad.sum())} values below float32's smallest normal number "
            f"(the coded file stores σ in float32), first {float(std[first])!r} at index "
            f"{first} (light, view, channel), stored as {stored!r}; expected "
            f"{FLOAT32_NORMAL:.3g} <= std <= {STAT_BOUND:g}"
        )
    check_statistics(
        replace(stats, mean=np.asarray(stats.mean, np.float32).astype(np.float64),
                std=std.astype(np.float32).astype(np.float64)),
        where,
    )  # fmt: skip


def read_mean_std(
    path: str | os.PathLike[str], n_lights: int = 151, n_views: int = 151
) -> Standardization:
    """The release's shared standardisation (index ``view·L + light``), checked as a coded
    file will store it (:func:`check_storable_statistics`)."""
    p = Path(path)
    j = n_lights * n_views
    size = _regular_size(p)
    if size != 16 * j:
        raise FileFormatError(f"{p}: {size} bytes, expected {16 * j} (2 × {j} float64)")
    a = np.fromfile(p, dtype="<f8")
    mean = a[:j].reshape(n_views, n_lights).T[..., None]
    std = a[j:].reshape(n_views, n_lights).T[..., None]
    stats = Standardization("shared", np.ascontiguousarray(mean), np.ascontiguousarray(std))
    check_statistics(stats, str(p))
    check_storable_statistics(stats, str(p))
    return stats


def read_angles(path: str | os.PathLike[str]) -> DirectionSet:
    """``bonn_angles.bin``: φ and elevation (radians) of the 151 directions."""
    p = Path(path)
    size = _regular_size(p)
    if size == 0 or size % 24:
        raise FileFormatError(f"{p}: {size} bytes; expected 3 rows of float64 (a multiple of 24)")
    check_allocation(2 * size, f"{p}: directions", FileFormatError)
    a = np.fromfile(p, dtype="<f8")
    if not np.all(np.isfinite(a)):
        i = int(np.flatnonzero(~np.isfinite(a))[0])
        raise FileFormatError(f"{p}: value {i} is {a[i]}; angles must be finite")
    phi, elev, _ = a.reshape(3, -1)
    try:
        directions = from_angles(np.pi / 2 - elev, phi, name="ubo2014")
    except BTFInputError as e:
        raise FileFormatError(f"{p}: {e}") from None
    check_directions(directions.xyz, f"{p} (φ, elevation)")
    return directions


def release_model(
    directory: str | os.PathLike[str], prefer: str = "mat"
) -> tuple[Model, list[str]]:
    """The release's Y/U/V ensembles in ``directory`` as a :class:`Model` (and notes).

    ``prefer``: the fp64 ``.mat`` files (exact, default) or the fp16 ``.bin`` files; the other
    kind is used for a channel that lacks the preferred one.
    """
    d = Path(directory)
    if not d.is_dir():
        raise FileFormatError(f"{d}: not a folder")
    notes: list[str] = []
    dicts: dict[str, list[np.ndarray]] = {}
    training: dict[str, dict[str, Any]] = {}
    for ch in ("Y", "U", "V"):
        cands = [d / f"DictEnsOrth4D{ch}.{ext}" for ext in ((prefer, "bin", "mat"))]
        src = next((c for c in cands if c.exists()), None)
        if src is None:
            notes.append(f"no dictionaries for channel {ch}")
            continue
        mats, extra = read_dictionaries(src)
        dicts[ch] = mats
        training[ch] = {"source_file": src.name}
        if "EnsHist" in extra:
            training[ch]["membership_counts"] = extra["EnsHist"]
        if "TrainTime" in extra:
            training[ch]["seconds"] = extra["TrainTime"]
        notes.append(f"channel {ch}: dictionaries from {src.name}")
    if not dicts:
        raise FileFormatError(f"{d}: no DictEnsOrth4D{{Y,U,V}}.bin/.mat files")
    directions = (
        read_angles(d / "bonn_angles.bin") if (d / "bonn_angles.bin").exists() else ubo2014()
    )
    if len(directions) != MODE_SIZES[2]:
        raise FileFormatError(
            f"{d / 'bonn_angles.bin'}: {len(directions)} directions, the release's dictionaries "
            f"have {MODE_SIZES[2]}"
        )
    model = Model(
        dicts,
        10,
        directions,
        directions,
        params={"n_dictionaries": 8, "std_mode": "shared", "source": "release"},
        provenance={"release": RELEASE, "licence": "MIT (LICENSE-SparseBTF)", "folder": str(d)},
        training=training,
    )
    return model, notes


#: Largest difference between the release's dictionaries and a model they are coded against
#: (``import_release(model=...)``): float32 rounding of entries <= 1 is below 2^-25.
MATCH_TOLERANCE = 2.0**-24


def check_same_dictionaries(a: Model, b: Model, tolerance: float = MATCH_TOLERANCE) -> float:
    """The largest entry difference of two models' ensembles; refuses more than ``tolerance``
    (or different channels / shapes)."""
    worst = 0.0
    for ch in a.channels:
        if ch not in b.dictionaries:
            raise ModelMismatchError(f"channel {ch} is in the release but not in the model")
        for n, (u, v) in enumerate(zip(a.dictionaries[ch], b.dictionaries[ch], strict=True)):
            if u.shape != v.shape:
                raise ModelMismatchError(
                    f"channel {ch}, mode {n + 1}: release {u.shape}, model {v.shape}"
                )
            worst = max(worst, float(np.abs(u - v).max()))
    if worst > tolerance:
        raise ModelMismatchError(
            f"the release's dictionaries differ from the model's by up to {worst:.3g} "
            f"(more than {tolerance:.3g}): not the same ensembles"
        )
    return worst


def import_release(
    directory: str | os.PathLike[str],
    prefer: str = "mat",
    height: int = 400,
    width: int = 400,
    model: Model | None = None,
) -> tuple[Model, dict[str, CodedBTF], list[str]]:
    """The release in ``directory`` as (model, coded BTFs by material, notes for the user).

    With ``model`` (e.g. the bundled ``release`` model, the same ensembles rounded to
    float32), the coefficients are coded against it instead, after checking that the folder's
    dictionaries equal it within :data:`MATCH_TOLERANCE`; it is returned as the model. A
    folder without dictionaries (as ``sparsebtf export-release`` writes) needs ``model``.
    ``height`` × ``width``: the texels of every material (the files do not say; the release's
    are 400 × 400).

    Incomplete or implausible input is refused in one line (:class:`FileFormatError` naming
    the file and field) before anything is returned, so a caller that writes afterwards
    writes nothing: a material without its U or V coefficient file, or without its
    ``*_mean_std.bin``; a coefficient file without dictionaries for its channel; statistics a
    coded file cannot store (:func:`check_storable_statistics`); a size whose point count does
    not fit the coefficient files (the message names the size and the count that fits).
    """
    if not all(isinstance(v, (int, np.integer)) and v > 0 and v % 10 == 0 for v in (height, width)):
        raise BTFInputError(
            f"size {height}x{width}: expected positive multiples of the release's 10-texel "
            "patches (400x400)"
        )
    d = Path(directory)
    if model is not None and d.is_dir() and not any(d.glob("DictEnsOrth4D*")):
        # A folder written by ``export-release``: no dictionaries, the codes refer to the
        # release's ensembles, which ``model`` holds.
        _check_folder_directions(d, model)
        return model, *_import_codes(d, model, model, height, width,
                                     [f"{d}: no dictionaries; the coefficients are read "
                                      f"against model {model.content_hash[:12]}"])  # fmt: skip
    own, notes = release_model(d, prefer)
    if model is not None:
        worst = check_same_dictionaries(own, model)
        if not (own.lights.equals(model.lights) and own.views.equals(model.views)):
            raise ModelMismatchError(
                f"{d}: the release's {len(own.lights)} directions differ from the model's"
            )
        notes.append(
            f"codes refer to model {model.content_hash[:12]} (its dictionaries differ from the "
            f"folder's by at most {worst:.2g})"
        )
    else:
        model = own
    return model, *_import_codes(d, own, model, height, width, notes)


def _check_folder_directions(d: Path, model: Model) -> None:
    """The folder's ``bonn_angles.bin`` (when there is one) names the model's directions."""
    p = d / "bonn_angles.bin"
    if p.exists() and not read_angles(p).equals(model.lights):
        raise ModelMismatchError(f"{p}: its directions differ from the model's")


def _import_codes(
    d: Path, own: Model, model: Model, height: int, width: int, notes: list[str]
) -> tuple[dict[str, CodedBTF], list[str]]:
    """The folder's coefficient and statistics files as coded BTFs on ``model`` (``own``: the
    folder's ensembles and directions)."""
    dicts = own.dictionaries
    directions = own.lights
    groups = _coefficient_groups(d, notes)
    coded: dict[str, CodedBTF] = {}
    n_points = (height // 10) * (width // 10)
    # Everything is read and checked before anything is returned (so before any file is
    # written): one line for the first problem, naming the file.
    for mat, files in groups.items():
        _check_complete(d, mat, files, dicts)
        stats_file = d / f"{mat}_mean_std.bin"
        if not stats_file.exists():
            raise FileFormatError(
                f"{stats_file}: missing; the statistics (μ, σ) of "
                f"{', '.join(f.name for f, _ in files.values())} must be beside them"
            )
        stats = read_mean_std(stats_file)
        codes = {}
        for ch in ("Y", "U", "V"):
            if ch not in files:
                notes.append(f"{mat}: no {ch} coefficients in the release; imported without {ch}")
                continue
            codes[ch] = read_coefficients(files[ch][0], n_points, texels=(height, width))
            if tuple(codes[ch].mode_sizes) != MODE_SIZES:
                raise FileFormatError(
                    f"{files[ch][0]}: header dims {tuple(codes[ch].mode_sizes)}, the release's "
                    f"dictionaries have {MODE_SIZES}"
                )
        eps = next(iter(files.values()))[1]
        c = CodedBTF(
            codes,
            stats,
            height,
            width,
            10,
            directions,
            directions,
            model.content_hash,
            params={
                "tau": {ch: int(codes[ch].counts.max()) for ch in codes},
                "eps": eps,
                "std_mode": "shared",
                "n_dictionaries": {ch: 8 for ch in codes},
                "source": "release",
            },
            name=mat,
            attrs={"release": RELEASE, "files": [files[ch][0].name for ch in codes]},
        )
        coded[mat] = c.attach(model)
        notes.append(f"{mat}: channels {', '.join(codes)} ({n_points} points)")
    return coded, notes


#: Channels every material's coefficients must have. Y may be absent: the authors' release
#: publishes U and V only (such a coded file serves ``lookup`` of U and V, not RGB).
REQUIRED_CHANNELS = ("U", "V")


def _coefficient_groups(d: Path, notes: list[str]) -> dict[str, dict[str, tuple[Path, float]]]:
    """The folder's ``Coeffs_BTF_<mat>_<ε>_<CH>.bin`` by material and channel; refuses two
    files for one channel or channels of one material with different ε."""
    groups: dict[str, dict[str, tuple[Path, float]]] = {}
    for f in sorted(d.glob("Coeffs_BTF_*.bin")):
        m = COEFF_RE.match(f.name)
        if m:
            try:
                eps = float(m["eps"])
            except ValueError:
                notes.append(f"{f.name}: skipped, its ε field {m['eps']!r} is not a number")
                continue
            have = groups.setdefault(m["mat"], {})
            if m["ch"] in have:
                raise FileFormatError(
                    f"{d}: two {m['ch']} coefficient files for {m['mat']}, "
                    f"{have[m['ch']][0].name} and {f.name}; expected one per channel"
                )
            have[m["ch"]] = (f, eps)
    for mat, files in groups.items():
        if len({eps for _, eps in files.values()}) > 1:
            raise FileFormatError(
                f"{d}: the coefficient files of {mat} give different ε "
                f"({', '.join(f.name for f, _ in files.values())}); expected one"
            )
    return groups


def _check_complete(
    d: Path, mat: str, files: dict[str, tuple[Path, float]], dicts: dict[str, Any]
) -> None:
    """``mat``'s coefficient files hold U and V (and Y, optionally), each with the folder's
    (or the model's) dictionaries for its channel."""
    some = next(iter(files.values()))[0]
    eps = COEFF_RE.match(some.name)["eps"]  # type: ignore[index]
    missing = [ch for ch in REQUIRED_CHANNELS if ch not in files]
    if missing:
        names = [f"Coeffs_BTF_{mat}_{eps}_{ch}.bin" for ch in missing]
        also = f" (and {', '.join(names[1:])})" if names[1:] else ""
        raise FileFormatError(
            f"{d / names[0]}: missing{also}; {mat} has "
            f"{', '.join(f.name for f, _ in files.values())}, and every material needs its U "
            "and V coefficient files (Y may be absent, as in the authors' release)"
        )
    for ch, (f, _) in files.items():
        if ch not in dicts:
            raise FileFormatError(
                f"{f}: no {ch} dictionaries to decode it with (DictEnsOrth4D{ch}.mat or .bin "
                f"in {d}, or a model with channel {ch})"
            )
