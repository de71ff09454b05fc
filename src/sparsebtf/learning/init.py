"""Initial dictionaries of an ensemble: random, one point's HOSVD, or pre-clustered.

``init="preclustered"`` (beyond the paper; the idea of [MHU19], which the paper's §5 names as
future work) groups the training points before the first iteration by their *sparsity
pattern* under a fixed, cheap basis and starts each dictionary from its group:

1. **Cheap basis**: the orthonormal DCT-II on every mode (:func:`dct_basis`), the same for
   every point and data set. Each point is projected on it once (one dictionary's projection:
   1/K of a full coding pass of the trainer).
2. **Support**: the indices of the point's ``s`` largest |coefficients| (``s`` = the
   ensemble's training sparsity τ_l, clipped to the point size): a set of s multi-indices.
3. **Grouping**: k-medoids on the Hamming distance between the binary support vectors,
   d(i, j) = 2 (s − |A_i ∩ A_j|) (the overlaps from one sparse product, N × N), seeded:
   k-means++ seeding from ``random_state``, then alternating assignment (nearest medoid, ties
   to the lower group) and medoid update (the member with the least summed distance, ties to
   the lower index) until nothing changes (at most :data:`KMEDOIDS_ITERATIONS`). K groups.
4. **Dictionaries**: dictionary k is the per-mode HOSVD of its group, the eigenvectors of
   Σ_{i∈C_k} [X_i]_(n) [X_i]_(n)ᵀ by decreasing eigenvalue (:func:`group_hosvd`; a second
   streaming pass over the points). An empty group (fewer points than K, or duplicated
   medoids) gets a Haar-random dictionary.

Every choice is a pure function of the points and ``random_state``: the same seed gives the
same dictionaries, in process or on a cluster (the points are streamed here, in the client,
as ``init="points"`` reads its seeds). Memory: the supports (N × s indices) and the N × N
distances (66 MB at N = 2880).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse

from .._threads import parallel_map
from .codes import topk_abs
from .tensor import project, unfold

__all__ = [
    "KMEDOIDS_ITERATIONS",
    "dct_basis",
    "gram_basis",
    "group_hosvd",
    "hosvd_bases",
    "kmedoids",
    "precluster",
    "preclustered_dictionaries",
    "random_orthonormal",
    "support_sets",
]

#: At most this many assignment/update rounds of the k-medoids grouping (it stops earlier
#: when the medoids stop moving; on the tests' points it took 2–4).
KMEDOIDS_ITERATIONS = 100


def random_orthonormal(m: int, rng: np.random.Generator) -> np.ndarray:
    """Haar-random orthonormal matrix: QR of a Gaussian with column signs fixed by diag(R)."""
    q, r = np.linalg.qr(rng.standard_normal((m, m)))
    return q * np.sign(np.where(np.diag(r) == 0, 1, np.diag(r)))


def gram_basis(gram: np.ndarray) -> np.ndarray:
    """(m, m) eigenvectors of an m×m Gram matrix Σ X_(n) X_(n)ᵀ by decreasing eigenvalue: the
    left singular vectors of the unfoldings, without their huge right factors."""
    w, u = np.linalg.eigh(gram)
    return u[:, np.argsort(-w, kind="stable")]


def hosvd_bases(point: np.ndarray) -> list[np.ndarray]:
    """Per-mode left singular vectors of one data point (complete square bases)."""
    x = np.asarray(point, dtype=np.float64)
    return [gram_basis(xn @ xn.T) for xn in (unfold(x, n) for n in range(x.ndim))]


def dct_basis(m: int) -> np.ndarray:
    """(m, m) orthonormal DCT-II basis, atoms as columns (column 0: the constant)."""
    j = np.arange(m)
    d = np.cos(np.pi * (j[None, :] + 0.5) * j[:, None] / m) * np.sqrt(2.0 / m)
    d[0] /= np.sqrt(2.0)
    return d.T


def support_sets(source: Any, s: int, batch_size: int = 4) -> np.ndarray:
    """(N, s) flat indices of each point's ``s`` largest |DCT coefficients| (sorted per row).

    float32 projections, one point per worker thread (the ranking is all that is kept)."""
    mats = [dct_basis(m).astype(np.float32) for m in source.mode_sizes]
    s = min(int(s), int(np.prod(source.mode_sizes)))

    def one(x: np.ndarray) -> np.ndarray:
        c = project(np.asarray(x, dtype=np.float32)[None], mats)[0].reshape(-1)
        return np.sort(topk_abs(c, s))

    rows = []
    for _, xb in source.batches(batch_size):
        rows += list(parallel_map(one, list(xb)))
    return np.array(rows, dtype=np.int64).reshape(len(rows), s)


def _hamming(supports: np.ndarray, size: int) -> np.ndarray:
    """(N, N) Hamming distances 2(s − |A_i ∩ A_j|) between the binary support vectors."""
    n, s = supports.shape
    a = scipy.sparse.csr_matrix(
        (np.ones(n * s), supports.reshape(-1), np.arange(0, n * s + 1, s)), shape=(n, size)
    )
    overlap = np.asarray((a @ a.T).todense(), dtype=np.float64)
    return 2.0 * (s - overlap)


def kmedoids(dist: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """(N,) group of each point: k-medoids on ``dist`` (k-means++ seeding from ``rng``, then
    alternating assignment and medoid update; every tie to the lower index)."""
    n = dist.shape[0]
    k = min(k, n)
    medoids = [int(rng.integers(n))]
    for _ in range(1, k):
        near = dist[:, medoids].min(axis=1)
        w = near**2
        # all remaining points coincide with a medoid: take the lowest unused index
        pick = int(rng.choice(n, p=w / w.sum())) if w.sum() > 0 else int(
            np.setdiff1d(np.arange(n), medoids)[0])  # fmt: skip
        medoids.append(pick)
    med = np.array(medoids)
    groups = np.argmin(dist[:, med], axis=1)
    for _ in range(KMEDOIDS_ITERATIONS):
        new = med.copy()
        for g in range(k):
            members = np.flatnonzero(groups == g)
            if members.size:
                new[g] = members[np.argmin(dist[np.ix_(members, members)].sum(axis=1))]
        groups = np.argmin(dist[:, new], axis=1)
        if np.array_equal(new, med):
            break
        med = new
    return groups


def precluster(source: Any, k: int, s: int, random_state: int, batch_size: int = 4
               ) -> np.ndarray:  # fmt: skip
    """(N,) group in [0, k) of every point of ``source`` by its top-``s`` DCT support
    (module docstring, steps 1–3)."""
    supports = support_sets(source, s, batch_size)
    dist = _hamming(supports, int(np.prod(source.mode_sizes)))
    return kmedoids(dist, k, np.random.default_rng(random_state))


def group_hosvd(source: Any, groups: np.ndarray, k: int, batch_size: int = 4
                ) -> list[np.ndarray | None]:  # fmt: skip
    """Per group, the per-mode HOSVD bases of its points (None for an empty group)."""
    sizes = source.mode_sizes
    grams = [np.zeros((k, m, m)) for m in sizes]

    def one(x: np.ndarray) -> list[np.ndarray]:
        # float32 products (one point's Gram), summed in float64 over the group
        x = np.asarray(x, dtype=np.float32)
        return [(lambda u: u @ u.T)(unfold(x, n)).astype(np.float64) for n in range(len(sizes))]

    for idx, xb in source.batches(batch_size):
        for i, g in zip(idx, parallel_map(one, list(xb)), strict=True):
            for n in range(len(sizes)):
                grams[n][groups[i]] += g[n]
    out: list[Any] = []
    for g in range(k):
        if not np.any(groups == g):
            out.append(None)
            continue
        out.append([gram_basis(grams[n][g]) for n in range(len(sizes))])
    return out


def preclustered_dictionaries(source: Any, k: int, s: int, random_state: int,
                              batch_size: int = 4) -> list[np.ndarray]:  # fmt: skip
    """The K initial dictionaries, per mode (K, m_n, m_n): module docstring, steps 1–4."""
    rng = np.random.default_rng(random_state)
    groups = precluster(source, k, s, int(rng.integers(2**32)), batch_size)
    dicts = [np.empty((k, m, m)) for m in source.mode_sizes]
    for g, bases in enumerate(group_hosvd(source, groups, k, batch_size)):
        for mode, m in enumerate(source.mode_sizes):
            dicts[mode][g] = random_orthonormal(m, rng) if bases is None else bases[mode]
    return dicts

