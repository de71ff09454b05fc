"""Rate control on a BTF (beyond §3.3): encode to a target size or compression ratio.

:func:`encode_rate_levels` streams a BTF's data points once, keeps the top candidates of each
point's chosen dictionary and spends one coefficient budget over every point and channel
(:func:`sparsebtf.learning.rate_control.allocate`); sizes count by Table 4
(:mod:`sparsebtf.learning.cost`). :class:`RateTargets` is that work as an encoding plan
(:mod:`.jobs`): candidates by point range (in process or on Dask workers), one allocation.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, ClassVar

import numpy as np

from .._threads import parallel_map
from ..colour import YUV_TO_RGB
from ..data.btf import BTF
from ..errors import BTFInputError, UnreachableTargetError
from ..execution import Execution
from ..learning.codes import RELEASE_TAU
from ..learning.coding import screen_dictionaries, topk_abs
from ..learning.cost import DICTIONARY_ENTRY_BYTES, location_width, raw_bytes
from ..learning.objective import DISPLAY_A, DISPLAY_GAMMA, objective_params
from ..learning.rate_control import ChannelCandidates, allocate, reference_counts
from ..learning.tensor import project
from ..model import CodedBTF, Model
from ..points.grid import PatchGrid, stream_points
from ..points.preprocessing import Preprocessor, Standardization
from .encode import batch_errors, check_model_objective, coded_btf, plan_candidates, rule_params
from .jobs import Header, run_plan
from .options import EncodeOptions
from .rate_objective import floored_candidates, pool_walks

__all__ = [
    "BUDGETS",
    "RateTargets",
    "encode_rate_levels",
    "encode_to_size",
    "material_target_bytes",
]


#: What a size or ratio target counts: the coded file's bytes, or the paper's Table 4 bytes.
BUDGETS = ("stored", "paper")
#: A stored-bytes target is met when the file is at most this fraction below it.
STORED_TOLERANCE = 0.004
#: Stored codes per Table 4 byte assumed to size the candidate pool (measured: 0.40–0.48,
#: ``benchmarks/bench_storage.py``).
_STORED_PER_TABLE4 = 0.42


def stored_target_bytes(
    btf: BTF | Header, *, target_bytes: int | None = None, target_ratio: float | None = None
) -> int:
    """The coded file's size asked for: ``target_bytes``, or raw fp16 bytes / ``target_ratio``
    (:func:`~sparsebtf.storage.storage_report`'s ``bytes_stored`` and
    ``compression_ratio_per_material``: everything the material stores)."""
    if (target_bytes is None) == (target_ratio is None):
        raise BTFInputError("give exactly one of target_bytes and target_ratio")
    if target_ratio is not None:
        if not target_ratio > 0:
            raise BTFInputError(f"target ratio must be > 0, got {target_ratio}")
        return int(raw_bytes(btf.n_values) / float(target_ratio))
    if int(target_bytes) <= 0:  # type: ignore[arg-type]
        raise BTFInputError(f"target bytes must be > 0, got {target_bytes}")
    return int(target_bytes)  # type: ignore[arg-type]


def material_target_bytes(
    btf: BTF | Header,
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
    raw = raw_bytes(btf.n_values)
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
    dicts = sum(DICTIONARY_ENTRY_BYTES * model.dictionary_entries(ch) for ch in model.channels)
    if total <= dicts:
        raise BTFInputError(
            f"{btf.label}: the target of {total:,d} bytes does not even hold the model's shared "
            f"dictionaries ({dicts:,d} bytes); ask for a per-material target "
            "(per_material=True; on the command line, without --with-dictionaries) or a larger size"
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
    * ``display`` (the display objective's): the same with x replaced by the derivative of
      the display mapping a·x^(1/γ) times x, (a/γ)·x^(1/γ), and 0 where it clips at 1.
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
    if weighting == "display":
        d = np.power(rgb, 1 / DISPLAY_GAMMA)
        rgb = np.where(DISPLAY_A * d < 1, (DISPLAY_A / DISPLAY_GAMMA) * d, 0.0)
    g = np.square(rgb, dtype=np.float64).mean(axis=(1, 2)).reshape(b, -1, 3)  # (b, J, rgb)
    return np.einsum("bjr,rc,jc->bc", g, m2, sd2)[:, :c] / sd2.shape[0]


@dataclass(frozen=True)
class RateTargets:
    """Rate control to per-material byte targets (see :func:`encode_rate_levels`).

    ``targets``: bytes per material by Table 4, one per level; or None, then each BTF's single
    target comes from ``target_bytes`` / ``target_ratio`` / ``per_material`` by
    :func:`material_target_bytes` (the BTFs of one call may differ in size). With ``budget``
    "stored" that single target is the coded file's size instead
    (:func:`stored_target_bytes`): the Table 4 budget is searched until the file written by
    :func:`~sparsebtf.storage.save_coded` is within :data:`STORED_TOLERANCE` below it.
    Those fields are the target; :meth:`bind` adds the options the plan uses (weighting,
    split, candidate factor, dtype, candidates, objective) and checks it against a model.
    """

    targets: tuple[int, ...] | None = None
    target_bytes: int | None = None
    target_ratio: float | None = None
    per_material: bool = False
    budget: str = "paper"
    weighting: str = "rgb"
    split: tuple[float, ...] | None = None
    candidate_factor: float = 4.0
    dtype: str = "float32"
    desc: str = "rate-encode"
    #: dictionaries projected exactly per point after screening (None: all); give it through
    #: :meth:`check`, which keeps None where it changes nothing
    candidates: int | None = None
    #: the coding objective (:mod:`sparsebtf.learning.objective`): with "linear" or "display"
    #: each point's dictionary is the one of least error in it at the reference count (its
    #: candidates the point's projections or a floored copy's,
    #: :func:`~.rate_objective.floored_candidates`), and the allocation spends on exact error
    #: curves (the file records weighting "exact")
    objective: str = "log"

    #: The fields that give a size target (the keywords of :func:`encode_to_size`).
    SIZE_FIELDS: ClassVar[tuple[str, ...]] = ("target_bytes", "target_ratio", "per_material",
                                              "budget")  # fmt: skip

    @classmethod
    def take(cls, keywords: dict[str, Any]) -> RateTargets | None:
        """The size target that ``keywords`` give (its fields are taken out of them), or None
        when they name neither a size nor a ratio."""
        size = {k: keywords.pop(k) for k in cls.SIZE_FIELDS if k in keywords}
        if size.get("target_bytes") is None and size.get("target_ratio") is None:
            keywords.update({k: v for k, v in size.items() if k not in cls.SIZE_FIELDS[:2]})
            return None
        return cls(**size)

    @property
    def kind(self) -> str:
        """The target as a refusal names it: "ratio" or "size"."""
        return "ratio" if self.target_ratio is not None else "size"

    def bind(self, model: Model, options: EncodeOptions) -> RateTargets:
        """This target with ``options``' weighting, split, candidate factor, dtype, candidates
        and objective, checked against ``model`` (:meth:`check`)."""
        return replace(
            self, weighting=options.weighting,
            split=None if options.split is None else tuple(options.split),
            candidate_factor=options.candidate_factor, dtype=options.dtype,
            candidates=options.candidates, objective=options.objective,
        ).check(model)  # fmt: skip

    def check(self, model: Model) -> RateTargets:
        """Refuse a target or a combination of options that cannot work, before any work;
        returns self (candidates as the plan keeps them, :func:`~.encode.plan_candidates`)."""
        if self.budget not in BUDGETS:
            raise BTFInputError(f"budget must be one of {BUDGETS}, got {self.budget!r}")
        if self.budget == "stored" and (self.targets is not None or not self.per_material):
            raise BTFInputError(
                "a stored-bytes target counts the coded file, which holds no dictionaries: "
                "the model file is shared by every material; give a per-material target "
                "(without --with-dictionaries) or use the paper's budget (--budget paper)"
            )
        if self.targets is not None and not self.targets:
            raise BTFInputError("give at least one target size")
        if "YUV" in model.channels:
            raise BTFInputError("rate control supports the 4D (Y, U, V) models only")
        check_model_objective(self.objective, model)
        if self.objective != "log" and self.weighting != "rgb":
            raise BTFInputError(
                f"the {self.objective} objective weighs the allocation itself; the weighting "
                f"{self.weighting!r} applies to the log objective only"
            )
        candidates = plan_candidates(self.candidates, model)
        return self if candidates == self.candidates else replace(self, candidates=candidates)

    @property
    def point_weighting(self) -> str:
        """The allocation's weighting under the log objective (:func:`_point_weights`):
        :attr:`weighting` (a linear or display objective spends on exact error curves)."""
        return self.weighting

    def prepare(self, header: Header, model: Model) -> dict[str, Any]:
        """The BTF's targets, reference counts and candidate counts per level."""
        targets = self.targets
        stored = None
        channels = model.channels
        n_pts = PatchGrid.for_btf(header, model.patch).n_points  # type: ignore[arg-type]
        if targets is None and self.budget == "stored":
            stored = stored_target_bytes(
                header, target_bytes=self.target_bytes, target_ratio=self.target_ratio
            )
            targets = (_table4_estimate(stored, header, n_pts, len(channels), model),)
        elif targets is None:
            targets = (material_target_bytes(
                header, model, target_bytes=self.target_bytes, target_ratio=self.target_ratio,
                per_material=self.per_material,
            ),)  # fmt: skip
        shape = model.mode_sizes
        size = int(np.prod(shape))
        split = self.split
        if split is None:
            split = RELEASE_TAU if model.transform == "log_yuv" else (1.0, 1.0, 1.0)
        loc_w = location_width(shape)
        refs = [reference_counts(int(t), n_pts, channels, loc_w, split, size) for t in targets]
        ncand = [
            {ch: min(size, int(self.candidate_factor * r[ch]) + 16) for ch in channels}
            for r in refs
        ]
        nmax = {ch: max(nc[ch] for nc in ncand) for ch in channels}
        return {"targets": targets, "refs": refs, "ncand": ncand, "nmax": nmax, "split": split,
                "stored_target": stored}

    def code_range(
        self, btf: BTF, model: Model, stats: Standardization, lo: int, hi: int,
        extra: dict[str, Any], batch_size: int, tick: Callable[[int], object] | None = None,
    ) -> list[dict[str, dict[str, np.ndarray]]]:  # fmt: skip
        """Candidates of data points ``[lo, hi)``: ``[level][channel]`` → arrays m (n,),
        idx (n, candidates), val, e (energy), w (weight)."""
        channels = model.channels
        refs, ncand, nmax = extra["refs"], extra["ncand"], extra["nmax"]
        pre = Preprocessor(stats)
        dt = np.dtype(self.dtype).type
        n_lv = len(refs)
        parts: list[dict[str, dict[str, list]]] = [
            {ch: {"m": [], "idx": [], "val": [], "e": [], "w": []} for ch in channels}
            for _ in range(n_lv)
        ]
        mats = {
            ch: [[np.asarray(d[k], dtype=dt) for d in model.dictionaries[ch]]
                 for k in range(model.n_dictionaries(ch))]
            for ch in channels
        }  # fmt: skip
        points = np.arange(lo, hi)
        for _, x in stream_points(btf, pre, model.patch, points, batch_size):
            judge = batch_errors(x, pre, self.objective)
            # an objective's allocation spends on exact error curves: no weights
            w = (_point_weights(x, pre, stats, channels, self.point_weighting)
                 if judge is None else np.ones((x.shape[0], len(channels))))  # fmt: skip
            for c, ch in enumerate(channels):
                xc = np.ascontiguousarray(x[..., c], dtype=dt)
                flat = xc.reshape(xc.shape[0], -1)
                energy = np.einsum("ij,ij->i", flat, flat, dtype=np.float64)
                n_k = len(mats[ch])
                # the dictionary rule here is the least residual at each level's reference
                # count: the coding rule with τ = that count and ε = 0
                mask = (
                    np.ones((xc.shape[0], n_k), dtype=bool) if self.candidates is None
                    else screen_dictionaries(xc, model.dictionaries[ch],
                                             [r[ch] for r in refs], 0.0, self.candidates, dtype=dt)
                )  # fmt: skip
                pairs = [(i, k) for i in range(xc.shape[0]) for k in range(n_k) if mask[i, k]]

                def task(ik: tuple[int, int], xc=xc, ch=ch) -> tuple[np.ndarray, np.ndarray]:
                    i, k = ik
                    s = project(xc[i : i + 1], mats[ch][k]).reshape(-1)
                    idx = topk_abs(s, nmax[ch])
                    return idx, s[idx]

                res = dict(zip(pairs, parallel_map(task, pairs), strict=True))
                losses = None
                if judge is not None:
                    res, losses = floored_candidates(xc, res, pairs, [r[ch] for r in refs],
                                                      mats[ch], nmax[ch], judge[c], dt)  # fmt: skip
                picks = []
                for i in range(xc.shape[0]):
                    ks = [k for k in range(n_k) if mask[i, k]]
                    cums = [np.cumsum(res[i, k][1].astype(np.float64) ** 2) for k in ks]
                    # one dictionary for every target of the call (nested codes, issue 46):
                    # the log rule's, of least residual at the largest target's reference
                    # count (so that target codes as it would alone); an objective's, of least
                    # error summed over every target's reference count. Ties: lowest k
                    r_top = max(r[ch] for r in refs)
                    kept = [cs[min(r_top, cs.size) - 1] for cs in cums]
                    k_pt = (ks[int(np.argmax(kept))] if losses is None
                            else ks[int(np.argmin([sum(losses[i, k]) for k in ks]))])  # fmt: skip
                    picks.extend((i, lv, k_pt) for lv in range(n_lv))
                # one candidate pool (the largest) for every target, so that with one
                # dictionary a larger target keeps a superset of a smaller one's coefficients;
                # the objective's candidates: its level-of-detail order with exact error curves
                pool = max(ncand[lv][ch] for lv in range(n_lv))
                walks = None if judge is None else pool_walks(xc, res, picks, pool, mats[ch],
                                                              judge[c])  # fmt: skip
                for i, lv, k in picks:
                    n = pool
                    d = parts[lv][ch]
                    d["m"].append(k)
                    if walks is None:
                        d["idx"].append(res[i, k][0][:n])
                        d["val"].append(res[i, k][1][:n].astype(np.float32))
                    else:
                        idx, val, curve = walks[i, k]
                        a = min(n, idx.size)
                        d["idx"].append(np.pad(idx[:a], (0, n - a)))
                        d["val"].append(np.pad(val[:a], (0, n - a)))
                        d.setdefault("curve", []).append(
                            np.pad(curve[: a + 1], (0, n - a), constant_values=np.nan))
                    d["e"].append(float(energy[i]))
                    d["w"].append(float(w[i, c]))
            if tick is not None:
                tick(x.shape[0])
        return [
            {ch: {"m": np.asarray(d["m"], dtype=np.int64),
                  "idx": np.stack(d["idx"]).astype(np.int64), "val": np.stack(d["val"]),
                  "e": np.asarray(d["e"]), "w": np.asarray(d["w"]),
                  **({"curve": np.stack(d["curve"])} if "curve" in d else {})}
             for ch, d in lv.items()}
            for lv in parts
        ]  # fmt: skip

    def finish(
        self, header: Header, model: Model, stats: Standardization,
        parts: list[list[dict[str, dict[str, np.ndarray]]]], extra: dict[str, Any],
    ) -> list[CodedBTF]:  # fmt: skip
        """One coefficient budget per level over every point and channel (allocate)."""
        channels = model.channels
        shape = model.mode_sizes
        loc_w = location_width(shape)
        out = []
        for lv, target in enumerate(extra["targets"]):
            def joined(ch: str, key: str, lv: int = lv) -> np.ndarray:
                return np.concatenate([p[lv][ch][key] for p in parts])

            cands = {
                ch: ChannelCandidates(
                    shape, joined(ch, "m"), joined(ch, "idx"), joined(ch, "val"),
                    joined(ch, "e"), joined(ch, "w"),
                    joined(ch, "curve") if self.objective != "log" else None,
                )
                for ch in channels
            }  # fmt: skip
            def build(t: int, lv: int = lv, cands: dict = cands) -> CodedBTF:
                codes, summary = allocate(cands, int(t), loc_w)
                control = {
                    "budget": self.budget,
                    "target_material_bytes": int(t),
                    "material_bytes": summary["bytes"],
                    "weighting": self.point_weighting if self.objective == "log" else "exact",
                    "reference_counts": extra["refs"][lv],
                    # the pool every target of the call shares (nested levels)
                    "candidates": {ch: max(nc[ch] for nc in extra["ncand"]) for ch in channels},
                    "split": list(extra["split"]),
                }
                if extra.get("stored_target") is not None:
                    control["target_stored_bytes"] = int(extra["stored_target"])
                params = {
                    "tau": {ch: int(codes[ch].counts.max()) for ch in channels},
                    "eps": 0.0,
                    "dtype": self.dtype,
                    "rate_control": control,
                    **rule_params(self.candidates),
                    **objective_params(self.objective),
                }
                return coded_btf(header, model, codes, stats, params)

            if extra.get("stored_target") is not None:
                out.append(_search_stored(build, cands, int(extra["stored_target"]), loc_w,
                                          header.name))  # fmt: skip
            else:
                out.append(build(int(target)))
        return out


def _table4_estimate(stored: int, header: Header | BTF, n_points: int, n_channels: int,
                     model: Model) -> int:  # fmt: skip
    """A Table 4 budget whose file is about ``stored`` bytes (sizes the candidate pool; the
    exact budget is searched later): the bytes left beside the statistics, directions and
    header, at :data:`_STORED_PER_TABLE4` stored bytes per Table 4 byte."""
    from ..learning.cost import material_bytes

    nl, nv = len(header.lights), len(header.views)
    fixed = 0.7 * 8 * nl * nv + 40 * (nl + nv) + 12_000
    least = material_bytes(n_points * n_channels, n_points, n_channels,
                           location_width(model.mode_sizes))  # fmt: skip
    return max(least, int((stored - fixed) / _STORED_PER_TABLE4))


def _search_stored(
    build: Callable[[int], CodedBTF], cands: dict[str, ChannelCandidates], target: int,
    loc_w: int, name: str,
) -> CodedBTF:  # fmt: skip
    """The coded BTF whose file is the largest not above ``target`` bytes: the file's size
    grows with the Table 4 budget, so a bracketing secant search over that budget, each step
    measured by writing the file in memory (:func:`~sparsebtf.storage.coded_file.coded_image`)
    until it is within :data:`STORED_TOLERANCE` below the target."""
    from ..learning.cost import material_bytes
    from ..storage.coded_file import coded_image

    p = next(iter(cands.values())).n_points
    c = len(cands)
    pool = sum(int(cd.values.shape[0] * cd.values.shape[1]) for cd in cands.values())
    lo_t = material_bytes(p * c, p, c, loc_w)
    hi_t = material_bytes(pool, p, c, loc_w)

    def size(t: int) -> tuple[int, CodedBTF]:
        coded = build(t)
        return len(coded_image(coded)), coded

    lo_s, best = size(lo_t)
    if lo_s > target:
        raise UnreachableTargetError(
            f"{name}: a target of {target:,d} stored bytes is below the smallest coded file "
            f"({lo_s:,d} bytes with one coefficient per point and channel: statistics, "
            "directions and header need most of it); ask for a larger size or a lower ratio"
        )
    hi_s, top = size(hi_t)
    if hi_s <= target:
        return top  # the candidate pool runs out first
    for _ in range(24):
        if target - lo_s <= STORED_TOLERANCE * target or hi_t - lo_t <= 5:
            break
        frac = (target - lo_s) / max(hi_s - lo_s, 1)
        t = int(lo_t + min(max(frac, 0.02), 0.98) * (hi_t - lo_t))
        s, coded = size(t)
        if s <= target:
            lo_t, lo_s, best = t, s, coded
        else:
            hi_t, hi_s = t, s
    return best


def encode_rate_levels(
    btf: BTF,
    model: Model,
    targets: Sequence[int],
    *,
    options: EncodeOptions | None = None,
    execution: Execution | None = None,
    **keywords: Any,
) -> list[CodedBTF]:
    """Encode to per-material byte targets by rate control (one projection pass for all).

    Beyond the paper, whose τ_t is fixed per point (§3.3, Table 3): one coefficient budget per
    target is spread over every data point and channel, largest weighted gain w·s² first
    (exact by Parseval, :mod:`sparsebtf.learning.rate_control`). ``targets`` are bytes per
    material by Table 4 (coefficients + membership/counts, dictionaries excluded; see
    :func:`material_target_bytes`). Each point's dictionary is the one with the least error at
    the point's reference count (the target split over channels as the option ``split``,
    default the release's 885:64:64, or equal for identity preprocessing); its top
    ``candidate_factor`` × that count (+16) coefficients are the candidates; with several
    targets, one dictionary per point for all of them (the largest target's: least
    residual at its reference count) and one pool (the largest), so that the largest target
    codes as it would alone, a larger target keeps a superset of a smaller one's
    coefficients, and no point's error in any channel grows with the target (nested levels,
    issue 46). ``weighting``
    is one of :data:`~.options.WEIGHTINGS` (see :func:`_point_weights`). Results hit each
    target to within one coefficient (5 bytes) unless the candidate pool runs out (a warning).
    ``options`` / ``execution`` / ``keywords`` as for :func:`~.encode.encode` (a Dask cluster
    gives the same result). ``candidates``: dictionaries projected exactly per point after
    screening, the others ranked by a partial projection
    (:func:`~sparsebtf.learning.coding.screen_dictionaries`); None: every dictionary.
    ``objective`` "linear" or "display" (:mod:`sparsebtf.learning.objective`): each point's
    dictionary is the one of least error in that objective at its reference count; its
    candidates come in the objective's order
    (:func:`~sparsebtf.learning.lod_order.walk_pool`, one evaluation of the error per block
    tried: the cost) with their exact error at the walk's stops, and the allocation spends
    on those curves (:func:`~sparsebtf.learning.rate_control.allocate`): no point's error
    in the objective, hence not the material's, grows with the target.
    """
    plan = RateTargets(tuple(int(t) for t in targets))
    (coded,) = run_plan([btf], model, plan, options, execution, **keywords)
    return coded


def encode_to_size(
    btf: BTF,
    model: Model,
    *,
    target_bytes: int | None = None,
    target_ratio: float | None = None,
    per_material: bool = False,
    budget: str = "paper",
    options: EncodeOptions | None = None,
    execution: Execution | None = None,
    **keywords: Any,
) -> CodedBTF:
    """Encode ``btf`` to a target size or compression ratio by rate control.

    ``budget="paper"``: ``target_bytes`` / ``target_ratio`` are in the sense of
    :func:`~sparsebtf.storage.storage_report`'s Table 4 figures (``bytes_total`` with the
    dictionaries, ``compression_ratio``), or per material with ``per_material`` (see
    :func:`material_target_bytes`); the result lands within one coefficient (5 bytes) of the
    target. ``budget="stored"`` (needs ``per_material``): they are the coded file's size
    (``bytes_stored``, ``compression_ratio_per_material``), met to within
    :data:`STORED_TOLERANCE` below. See :func:`encode_rate_levels` (options, execution).
    """
    plan = RateTargets(target_bytes=target_bytes, target_ratio=target_ratio,
                       per_material=per_material, budget=budget)  # fmt: skip
    ((coded,),) = run_plan([btf], model, plan, options, execution, **keywords)
    return coded
