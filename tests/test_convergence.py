"""The neural baselines' stop rule (training until the held-out loss plateaus) on toy problems:
it stops on a plateau and not before, runs to its cap when the loss keeps falling, records
what it did, and a larger latent at convergence is not worse."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from sparsebtf.data.btf import ArrayBTF  # noqa: E402
from sparsebtf.data.directions import tiny  # noqa: E402
from sparsebtf.evaluation.methods import PAPER, Budget  # noqa: E402
from sparsebtf.evaluation.neural import rjgw19  # noqa: E402
from sparsebtf.evaluation.neural._convergence import (  # noqa: E402
    StopRule,
    plateaued,
    train_to_convergence,
)
from sparsebtf.evaluation.neural._torch import heldout_pairs, read_pool, seed_generator  # noqa: E402

RULE = StopRule(max_queries_per_texel=1000, eval_every=10)


def test_plateau_needs_less_than_tolerance_over_the_last_fifth():
    falling = [(q, 0.9 ** (q / 10)) for q in range(0, 210, 10)]  # -19% per fifth at the end
    assert not plateaued(falling, 0.0, RULE)
    flat = [(0, 1.0), *((q, 0.5 - 1e-4 * q / 10) for q in range(10, 210, 10))]
    assert plateaued(flat, 0.0, RULE)
    # the last fifth (160..200) must lie after the last learning-rate drop
    assert not plateaued(flat, 170.0, RULE)
    assert plateaued(flat, 160.0, RULE)
    # nor is it tested before the minimum effort (NeuMIP's blur)
    assert not plateaued(flat, 0.0, StopRule(1000, 10, min_queries_per_texel=250))
    # the best loss counts: a noisy rise after a low is no improvement
    bumpy = [(0, 1.0), (10, 0.5), (20, 0.6), (30, 0.55), (40, 0.52), (50, 0.51)]
    assert plateaued(bumpy, 0.0, RULE)
    assert plateaued([(0, 1.0), (10, float("inf"))], 0.0, RULE)  # diverged


def _regression(seed: int = 0):
    """A noisy linear least-squares problem: its held-out loss falls to the noise and stays."""
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(4096, 8, generator=g)
    y = x @ torch.randn(8, 1, generator=g) + 0.1 * torch.randn(4096, 1, generator=g)
    w = torch.zeros(8, 1, requires_grad=True)
    xt, yt, xh, yh = x[:3072], y[:3072], x[3072:], y[3072:]

    def loss_at(_: int, __: float) -> torch.Tensor:
        i = torch.randint(0, 3072, (64,), generator=g)
        return ((xt[i] @ w - yt[i]) ** 2).mean()

    def heldout() -> float:
        return float(((xh @ w - yh) ** 2).mean())

    return w, loss_at, heldout


def test_stops_on_a_plateau_and_not_before():
    w, loss_at, heldout = _regression()
    fit = train_to_convergence([w], loss_at, heldout, 1.0, (0.05, 0.005), RULE, "toy", False)
    assert fit["converged"] and fit["iterations"] < RULE.max_queries_per_texel
    assert fit["heldout_loss"] < 0.02  # the noise's 0.01, not the start's ~8
    curve = [tuple(p) for p in fit["loss_curve"]]
    assert curve[0][0] == 0 and curve[-1][0] == fit["queries_per_texel"]
    drops = fit["lr_drops"]
    assert len(drops) == 2  # 0.05 -> 0.015 -> 0.005 (the floor), then the final plateau
    since = drops[-1]
    assert plateaued(curve, since, RULE)
    # no earlier evaluation at the floor rate had plateaued: it did not stop early
    for k in range(1, len(curve)):
        if curve[k - 1][0] > since:
            assert not plateaued(curve[:k], since, RULE)


def test_runs_to_its_cap_while_the_loss_keeps_falling():
    calls = []

    def heldout() -> float:
        calls.append(1)
        return 0.8 ** len(calls)

    p = torch.zeros(1, requires_grad=True)
    fit = train_to_convergence([p], lambda t, q: (p - 1).pow(2).sum(), heldout, 2.0,
                               (1e-2, 1e-3), StopRule(200, 20), "toy", False)  # fmt: skip
    assert not fit["converged"] and fit["lr_drops"] == []
    assert fit["iterations"] == 100 and fit["queries_per_texel"] == 200
    assert len(fit["loss_curve"]) == 11 and fit["cpu_seconds"] >= 0


def test_heldout_pairs_avoid_the_training_pairs():
    gen = seed_generator(1)
    taken = np.stack([np.arange(10), np.arange(5, 15), np.zeros(10, int)])
    rows, pairs = heldout_pairs(taken, 20, 6, gen)
    for r in range(3):
        mine = pairs[rows == r]
        assert 0 < mine.size <= 6 and len(set(mine)) == mine.size
        assert not set(mine) & set(taken[r])
    btf = ArrayBTF(np.random.default_rng(0).uniform(0.1, 1, (4, 4, 13, 13, 3)).astype(
        np.float32), tiny(13), tiny(13))  # fmt: skip
    pool = read_pool(btf, 40, seed_generator(2), heldout=8, heldout_texels=5)
    ho = pool.heldout
    assert len(set(ho.rows.tolist())) == 5
    flat_pool = pool.lights.long() * 13 + pool.views.long()
    for r in set(ho.rows.tolist()):
        mine = (ho.lights[ho.rows == r] * 13 + ho.views[ho.rows == r]).tolist()
        assert not set(mine) & set(flat_pool[r].tolist())
    values = btf.read(slice(None), slice(None), slice(None), slice(None)).reshape(16, 13, 13, 3)
    texel = pool.texels[ho.rows.numpy()]
    np.testing.assert_allclose(ho.values.numpy(), np.log1p(values[texel, ho.lights.numpy(),
                                                                    ho.views.numpy()]),
                               rtol=1e-6)  # fmt: skip


def _mixture_btf(size: int = 8, lobes: int = 6, noise: float = 0.05, seed: int = 0) -> ArrayBTF:
    """Texels, each its own mixture of ``lobes`` angular lobes (and ``noise``, a floor the
    held-out loss reaches): few latents cannot tell the texels apart, more can."""
    rng = np.random.default_rng(seed)
    d = tiny(13)
    axes = rng.normal(size=(lobes, 3))
    axes[:, 2] = np.abs(axes[:, 2]) + 0.5
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    half = d.xyz[:, None, :] + d.xyz[None, :, :]
    half /= np.linalg.norm(half, axis=-1, keepdims=True)
    lobe = np.exp(8 * (half @ axes.T - 1))  # (13, 13, lobes)
    weights = rng.dirichlet(np.ones(lobes), (size, size)) * rng.uniform(0.2, 1.0, (size, size, 1))
    colour = rng.uniform(0.3, 1.0, (lobes, 3))
    data = 10 * np.einsum("hwk,lvk,kc->hwlvc", weights, lobe, colour) + 0.2
    data *= 1 + noise * rng.standard_normal(data.shape)
    return ArrayBTF(data.astype(np.float32), d, d, name="mixture")


def test_a_larger_latent_is_not_worse_at_convergence():
    btf = _mixture_btf(noise=0.2)
    ref = btf.read(slice(None), slice(None), slice(None), slice(None))
    method = rjgw19.RJGW19Method(max_queries_per_texel=40_000, eval_every=400, pool=80,
                                 heldout=8, tolerance=0.02, seed=0, progress=False)  # fmt: skip
    small = method.latent_size(5600, 64)
    codings = method.code(btf, [Budget(2, 5600, PAPER), Budget(16, 12_000, PAPER)])
    sizes = [c.info["latent_size"] for c in codings]
    assert sizes[0] == small < sizes[1]
    assert all(c.info["converged"] for c in codings)
    err = [float(((c.reconstruction.read(slice(None), slice(None), slice(None), slice(None))
                   - ref) ** 2).mean()) for c in codings]  # fmt: skip
    assert err[1] <= 1.05 * err[0], (sizes, err)


# -- reading a run: the verdicts count converged cells only ---------------------------------------
def _run(converged: dict[tuple[str, str, int], bool], mse: dict[tuple[str, str, int], float]):
    rows = []
    for (m, mat, lv), v in mse.items():
        row = {"material": mat, "set": "test", "method": m, "level": lv, "mse_rgb": v * 1e-4}
        if m != "sparsebtf":
            row.update(matching=PAPER, budget_factor=1, latent_size=lv,
                       heldout_loss=v * 1e-3, converged=converged.get((m, mat, lv), True),
                       loss_curve=[[0.0, 1.0], [100.0, v * 1e-3]])  # fmt: skip
        rows.append(row)
    return {"config": {"levels": [16, 128]}, "rows": rows,
            "methods": {"sparsebtf": "SparseBTF", "rjgw19": "RJGW19", "rgjw20": "RGJW20"},
            "method_runs": {"rjgw19": {"label": "RJGW19", "scope": "per_material"},
                            "rgjw20": {"label": "RGJW20", "scope": "shared"}}}  # fmt: skip


def test_verdicts_leave_out_unconverged_cells_and_count_them():
    from sparsebtf.evaluation.claims3 import NOT_CONVERGED, summarise_table3, table3_comparison

    mse = {}
    for mat in ("a", "b"):
        for lv, (s, r20, r19) in {16: (10, 20, 5), 128: (4, 20, 30)}.items():
            mse.update({("sparsebtf", mat, lv): s, ("rgjw20", mat, lv): r20,
                        ("rjgw19", mat, lv): r19})  # fmt: skip
    everything = summarise_table3(_run({}, mse), 16)
    assert everything["table3_rjgw19_lowest"]["cells_lowest"] == "2/4"
    cap = everything["table3_capacity"]
    assert cap["verdict"] == "fails in 2/2" and cap["methods"] == ["rjgw19"]
    assert cap["failures"][0]["ratio"] == pytest.approx(6.0)
    assert "rose too" in cap["failures"][0]["cause"]  # its held-out loss rose with L

    # RJGW19 at 128 stopped at its cap on material a: that cell and that pair are left out
    s = summarise_table3(_run({("rjgw19", "a", 128): False}, mse), 16)
    low = s["table3_rjgw19_lowest"]
    assert low["cells_lowest"] == "2/3" and low["not_converged_cells"] == ["a (128)"]
    assert s["table3_vs_rgjw20"]["cells_won"] == "4/4"  # RGJW20's cells all converged
    assert s["table3_vs_rgjw20"]["not_converged"] == 0
    cap = s["table3_capacity"]
    assert cap["pairs_holding"] == "0/1" and cap["not_converged_pairs"] == ["rjgw19 a"]
    # converged, a larger latent that is not worse holds
    good = {**mse, ("rjgw19", "a", 128): 5.2, ("rjgw19", "b", 128): 4}
    assert summarise_table3(_run({}, good), 16)["table3_capacity"]["verdict"] == "holds"
    text = table3_comparison(_run({("rjgw19", "a", 128): False}, mse))
    assert f"| RJGW19 (128) | 30{NOT_CONVERGED} | 30 |" in text


def test_learning_curve_figure_and_budget_table(tmp_path):
    from sparsebtf.evaluation.plots import learning_curve_rows, learning_curves
    from sparsebtf.evaluation.report import _budgets_table

    mse = {(m, mat, lv): 1.0 + lv for m in ("rjgw19", "sparsebtf") for mat in ("a", "b", "c")
           for lv in (16, 128)}  # fmt: skip
    result = _run({("rjgw19", "b", 128): False}, mse)
    data = learning_curve_rows(result)
    assert set(data) == {"rjgw19"} and set(data["rjgw19"]) == {"a", "b"}  # two materials
    assert sorted(data["rjgw19"]["a"]) == [16, 128]
    assert learning_curves(result, tmp_path / "lc.png").stat().st_size > 1000
    assert learning_curves({"rows": [], "config": {"levels": []}}, tmp_path / "x.png") is None
    result["method_runs"]["rjgw19"]["training_budget"] = {
        "seconds": 2.0, "cpu_seconds": 3.5, "converged": "3/4", "queries_per_texel": 9000.0,
        "queries_per_texel_min": 4000.0, "stop_rule": StopRule(20_000, 500).describe()}
    table = "\n".join(_budgets_table(result, "results/"))
    assert ("| RJGW19 | per_material | 0 | 2 | 4 | 4,000–9,000 | 3/4 | held-out gain < 1% over "
            "the last 20%; eval every 500, from 0, cap 20,000 queries per texel |") in table
    assert "![learning curves](results/learning_curves.png)" in table
