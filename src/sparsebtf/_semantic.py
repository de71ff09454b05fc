"""Semantic checks of values read from files: what a well-formed file may still get wrong.

:mod:`sparsebtf._h5check` makes sure a file's fields are readable (type, shape, size,
finiteness); this module makes sure they *mean* something possible, before any work is done:

====================  =============================================================================
direction tables      finite, unit length within :data:`UNIT_TOLERANCE`, on the upper hemisphere
                      (z ≥ −:data:`UNIT_TOLERANCE`), pairwise distinct (chord > :data:`MIN_CHORD`)
statistics            μ, σ finite, \\|μ\\| ≤ :data:`STAT_BOUND`, 0 < σ ≤ :data:`STAT_BOUND`,
                      the log offset (``stats@eps``) in :data:`LOG_OFFSET_RANGE`, the bound on
                      ln(RGB + offset) (when present) finite, in [ln offset, :data:`STAT_BOUND`]
sparse codes          counts ≥ 0 summing to the number of values, memberships in [0, K), locations
                      inside the data point and distinct within a point, values finite and sorted
                      by decreasing \\|v\\| within a point, residuals ≥ 0 or NaN (unknown)
dictionary rule       ``dictionary_rule`` (when present) "exhaustive" or "screened"; screened with
                      an integer ``dictionary_candidates`` in [1, K) (K: the largest channel's)
dictionaries          orthonormal: max \\|UᵀU − I\\| ≤ :data:`ORTHONORMAL_TOLERANCE` (binary16
                      storage: :data:`ORTHONORMAL_TOLERANCE_FP16`), one matmul per matrix
UBO2014 colour        ``ColorMean`` and ``ColorTransform`` finite, entries ≤ :data:`COLOR_BOUND`
====================  =============================================================================

Every check raises a :class:`~sparsebtf.errors.FileFormatError` whose one line names the file
and field (``where``), the index and what was expected vs found. The per-kind validators
(:func:`validate_coded`, :func:`validate_model_dictionaries`) combine them; readers call them
once per file. The bounds are documented in ``docs/format.md`` §7.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Protocol

import numpy as np

from .errors import FileFormatError


# What the checks read of the project's objects, named by structure: this module sits under
# every reader (data, formats, learning, storage), so it imports none of the layers above.
class Standardization(Protocol):
    """The fields of :class:`sparsebtf.points.preprocessing.Standardization` checked here."""

    mean: np.ndarray
    std: np.ndarray
    log_offset: float
    transform: str
    bound: np.ndarray | None


class SparseCodes(Protocol):
    """The fields of :class:`sparsebtf.learning.coding.SparseCodes` checked here."""

    mode_sizes: tuple[int, ...]
    membership: np.ndarray
    counts: np.ndarray
    values: np.ndarray
    locations: np.ndarray
    errors: np.ndarray


class CodedBTF(Protocol):
    """The fields of :class:`sparsebtf.model.CodedBTF` checked here."""

    @property
    def stats(self) -> Standardization: ...

    @property
    def codes(self) -> Mapping[str, SparseCodes]: ...

    @property
    def params(self) -> Mapping[str, object]: ...

__all__ = [
    "COLOR_BOUND",
    "DICTIONARY_RULES",
    "LOG_OFFSET_RANGE",
    "MIN_CHORD",
    "ORTHONORMAL_TOLERANCE",
    "ORTHONORMAL_TOLERANCE_FP16",
    "STAT_BOUND",
    "UNIT_TOLERANCE",
    "check_codes",
    "check_color_header",
    "check_dictionary_rule",
    "check_directions",
    "check_orthonormal",
    "check_same_directions",
    "check_statistics",
    "orthonormality_error",
    "stored_dtype",
    "validate_coded",
    "validate_model_dictionaries",
]

#: Largest |‖v‖ − 1| of a stored direction (float32 rounding is 6e-8; our writers store
#: float64 unit vectors).
UNIT_TOLERANCE = 1e-6
#: Smallest chord distance between two directions of one table (about 0.006°; the closest
#: UBO2014 directions are 7.5° apart).
MIN_CHORD = 1e-4
#: Bound on |μ| and σ of log-YUV statistics: ln(x + ε) of any reflectance x in [0, 1e12] with
#: ε ≥ 1e-12 lies within ±27.7, so Y within ±27.7, U within ±24.1 and V within ±34.0 (the sums
#: of the absolute BT.601 coefficients times 27.7). Beyond ±88.7 exp() overflows float32.
STAT_BOUND = 40.0
#: Accepted log offsets (the paper's and the release's is 1e-5; ``encode --log-offset``
#: chooses one per material in [1e-5, the upper end]).
LOG_OFFSET_RANGE = (1e-12, 1e3)
#: Orthonormality of float32 / float64 dictionaries: the bundled float32 model gives 8.1e-8,
#: the release's float64 ``.mat`` files 1.2e-14.
ORTHONORMAL_TOLERANCE = 1e-4
#: Orthonormality of binary16 dictionaries: the release's ``.bin`` files give up to 6.7e-4.
ORTHONORMAL_TOLERANCE_FP16 = 2e-3
#: Bound on the entries of a UBO2014 header's ``ColorMean`` and ``ColorTransform`` (a PCA
#: colour basis has entries ≤ 1, a mean colour of reflectances a few units).
COLOR_BOUND = 1e4


def _fail(where: str, text: str) -> FileFormatError:
    return FileFormatError(f"{where}: {text}")


# --------------------------------------------------------------------------- directions


def check_directions(xyz: np.ndarray, where: str) -> None:
    """A direction table ``xyz`` (n, 3): finite unit vectors (within :data:`UNIT_TOLERANCE`)
    on the upper hemisphere, pairwise more than :data:`MIN_CHORD` apart. Errors name the row."""
    v = np.asarray(xyz, dtype=np.float64)
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise _fail(where, f"row {i} is {v[i].tolist()}; expected a finite unit vector")
    norm = np.linalg.norm(v, axis=1)
    off = np.abs(norm - 1.0) > UNIT_TOLERANCE
    if off.any():
        i = int(np.flatnonzero(off)[0])
        raise _fail(
            where,
            f"row {i} has length {norm[i]:.9g}; expected a unit vector (length 1 ± "
            f"{UNIT_TOLERANCE:g})",
        )
    below = v[:, 2] < -UNIT_TOLERANCE
    if below.any():
        i = int(np.flatnonzero(below)[0])
        raise _fail(
            where, f"row {i} points below the surface (z = {v[i, 2]:.6g}); expected z >= 0"
        )
    if len(v) > 1:
        from scipy.spatial import cKDTree

        pairs = cKDTree(v).query_pairs(MIN_CHORD, output_type="ndarray")
        if len(pairs):
            i, j = (int(x) for x in pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))[0]])
            raise _fail(
                where,
                f"rows {i} and {j} are the same direction {np.round(v[i], 6).tolist()} "
                f"(chord {float(np.linalg.norm(v[i] - v[j])):.3g}); expected distinct directions "
                f"(chord > {MIN_CHORD:g})",
            )


def check_same_directions(xyz: np.ndarray, reference: np.ndarray, where: str, whose: str) -> None:
    """``xyz`` equal to ``reference`` row by row (within :data:`UNIT_TOLERANCE`): codes index
    the directions of the model they were made with, in its order."""
    if xyz.shape != reference.shape:
        raise _fail(where, f"{len(xyz)} directions, but {whose} table has {len(reference)}")
    differ = np.abs(np.asarray(xyz) - np.asarray(reference)).max(axis=1) > UNIT_TOLERANCE
    if differ.any():
        i = int(np.flatnonzero(differ)[0])
        raise _fail(
            where,
            f"row {i} is {np.round(xyz[i], 6).tolist()}, but {whose} is "
            f"{np.round(reference[i], 6).tolist()}; expected the same directions in the same "
            "order",
        )


# --------------------------------------------------------------------------- statistics


def check_statistics(stats: Standardization, where: str) -> None:
    """Log-YUV statistics: μ and σ finite, \\|μ\\| ≤ :data:`STAT_BOUND`,
    0 < σ ≤ :data:`STAT_BOUND`, the log offset in :data:`LOG_OFFSET_RANGE`, the bound (if
    any) in [ln offset, :data:`STAT_BOUND`]. The one home of these rules."""
    offset = float(stats.log_offset)
    lo, hi = LOG_OFFSET_RANGE
    if not (np.isfinite(offset) and lo <= offset <= hi):
        # named as the file's attribute: stats@eps
        raise _fail(f"{where}@eps", f"log offset is {offset!r}; expected {lo:g} <= eps <= {hi:g}")
    if stats.transform != "log_yuv":
        return  # identity statistics (μ = 0, σ = 1) are never read from a file
    _check_range(np.asarray(stats.mean), f"{where}/mean", -STAT_BOUND, STAT_BOUND, "mean")
    _check_range(np.asarray(stats.std), f"{where}/std", 0.0, STAT_BOUND, "std", lo_open=True)
    if stats.bound is not None:
        # No angular image lies below ln(0 + offset), the log of black (the bound is rounded up).
        _check_range(np.asarray(stats.bound), f"{where}/bound", float(np.log(offset)) - 1e-2,
                     STAT_BOUND, "bound")


def _check_range(
    a: np.ndarray, where: str, lo: float, hi: float, what: str, lo_open: bool = False
) -> None:
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(a) & (a <= hi) & ((a > lo) if lo_open else (a >= lo))
    if ok.all():
        return
    first = tuple(int(x[0]) for x in np.nonzero(~ok))
    want = f"{lo:g} {'<' if lo_open else '<='} {what} <= {hi:g}"
    raise _fail(
        where,
        f"{int((~ok).sum())} implausible values, first {float(a[first])!r} at index {first} "
        f"(light, view, channel); expected finite values with {want}",
    )


# --------------------------------------------------------------------------- sparse codes


def check_codes(codes: SparseCodes, where: str, n_dictionaries: int | None = None,
                magnitude_order: bool = True) -> None:  # fmt: skip
    """One channel's codes (in memory, whatever the file's layout): see the module table.

    ``n_dictionaries`` (K), when known, bounds the memberships. ``magnitude_order``: each
    point's values must come by decreasing magnitude (the log objective's level-of-detail
    order); a linear or display objective's files keep the order of their objective instead
    (:mod:`sparsebtf.learning.lod_order`)."""
    sizes = np.asarray(codes.mode_sizes, dtype=np.int64)
    member = np.asarray(codes.membership)
    counts = np.asarray(codes.counts, dtype=np.int64)
    values = np.asarray(codes.values)
    loc = np.asarray(codes.locations, dtype=np.int64)
    if counts.size and int(counts.min()) < 0:
        i = int(np.argmin(counts))
        raise _fail(f"{where}/counts", f"point {i} has count {int(counts[i])}; expected >= 0")
    if int(counts.sum()) != values.shape[0] or loc.shape[0] != values.shape[0]:
        raise _fail(
            f"{where}/counts",
            f"counts sum to {int(counts.sum())}, but there are {values.shape[0]} values and "
            f"{loc.shape[0]} locations; expected all three equal",
        )
    k = n_dictionaries
    bad = (member < 0) | (member >= k) if k is not None else member < 0
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        want = f"0 <= m < K = {k}" if k is not None else "m >= 0"
        raise _fail(
            f"{where}/membership", f"point {i} uses dictionary {int(member[i])}; expected {want}"
        )
    if loc.size:
        out = (loc < 0) | (loc >= sizes)
        if out.any():
            i, n = (int(x[0]) for x in np.nonzero(out))
            raise _fail(
                f"{where}/locations",
                f"coefficient {i} has index {int(loc[i, n])} on mode {n + 1}; expected 0 <= l "
                f"< {int(sizes[n])}",
            )
    finite = np.isfinite(values)
    if not finite.all():
        i = int(np.flatnonzero(~finite)[0])
        raise _fail(f"{where}/values", f"value {i} is {float(values[i])}; expected finite values")
    owner = np.repeat(np.arange(counts.size, dtype=np.int64), counts)
    _check_distinct(loc, sizes, owner, f"{where}/locations")
    if magnitude_order:
        _check_order(values, owner, f"{where}/values")
    errors = np.asarray(codes.errors, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        bad = np.isinf(errors) | (errors < 0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise _fail(
            f"{where}/errors",
            f"point {i} has residual {float(errors[i])}; expected >= 0 (or NaN: unknown)",
        )


def _check_distinct(loc: np.ndarray, sizes: np.ndarray, owner: np.ndarray, where: str) -> None:
    """No location twice within one point (a repeat would add two values to one entry)."""
    if loc.shape[0] < 2:
        return
    strides = np.cumprod(np.concatenate([[1], sizes[:-1]]))
    linear = loc @ strides
    total = int(np.prod(sizes, dtype=object))
    if (int(owner[-1]) + 1) * total < 2**63:  # one int64 key per coefficient: a plain sort
        key = owner * total + linear
        if not (np.diff(np.sort(key)) == 0).any():
            return
        order = np.argsort(key, kind="stable")  # only to name the repeat
        same = np.diff(key[order]) == 0
    else:
        order = np.lexsort((linear, owner))
        same = (np.diff(owner[order]) == 0) & (np.diff(linear[order]) == 0)
    if same.any():
        j = int(np.flatnonzero(same)[0])
        a, b = sorted((int(order[j]), int(order[j + 1])))
        raise _fail(
            where,
            f"point {int(owner[a])} repeats location {tuple(int(x) for x in loc[a])} at "
            f"coefficients {a} and {b}; expected distinct locations within a point",
        )


def stored_dtype(values: np.ndarray) -> np.dtype:
    """The type a coded file stores ``values`` in: binary16, or float32 when a finite value
    lies beyond binary16's ±65504 (the format's rule, docs/format.md §3)."""
    vals = np.asarray(values)
    big = vals.size and float(np.max(np.abs(vals))) > float(np.finfo(np.float16).max)
    return np.dtype("<f4" if big else "<f2")


def _check_order(values: np.ndarray, owner: np.ndarray, where: str) -> None:
    """|v| non-increasing within each point: truncating to τ reads a prefix. Compared in the
    precision a coded file stores (binary16 unless a value overflows it): the encoders order
    values that round to the same binary16 number by location, not by their float32 digits."""
    if values.shape[0] < 2:
        return
    mag = np.abs(values.astype(stored_dtype(values)).astype(np.float64))
    rise = (np.diff(owner) == 0) & (np.diff(mag) > 0)
    if rise.any():
        j = int(np.flatnonzero(rise)[0])
        raise _fail(
            where,
            f"point {int(owner[j])}: |value| rises from {mag[j]:.6g} (coefficient {j}) to "
            f"{mag[j + 1]:.6g} (coefficient {j + 1}); expected decreasing magnitudes within a "
            "point",
        )


def validate_coded(
    coded: CodedBTF, where: str, n_dictionaries: dict[str, int] | None = None
) -> None:
    """Everything a coded BTF's decoding relies on, beyond the shapes: its statistics and
    every channel's codes (direction tables are checked where they are read)."""
    check_statistics(coded.stats, f"{where}/stats")
    ks = n_dictionaries or {}
    by_magnitude = coded.params.get("objective", "log") == "log"
    for ch, c in coded.codes.items():
        check_codes(c, f"{where}/codes/{ch}", ks.get(ch), by_magnitude)
    check_dictionary_rule(coded.params, f"{where}: attribute 'params_json'", ks)


#: The dictionary rules a coded file may record (``params["dictionary_rule"]``).
DICTIONARY_RULES = ("exhaustive", "screened")


def check_dictionary_rule(params: Mapping[str, object], where: str,
                          n_dictionaries: Mapping[str, int]) -> None:  # fmt: skip
    """``dictionary_rule`` absent (older files: exhaustive) or one of :data:`DICTIONARY_RULES`;
    "screened" with an integer ``dictionary_candidates`` >= 1 and below the largest K known
    (``n_dictionaries``, per channel), since K or more candidates is the exhaustive rule."""
    rule = params.get("dictionary_rule")
    cand = params.get("dictionary_candidates")
    if rule is None and cand is None:
        return
    if rule not in DICTIONARY_RULES:
        raise _fail(where, f"'dictionary_rule' must be one of {DICTIONARY_RULES}, found {rule!r}")
    if rule == "exhaustive":
        if cand is not None:
            raise _fail(where, f"'dictionary_candidates' = {cand!r} with the exhaustive rule "
                        "(every dictionary): expected none")  # fmt: skip
        return
    k_max = max(n_dictionaries.values(), default=None)
    ok = isinstance(cand, int) and not isinstance(cand, bool) and cand >= 1
    if not ok or (k_max is not None and cand >= k_max):  # type: ignore[operator]
        want = "an integer >= 1" + (f" and < K = {k_max}" if k_max is not None else "")
        raise _fail(where, f"'dictionary_candidates' of the screened rule must be {want}, "
                    f"found {cand!r}")  # fmt: skip


# --------------------------------------------------------------------------- dictionaries


def orthonormality_error(u: np.ndarray) -> np.ndarray:
    """max \\|UᵀU − I\\| of each matrix in ``u`` (K, m, m): one matmul per matrix."""
    a = np.asarray(u, dtype=np.float64)
    with np.errstate(all="ignore"):  # NaN / huge entries give NaN / inf: not orthonormal
        gram = np.matmul(a.transpose(0, 2, 1), a)
        gram -= np.eye(a.shape[-1])
        return np.abs(gram).max(axis=(1, 2))


def check_orthonormal(
    mats: Sequence[np.ndarray], where: str, tolerance: float = ORTHONORMAL_TOLERANCE
) -> float:
    """Every (K, m, m) mode of one ensemble orthonormal within ``tolerance``; returns the
    largest deviation. Errors name the mode and the dictionary k."""
    worst = 0.0
    for n, u in enumerate(mats, start=1):
        dev = orthonormality_error(u)
        with np.errstate(invalid="ignore"):
            bad = ~(dev <= tolerance)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise _fail(
                f"{where}/mode{n}",
                f"dictionary {k} is not orthonormal: max |U^T U - I| = {float(dev[k]):.3g}, "
                f"expected <= {tolerance:g}",
            )
        worst = max(worst, float(dev.max()) if dev.size else 0.0)
    return worst


def validate_model_dictionaries(
    dictionaries: dict[str, list[np.ndarray]],
    where: str,
    tolerance: float | dict[str, float] = ORTHONORMAL_TOLERANCE,
) -> None:
    """Every channel's ensemble orthonormal (``tolerance`` per channel, or one for all)."""
    for ch, mats in dictionaries.items():
        tol = tolerance.get(ch, ORTHONORMAL_TOLERANCE) if isinstance(tolerance, dict) else tolerance
        check_orthonormal(mats, f"{where}/{ch}", tol)


# --------------------------------------------------------------------------- UBO2014 header


def check_color_header(color_mean: np.ndarray, color_transform: np.ndarray, where: str) -> None:
    """A DFMF header's ``ColorMean`` (3,) and ``ColorTransform`` (3, 3): finite, entries
    within ±:data:`COLOR_BOUND`."""
    for name, a in (("ColorMean", color_mean), ("ColorTransform", color_transform)):
        flat = np.asarray(a, dtype=np.float64).ravel()
        with np.errstate(invalid="ignore"):
            bad = ~(np.abs(flat) <= COLOR_BOUND)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise _fail(
                f"{where}: header field '{name}'",
                f"entry {i} is {float(flat[i])!r}; expected a finite number within "
                f"±{COLOR_BOUND:g}",
            )
