"""Adaptive patch sizes (issue 35; beyond the paper, its §5) as a benchmark method:
``sparsebtf-adaptive``, against the reference's fixed P×P patches at equal bytes.

:class:`AdaptiveMethod` trains one model of two nested patch sizes, (P, P/2) — P the
benchmark's patch, 10×10 by default, so (10, 5) — on the benchmark's training materials with
the reference's K, sample, iterations, tolerance, τ_l and seed (what ``sparsebtf train
--patch 10,5`` makes: the same τ_l per point at every size; the P×P ensemble is the
reference's own, reused when it was trained alike, since training it again gives the same:
:func:`~sparsebtf.codec.train.join_patch_sizes`), and codes every test material adaptively
(:func:`~sparsebtf.codec.adaptive.encode_adaptive`: a rate–distortion quadtree) at each
level's budget: the reference's own Table 4 bytes on that material, which the adaptive code's
Table 4 bytes — tree bits included — never exceed. So the comparison is at equal bytes.

Why (P, P/2) and not the issue's 20, 10, 5: every benchmark material must cut into blocks of
the largest size. The full configuration's test materials are 30×30 and its training ones
50×50 (the captured ones 30×30), which 20 does not divide; P and P/2 divide every
configuration's sizes (the quick one's 20×20 too). The tree therefore starts from the
reference's own P×P blocks and can only split them: what is measured is whether busy regions
gain from smaller patches, not whether smooth ones gain from larger.

Each node's cap is :data:`CAP_FACTOR` × the level's fixed τ per P×P point (scaled to the
node's texels): the tree's λ then moves bytes between nodes, up to that many coefficients in a
busy one (rate control keeps a like pool of candidates, 4× its mean count + 16). The
encode's cost is measured beside a fixed-τ encode of the same level on the same model's P×P
ensemble (the reference's coding), both timed here, one level at a time: each row's
``encode_seconds`` and ``fixed_encode_seconds``. Beside them, the coder's own error
(standardised, by Parseval from the codes) of the tree, of the fixed code and of every point
coded at P/2 with the same coefficients per texel: whether smaller patches alone cost error
(``mse_std_coded``, ``mse_std_fixed``, ``mse_std_small``). Every test material's tree at the
reference level is drawn over its texture (:func:`~sparsebtf.evaluation.plots.tree_figure`)
into ``adaptive/`` of the run's folder, named in its row's ``tree_figure``.

The verdict is :mod:`sparsebtf.evaluation.adaptive_verdicts`'.
"""

from __future__ import annotations

import re
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ...codec import encode_levels
from ...codec.adaptive import encode_adaptive
from ...codec.train import join_patch_sizes
from ...data.btf import BTF
from ...display import tone_map
from ...errors import BTFInputError, UnreachableTargetError
from ...model import CodedBTF
from ...patch_tree import AdaptiveCodedBTF, node_taus
from ...runtime.adaptive import decoded_view
from ...storage.adaptive_file import adaptive_report
from ..benchmark_set import reference_level
from ..scoring import coded_mse_std
from .base import PER_MATERIAL, Budget, Coding, FitContext, Method
from .sparse import _Ensemble

__all__ = ["CAP_FACTOR", "FIGURE_FOLDER", "AdaptiveMethod", "adaptive_sizes"]

#: A node's cap: this many times the level's fixed τ (per point of the largest size).
CAP_FACTOR = 2
#: The run's subfolder of the tree pictures.
FIGURE_FOLDER = "adaptive"


def adaptive_sizes(patch: int) -> tuple[int, int]:
    """The nested patch sizes of ``sparsebtf-adaptive`` for the benchmark's patch: (P, P/2)."""
    if patch < 2 or patch % 2:
        raise BTFInputError(f"sparsebtf-adaptive: the benchmark's patch {patch} must be even "
                            "(its tree splits each patch into four of half the size)")
    return patch, patch // 2


class AdaptiveMethod(_Ensemble):
    """A model of patch sizes (P, P/2) coding each material with a rate–distortion quadtree
    at the reference's bytes (the module's rule)."""

    name = "sparsebtf-adaptive"
    label = "SparseBTF, adaptive patches"
    matchings = (PER_MATERIAL,)
    # the tree is chosen by the log objective (encode_adaptive refuses the others)
    weighs_objective = False

    #: while fitting beside the reference: train the smaller size only
    small_only_ = False

    def train_patch(self) -> int | tuple[int, ...]:
        sizes = adaptive_sizes(self.patch)
        return sizes[1] if self.small_only_ else sizes

    def fit(self, train_btfs: Sequence[BTF], context: FitContext) -> Method:
        adaptive_sizes(self.patch)  # one line before any training
        ref = context.reference
        if not self._same_training(ref):
            return super().fit(train_btfs, context)
        # The P x P ensemble is the reference's: trained alone with the same settings and
        # seed it comes out the same (a size's ensemble does not depend on the others), so
        # only the P/2 one is trained; the training seconds count the reference's too.
        self.small_only_ = True
        try:
            super().fit(train_btfs, context)
        finally:
            self.small_only_ = False
        self.model_ = join_patch_sizes([ref.model_, self.model_])
        self.seconds_ += ref.seconds_
        self.reused_reference_ = True
        return self

    def _same_training(self, ref: Any) -> bool:
        """Whether the fitted reference ``ref`` trained its ensemble as this method would
        train its P x P one (then it is reused)."""
        keys = ("n_dictionaries", "patch", "sample", "iters", "tol", "log_offset")
        return (isinstance(ref, _Ensemble) and getattr(ref, "model_", None) is not None
                and ref.base_ is None and not ref.model_.patches
                and all(getattr(ref, k) == getattr(self, k) for k in keys)
                and tuple(ref.train_tau()) == tuple(self.train_tau())
                and ref.training_options == self.training_options)  # fmt: skip

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "patch_sizes": list(adaptive_sizes(self.patch)),
                "reuses_reference_ensemble": bool(getattr(self, "reused_reference_", False))}

    def shared_bytes(self) -> int:
        """Every size's dictionaries in binary16 (every material shares them)."""
        m = self.model_
        return int(sum(2 * m.for_patch(p).dictionary_entries(ch)
                       for p in m.patch_sizes for ch in m.channels))  # fmt: skip

    def code(self, btf: BTF, budgets: Sequence[Budget]) -> list[Coding]:
        out = []
        for b in budgets:
            assert b.level is not None
            tau = self.level_tau(btf, b.level)
            cap = tuple(CAP_FACTOR * t for t in tau)
            t0 = time.perf_counter()
            try:
                coded = encode_adaptive(btf, self.model_, cap, target_bytes=b.material_bytes,
                                        **self._options())  # fmt: skip
            except UnreachableTargetError as e:
                out.append(Coding(None, 0, self.shared_bytes(), note=str(e)))
                continue
            seconds = time.perf_counter() - t0
            t0 = time.perf_counter()
            (fixed,) = self.encode(btf, [tau])  # the reference's fixed-τ coding, timed
            fixed_s = time.perf_counter() - t0
            info = {"tau": list(tau), "cap_tau": list(cap), "encode_seconds": seconds,
                    "fixed_encode_seconds": fixed_s, **self._row(coded),
                    **self._std_errors(btf, coded, fixed, tau)}  # fmt: skip
            if b.level == reference_level(self.context_.levels):
                info["tree_figure"] = self._figure(btf, coded, b.level)
            out.append(Coding(decoded_view(coded), info["material_bytes"], self.shared_bytes(),
                              info=info))  # fmt: skip
        return out

    def _options(self) -> dict[str, Any]:
        ctx = self.context_
        return {"log_offset": self.log_offset,
                "candidates": self.candidates, "progress": ctx.progress,
                "client": ctx.executor}  # fmt: skip

    def _std_errors(self, btf: BTF, coded: AdaptiveCodedBTF, fixed: CodedBTF,
                    tau: tuple[int, ...]) -> dict[str, float]:  # fmt: skip
        """The coder's own error (standardised log-YUV MSE per value, by Parseval from the
        codes) of the adaptive code, of the fixed P x P code at τ, and of every point coded at
        the smaller size with the same coefficients per texel (τ·(s/P)², the tree's caps):
        whether smaller patches alone cost or save error at equal coefficients, which is
        what the tree weighs."""
        small = self.model_.patch_sizes[-1]
        taus = node_taus(dict(zip(fixed.channels, tau, strict=True)), self.model_, small)
        ctx = self.context_
        (all_small,) = encode_levels(
            btf, self.model_.for_patch(small), [taus], eps=0.0, allow_below_training=True,
            log_offset=self.log_offset, candidates=self.candidates, progress=ctx.progress,
            client=ctx.executor)  # fmt: skip
        return {"mse_std_coded": sum(coded_mse_std(v) for v in coded.layers.values()),
                "mse_std_fixed": coded_mse_std(fixed),
                "mse_std_small": coded_mse_std(all_small)}

    def _row(self, coded: AdaptiveCodedBTF) -> dict[str, Any]:
        """Its row's fields: Table 4 bytes with the tree, stored bytes, nodes per size, the
        share of texels in nodes smaller than the largest size, λ."""
        rep = adaptive_report(coded, self.model_)
        tree = coded.tree
        small = tree.nodes[tree.nodes[:, 2] < tree.sizes[0], 2]
        nnz = rep["nnz"]
        return {
            "material_bytes": int(rep["bytes_table4_material"]),
            "bytes_tree": int(rep["bytes_tree"]),
            "bytes_raw": int(rep["bytes_raw"]),
            "ratio_per_material": rep["compression_ratio_table4_material"],
            "stored_bytes": rep.get("bytes_stored"),
            "nodes": {str(p): n for p, n in tree.counts().items()},
            "small_texel_share": float((small**2).sum()) / (tree.height * tree.width),
            "nnz": {k: int(v) for k, v in nnz.items()},
            "coefficients_per_point": sum(nnz.values()) / tree.n_nodes,
            "lambda": float(coded.params["adaptive"]["lambda"]),
            "log_offset": float(coded.stats.log_offset),
        }

    def _figure(self, btf: BTF, coded: AdaptiveCodedBTF, level: int) -> str | None:
        """The tree over the material's texture (lit from 30°, seen from above), in the run's
        :data:`FIGURE_FOLDER`; its path relative to the run's folder (None: no folder)."""
        out = self.context_.out
        if out is None:
            return None
        from ..plots import tree_figure

        li = int(btf.lights.nearest(np.array([0.5, 0.0, np.sqrt(0.75)]))[0][0])
        vi = int(btf.views.nearest(np.array([0.0, 0.0, 1.0]))[0][0])
        img = btf.read(np.arange(btf.height), np.arange(btf.width), [li], [vi])[:, :, 0, 0]
        top = float(np.percentile(img, 99)) or 1.0
        name = re.sub(r"[^A-Za-z0-9_.-]+", "_", str(btf.name)) or "material"
        rel = f"{FIGURE_FOLDER}/tree_{name}_{level}.png"
        (Path(out) / FIGURE_FOLDER).mkdir(parents=True, exist_ok=True)
        counts = ", ".join(f"{n} of {p}x{p}" for p, n in coded.tree.counts().items())
        tree_figure(tone_map(img / top, a=1.0), coded.tree.nodes, coded.tree.sizes,
                    Path(out) / rel, f"{btf.name}, level {level}: {counts}")  # fmt: skip
        return rel
