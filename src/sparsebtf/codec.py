"""The SparseBTF codec end to end: train a model once, encode any BTF, decode it (§3.2–3.4).

>>> model = train([btf_a, btf_b], tau_train=(256, 32, 32))           # doctest: +SKIP
>>> coded = encode(btf_c, model, tau=(885, 64, 64), eps=1e-5)          # doctest: +SKIP
>>> image = coded_btf_view(coded).angular_image(0, 0)                  # doctest: +SKIP

Everything streams: statistics by view block, data points by patch, decoding by request.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from importlib import metadata
from typing import Any

import numpy as np

from ._progress import bar
from .data.btf import BTF, Index, as_index
from .datapoints import PatchGrid, iter_points, sample_points
from .errors import BTFInputError, ModelMismatchError
from .learning.coding import SparseCodes, sparse_code
from .learning.ensemble import DictionaryEnsemble
from .learning.tensor import reconstruct
from .model import CHANNELS, CodedBTF, Model
from .preprocessing import Preprocessor, StdMode, gather_statistics

__all__ = [
    "BTFPointSource",
    "DecodedBTF",
    "coded_btf_view",
    "decode_points",
    "encode",
    "parse_tau",
    "train",
]


def _version() -> str:
    try:
        return metadata.version("sparsebtf")
    except metadata.PackageNotFoundError:  # pragma: no cover - source checkout without install
        return "unknown"


def parse_tau(tau: int | str | Sequence[int], channels: Sequence[str] = CHANNELS) -> dict[str, int]:
    """τ per channel from an int (all channels), "885,64,64", or a sequence."""
    if isinstance(tau, str):
        try:
            vals = [int(t) for t in tau.split(",")]
        except ValueError:
            raise BTFInputError(f"tau must be integers separated by commas, got {tau!r}") from None
    elif isinstance(tau, int | np.integer):
        vals = [int(tau)]
    else:
        vals = [int(t) for t in tau]
    if len(vals) == 1:
        vals = vals * len(channels)
    if len(vals) != len(channels):
        raise BTFInputError(
            f"tau needs one value per channel {tuple(channels)}, got {len(vals)} values"
        )
    if any(v < 1 for v in vals):
        raise BTFInputError(f"every tau must be >= 1, got {vals}")
    return dict(zip(channels, vals, strict=True))


class BTFPointSource:
    """Training points of several BTFs for one channel, streamed from the BTFs themselves.

    ``channel`` is 0/1/2 (Y/U/V: 4D points) or None (5D points with colour as the last mode).
    Memory is one batch; every pass re-reads the patches.
    """

    def __init__(
        self,
        items: Sequence[tuple[BTF, Preprocessor, np.ndarray]],
        patch: int,
        channel: int | None,
    ) -> None:
        self.items = list(items)
        self.patch = patch
        self.channel = channel
        self._starts = np.cumsum([0] + [len(ix) for _, _, ix in self.items])
        btf0 = self.items[0][0]
        spatial = (patch, patch, btf0.shape[2], btf0.shape[3])
        self._shape = spatial if channel is not None else (*spatial, 3)

    @property
    def n_points(self) -> int:
        return int(self._starts[-1])

    @property
    def mode_sizes(self) -> tuple[int, ...]:
        return self._shape

    def _pick(self, x: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(x[..., self.channel]) if self.channel is not None else x

    def batches(self, batch_size: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for j, (btf, pre, idx) in enumerate(self.items):
            done = 0
            for _, x in iter_points(btf, pre, self.patch, idx, batch_size):
                g = np.arange(done, done + x.shape[0]) + self._starts[j]
                done += x.shape[0]
                yield g, self._pick(x)

    def take(self, indices: np.ndarray) -> np.ndarray:
        out = np.empty((len(indices), *self._shape), dtype=np.float32)
        for n, g in enumerate(np.asarray(indices)):
            j = int(np.searchsorted(self._starts, g, side="right") - 1)
            btf, pre, idx = self.items[j]
            _, x = next(iter_points(btf, pre, self.patch, [int(idx[g - self._starts[j]])], 1))
            out[n] = self._pick(x)[0]
        return out


def _check_same_directions(btfs: Sequence[BTF]) -> None:
    ref = btfs[0]
    for b in btfs[1:]:
        if not (b.lights.equals(ref.lights) and b.views.equals(ref.views)):
            raise BTFInputError(
                f"{b.name}: its direction tables ({len(b.lights)} lights, {len(b.views)} views) "
                f"differ from {ref.name}'s; one model needs one angular sampling"
            )


def train(
    btfs: Sequence[BTF],
    *,
    n_dictionaries: int = 8,
    tau_train: int | str | Sequence[int] = (256, 32, 32),
    patch: int = 10,
    sample: float = 0.1,
    max_iter: int = 10,
    tol: float = 1e-4,
    std_mode: StdMode = "shared",
    colour_mode: bool = False,
    init: str = "points",
    batch_size: int = 4,
    dtype: str = "float32",
    seed: int = 0,
    checkpoint_dir: str | None = None,
    progress: bool | None = None,
) -> Model:
    """Learn a model from BTFs (paper §3.2): one ensemble per YUV channel, or one 5D ensemble.

    ``sample`` is the fraction of each BTF's data points used (paper: 10% of 18 BTFs).
    ``colour_mode`` trains one ensemble on 5D points (p, p, L, V, 3), the paper's Table 6.
    With ``checkpoint_dir`` each channel resumes from its last completed iteration.
    """
    if not btfs:
        raise BTFInputError("training needs at least one BTF")
    _check_same_directions(btfs)
    grids = [PatchGrid.for_btf(b, patch) for b in btfs]
    channels = ("YUV",) if colour_mode else CHANNELS
    taus = parse_tau(tau_train, channels)
    t0 = time.perf_counter()
    pres = [Preprocessor(gather_statistics(b, std_mode, progress=progress)) for b in btfs]
    samples = sample_points([g.n_points for g in grids], sample, seed)
    items = [(btfs[b], pres[b], idx) for b, idx in samples]
    dictionaries: dict[str, list[np.ndarray]] = {}
    training: dict[str, dict[str, Any]] = {}
    for c, ch in enumerate(channels):
        ens = DictionaryEnsemble(
            n_dictionaries=n_dictionaries,
            tau=taus[ch],
            max_iter=max_iter,
            tol=tol,
            init=init,
            batch_size=batch_size,
            dtype=dtype,
            random_state=seed + c,
            checkpoint=None if checkpoint_dir is None else f"{checkpoint_dir}/train_{ch}.npz",
            progress=progress,
        )
        src = BTFPointSource(items, patch, None if colour_mode else c)
        ens.fit(src, desc=f"train {ch}")
        dictionaries[ch] = ens.dictionaries_
        training[ch] = {
            "objective": [float(v) for v in ens.objective_],
            "membership_counts": [int(v) for v in ens.counts_],
            "n_iter": int(ens.n_iter_),
            "seconds": float(ens.fit_seconds_),
            "n_points": int(src.n_points),
        }
    params = {
        "n_dictionaries": n_dictionaries,
        "tau_train": taus,
        "patch": patch,
        "sample": sample,
        "max_iter": max_iter,
        "tol": tol,
        "std_mode": std_mode,
        "colour_mode": colour_mode,
        "init": init,
        "seed": seed,
        "dtype": dtype,
    }
    provenance = {
        "library": f"sparsebtf {_version()}",
        "materials": [b.name for b in btfs],
        "material_attrs": [b.attrs for b in btfs],
        "seconds": time.perf_counter() - t0,
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    return Model(dictionaries, patch, btfs[0].lights, btfs[0].views, params, provenance, training)


def encode(
    btf: BTF,
    model: Model,
    *,
    tau: int | str | Sequence[int] = (885, 64, 64),
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
    if not (btf.lights.equals(model.lights) and btf.views.equals(model.views)):
        raise ModelMismatchError(
            f"{btf.name}: {len(btf.lights)} lights x {len(btf.views)} views do not match the "
            f"model's {len(model.lights)} x {len(model.views)} direction tables"
        )
    grid = PatchGrid.for_btf(btf, model.patch)
    channels = model.channels
    taus = parse_tau(tau, channels)
    tau_train = model.params.get("tau_train", {})
    for ch in channels:
        if ch in tau_train and taus[ch] < int(tau_train[ch]) and not allow_below_training:
            raise BTFInputError(
                f"channel {ch}: testing sparsity tau_t = {taus[ch]} is below the training "
                f"sparsity tau_l = {tau_train[ch]}; the paper requires tau_t >= tau_l "
                "(pass allow_below_training / --allow-below-training to force it)"
            )
    if eps < 0:
        raise BTFInputError(f"eps must be >= 0, got {eps}")
    mode = std_mode or model.params.get("std_mode", "shared")
    stats = gather_statistics(btf, mode, progress=progress)
    pre = Preprocessor(stats)
    dt = np.dtype(dtype).type
    parts: dict[str, list[SparseCodes]] = {ch: [] for ch in channels}
    with bar(grid.n_points, f"encode {btf.name}", "pt", progress) as pb:
        for _, x in iter_points(btf, pre, model.patch, None, batch_size):
            for c, ch in enumerate(channels):
                xc = x if ch == "YUV" else np.ascontiguousarray(x[..., c])
                parts[ch].append(sparse_code(xc, model.dictionaries[ch], taus[ch], eps, dt))
            pb.update(x.shape[0])
    codes = {ch: SparseCodes.concatenate(parts[ch]) for ch in channels}
    params = {"tau": taus, "eps": eps, "std_mode": mode, "dtype": dtype}
    coded = CodedBTF(
        codes, stats, btf.height, btf.width, model.patch, btf.lights, btf.views,
        model.content_hash, params, btf.name, dict(btf.attrs),
    )
    return coded.attach(model)


def decode_points(
    coded: CodedBTF,
    channel: str,
    points: Sequence[int] | np.ndarray,
    lights: Index = slice(None),
    views: Index = slice(None),
) -> np.ndarray:
    """Eq. 4 for chosen points of one channel, restricted to chosen lights and views.

    Returns standardised values (n, p, p, l, v) (plus a colour axis for "YUV"). Restricting
    the angular modes multiplies by the needed rows of U3, U4 only.
    """
    model = coded.require_model()
    codes = coded.codes[channel]
    li = as_index(lights, len(coded.lights), "light")
    vi = as_index(views, len(coded.views), "view")
    idx = np.asarray(points, dtype=np.int64)
    out = np.empty((idx.size, coded.patch, coded.patch, li.size, vi.size, *codes.mode_sizes[4:]))
    dicts = model.dictionaries[channel]
    for j, i in enumerate(idx):
        loc, val = codes.point(int(i))
        k = int(codes.membership[i])
        s = np.zeros((1, *codes.mode_sizes))
        s[(0, *loc.T)] = val
        mats = [d[k] for d in dicts]
        mats[2] = mats[2][li]
        mats[3] = mats[3][vi]
        out[j] = reconstruct(s, mats)[0]
    return out


class DecodedBTF(BTF):
    """A coded BTF seen as a lazy :class:`BTF`: every read decodes what it needs (Eq. 4).

    Reads decode the data points that cover the requested texels, only at the requested
    directions, then undo the standardisation, YUV and log (linear RGB, float32).
    """

    def __init__(self, coded: CodedBTF) -> None:
        coded.require_model()
        if "YUV" not in coded.channels and len(coded.channels) < 3:
            raise BTFInputError(
                f"{coded.name}: only channels {coded.channels} are coded; RGB needs Y, U and V"
            )
        super().__init__(coded.height, coded.width, coded.lights, coded.views,
                         coded.name, dict(coded.attrs))
        self.coded = coded
        self.grid = PatchGrid(coded.height, coded.width, coded.patch)
        self.pre = Preprocessor(coded.stats)

    def read(self, rows: Index, cols: Index, lights: Index, views: Index) -> np.ndarray:
        h, w, nl, nv, _ = self.shape
        r = as_index(rows, h, "row")
        c = as_index(cols, w, "col")
        li = as_index(lights, nl, "light")
        vi = as_index(views, nv, "view")
        p = self.coded.patch
        rb = np.unique(r // p)
        cb = np.unique(c // p)
        pts = self.grid.index(rb[:, None], cb[None, :]).T.ravel()  # col-block major order
        z = np.empty((rb.size * p, cb.size * p, li.size, vi.size, 3))
        for ch_i, ch in enumerate(self.coded.channels):
            vals = decode_points(self.coded, ch, pts, li, vi)
            # (cb, rb, i1, i2, ...) → (rb, i1, cb, i2, ...)
            vals = vals.reshape(cb.size, rb.size, p, p, li.size, vi.size, *vals.shape[5:])
            vals = np.moveaxis(vals, 0, 2).reshape(rb.size * p, cb.size * p, li.size, vi.size,
                                                   *vals.shape[6:])
            if ch == "YUV":
                z[...] = vals
            else:
                z[..., ch_i] = vals
        # Map requested rows/cols into the decoded block.
        row_pos = (np.searchsorted(rb, r // p) * p + r % p)
        col_pos = (np.searchsorted(cb, c // p) * p + c % p)
        z = z[np.ix_(row_pos, col_pos, np.arange(li.size), np.arange(vi.size), np.arange(3))]
        return self.pre.inverse(z, li, vi).astype(np.float32)


def coded_btf_view(coded: CodedBTF) -> DecodedBTF:
    """The decoded BTF of ``coded`` as a lazy :class:`BTF` (needs the model attached)."""
    return DecodedBTF(coded)
