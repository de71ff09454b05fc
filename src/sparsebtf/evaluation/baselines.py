"""Baselines at equal storage: per-material PCA (truncated SVD) of the ABRDF matrix.

The paper's Table 5 compares SparseBTF with PCA at twice SparseBTF's storage. UBO2014 itself
ships every material as per-channel truncated SVD factors (DFMF, ``peers.md``), so this is the
natural per-material baseline: for each colour channel c the texels × (lights·views) matrix

    X_c[t, light·V + view]   (t = row·W + col)

is approximated by a rank-r_c product ``S_c A_cᵀ`` whose factors are stored in binary16:

    bytes = 2 · Σ_c r_c · (H·W + L·V)

The ranks r_c share one budget, spread over the channels greedily by captured energy (σ²),
which is optimal for the squared error in the fitted domain. Two domains are offered: linear
RGB, and ln(RGB + 1e-5) (UBO2014's dynamic-range reduction); the benchmark reports both.

The SVD is a randomized range finder with power iterations (Halko, Martinsson & Tropp 2011)
streamed by spatial tiles: memory is one tile plus the (H·W + L·V) × k sketches, never the
whole matrix, and it is exact when k >= min(H·W, L·V). The per-material bytes exclude
nothing (PCA has no shared part); SparseBTF's shared dictionaries are reported apart.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Literal

import numpy as np

from .._progress import bar
from ..data.btf import BTF, RELEASE_LOG_OFFSET, FactorBTF
from ..errors import BTFInputError

__all__ = [
    "PCAFit",
    "allocate_ranks",
    "fit_pca",
    "fit_pca_domains",
    "pca_bytes",
    "pca_rank_for_budget",
    "pca_reconstruction",
]

PCADomain = Literal["log", "linear"]
#: Log offset of the log-domain PCA (UBO2014's and the release's 1e-5).
PCA_LOG_OFFSET = RELEASE_LOG_OFFSET


def pca_bytes(ranks: int | list[int] | tuple[int, ...], n_texels: int, n_angular: int) -> int:
    """binary16 bytes of per-channel rank-r factors: 2 · Σ r_c · (texels + lights·views)."""
    total = int(ranks) if isinstance(ranks, int | np.integer) else int(sum(ranks))
    if total < 0:
        raise BTFInputError(f"ranks must be >= 0, got {ranks}")
    return 2 * total * (int(n_texels) + int(n_angular))


def pca_rank_for_budget(budget_bytes: int, n_texels: int, n_angular: int) -> int:
    """The largest total rank Σ r_c whose factors fit in ``budget_bytes`` (0 if none fits)."""
    if budget_bytes < 0:
        raise BTFInputError(f"budget must be >= 0 bytes, got {budget_bytes}")
    return int(budget_bytes) // (2 * (int(n_texels) + int(n_angular)))


@dataclass(eq=False)
class PCAFit:
    """Leading singular triplets of each channel's ABRDF matrix.

    Attributes
    ----------
    u : (3, H·W, k) left singular vectors.
    s : (3, k) singular values, decreasing.
    v : (3, L·V, k) right singular vectors.
    domain : "log" or "linear".
    """

    u: np.ndarray
    s: np.ndarray
    v: np.ndarray
    domain: PCADomain
    height: int
    width: int

    @property
    def max_rank(self) -> int:
        return int(self.s.shape[1])


def _tiles(btf: BTF, tile: int) -> Iterator[tuple[np.ndarray, slice, slice]]:
    h, w = btf.height, btf.width
    for r in range(0, h, tile):
        for c in range(0, w, tile):
            rows, cols = slice(r, min(r + tile, h)), slice(c, min(c + tile, w))
            ridx = np.arange(rows.start, rows.stop)
            cidx = np.arange(cols.start, cols.stop)
            yield (ridx[:, None] * w + cidx[None, :]).ravel(), rows, cols


def _tile_matrix(
    btf: BTF, rows: slice, cols: slice, domains: tuple[PCADomain, ...]
) -> np.ndarray:
    """(3·D, texels, L·V) float32 rows of the ABRDF matrices of a tile, per domain."""
    x = np.maximum(btf.region(rows, cols).astype(np.float32), 0)
    n = x.shape[0] * x.shape[1]
    x = np.moveaxis(x.reshape(n, -1, 3), 2, 0)
    parts = [np.log(x + np.float32(PCA_LOG_OFFSET)) if d == "log" else x for d in domains]
    return np.ascontiguousarray(np.concatenate(parts) if len(parts) > 1 else parts[0])


def fit_pca(
    btf: BTF,
    max_rank: int,
    *,
    domain: PCADomain = "log",
    oversample: int = 8,
    power_iters: int = 2,
    tile: int = 20,
    seed: int = 0,
    progress: bool | None = None,
) -> PCAFit:
    """Top ``max_rank`` singular triplets per RGB channel, streamed by spatial tiles.

    Passes over the BTF: 2 + 2 · ``power_iters``. Sketch width k = max_rank + oversample,
    clipped to min(H·W, L·V) (then the result is exact).
    """
    return fit_pca_domains(
        btf, max_rank, domains=(domain,), oversample=oversample, power_iters=power_iters,
        tile=tile, seed=seed, progress=progress,
    )[0]


def fit_pca_domains(
    btf: BTF,
    max_rank: int,
    *,
    domains: tuple[PCADomain, ...] = ("log", "linear"),
    oversample: int = 8,
    power_iters: int = 2,
    tile: int = 20,
    seed: int = 0,
    progress: bool | None = None,
) -> list[PCAFit]:
    """:func:`fit_pca` for several domains from the same passes over the BTF (one read each)."""
    for domain in domains:
        if domain not in ("log", "linear"):
            raise BTFInputError(f"PCA domain must be 'log' or 'linear', got {domain!r}")
    if not domains:
        raise BTFInputError("give at least one PCA domain")
    if max_rank < 1:
        raise BTFInputError(f"PCA needs max_rank >= 1, got {max_rank}")
    t = btf.height * btf.width
    a = len(btf.lights) * len(btf.views)
    k = min(max_rank + oversample, t, a)
    nc = 3 * len(domains)
    rng = np.random.default_rng(seed)
    tiles = list(_tiles(btf, tile))
    n_pass = 2 + 2 * power_iters
    pb = bar(n_pass * len(tiles), f"PCA {btf.name}", "tile", progress)

    def right(omega: np.ndarray) -> np.ndarray:
        """Y = X Ω per channel: (3, T, k)."""
        y = np.empty((nc, t, omega.shape[2]))
        om = omega.astype(np.float32)
        for idx, rows, cols in tiles:
            x = _tile_matrix(btf, rows, cols, domains)
            y[:, idx] = np.matmul(x, om)
            pb.update(1)
        return y

    def left(q: np.ndarray) -> np.ndarray:
        """Z = Xᵀ Q per channel: (3, A, k)."""
        z = np.zeros((nc, a, q.shape[2]))
        for idx, rows, cols in tiles:
            x = _tile_matrix(btf, rows, cols, domains)
            z += np.matmul(np.swapaxes(x, 1, 2), q[:, idx].astype(np.float32))
            pb.update(1)
        return z

    def orth(m: np.ndarray) -> np.ndarray:
        return np.stack([np.linalg.qr(m[c])[0] for c in range(nc)])

    with pb:
        y = right(rng.standard_normal((nc, a, k)))
        for _ in range(power_iters):
            z = orth(left(orth(y)))
            y = right(z)
        q = orth(y)
        z = left(q)  # Bᵀ = Xᵀ Q, B = Qᵀ X (k × A)
    us, ss, vs = [], [], []
    r = min(max_rank, k)
    for c in range(nc):
        ub, s, vt = np.linalg.svd(z[c].T, full_matrices=False)
        us.append(q[c] @ ub[:, :r])
        ss.append(s[:r])
        vs.append(vt[:r].T)
    return [
        PCAFit(np.stack(us[3 * d : 3 * d + 3]), np.stack(ss[3 * d : 3 * d + 3]),
               np.stack(vs[3 * d : 3 * d + 3]), dom, btf.height, btf.width)
        for d, dom in enumerate(domains)
    ]


def allocate_ranks(fit: PCAFit, total_rank: int) -> tuple[int, int, int]:
    """Split ``total_rank`` over R, G, B greedily by σ² (largest captured energy first)."""
    if total_rank < 0:
        raise BTFInputError(f"total rank must be >= 0, got {total_rank}")
    total_rank = min(total_rank, 3 * fit.max_rank)
    flat = fit.s.ravel() ** 2
    order = np.argsort(-flat, kind="stable")[:total_rank]
    ranks = np.bincount(order // fit.max_rank, minlength=3)
    return int(ranks[0]), int(ranks[1]), int(ranks[2])


def pca_reconstruction(
    fit: PCAFit, ranks: tuple[int, int, int], like: BTF, name: str | None = None
) -> FactorBTF:
    """The rank-(r_R, r_G, r_B) reconstruction with binary16 factors, as a lazy BTF.

    Factors are split as S = U·√σ and A = V·√σ, rounded to binary16 (what the bytes count),
    and channels of lower rank are padded with zero columns. A channel of rank 0 is 0 (linear)
    or exp(0) − offset ≈ 1 (log), the honest value of storing nothing.
    """
    if any(r > fit.max_rank for r in ranks):
        raise BTFInputError(f"ranks {ranks} exceed the fitted rank {fit.max_rank}")
    rmax = max(1, max(ranks))
    t, a = fit.u.shape[1], fit.v.shape[1]
    sp = np.zeros((3, t, rmax), dtype=np.float32)
    an = np.zeros((3, a, rmax), dtype=np.float32)
    for c, r in enumerate(ranks):
        root = np.sqrt(fit.s[c, :r])
        sp[c, :, :r] = (fit.u[c, :, :r] * root).astype(np.float16)
        an[c, :, :r] = (fit.v[c, :, :r] * root).astype(np.float16)
    return FactorBTF(
        sp, an, like.height, like.width, like.lights, like.views,
        log_domain=fit.domain == "log", log_offset=PCA_LOG_OFFSET,
        name=name or f"{like.name}-pca{sum(ranks)}-{fit.domain}",
    )
