"""Eq. 7–9 on one channel's codes: the weighted sum of several inputs' data points in the
dictionary of the dominant input, cut back to τ coefficients (:mod:`.blend` says the rule)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .._progress import bar
from .._threads import parallel_map
from ..learning.coding import SparseCodes, topk_abs
from ..learning.tensor import reconstruct

__all__ = ["blend_channel"]


def _sparse_part(
    parts: list[tuple[SparseCodes, float]], idx: np.ndarray, size: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(point, linear location, weighted value) of the same-dictionary contributions."""
    pt, lin, val = [], [], []
    for codes, w in parts:
        cnt = codes.counts[idx].astype(np.int64)
        owner = np.repeat(idx, cnt)
        rank = np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        pos = np.repeat(codes.offsets[idx], cnt) + rank
        pt.append(owner)
        lin.append(np.ravel_multi_index(tuple(codes.locations[pos].T.astype(np.int64)),
                                        codes.mode_sizes))  # fmt: skip
        val.append(w * codes.values[pos].astype(np.float64))
    return np.concatenate(pt), np.concatenate(lin), np.concatenate(val)


def blend_channel(
    inputs: Sequence[SparseCodes],
    weights: np.ndarray,
    dicts: list[np.ndarray],
    tau: int,
    progress: bool | None,
    label: str,
) -> SparseCodes:
    """The blend of ``inputs`` (the same points, one size) with ``weights``: each point on the
    dictionary of the input of largest weight, the others' coefficients rotated into it
    (Eq. 8–9, ``dicts`` per mode (K, m, m)), then its ``tau`` largest kept; ``errors`` the
    mean square of what was dropped."""
    shape = inputs[0].mode_sizes
    size = int(np.prod(shape))
    n_pts = inputs[0].n_points
    lead = int(np.argmax(weights))
    target = inputs[lead].membership.astype(np.int64)
    active = [j for j in range(len(inputs)) if weights[j] != 0]
    same = np.ones(n_pts, dtype=bool)
    for j in active:
        same &= inputs[j].membership == target
    out_vals: list[np.ndarray] = [np.empty(0)] * n_pts
    out_locs: list[np.ndarray] = [np.empty((0, len(shape)), dtype=np.int64)] * n_pts
    errors = np.zeros(n_pts)

    # Points where every input uses the target dictionary: Eq. 7, sums of sparse terms.
    idx = np.flatnonzero(same)
    if idx.size:
        pt, lin, val = _sparse_part([(inputs[j], weights[j]) for j in active], idx, size)
        key = pt * size + lin
        uniq, inv = np.unique(key, return_inverse=True)
        summed = np.bincount(inv, weights=val, minlength=uniq.size)
        upt, ulin = uniq // size, uniq % size
        energy = np.bincount(upt, weights=summed**2, minlength=n_pts)
        order = np.lexsort((ulin, -np.abs(summed), upt))
        upt, ulin, summed = upt[order], ulin[order], summed[order]
        start = np.searchsorted(upt, upt, side="left")
        keep = (np.arange(upt.size) - start) < tau
        kept_energy = np.bincount(upt[keep], weights=summed[keep] ** 2, minlength=n_pts)
        errors[idx] = np.maximum(energy[idx] - kept_energy[idx], 0.0) / size
        upt, ulin, summed = upt[keep], ulin[keep], summed[keep]
        bounds = np.searchsorted(upt, np.concatenate([idx, [n_pts]]))
        locs = np.stack(np.unravel_index(ulin, shape), axis=1)
        for n, i in enumerate(idx):
            out_vals[i] = summed[bounds[n] : bounds[n + 1]]
            out_locs[i] = locs[bounds[n] : bounds[n + 1]]

    # Points where some input uses another dictionary: rotate its coefficients (Eq. 8–9).
    cross = np.flatnonzero(~same)

    def task(i: int) -> tuple[int, np.ndarray, np.ndarray, float]:
        k = int(target[i])
        acc = np.zeros(shape)
        for j in active:
            s = inputs[j].dense(i)
            p = int(inputs[j].membership[i])
            if p != k:
                rot = [d[k].T @ d[p] for d in dicts]
                s = reconstruct(s[None], rot)[0]
            acc += weights[j] * s
        flat = acc.ravel()
        top = topk_abs(flat, min(tau, size))
        kept = flat[top]
        err = max(float(flat @ flat - kept @ kept), 0.0) / size
        return i, kept, np.stack(np.unravel_index(top, shape), axis=1), err

    with bar(cross.size, label, "pt", progress) as pb:
        for i, kept, loc, err in parallel_map(task, cross.tolist()):
            out_vals[i], out_locs[i], errors[i] = kept, loc, err
            pb.update(1)

    counts = np.array([v.size for v in out_vals], dtype=np.int64)
    first = inputs[0]
    return SparseCodes(
        shape,
        target.astype(first.membership.dtype),
        counts,
        np.concatenate(out_vals).astype(np.float32),
        np.concatenate(out_locs).astype(first.locations.dtype),
        errors,
    )
