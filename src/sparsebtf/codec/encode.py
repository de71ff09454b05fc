"""Encode a BTF on a trained model (paper §3.3, Eq. 3): the sparsest, then least-error code of
every data point on its best dictionary, streamed point by point.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .._progress import bar
from ..data.btf import BTF
from ..errors import BTFInputError
from ..learning.coding import SparseCodes, sparse_code_levels
from ..learning.parallel import prefetch
from ..model import CodedBTF, Model, TauSpec, parse_tau
from ..points.grid import PatchGrid, iter_points
from ..points.preprocessing import Preprocessor, Standardization, StdMode, gather_statistics

__all__ = ["coded_btf", "encode", "encode_levels", "material_statistics"]


def material_statistics(
    btf: BTF, model: Model, std_mode: StdMode | None, progress: bool | None
) -> Standardization:
    """The standardisation of ``btf`` in the model's preprocessing (the model's std mode
    unless ``std_mode`` overrides it)."""
    return gather_statistics(
        btf, std_mode or model.std_mode, progress=progress, transform=model.transform
    )


def coded_btf(
    btf: BTF,
    model: Model,
    codes: dict[str, SparseCodes],
    stats: Standardization,
    params: dict[str, Any],
) -> CodedBTF:
    """The coded BTF of ``btf`` on ``model`` (model attached), from its codes and statistics."""
    params = {
        **params,
        "std_mode": stats.mode,
        "n_dictionaries": {ch: model.n_dictionaries(ch) for ch in codes},
    }
    coded = CodedBTF(
        codes, stats, btf.height, btf.width, model.patch, btf.lights, btf.views,
        model.content_hash, params, btf.name, dict(btf.attrs),
    )  # fmt: skip
    return coded.attach(model)


def encode(
    btf: BTF,
    model: Model,
    *,
    tau: TauSpec = (885, 64, 64),
    eps: float = 1e-5,
    std_mode: StdMode | None = None,
    batch_size: int = 4,
    dtype: str = "float32",
    allow_below_training: bool = False,
    progress: bool | None = None,
) -> CodedBTF:
    """Sparse representation of one BTF on a trained model (paper §3.3, Eq. 3).

    ``tau`` caps the coefficients per data point and channel (release: Y 885, U 64, V 64);
    ``eps`` is the mean-squared-residual threshold. τ_t < τ_l is refused (the paper requires
    τ_t >= τ_l) unless ``allow_below_training``.
    """
    return encode_levels(
        btf,
        model,
        [tau],
        eps=eps,
        std_mode=std_mode,
        batch_size=batch_size,
        dtype=dtype,
        allow_below_training=allow_below_training,
        progress=progress,
    )[0]


def _check_levels(levels: list[dict[str, int]], model: Model, allow_below: bool) -> None:
    tau_train = model.tau_train
    for taus_c in levels:
        for ch, t in taus_c.items():
            if ch in tau_train and t < tau_train[ch] and not allow_below:
                raise BTFInputError(
                    f"channel {ch}: testing sparsity tau_t = {t} is below the training "
                    f"sparsity tau_l = {tau_train[ch]}; the paper requires tau_t >= tau_l "
                    "(pass allow_below_training / --allow-below-training to force it)"
                )


def encode_levels(
    btf: BTF,
    model: Model,
    taus: Sequence[TauSpec],
    *,
    eps: float = 1e-5,
    std_mode: StdMode | None = None,
    batch_size: int = 4,
    dtype: str = "float32",
    allow_below_training: bool = False,
    progress: bool | None = None,
) -> list[CodedBTF]:
    """:func:`encode` at several sparsity levels from one pass (projections are shared)."""
    model.check_directions(btf)
    grid = PatchGrid.for_btf(btf, model.patch)
    channels = model.channels
    levels = [parse_tau(t, channels) for t in taus]
    _check_levels(levels, model, allow_below_training)
    if eps < 0:
        raise BTFInputError(f"eps must be >= 0, got {eps}")
    stats = material_statistics(btf, model, std_mode, progress)
    pre = Preprocessor(stats)
    dt = np.dtype(dtype).type
    parts: list[dict[str, list[SparseCodes]]] = [{ch: [] for ch in channels} for _ in levels]
    with bar(grid.n_points, f"encode {btf.name}", "pt", progress) as pb:
        for _, x in prefetch(iter_points(btf, pre, model.patch, None, batch_size)):
            for c, ch in enumerate(channels):
                xc = x if ch == "YUV" else np.ascontiguousarray(x[..., c])
                coded = sparse_code_levels(
                    xc, model.dictionaries[ch], [lv[ch] for lv in levels], eps, dt
                )
                for j, sc in enumerate(coded):
                    parts[j][ch].append(sc)
            pb.update(x.shape[0])
    return [
        coded_btf(
            btf, model, {ch: SparseCodes.concatenate(parts[j][ch]) for ch in channels}, stats,
            {"tau": taus_c, "eps": eps, "dtype": dtype},
        )
        for j, taus_c in enumerate(levels)
    ]  # fmt: skip
