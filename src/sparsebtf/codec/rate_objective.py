"""Rate control's candidates under a linear or display objective (issue 32, 46): per data
point and candidate dictionary, the objective's exact error at the reference counts
(:func:`objective_losses`), the candidates of the point's projection or of a floored copy's
(:func:`floored_candidates`), and the chosen pool in its level-of-detail order with its exact
error curve (:func:`pool_walks`). :class:`~.rate.RateTargets` calls them per batch of points.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._threads import parallel_map
from ..learning.coding import topk_abs
from ..learning.lod_order import walk_pool
from ..learning.objective import FLOOR_STEPS
from ..learning.tensor import project, reconstruct_sparse

__all__ = ["floored_candidates", "objective_losses", "pool_walks"]


def objective_losses(
    xc: np.ndarray, res: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]],
    pairs: list[tuple[int, int]], counts: list[int], mats: list[list[np.ndarray]],
    judge: Any,
) -> dict[tuple[int, int], list[float]]:  # fmt: skip
    """Per (point, dictionary) the objective's error (a
    :class:`~sparsebtf.learning.objective.ChannelError`) of its top ``counts[lv]``
    coefficients, per level: one sparse reconstruction per level."""
    return dict(zip(pairs, parallel_map(
        lambda ik: _prefix_losses(xc, ik[0], *res[ik], mats[ik[1]], counts, judge), pairs),
        strict=True))  # fmt: skip


def _prefix_losses(xc: np.ndarray, i: int, idx: np.ndarray, vals: np.ndarray,
                   mats: list[np.ndarray], counts: list[int], judge: Any
                   ) -> list[float]:  # fmt: skip
    """The objective's error of point ``i`` coded by the first ``counts[lv]`` of ``(idx,
    vals)`` (flat indices into the point, values) on the dictionary ``mats``, per level."""
    loc = np.stack(np.unravel_index(idx, xc.shape[1:]), axis=1)
    m64 = [m.astype(np.float64) for m in mats]
    ref = judge.reference(i)
    out = []
    for r in counts:
        n = min(r, idx.size)
        rec = reconstruct_sparse(loc[:n], vals[:n].astype(np.float64), m64)
        out.append(judge(i, rec - xc[i], ref))
    return out


def floored_candidates(
    xc: np.ndarray, res: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]],
    pairs: list[tuple[int, int]], counts: list[int], mats: list[list[np.ndarray]], nmax: int,
    judge: Any, dtype: type,
) -> tuple[dict[tuple[int, int], tuple[np.ndarray, np.ndarray]],
           dict[tuple[int, int], list[float]]]:  # fmt: skip
    """Per (point, dictionary) the candidates of the point's own projection or of one of its
    floored copies (:meth:`~sparsebtf.learning.objective.ChannelError.floored`, the floors
    of :data:`~sparsebtf.learning.objective.FLOOR_STEPS`, as the fixed-τ rule judges them),
    whichever has the least objective error summed over the reference ``counts``, with those
    errors (:func:`objective_losses`)."""
    losses = objective_losses(xc, res, pairs, counts, mats, judge)
    floors = list(parallel_map(judge.floor, range(xc.shape[0])))

    def lifted(ikm: tuple[int, int, float]) -> tuple[np.ndarray, np.ndarray, list[float]] | None:
        i, k, m = ikm
        target = judge.floored(i, xc[i], floors[i] * m)
        if target is None:
            return None
        s = project(np.asarray(target, dtype=dtype)[None], mats[k]).reshape(-1)
        idx = topk_abs(s, nmax)
        return idx, s[idx], _prefix_losses(xc, i, idx, s[idx], mats[k], counts, judge)

    jobs = [(i, k, m) for i, k in pairs for m in FLOOR_STEPS]
    res, losses = dict(res), dict(losses)
    for (i, k, _), got in zip(jobs, parallel_map(lifted, jobs), strict=True):
        if got is not None and sum(got[2]) < sum(losses[i, k]):
            res[i, k], losses[i, k] = (got[0], got[1]), got[2]
    return res, losses


def pool_walks(
    xc: np.ndarray, res: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]],
    picks: list[tuple[int, int, int]], pool: int, mats: list[list[np.ndarray]], judge: Any,
) -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]]:  # fmt: skip
    """Per chosen (point, dictionary) of ``picks`` (point, level, dictionary) its first
    ``pool`` candidates in the objective's level-of-detail order with their exact error
    curve (:func:`~sparsebtf.learning.lod_order.walk_pool`)."""
    keys = sorted({(i, k) for i, _, k in picks})

    def task(ik: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        i, k = ik
        m64 = [m.astype(np.float64) for m in mats[k]]
        return walk_pool(judge, i, xc[i], res[i, k][0], res[i, k][1], m64, pool)

    return dict(zip(keys, parallel_map(task, keys), strict=True))
