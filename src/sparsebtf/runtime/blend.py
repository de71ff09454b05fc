"""Inter-BTF interpolation in coefficient space (paper §3.5, Eq. 7–9).

For weights w_j (Σ w_j = 1) over coded BTFs B_j of one model, each data point i of the blend is

    S_i = Σ_j w_j S̃_j,i   on dictionary k = the membership of the dominant input (largest w_j)

where S̃_j,i = S_j,i when B_j's point i already uses dictionary k (Eq. 7), and otherwise
S̃_j,i = S_j,i ×_1 R⁽¹⁾ ×_2 R⁽²⁾ ×_3 R⁽³⁾ ×_4 R⁽⁴⁾ with R⁽ⁿ⁾ = U⁽ⁿ'ᵏ⁾ᵀ U⁽ⁿ'ᵖ⁾ (Eq. 8–9), the exact
change of orthonormal basis from the input's dictionary p to k. Before re-sparsification the
blend therefore equals the data-space blend Σ_j w_j X_j of the standardised reconstructions;
it is then cut back to the τ largest coefficients per point (the output's sparsity).

The blend lives in each material's standardised domain; the output's statistics μ, σ, its log
offset and its bound on ln(RGB + offset) are the same weighted sums of the inputs' (so α = 0 and
1 return the inputs exactly; the bound is rounded up to 1/32 like every stored bound).

Materials coded with adaptive patch sizes blend on the common refinement of their trees, each
coarse node re-expressed exactly at the finer size (:mod:`.blend_adaptive`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import BTFInputError, ModelMismatchError
from ..model import CodedBTF, TauSpec, model_text, parse_tau
from ..patch_tree import AdaptiveCodedBTF
from ..points.preprocessing import Standardization, round_up_bound
from ..storage.coded_streams import canonical_codes
from .blend_adaptive import blend_trees
from .blend_codes import blend_channel

__all__ = ["blend", "check_blendable"]


def check_blendable(coded: Sequence[CodedBTF]) -> None:
    """Clear errors for inputs that cannot share one coefficient space."""
    if len(coded) < 2:
        raise BTFInputError("blending needs at least two coded BTFs")
    for c in coded:
        if getattr(c, "highlight_store", None) is not None:  # an adaptive material has none
            # its corrections are linear RGB at nodes, not coefficients: no blend of them
            # would be the blend of the materials the codes blend to
            raise BTFInputError(f"{c.label} has a highlight store (encode --highlights): "
                                "blending works in coefficient space; encode it without one")
    a = coded[0]
    for b in coded[1:]:
        if b.model_hash != a.model_hash:
            raise ModelMismatchError(
                f"{a.label} was coded with {model_text(a.model_hash, a.model_file)}, {b.label} "
                f"with {model_text(b.model_hash, b.model_file)}: blending needs both coded with "
                "the same model"
            )
        if not (b.lights.equals(a.lights) and b.views.equals(a.views)):
            raise BTFInputError(
                f"{a.label} ({len(a.lights)}x{len(a.views)} directions) and {b.label} "
                f"({len(b.lights)}x{len(b.views)}) have different direction tables"
            )
        if (b.height, b.width, b.patch) != (a.height, a.width, a.patch):
            raise BTFInputError(
                f"{a.label} is {a.height}x{a.width} (patch {a.patch}), {b.label} is "
                f"{b.height}x{b.width} (patch {b.patch}): crop them to one size first"
            )
        if b.channels != a.channels:
            raise BTFInputError(f"{a.label} has channels {a.channels}, {b.label} {b.channels}")
        if (b.stats.mode, b.stats.transform) != (a.stats.mode, a.stats.transform):
            raise BTFInputError(
                f"{a.label} uses {a.stats.mode} standardisation ({a.stats.transform}), "
                f"{b.label} {b.stats.mode} ({b.stats.transform}); they cannot be blended"
            )
    a.require_model()


def _check_coded(coded: object) -> None:
    """Refuse inputs that are no coded BTFs, in one line naming the argument (not an
    AttributeError from inside the blend)."""
    from ..constraints import wrong_type

    what = ("a list of two or more coded BTFs (sparsebtf.encode's results, or coded .h5 files "
            "read with sparsebtf.storage.load_coded)")
    if isinstance(coded, CodedBTF | AdaptiveCodedBTF | str | bytes) or not isinstance(
            coded, Sequence):  # fmt: skip
        raise wrong_type("blend", "coded", what, coded)
    for i, c in enumerate(coded):
        if not isinstance(c, CodedBTF | AdaptiveCodedBTF):
            raise wrong_type("blend", f"coded[{i}]", "a coded BTF (CodedBTF or "
                             "AdaptiveCodedBTF: sparsebtf.encode's result, or a coded .h5 file "
                             "read with sparsebtf.storage.load_coded)", c)  # fmt: skip


def blend(
    coded: Sequence[CodedBTF] | Sequence[AdaptiveCodedBTF],
    weights: Sequence[float] | None = None,
    alpha: float | None = None,
    tau: TauSpec = None,
    name: str | None = None,
    progress: bool | None = None,
) -> CodedBTF | AdaptiveCodedBTF:
    """Blend coded BTFs in coefficient space (Eq. 7–9) and re-sparsify to ``tau``.

    Materials coded with adaptive patch sizes (all inputs, one model) blend on the common
    refinement of their trees, coarse nodes re-expressed at the finer size
    (:mod:`.blend_adaptive`); the result is an :class:`~sparsebtf.patch_tree.AdaptiveCodedBTF`.

    Parameters
    ----------
    coded : two or more coded BTFs of one model, sizes and direction tables.
    weights : one weight per input, summing to 1 (negative or > 1 extrapolates).
    alpha : shorthand for two inputs: weights (1 − α, α) as in Eq. 7.
    tau : sparsity of the output per channel; default the largest coded τ of the inputs
        (adaptive: per point of the largest size, each node's cap scaled to its texels).
    """
    _check_coded(coded)
    kinds = {isinstance(c, AdaptiveCodedBTF) for c in coded}
    if len(kinds) > 1:
        one = next(c for c in coded if not isinstance(c, AdaptiveCodedBTF))
        many = next(c for c in coded if isinstance(c, AdaptiveCodedBTF))
        raise BTFInputError(
            f"{one.label} is coded with one patch size, {many.label} with adaptive patch "
            "sizes: blending needs all inputs coded one way"
        )
    adaptive = kinds == {True}
    # the largest size's layers carry what every layer shares (model, directions, stats)
    plain: list[CodedBTF] = [c.first if isinstance(c, AdaptiveCodedBTF) else c for c in coded]
    check_blendable(plain)
    if (weights is None) == (alpha is None):
        raise BTFInputError("give either weights or alpha")
    if alpha is not None:
        if len(coded) != 2:
            raise BTFInputError(f"alpha blends two BTFs; got {len(coded)} (pass weights)")
        weights = [1.0 - float(alpha), float(alpha)]
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (len(coded),) or not np.all(np.isfinite(w)):
        raise BTFInputError(f"need {len(coded)} finite weights, got {weights}")
    if abs(w.sum() - 1.0) > 1e-9:
        raise BTFInputError(f"weights must sum to 1, got {w.tolist()} (sum {w.sum():g})")
    first = plain[0]
    model = coded[0].require_model()
    channels = first.channels
    widest = {ch: max(c.coded_tau[ch] for c in plain) for ch in channels}
    taus = parse_tau(tau, channels, full=widest)
    st = first.stats
    pairs = list(zip(w, plain, strict=True))
    bounded = all(c.stats.bound is not None for c in plain)
    offset = float(sum(wj * c.stats.log_offset for wj, c in pairs))
    stats = Standardization(
        st.mode,
        sum(wj * c.stats.mean for wj, c in pairs),
        sum(wj * c.stats.std for wj, c in pairs),
        offset if len({c.stats.log_offset for c in plain}) > 1 else st.log_offset,
        st.transform,
        round_up_bound(sum(wj * c.stats.bound.astype(np.float64) for wj, c in pairs))
        if bounded else None,
    )
    names = [c.name for c in plain]
    params = dict(first.params)
    # the blend keeps the largest summed coefficients in magnitude order: the log rule's
    # order, whatever objective its inputs were coded for
    params.pop("objective", None)
    # an adaptive input's tree choice (λ, budget) does not describe the blend's tree
    params.pop("adaptive", None)
    params["tau"] = taus
    params["blend"] = {"inputs": names, "weights": w.tolist()}
    label = name or "blend(" + ", ".join(f"{n}:{wj:g}" for n, wj in zip(names, w, strict=True))
    if name is None:
        label += ")"
    attrs = {"blend_of": names, "weights": w.tolist()}
    if adaptive:
        tree, layer_codes = blend_trees(coded, w, taus, progress)  # type: ignore[arg-type]
        layers = {
            s: CodedBTF({ch: canonical_codes(c) for ch, c in per.items()}, stats, first.height,
                        first.width, s, first.lights, first.views, first.model_hash,
                        dict(params), label, dict(attrs), model.for_patch(s))
            for s, per in layer_codes.items()
        }  # fmt: skip
        return AdaptiveCodedBTF(tree, layers, model)
    # in the coded files' magnitude order (ties of stored magnitude by location), so a saved
    # blend needs no explicit order (storage.coded_streams)
    codes = {
        ch: canonical_codes(blend_channel(
            [c.codes[ch] for c in plain], w, model.dictionaries[ch], taus[ch], progress,
            f"blend {ch}",
        ))
        for ch in channels
    }  # fmt: skip
    return CodedBTF(
        codes, stats, first.height, first.width, first.patch, first.lights, first.views,
        first.model_hash, params, label, attrs, model,
    )  # fmt: skip
