"""The SparseBTF codec end to end: train a model once, encode any BTF, decode it (§3.2–3.4).

>>> model = train([btf_a, btf_b], tau_train=(256, 32, 32))           # doctest: +SKIP
>>> coded = encode(btf_c, model, tau=(885, 64, 64), eps=1e-5)          # doctest: +SKIP
>>> image = coded_btf_view(coded).angular_image(0, 0)                  # doctest: +SKIP

Everything streams: statistics by view block, data points by patch, decoding by request.
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
import time
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from . import library_version
from ._progress import bar
from .data.btf import BTF, Index, as_index
from .datapoints import PatchGrid, iter_points, sample_points
from .errors import BTFInputError, ModelMismatchError
from .learning.coding import SparseCodes, sparse_code_levels, topk_abs
from .learning.ensemble import DictionaryEnsemble
from .learning.parallel import parallel_map, prefetch
from .learning.rate_control import (
    PAPER_SPLIT,
    ChannelCandidates,
    allocate,
    reference_counts,
)
from .learning.tensor import project, reconstruct
from .model import CHANNELS, CodedBTF, Model
from .preprocessing import (
    TRANSFORMS,
    YUV_TO_RGB,
    Preprocessor,
    Standardization,
    StdMode,
    Transform,
    gather_statistics,
)

#: Up to this many (light, view) pairs a read uses Eq. 5 (sparse sums), above it Eq. 4.
EQ5_MAX_DIRECTIONS = 16

__all__ = [
    "BTFPointSource",
    "DecodedBTF",
    "coded_btf_view",
    "decode_points",
    "decode_points_eq5",
    "encode",
    "encode_levels",
    "encode_rate_levels",
    "encode_to_size",
    "material_target_bytes",
    "parse_tau",
    "train",
]


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


class StagedPoints:
    """Training points preprocessed once into a temporary HDF5 file, one dataset per channel.

    Training makes K + 4 passes per iteration per channel; reading contiguous float32 points
    back is far cheaper than re-reading and re-preprocessing the BTFs each time. Memory stays
    at one batch: points are written and read one batch at a time. ``source`` yields all three
    colour channels (``channel=None``); each staged dataset keeps one of them, or all for 5D.
    """

    def __init__(
        self,
        path: str,
        source: BTFPointSource,
        channels: Sequence[str],
        batch_size: int = 4,
        progress: bool | None = None,
    ) -> None:
        import h5py

        self.path = path
        self._file = h5py.File(path, "w")
        n = source.n_points
        shape = (source.patch, source.patch, *source.mode_sizes[2:4])
        full = (*shape, 3) if channels == ("YUV",) else shape
        self._ds = {
            ch: self._file.create_dataset(ch, shape=(n, *full), dtype="float32", chunks=(1, *full))
            for ch in channels
        }
        with bar(n, "stage points", "pt", progress) as pb:
            for g, x in source.batches(batch_size):
                lo, hi = int(g[0]), int(g[-1]) + 1
                for c, ch in enumerate(channels):
                    self._ds[ch][lo:hi] = x if ch == "YUV" else x[..., c]
                pb.update(hi - lo)

    def source(self, channel: str) -> _StagedChannel:
        return _StagedChannel(self._ds[channel])

    def close(self) -> None:
        self._file.close()


class _StagedChannel:
    """:class:`~sparsebtf.learning.ensemble.PointSource` over one staged dataset."""

    def __init__(self, ds: Any) -> None:
        self._ds = ds

    @property
    def n_points(self) -> int:
        return int(self._ds.shape[0])

    @property
    def mode_sizes(self) -> tuple[int, ...]:
        return tuple(int(v) for v in self._ds.shape[1:])

    def batches(self, batch_size: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for s in range(0, self.n_points, batch_size):
            e = min(s + batch_size, self.n_points)
            yield np.arange(s, e), self._ds[s:e]

    def take(self, indices: np.ndarray) -> np.ndarray:
        return np.stack([self._ds[int(i)] for i in np.asarray(indices)])


#: Training points are staged on disk when they need at most this many bytes.
STAGE_LIMIT_BYTES = 32 * 2**30


def _check_same_directions(btfs: Sequence[BTF]) -> None:
    ref = btfs[0]
    for b in btfs[1:]:
        if not (b.lights.equals(ref.lights) and b.views.equals(ref.views)):
            raise BTFInputError(
                f"{b.name}: its direction tables ({len(b.lights)} lights, {len(b.views)} views) "
                f"differ from {ref.name}'s; one model needs one angular sampling"
            )


def _check_model_directions(btf: BTF, model: Model) -> None:
    """Codes only mean something on the direction tables the model was trained for."""
    if not (btf.lights.equals(model.lights) and btf.views.equals(model.views)):
        raise ModelMismatchError(
            f"{btf.name}: {len(btf.lights)} lights x {len(btf.views)} views do not match the "
            f"model's {len(model.lights)} x {len(model.views)} direction tables"
        )


def _train_channels(
    channels: Sequence[str],
    taus: dict[str, int],
    items: list,
    patch: int,
    colour_mode: bool,
    staged: StagedPoints | None,
    dictionaries: dict[str, list[np.ndarray]],
    training: dict[str, dict[str, Any]],
    *,
    n_dictionaries: int,
    max_iter: int,
    tol: float,
    init: str,
    batch_size: int,
    dtype: str,
    seed: int,
    checkpoint_dir: str | None,
    progress: bool | None,
) -> None:
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
        src = (
            staged.source(ch)
            if staged is not None
            else BTFPointSource(items, patch, None if colour_mode else c)
        )
        ens.fit(src, desc=f"train {ch}")
        dictionaries[ch] = ens.dictionaries_
        training[ch] = {
            "objective": [float(v) for v in ens.objective_],
            "membership_counts": [int(v) for v in ens.counts_],
            "n_iter": int(ens.n_iter_),
            "seconds": float(ens.fit_seconds_),
            "n_points": int(src.n_points),
        }


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
    stage: bool | None = None,
    stage_dir: str | None = None,
    progress: bool | None = None,
    preprocessing: Transform = "log_yuv",
) -> Model:
    """Learn a model from BTFs (paper §3.2): one ensemble per YUV channel, or one 5D ensemble.

    ``sample`` is the fraction of each BTF's data points used (paper: 10% of 18 BTFs).
    ``colour_mode`` trains one ensemble on 5D points (p, p, L, V, 3), the paper's Table 6.
    With ``checkpoint_dir`` each channel resumes from its last completed iteration.
    ``stage`` preprocesses the sampled points once into a temporary file in ``stage_dir``
    (default: when they need at most :data:`STAGE_LIMIT_BYTES` and half the free disk);
    otherwise every pass streams them from the BTFs.
    ``preprocessing="identity"`` skips log, YUV and standardisation: the ensembles learn raw
    linear R, G, B (in the channel slots Y, U, V) — the [MHU19] baseline of the paper's Table 2.
    Encoding with the model then uses the same (no) processing.
    """
    if not btfs:
        raise BTFInputError("training needs at least one BTF")
    if preprocessing not in TRANSFORMS:
        raise BTFInputError(f"preprocessing must be one of {TRANSFORMS}, got {preprocessing!r}")
    _check_same_directions(btfs)
    grids = [PatchGrid.for_btf(b, patch) for b in btfs]
    channels = ("YUV",) if colour_mode else CHANNELS
    taus = parse_tau(tau_train, channels)
    t0 = time.perf_counter()
    pres = [
        Preprocessor(
            gather_statistics(b, std_mode, progress=progress, transform=preprocessing)
        )
        for b in btfs
    ]
    samples = sample_points([g.n_points for g in grids], sample, seed)
    items = [(btfs[b], pres[b], idx) for b, idx in samples]
    dictionaries: dict[str, list[np.ndarray]] = {}
    training: dict[str, dict[str, Any]] = {}
    raw = BTFPointSource(items, patch, None)
    need = raw.n_points * int(np.prod(raw.mode_sizes)) * 4
    if stage is None:
        stage = (
            need <= STAGE_LIMIT_BYTES
            and need < shutil.disk_usage(stage_dir or tempfile.gettempdir()).free // 2
        )
    with contextlib.ExitStack() as stack:
        staged = None
        if stage:
            tmp = stack.enter_context(
                tempfile.TemporaryDirectory(dir=stage_dir, prefix="sparsebtf-stage-")
            )
            staged = StagedPoints(f"{tmp}/points.h5", raw, channels, batch_size, progress)
            stack.callback(staged.close)
        _train_channels(
            channels,
            taus,
            items,
            patch,
            colour_mode,
            staged,
            dictionaries,
            training,
            n_dictionaries=n_dictionaries,
            max_iter=max_iter,
            tol=tol,
            init=init,
            batch_size=batch_size,
            dtype=dtype,
            seed=seed,
            checkpoint_dir=checkpoint_dir,
            progress=progress,
        )
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
    if preprocessing != "log_yuv":
        params["preprocessing"] = preprocessing
    provenance = {
        "library": f"sparsebtf {library_version()}",
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


def encode_levels(
    btf: BTF,
    model: Model,
    taus: Sequence[int | str | Sequence[int]],
    *,
    eps: float = 1e-5,
    std_mode: StdMode | None = None,
    batch_size: int = 4,
    dtype: str = "float32",
    allow_below_training: bool = False,
    progress: bool | None = None,
) -> list[CodedBTF]:
    """:func:`encode` at several sparsity levels from one pass (projections are shared)."""
    _check_model_directions(btf, model)
    grid = PatchGrid.for_btf(btf, model.patch)
    channels = model.channels
    levels = [parse_tau(t, channels) for t in taus]
    tau_train = model.params.get("tau_train", {})
    for taus_c in levels:
        for ch in channels:
            if ch in tau_train and taus_c[ch] < int(tau_train[ch]) and not allow_below_training:
                raise BTFInputError(
                    f"channel {ch}: testing sparsity tau_t = {taus_c[ch]} is below the training "
                    f"sparsity tau_l = {tau_train[ch]}; the paper requires tau_t >= tau_l "
                    "(pass allow_below_training / --allow-below-training to force it)"
                )
    if eps < 0:
        raise BTFInputError(f"eps must be >= 0, got {eps}")
    mode = std_mode or model.params.get("std_mode", "shared")
    stats = gather_statistics(
        btf, mode, progress=progress, transform=model.params.get("preprocessing", "log_yuv")
    )
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
    out = []
    for j, taus_c in enumerate(levels):
        codes = {ch: SparseCodes.concatenate(parts[j][ch]) for ch in channels}
        params = {
            "tau": taus_c,
            "eps": eps,
            "std_mode": mode,
            "dtype": dtype,
            "n_dictionaries": {ch: model.n_dictionaries(ch) for ch in channels},
        }
        coded_btf = CodedBTF(
            codes,
            stats,
            btf.height,
            btf.width,
            model.patch,
            btf.lights,
            btf.views,
            model.content_hash,
            params,
            btf.name,
            dict(btf.attrs),
        )
        out.append(coded_btf.attach(model))
    return out


#: Error weightings of the rate control (see :func:`encode_rate_levels`).
WEIGHTINGS = ("rgb", "log", "uniform")


def material_target_bytes(
    btf: BTF,
    model: Model,
    *,
    target_bytes: int | None = None,
    target_ratio: float | None = None,
    per_material: bool = False,
) -> int:
    """Per-material byte target (Table 4 without dictionaries) from a size or a ratio.

    ``target_bytes`` / ``target_ratio`` mean :func:`~sparsebtf.storage.storage_report`'s
    ``bytes_total`` / ``compression_ratio`` (dictionaries included, as in the paper's Table 4),
    unless ``per_material``: then they mean coefficients + membership/counts only
    (``compression_ratio_per_material``), the part that grows with each material.
    """
    if (target_bytes is None) == (target_ratio is None):
        raise BTFInputError("give exactly one of target_bytes and target_ratio")
    raw = 2 * btf.n_values
    if target_ratio is not None:
        if not target_ratio > 0:
            raise BTFInputError(f"target ratio must be > 0, got {target_ratio}")
        total = int(raw / float(target_ratio))
    else:
        total = int(target_bytes)  # type: ignore[arg-type]
        if total <= 0:
            raise BTFInputError(f"target bytes must be > 0, got {target_bytes}")
    if per_material:
        return total
    dicts = sum(2 * model.dictionary_entries(ch) for ch in model.channels)
    if total <= dicts:
        raise BTFInputError(
            f"{btf.name}: the target of {total:,d} bytes does not even hold the model's shared "
            f"dictionaries ({dicts:,d} bytes); ask for a per-material target "
            "(per_material=True, --per-material) or a larger size"
        )
    return total - dicts


def _point_weights(
    x: np.ndarray, pre: Preprocessor, stats: Standardization, channels: Sequence[str],
    weighting: str,
) -> np.ndarray:
    """(b, C) error weight of each point's channels for the rate control.

    * ``identity`` preprocessing: 1 (the channels are linear R, G, B: squared errors add up
      to the RGB squared error exactly).
    * ``uniform``: 1 (squared error in the standardised log-YUV domain, plain Parseval).
    * ``log``: ``‖YUV_TO_RGB[:, c]‖² · mean_j σ_{j,c}²``, the log-RGB squared error caused by a
      unit standardised error in channel c (U errors cost 1.4x Y errors, V 0.55x).
    * ``rgb`` (default): the same to first order in linear RGB, where a log error δ at value
      x costs x²δ²: ``mean_j σ_{j,c}² Σ_r (YUV_TO_RGB[r, c])² · mean_texels x_{r,j}²``.
    """
    b = x.shape[0]
    c = len(channels)
    if stats.transform == "identity" or weighting == "uniform":
        return np.ones((b, c))
    sd2 = np.square(stats.std).reshape(-1, stats.std.shape[2])  # (J, 1 or 3)
    m2 = np.square(YUV_TO_RGB)  # (rgb, yuv)
    if sd2.shape[1] == 1:
        sd2 = np.repeat(sd2, 3, axis=1)
    if weighting == "log":
        w = m2.sum(axis=0) * sd2.mean(axis=0)
        return np.broadcast_to(w[:c], (b, c)).copy()
    rgb = np.maximum(pre.inverse(x), 0)
    g = np.square(rgb, dtype=np.float64).mean(axis=(1, 2)).reshape(b, -1, 3)  # (b, J, rgb)
    return np.einsum("bjr,rc,jc->bc", g, m2, sd2)[:, :c] / sd2.shape[0]


def encode_rate_levels(
    btf: BTF,
    model: Model,
    targets: Sequence[int],
    *,
    weighting: str = "rgb",
    split: Sequence[float] | None = None,
    candidate_factor: float = 4.0,
    std_mode: StdMode | None = None,
    batch_size: int = 4,
    dtype: str = "float32",
    progress: bool | None = None,
) -> list[CodedBTF]:
    """Encode to per-material byte targets by rate control (one projection pass for all).

    Beyond the paper, whose τ_t is fixed per point (§3.3, Table 3): one coefficient budget per
    target is spread over every data point and channel, largest weighted gain w·s² first
    (exact by Parseval, :mod:`sparsebtf.learning.rate_control`). ``targets`` are bytes per
    material by Table 4 (coefficients + membership/counts, dictionaries excluded; see
    :func:`material_target_bytes`). Each point's dictionary is the one with the least error at
    the point's reference count (the target split over channels as ``split``, default the
    release's 885:64:64, or equal for identity preprocessing); its top
    ``candidate_factor`` × that count (+16) coefficients are the candidates. ``weighting``
    is one of :data:`WEIGHTINGS` (see :func:`_point_weights`). Results hit each target to
    within one coefficient (5 bytes) unless the candidate pool runs out (a warning).
    """
    from .storage.coded_file import location_width

    if weighting not in WEIGHTINGS:
        raise BTFInputError(f"weighting must be one of {WEIGHTINGS}, got {weighting!r}")
    if not targets:
        raise BTFInputError("give at least one target size")
    if candidate_factor < 1:
        raise BTFInputError(f"candidate_factor must be >= 1, got {candidate_factor}")
    _check_model_directions(btf, model)
    channels = model.channels
    if "YUV" in channels:
        raise BTFInputError("rate control supports the 4D (Y, U, V) models only")
    grid = PatchGrid.for_btf(btf, model.patch)
    n_pts = grid.n_points
    shape = model.mode_sizes
    size = int(np.prod(shape))
    loc_w = location_width(shape)
    transform = model.params.get("preprocessing", "log_yuv")
    if split is None:
        split = PAPER_SPLIT if transform == "log_yuv" else (1.0, 1.0, 1.0)
    refs = [
        reference_counts(int(t), n_pts, channels, loc_w, split, size) for t in targets
    ]
    ncand = [
        {ch: min(size, int(candidate_factor * r[ch]) + 16) for ch in channels} for r in refs
    ]
    nmax = {ch: max(nc[ch] for nc in ncand) for ch in channels}
    mode = std_mode or model.params.get("std_mode", "shared")
    stats = gather_statistics(btf, mode, progress=progress, transform=transform)
    pre = Preprocessor(stats)
    dt = np.dtype(dtype).type
    n_lv = len(targets)
    # per level, channel: lists of per-point rows
    parts: list[dict[str, dict[str, list]]] = [
        {ch: {"m": [], "idx": [], "val": [], "e": [], "w": []} for ch in channels}
        for _ in range(n_lv)
    ]
    mats = {
        ch: [[np.asarray(d[k], dtype=dt) for d in model.dictionaries[ch]]
             for k in range(model.n_dictionaries(ch))]
        for ch in channels
    }
    with bar(n_pts, f"rate-encode {btf.name}", "pt", progress) as pb:
        for _, x in prefetch(iter_points(btf, pre, model.patch, None, batch_size)):
            w = _point_weights(x, pre, stats, channels, weighting)
            for c, ch in enumerate(channels):
                xc = np.ascontiguousarray(x[..., c], dtype=dt)
                flat = xc.reshape(xc.shape[0], -1)
                energy = np.einsum("ij,ij->i", flat, flat, dtype=np.float64)
                n_k = len(mats[ch])
                pairs = [(i, k) for i in range(xc.shape[0]) for k in range(n_k)]

                def task(ik: tuple[int, int], xc=xc, ch=ch) -> tuple[np.ndarray, np.ndarray]:
                    i, k = ik
                    s = project(xc[i : i + 1], mats[ch][k]).reshape(-1)
                    idx = topk_abs(s, nmax[ch])
                    return idx, s[idx]

                res = list(parallel_map(task, pairs))
                for i in range(xc.shape[0]):
                    opts = res[i * n_k : (i + 1) * n_k]
                    cums = [np.cumsum(v.astype(np.float64) ** 2) for _, v in opts]
                    for lv in range(n_lv):
                        r = refs[lv][ch]
                        # least residual at the reference count; ties: lowest k
                        k = int(np.argmax([cs[min(r, cs.size) - 1] for cs in cums]))
                        n = ncand[lv][ch]
                        d = parts[lv][ch]
                        d["m"].append(k)
                        d["idx"].append(opts[k][0][:n])
                        d["val"].append(opts[k][1][:n].astype(np.float32))
                        d["e"].append(float(energy[i]))
                        d["w"].append(float(w[i, c]))
            pb.update(x.shape[0])
    out = []
    for lv, target in enumerate(targets):
        cands = {
            ch: ChannelCandidates(
                shape,
                np.asarray(parts[lv][ch]["m"], dtype=np.int64),
                np.stack(parts[lv][ch]["idx"]).astype(np.int64),
                np.stack(parts[lv][ch]["val"]),
                np.asarray(parts[lv][ch]["e"]),
                np.asarray(parts[lv][ch]["w"]),
            )
            for ch in channels
        }
        codes, summary = allocate(cands, int(target), loc_w)
        params = {
            "tau": {ch: int(codes[ch].counts.max()) for ch in channels},
            "eps": 0.0,
            "std_mode": mode,
            "dtype": dtype,
            "n_dictionaries": {ch: model.n_dictionaries(ch) for ch in channels},
            "rate_control": {
                "target_material_bytes": int(target),
                "material_bytes": summary["bytes"],
                "weighting": weighting,
                "reference_counts": refs[lv],
                "candidates": ncand[lv],
                "split": list(split),
            },
        }
        coded_btf = CodedBTF(
            codes, stats, btf.height, btf.width, model.patch, btf.lights, btf.views,
            model.content_hash, params, btf.name, dict(btf.attrs),
        )
        out.append(coded_btf.attach(model))
    return out


def encode_to_size(
    btf: BTF,
    model: Model,
    *,
    target_bytes: int | None = None,
    target_ratio: float | None = None,
    per_material: bool = False,
    weighting: str = "rgb",
    std_mode: StdMode | None = None,
    batch_size: int = 4,
    dtype: str = "float32",
    progress: bool | None = None,
) -> CodedBTF:
    """Encode ``btf`` to a target size or compression ratio by rate control.

    ``target_bytes`` / ``target_ratio`` are in the sense of
    :func:`~sparsebtf.storage.storage_report` (``bytes_total`` with the dictionaries,
    ``compression_ratio``), or per material with ``per_material`` (see
    :func:`material_target_bytes`). The storage report of the result lands within one
    coefficient (5 bytes) of the target. See :func:`encode_rate_levels`.
    """
    target = material_target_bytes(
        btf, model, target_bytes=target_bytes, target_ratio=target_ratio,
        per_material=per_material,
    )
    return encode_rate_levels(
        btf, model, [target], weighting=weighting, std_mode=std_mode, batch_size=batch_size,
        dtype=dtype, progress=progress,
    )[0]


def decode_points(
    coded: CodedBTF,
    channel: str,
    points: Sequence[int] | np.ndarray,
    lights: Index = slice(None),
    views: Index = slice(None),
    dtype: type = np.float64,
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
    if li.size * vi.size <= EQ5_MAX_DIRECTIONS:
        return decode_points_eq5(coded, channel, idx, li, vi).astype(dtype, copy=False)
    out = np.empty(
        (idx.size, coded.patch, coded.patch, li.size, vi.size, *codes.mode_sizes[4:]), dtype=dtype
    )
    dicts = model.dictionaries[channel]

    def task(j: int) -> None:
        i = int(idx[j])
        loc, val = codes.point(i)
        k = int(codes.membership[i])
        s = np.zeros((1, *codes.mode_sizes), dtype=dtype)
        s[(0, *loc.T)] = val
        mats = [np.asarray(d[k], dtype=dtype) for d in dicts]
        mats[2] = mats[2][li]
        mats[3] = mats[3][vi]
        out[j] = reconstruct(s, mats)[0]

    for _ in parallel_map(task, range(idx.size)):
        pass
    return out


def decode_points_eq5(
    coded: CodedBTF,
    channel: str,
    points: Sequence[int] | np.ndarray,
    lights: Index = slice(None),
    views: Index = slice(None),
) -> np.ndarray:
    """Eq. 5 for chosen points: Σ_s v_s U1[i1,l1] U2[i2,l2] U3[light,l3] U4[view,l4].

    Sums the sparse coefficients directly (no dense coefficient tensor): the cost is
    p²·l·v·τ per point, so this is the path for a few directions. Points are batched by
    padding every point to the largest count with zero coefficients.
    """
    model = coded.require_model()
    codes = coded.codes[channel]
    li = as_index(lights, len(coded.lights), "light")
    vi = as_index(views, len(coded.views), "view")
    idx = np.asarray(points, dtype=np.int64)
    dicts = model.dictionaries[channel]
    o = codes.offsets
    cnt = codes.counts[idx]
    width = int(cnt.max()) if idx.size else 0
    pos = o[idx][:, None] + np.arange(width)[None, :]
    valid = np.arange(width)[None, :] < cnt[:, None]
    pos = np.where(valid, pos, 0)
    val = np.where(valid, codes.values[pos], 0.0).astype(np.float64)
    loc = codes.locations[pos]  # (n, width, N)
    k = codes.membership[idx][:, None]
    a1 = dicts[0][k, :, loc[..., 0]]  # (n, width, p)
    a2 = dicts[1][k, :, loc[..., 1]]
    a3 = dicts[2][k[..., None], li[None, None, :], loc[..., 2][..., None]]  # (n, width, l)
    a4 = dicts[3][k[..., None], vi[None, None, :], loc[..., 3][..., None]]
    if len(dicts) == 5:  # colour mode
        a5 = dicts[4][k, :, loc[..., 4]]
        return np.einsum("nw,nwa,nwb,nwc,nwd,nwe->nabcde", val, a1, a2, a3, a4, a5, optimize=True)
    return np.einsum("nw,nwa,nwb,nwc,nwd->nabcd", val, a1, a2, a3, a4, optimize=True)


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
        super().__init__(
            coded.height, coded.width, coded.lights, coded.views, coded.name, dict(coded.attrs)
        )
        self.coded = coded
        self.grid = PatchGrid(coded.height, coded.width, coded.patch)
        self.pre = Preprocessor(coded.stats)

    def read(self, rows: Index, cols: Index, lights: Index, views: Index) -> np.ndarray:
        r, c, li, vi = self.indices(rows, cols, lights, views)
        p = self.coded.patch
        rb = np.unique(r // p)
        cb = np.unique(c // p)
        pts = self.grid.index(rb[:, None], cb[None, :]).T.ravel()  # col-block major order
        z = np.empty((rb.size * p, cb.size * p, li.size, vi.size, 3), dtype=np.float32)
        for ch_i, ch in enumerate(self.coded.channels):
            # float32 decoding: its rounding (~1e-7) is far below any coding error.
            vals = decode_points(self.coded, ch, pts, li, vi, dtype=np.float32)
            # (cb, rb, i1, i2, ...) → (rb, i1, cb, i2, ...)
            vals = vals.reshape(cb.size, rb.size, p, p, li.size, vi.size, *vals.shape[5:])
            vals = np.moveaxis(vals, 0, 2).reshape(
                rb.size * p, cb.size * p, li.size, vi.size, *vals.shape[6:]
            )
            if ch == "YUV":
                z[...] = vals
            else:
                z[..., ch_i] = vals
        # Map requested rows/cols into the decoded block.
        row_pos = np.searchsorted(rb, r // p) * p + r % p
        col_pos = np.searchsorted(cb, c // p) * p + c % p
        if not np.array_equal(row_pos, np.arange(z.shape[0])):
            z = z[row_pos]
        if not np.array_equal(col_pos, np.arange(z.shape[1])):
            z = z[:, col_pos]
        return self.pre.inverse(z, li, vi).astype(np.float32, copy=False)


def coded_btf_view(coded: CodedBTF) -> DecodedBTF:
    """The decoded BTF of ``coded`` as a lazy :class:`BTF` (needs the model attached)."""
    return DecodedBTF(coded)
