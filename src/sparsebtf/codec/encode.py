"""Encode a BTF on a trained model (paper §3.3, Eq. 3): the sparsest, then least-error code of
every data point on its best dictionary, streamed point by point.

:class:`FixedTau` is the work: :meth:`FixedTau.code_range` codes a range of data points (a
pure function of the BTF, the model and the statistics: what a task runs, in process or on a
Dask worker); :mod:`.jobs` runs the ranges and the statistics pass on an executor.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..data.btf import BTF
from ..errors import BTFInputError
from ..execution import Execution
from ..learning.codes import RELEASE_EPS, RELEASE_TAU
from ..learning.coding import SparseCodes, sparse_code_batches, sparse_code_objective
from ..learning.lod_order import lod_orders
from ..learning.objective import ChannelError, check_objective, joint_choice, objective_params
from ..model import CHANNELS, CodedBTF, Model, TauSpec, parse_tau
from ..points.grid import stream_points
from ..points.preprocessing import Preprocessor, Standardization
from .jobs import Header, Source, run_plan
from .options import EncodeOptions, encode_settings

__all__ = [
    "FixedTau",
    "batch_errors",
    "check_model_objective",
    "coded_btf",
    "encode",
    "encode_levels",
    "plan_candidates",
    "rule_params",
]


def coded_btf(
    btf: BTF | Header,
    model: Model,
    codes: dict[str, SparseCodes],
    stats: Standardization,
    params: dict[str, Any],
) -> CodedBTF:
    """The coded BTF of ``btf`` (or its header) on ``model`` (model attached), from its codes
    and statistics; each point's coefficients in the magnitude rule's order (decreasing
    stored magnitude, ties by location: :func:`~sparsebtf.storage.coded_streams.canonical_codes`),
    the order every coded file gives back; under a linear or display objective
    (``params["objective"]``) in the order the codes come in, the objective's
    (:func:`~sparsebtf.learning.lod_order.lod_orders`), which the file keeps."""
    from ..storage.coded_streams import canonical_codes

    if params.get("objective", "log") == "log":
        codes = {ch: canonical_codes(c) for ch, c in codes.items()}
    # else the objective's level-of-detail order (learning.lod_order) is kept
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
    tau: TauSpec = RELEASE_TAU,
    *,
    options: EncodeOptions | None = None,
    execution: Execution | None = None,
    **keywords: Any,
) -> CodedBTF:
    """Sparse representation of one BTF on a trained model (paper §3.3, Eq. 3).

    ``tau`` caps the coefficients per data point and channel (default the release's: Y 885,
    U 64, V 64); each point keeps the fewest coefficients whose mean squared residual is below
    ``eps``. How it codes is ``options`` (:class:`~.options.EncodeOptions`: ``eps``,
    ``candidates``, ``objective``, ``log_offset`` …), where it runs ``execution``
    (:class:`~sparsebtf.execution.Execution`: in process, ``workers``, ``scheduler``,
    ``client``; the codes are the same); ``keywords`` set either's fields (``eps=0.0``,
    ``workers=4``). τ_t < τ_l is refused (the paper requires τ_t >= τ_l) unless
    ``allow_below_training``. The coded file records the dictionary rule
    (:func:`rule_params`) and a weighted objective (``params["objective"]``, absent for "log").
    """
    return encode_levels(btf, model, [tau], options=options, execution=execution, **keywords)[0]


def _check_levels(levels: list[dict[str, int]], model: Model, allow_below: bool) -> None:
    tau_train = model.tau_train
    for taus_c in levels:
        for ch, t in taus_c.items():
            atoms = math.prod(int(d.shape[1]) for d in model.dictionaries[ch])
            if t > atoms:
                sizes = "x".join(str(int(d.shape[1])) for d in model.dictionaries[ch])
                raise BTFInputError(
                    f"channel {ch}: tau = {t} is more coefficients than a data point has "
                    f"({sizes} = {atoms:,}); give at most {atoms}"
                )
            if ch in tau_train and t < tau_train[ch] and not allow_below:
                raise BTFInputError(
                    f"channel {ch}: testing sparsity tau_t = {t} is below the training "
                    f"sparsity tau_l = {tau_train[ch]}; the paper requires tau_t >= tau_l "
                    "(pass allow_below_training / --allow-below-training to force it)"
                )


def plan_candidates(candidates: int | None, model: Model) -> int | None:
    """``candidates`` (an option, :class:`~.options.EncodeOptions`) as an encoding plan keeps
    it: None (exhaustive) when it is None or at least every channel's K, or when the model's
    data points are not 4D (the screening's partial projection needs two spatial and two
    angular modes)."""
    if candidates is None:
        return None
    k_max = max(model.n_dictionaries(ch) for ch in model.channels)
    if int(candidates) >= k_max or len(model.mode_sizes) != 4:
        return None
    return int(candidates)


def rule_params(candidates: int | None) -> dict[str, Any]:
    """The coded file's record of how each point's dictionary was chosen (docs/format.md):
    ``dictionary_rule`` "exhaustive" (every dictionary projected, the paper's rule) or
    "screened" with ``dictionary_candidates`` (how many were projected exactly)."""
    if candidates is None:
        return {"dictionary_rule": "exhaustive"}
    return {"dictionary_rule": "screened", "dictionary_candidates": int(candidates)}


def check_model_objective(objective: object, model: Model) -> str:
    """``objective`` checked (:func:`~sparsebtf.learning.objective.check_objective`) against
    the model: a weighted one needs a Y, U, V model of log-YUV data points."""
    name = check_objective(objective)
    if name != "log" and (model.transform != "log_yuv" or set(model.channels) != {"Y", "U", "V"}):
        raise BTFInputError(
            f"the {name} objective weighs log-YUV errors by their effect on RGB: it needs a "
            f"model of Y, U, V log-YUV data points (this one: channels {model.channels}, "
            f"preprocessing {model.transform}); use the log objective"
        )
    return name


def batch_errors(x: np.ndarray, pre: Preprocessor, objective: str
                 ) -> list[ChannelError] | None:  # fmt: skip
    """The Y, U, V errors of a batch of standardised points in a linear or display objective
    (:class:`~sparsebtf.learning.objective.ChannelError`), from the batch as
    :func:`~sparsebtf.points.grid.stream_points` gives it ((B, …, 3) or planar (3, B, …));
    None for the log objective."""
    if objective == "log":
        return None
    from ..colour import yuv_to_rgb

    z = x if x.shape[-1] == 3 and x.ndim == 6 else np.moveaxis(x, 0, -1)
    st = pre.stats
    log_rgb = np.ascontiguousarray(yuv_to_rgb(st.invert(z)), dtype=np.float32)
    return [ChannelError.for_batch(objective, log_rgb, st.std, st.bound, st.log_offset, c)
            for c in range(3)]  # fmt: skip


@dataclass(frozen=True)
class FixedTau:
    """Encoding at fixed sparsity levels (τ per channel, ε): one coded BTF per level.

    ``FixedTau(taus)`` is the target; :meth:`bind` (or :meth:`for_model`) parses the levels
    and checks them against a model, with the options the plan uses.
    """

    taus: tuple[Any, ...]
    levels: tuple[dict[str, int], ...] = ()
    eps: float = RELEASE_EPS
    dtype: str = "float32"
    desc: str = "encode"
    #: dictionaries projected exactly after screening; None: all (see :func:`check_candidates`)
    candidates: int | None = None
    #: the coding objective (:mod:`sparsebtf.learning.objective`)
    objective: str = "log"

    kind: ClassVar[str] = "tau"

    @classmethod
    def for_model(
        cls, model: Model, taus: Sequence[TauSpec], options: EncodeOptions | None = None,
        **keywords: Any,
    ) -> FixedTau:  # fmt: skip
        """The plan of ``taus`` on ``model`` with ``options`` (``keywords`` set its fields)."""
        return cls(tuple(taus)).bind(model, EncodeOptions.build(options, **keywords))

    def bind(self, model: Model, options: EncodeOptions) -> FixedTau:
        """The levels parsed (a fraction of the release's τ where the channels are Y, U, V)
        and checked against ``model``, with ``options``' ε, dtype, candidates, objective."""
        release = dict(zip(CHANNELS, RELEASE_TAU, strict=True))
        nominal = release if set(model.channels) <= set(release) else None
        levels = [parse_tau(t, model.channels, nominal=nominal) for t in self.taus]
        _check_levels(levels, model, options.allow_below_training)
        return FixedTau(self.taus, tuple(levels), options.eps, options.dtype,
                        candidates=plan_candidates(options.candidates, model),
                        objective=check_model_objective(options.objective, model))  # fmt: skip

    def prepare(self, header: Header, model: Model) -> None:
        return None

    def code_range(
        self, btf: BTF, model: Model, stats: Standardization, lo: int, hi: int, extra: None,
        batch_size: int, tick: Callable[[int], object] | None = None,
    ) -> list[dict[str, SparseCodes]]:  # fmt: skip
        """Codes of data points ``[lo, hi)`` at every level: ``[level][channel]``."""
        channels = model.channels
        dt = np.dtype(self.dtype).type
        pre = Preprocessor(stats)
        parts: list[dict[str, list[SparseCodes]]] = [{ch: [] for ch in channels}
                                                     for _ in self.levels]  # fmt: skip
        points = np.arange(lo, hi)
        # Y, U, V apart: the reader writes each channel's batch contiguous (no copy per channel
        # here on the main thread, where it held both cores back)
        planar = "YUV" not in channels
        for _, x in stream_points(btf, pre, model.patch, points, batch_size, planar):
            errors = batch_errors(x, pre, self.objective)
            if errors is not None:  # a linear or display objective: the channels judged jointly
                self._code_objective(x, planar, model, errors, dt, parts)
            else:  # the channels' points side by side on the worker threads
                coded = sparse_code_batches(
                    [x[c] if planar else x for c in range(len(channels))],
                    [model.dictionaries[ch] for ch in channels],
                    [[lv[ch] for lv in self.levels] for ch in channels],
                    self.eps, dt, self.candidates,
                )  # fmt: skip
                for ch, levels in zip(channels, coded, strict=True):
                    for j, sc in enumerate(levels):
                        parts[j][ch].append(sc)
            if tick is not None:
                tick(x.shape[1] if planar else x.shape[0])
        return [{ch: SparseCodes.concatenate(p[ch]) for ch in channels} for p in parts]

    def _code_objective(
        self, x: np.ndarray, planar: bool, model: Model, errors: list[ChannelError],
        dt: type, parts: list[dict[str, list[SparseCodes]]],
    ) -> None:  # fmt: skip
        """One batch under a linear or display objective: each channel by its own error
        (:func:`~sparsebtf.learning.coding.sparse_code_objective`), then the three judged
        together against the paper's rule and the lower levels
        (:func:`~sparsebtf.learning.objective.joint_choice`), each code in its level-of-detail
        order (:func:`~sparsebtf.learning.lod_order.lod_orders`)."""
        channels = model.channels
        xs = [np.ascontiguousarray(x[c] if planar else x[..., c]) for c in range(3)]
        taus = [[lv[ch] for lv in self.levels] for ch in channels]
        judged, log = [], []
        for c, ch in enumerate(channels):
            j, g = sparse_code_objective(xs[c], model.dictionaries[ch], taus[c], self.eps, dt,
                                         self.candidates, errors[c])  # fmt: skip
            judged.append(j)
            log.append(g)
        dicts = [model.dictionaries[ch] for ch in channels]
        chosen, _ = lod_orders(xs, errors, joint_choice(xs, errors, judged, log, dicts, taus),
                               dicts, taus)  # fmt: skip
        for c, ch in enumerate(channels):
            for j, sc in enumerate(chosen[c]):
                parts[j][ch].append(sc)

    def finish(
        self, header: Header, model: Model, stats: Standardization,
        parts: list[list[dict[str, SparseCodes]]], extra: None,
    ) -> list[CodedBTF]:  # fmt: skip
        return [
            coded_btf(
                header, model,
                {ch: SparseCodes.concatenate([p[j][ch] for p in parts]) for ch in model.channels},
                stats, {"tau": taus_c, "eps": self.eps, "dtype": self.dtype,
                        **rule_params(self.candidates), **objective_params(self.objective)},
            )
            for j, taus_c in enumerate(self.levels)
        ]  # fmt: skip


def encode_levels(
    btf: BTF,
    model: Model,
    taus: Sequence[TauSpec],
    *,
    options: EncodeOptions | None = None,
    execution: Execution | None = None,
    **keywords: Any,
) -> list[CodedBTF]:
    """:func:`encode` at several sparsity levels from one pass (projections are shared).

    The levels are nested (issue 46): per point and channel, the error in the chosen
    objective never grows with the level's τ (levels whose τ are ordered channel by
    channel). Under "log" the levels share the projections and the screening's candidates
    (:func:`~sparsebtf.learning.coding.sparse_code_levels`); under "linear" or "display"
    each channel's error (the other two exact) and the joint error are nested
    (:func:`~sparsebtf.learning.lod_order.lod_orders`). Separate calls at one τ each are
    nested only under "log" with the exhaustive rule (``candidates=None``): a screened call
    ranks its candidates for its own τ, and an objective's call judges its own prefix
    lengths.

    With ``highlights`` each level's τ is a byte budget spent on codes and a highlight store
    (:func:`~.highlights.choose_highlights`); the material's linear error then never grows
    with the level."""
    opts, where = encode_settings(options, execution, dict(keywords), kind="tau", many=False)
    if opts.highlights:
        return _encode_highlights(btf, model, taus, opts, where)
    (coded,) = run_plan([btf], model, FixedTau(tuple(taus)), options, execution, **keywords)
    return coded


def _encode_highlights(btf: BTF | str | os.PathLike[str], model: Model, taus: Sequence[TauSpec],
                       opts: EncodeOptions, where: Execution) -> list[CodedBTF]:  # fmt: skip
    """:func:`encode_levels` with a highlight store: the levels and the bases below them in
    one pass, then each level's budget spent (:mod:`.highlights`)."""
    from .highlights import base_taus, choose_highlights

    levels = list(FixedTau(tuple(taus)).bind(model, opts).levels)
    extra = base_taus(levels)
    plain = dataclasses.replace(opts, highlights=False, allow_below_training=True)
    (coded,) = run_plan([btf], model, FixedTau(tuple(levels + extra)), plain, where)
    source = Source.of(btf, opts.crop).open()
    return choose_highlights(source, coded[: len(levels)], coded[len(levels):], model,
                             opts.progress, lobes=opts.highlights != "entries")  # fmt: skip
