"""Rate control: one coefficient budget spread over all data points and channels.

The paper fixes the testing sparsity τ_t per data point (§3.3, Table 3: "we assume that all
data points have τ_t coefficients"). Points differ a lot in how compressible they are, so at
equal storage a better rule gives each coefficient to whichever (point, channel) it reduces
the error most. With orthonormal dictionaries this is exact and cheap: keeping coefficient s
of a point removes s² from its squared error (Parseval, the identity behind Eq. 3), and every
coefficient costs the same bytes (Table 4: 2 B value + 3 B location). A knapsack with equal
item costs is solved exactly by taking the largest gains first, so the allocation below is the
optimum of the weighted squared error for the chosen dictionaries::

    minimise   Σ_{p,c} w_{p,c} · (‖X_{p,c}‖² − Σ_{s kept} s²)
    subject to (2 + loc) · NNZ + 2 · P · C  <=  target bytes          (Table 4 per material)

Memory stays bounded: for each point and channel only the top-N candidates of the chosen
dictionary (sorted by |s|) are kept, never the dense projections. Because the candidates of
a point are sorted and its weight is constant, the kept set of each point is a prefix, so the
result is an ordinary :class:`~sparsebtf.learning.coding.SparseCodes` (counts vary per point).

This module holds the array-level algorithm; :func:`sparsebtf.codec.encode_to_size` streams a
BTF through it. Bytes are counted by :mod:`sparsebtf.learning.cost` (Table 4).
"""

from __future__ import annotations

import itertools
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import BTFInputError
from .codes import RELEASE_TAU, SparseCodes
from .cost import coefficient_budget, material_bytes

__all__ = [
    "ChannelCandidates",
    "allocate",
    "hull_gains",
    "reference_counts",
]

def _coefficient_budget(target_bytes: int, n_points: int, n_channels: int,
                        location_bytes: int) -> int:
    """Coefficients that ``target_bytes`` pays for beside the per-point bytes (Table 4);
    refuses a target below one coefficient per point and channel."""
    need = material_bytes(n_points * n_channels, n_points, n_channels, location_bytes)
    if target_bytes < need:
        raise BTFInputError(
            f"target of {target_bytes} bytes is below the minimum {need} bytes (one coefficient "
            f"per data point and channel, {n_points} points x {n_channels} channels)"
        )
    return coefficient_budget(target_bytes, n_points, n_channels, location_bytes)


def reference_counts(
    target_bytes: int,
    n_points: int,
    channels: Sequence[str],
    location_bytes: int = 3,
    split: Sequence[float] | Mapping[str, float] = RELEASE_TAU,
    size: int | None = None,
) -> dict[str, int]:
    """Mean coefficients per point and channel if ``target_bytes`` were split as ``split``.

    Used to choose each point's dictionary (least error at this count) and the candidate
    pool. Raises :class:`BTFInputError` if the target cannot hold one coefficient per point
    and channel.
    """
    c = len(channels)
    budget = _coefficient_budget(target_bytes, n_points, c, location_bytes)
    if isinstance(split, Mapping):
        f = np.array([float(split.get(ch, 1.0)) for ch in channels])
    else:
        f = np.array([float(v) for v in split][:c]) if len(split) >= c else np.ones(c)
    if np.any(f <= 0):
        raise BTFInputError(f"channel split must be positive, got {list(f)}")
    f = f / f.sum()
    out = {}
    for ch, fc in zip(channels, f, strict=True):
        n = max(1, round(budget * fc / n_points))
        out[ch] = min(n, size) if size else n
    return out


@dataclass(eq=False)
class ChannelCandidates:
    """Top-N coefficients of the chosen dictionary for every point of one channel.

    Attributes
    ----------
    mode_sizes : data-point shape.
    membership : (P,) chosen dictionary.
    indices : (P, N) C-order linear indices into the coefficient tensor, by decreasing |v|.
    values : (P, N) the coefficients.
    energy : (P,) ‖X‖² of each point (float64).
    weights : (P,) error weight w of each point (see :func:`allocate`).
    curves : None, or (P, N + 1) each point's exact error after its first 0, 1, …, N
        candidates (a linear or display objective's, non-increasing where known: the
        candidates in its order, :func:`~sparsebtf.learning.lod_order.walk_pool`);
        NaN between the walk's stops and past the candidates a point has. Then the
        allocation spends on these curves, not on w·s².
    """

    mode_sizes: tuple[int, ...]
    membership: np.ndarray
    indices: np.ndarray
    values: np.ndarray
    energy: np.ndarray
    weights: np.ndarray
    curves: np.ndarray | None = None

    @property
    def n_points(self) -> int:
        return int(self.membership.shape[0])


def hull_gains(curves: np.ndarray) -> np.ndarray:
    """(P, N + 1) error curves (non-increasing where known; NaN between the counts a walk
    evaluated and past a point's candidates) → (P, N + 1) the gain of each candidate for the
    allocation: the slope of the lower convex hull of the known (k, e_k) over the segment
    holding it (column 0: the slope into the first), −inf past the last known count. The
    gains fall along each point, so the largest ``extra`` of all points are a prefix of
    each, and the hull errs no more than the curve where they meet."""
    p, n1 = curves.shape
    out = np.full((p, n1), -np.inf)
    for i in range(p):
        ks = np.flatnonzero(np.isfinite(curves[i]))
        e = curves[i][ks]
        hull = [0]  # indices into ks of the lower convex hull of (k, e_k)
        for j in range(1, ks.size):
            while len(hull) >= 2:
                a, b = hull[-2], hull[-1]
                if (e[b] - e[a]) * (ks[j] - ks[a]) >= (e[j] - e[a]) * (ks[b] - ks[a]):
                    hull.pop()  # b on or above the chord from a to j
                else:
                    break
            hull.append(j)
        for a, b in itertools.pairwise(hull):
            out[i, ks[a] + 1 : ks[b] + 1] = (e[a] - e[b]) / (ks[b] - ks[a])
        out[i, 0] = out[i, 1] if ks.size > 1 else -np.inf
    return out


def known_count(curves: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Each point's ``counts`` rounded down to a count its curve knows (a stop of the walk,
    :func:`~sparsebtf.learning.lod_order.walk_stops`; 0 where the walk kept none):
    the allocation's marginal point may end inside a hull segment, where the error between
    two stops was not evaluated."""
    known = np.isfinite(curves)
    known[:, 0] = False
    idx = np.where(known, np.arange(curves.shape[1])[None, :], 0)
    best = np.maximum.accumulate(idx, axis=1)  # the largest known count <= each count
    c = np.minimum(counts, curves.shape[1] - 1)
    return best[np.arange(curves.shape[0]), c]


def _top_stable(pool: np.ndarray, extra: int) -> np.ndarray:
    """The positions of the ``extra`` largest of ``pool``, ties to the lower position: what
    ``np.argsort(-pool, kind="stable")[:extra]`` selects, in linear time (a partition, then
    the ties at the threshold by position)."""
    if extra >= pool.size:
        return np.arange(pool.size)
    thr = np.partition(pool, pool.size - extra)[pool.size - extra]
    above = np.flatnonzero(pool > thr)
    tied = np.flatnonzero(pool == thr)
    return np.concatenate([above, tied[: extra - above.size]])


def allocate(
    candidates: Mapping[str, ChannelCandidates],
    target_bytes: int,
    location_bytes: int = 3,
) -> tuple[dict[str, SparseCodes], dict[str, object]]:
    """Spend ``target_bytes`` (per material, Table 4) on the candidates, largest w·s² first.

    Every point and channel keeps at least one coefficient (as the release's coder does); the
    rest of the budget goes by decreasing gain ``w_{p,c} · s²`` over all points and channels.
    With exact error curves (``curves``, a linear or display objective) the gains are those
    curves' (:func:`hull_gains`); either way they are taken in a stable order (ties to the
    lower position, :func:`_top_stable`): on the same candidates a larger budget keeps a
    superset, so no point's error grows with the budget, nor the material's; a point keeps
    no coefficient its curve lacks.
    Returns the codes per channel and a summary (``bytes``, ``nnz``, ``exhausted``: whether
    the candidate pool ran out before the budget did, leaving the result below target).
    """
    chans = list(candidates)
    if not chans:
        raise BTFInputError("no channels to allocate")
    p = candidates[chans[0]].n_points
    if any(candidates[ch].n_points != p for ch in chans):
        raise BTFInputError("every channel needs candidates for the same points")
    c = len(chans)
    budget = _coefficient_budget(target_bytes, p, c, location_bytes)
    extra = budget - p * c
    exact = candidates[chans[0]].curves is not None
    gains = []
    for ch in chans:
        cand = candidates[ch]
        if exact:
            gains.append(hull_gains(cand.curves)[:, 1:].ravel())  # type: ignore[arg-type]
            continue
        v = cand.values[:, 1:].astype(np.float64)
        gains.append((cand.weights[:, None] * v * v).ravel())
    pool = np.concatenate(gains) if gains else np.empty(0)
    exhausted = extra >= pool.size
    if exhausted:
        chosen = np.ones(pool.size, dtype=bool)
        if extra > pool.size:
            warnings.warn(
                f"rate control: the candidate pool ({pool.size + p * c} coefficients) is "
                f"smaller than the budget ({budget}); the result is below the target",
                stacklevel=2,
            )
    else:
        chosen = np.zeros(pool.size, dtype=bool)
        if extra > 0:
            # a stable order: a larger budget keeps a superset (ties by point, then position)
            chosen[_top_stable(pool, extra)] = True
    codes: dict[str, SparseCodes] = {}
    start = 0
    total_nnz = 0
    for ch in chans:
        cand = candidates[ch]
        n = cand.values.shape[1]
        sel = chosen[start : start + p * (n - 1)].reshape(p, n - 1)
        start += p * (n - 1)
        # Counts per point; the prefix of that length has gains >= the chosen ones (sorted).
        counts = 1 + sel.sum(axis=1).astype(np.int64)
        if exact:  # where the walk evaluated the error (NaN between stops and past them)
            counts = known_count(cand.curves, counts)  # type: ignore[arg-type]
        keep = np.arange(n)[None, :] < counts[:, None]
        vals = cand.values[keep].astype(np.float32)
        lin = cand.indices[keep]
        locs = np.stack(np.unravel_index(lin, cand.mode_sizes), axis=1).astype(np.int32)
        kept = np.where(keep, cand.values.astype(np.float64) ** 2, 0.0).sum(axis=1)
        size = float(np.prod(cand.mode_sizes))
        errors = np.maximum(cand.energy - kept, 0.0) / size
        if exact:
            errors = cand.curves[np.arange(p), counts]  # type: ignore[index]
        codes[ch] = SparseCodes(
            cand.mode_sizes, cand.membership.astype(np.int64), counts, vals, locs, errors
        )
        total_nnz += int(counts.sum())
    summary: dict[str, object] = {
        "target_bytes": int(target_bytes),
        "bytes": material_bytes(total_nnz, p, c, location_bytes),
        "nnz": {ch: codes[ch].nnz for ch in chans},
        "exhausted": bool(exhausted and extra > pool.size),
    }
    return codes, summary
