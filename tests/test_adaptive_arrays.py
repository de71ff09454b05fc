"""The renderer arrays of an adaptive material (issue 35): every node in one set of flat
arrays with a texel-to-node table, evaluated by hand as a shader would, against the runtime."""

from __future__ import annotations

import numpy as np
import pytest

from sparsebtf.runtime import AdaptiveRuntimeBTF, angular_weights

from .test_adaptive import code_mixed
from .test_adaptive import model as model  # the module's fixture, reused


@pytest.fixture(scope="module")
def rt(model):
    coded = code_mixed(model)
    return AdaptiveRuntimeBTF(coded)


def _by_hand(a: dict, meta: dict, wi: np.ndarray, wo: np.ndarray, row: int, col: int,
             tau_fraction: float | None = None) -> np.ndarray:  # fmt: skip
    """Eq. 5/6 from the flat arrays only (linear interpolation, standardized domain): the
    node from ``cells``, (i1, i2) from its size, the padded dictionaries at stride P."""
    small = meta["smallest"]
    node = a["cells"][row // small + (meta["height"] // small) * (col // small)]
    p = a["node_patch"][node]
    li, lw = angular_weights(a["lights_xyz"], wi[None], "linear")
    vi, vw = angular_weights(a["views_xyz"], wo[None], "linear")
    log = []
    for ch in "YUV":
        k = a[f"membership_{ch}"][node]
        s0, s1 = a[f"offsets_{ch}"][node], a[f"offsets_{ch}"][node + 1]
        if tau_fraction is not None:
            s1 = min(s1, s0 + int(np.ceil(tau_fraction * a[f"tau_{ch}"][node])))
        x = 0.0
        for s in range(s0, s1):
            code = int(a[f"locations_{ch}"][s])
            l1, l2, l3, l4 = code & 255, (code >> 8) & 255, (code >> 16) & 255, code >> 24
            assert l1 < p and l2 < p  # never the padding
            g3 = sum(lw[0, j] * a[f"dict3_{ch}"][k, li[0, j], l3] for j in range(2))
            g4 = sum(vw[0, j] * a[f"dict4_{ch}"][k, vi[0, j], l4] for j in range(2))
            x += (a[f"values_{ch}"][s] * a[f"dict1_{ch}"][k, row % p, l1]
                  * a[f"dict2_{ch}"][k, col % p, l2] * g3 * g4)  # fmt: skip
        w = np.outer(lw[0], vw[0])
        sel = np.ix_([0], li[0], vi[0])
        log.append(x * np.sum(w * a["std"][sel][0]) + np.sum(w * a["mean"][sel][0]))
    bound = np.sum(np.outer(lw[0], vw[0]) * a["bound"][np.ix_(li[0], vi[0])])
    return np.exp(np.minimum(a["yuv_to_rgb"] @ np.array(log), bound)) - meta["eps"]


def test_flat_arrays_reproduce_the_runtime_in_nodes_of_each_size(rt):
    a, meta = rt.arrays(), rt.flat_meta
    tree = rt.coded.tree
    assert meta["adaptive"] and meta["patch"] == 4 and meta["smallest"] == 2
    assert meta["n_points"] == tree.n_nodes == a["node_patch"].size
    assert a["cells"].shape == (16,) and a["dict1_Y"].shape[1:] == (4, 4)
    for ch in "YUV":
        assert a[f"offsets_{ch}"].shape == (tree.n_nodes + 1,)
        assert a[f"values_{ch}"].size == meta["nnz"][ch] > rt.layers[4].meta["nnz"][ch]
        assert a[f"membership_{ch}"].max() < a[f"dict3_{ch}"].shape[0]
    # the padding of the 2x2 dictionaries is zero
    k4 = rt.layers[4].arrays(neighbours=False)["dict1_Y"].shape[0]
    assert not a["dict1_Y"][k4:, 2:, :].any() and not a["dict1_Y"][k4:, :, 2:].any()
    rng = np.random.default_rng(2)
    # texels in 4x4 nodes, in 2x2 nodes, and on both sides of the borders between them
    texels = [(0, 0), (3, 3), (3, 4), (4, 3), (4, 4), (1, 6), (6, 1), (7, 7), (5, 2), (2, 5)]
    assert set(tree.sizes_at(*np.array(texels).T).tolist()) == {2, 4}
    for row, col in texels:
        wi, wo = rng.normal(size=3), rng.normal(size=3)
        wi[2], wo[2] = abs(wi[2]) + 0.3, abs(wo[2]) + 0.3
        wi, wo = wi / np.linalg.norm(wi), wo / np.linalg.norm(wo)
        want = rt.evaluate(wi[None], wo[None], texel=np.array([[row, col]]), backend="numpy")
        np.testing.assert_allclose(_by_hand(a, meta, wi, wo, row, col), want[0], rtol=1e-5)
        # a level-of-detail fraction of each node's own τ, as the runtime's per-query τ
        frac = 0.5
        caps = np.array([a[f"tau_{ch}"][a["cells"][row // 2 + 4 * (col // 2)]] for ch in "YUV"])
        want = rt.evaluate(wi[None], wo[None], texel=np.array([[row, col]]), backend="numpy",
                           tau=np.ceil(frac * caps)[None, :])  # fmt: skip
        np.testing.assert_allclose(_by_hand(a, meta, wi, wo, row, col, frac), want[0],
                                   rtol=1e-5)  # fmt: skip


def test_a_tau_fraction_is_of_each_sizes_own_cap(rt):
    """``tau="0.5"`` halves every size's cap (the coded τ scaled to the node's texels), so the
    small nodes lose coefficients too; counts cap every size alike."""
    import math

    from sparsebtf.patch_tree import node_taus

    coded = rt.coded
    half = AdaptiveRuntimeBTF(coded, "0.5")
    for p, layer in half.layers.items():
        cap = node_taus(coded.first.coded_tau, coded.model, p)
        assert layer.tau == {ch: math.ceil(0.5 * t) for ch, t in cap.items()}
    assert half.layers[2].tau["Y"] < half.layers[4].tau["Y"]
    # with_tau takes the fraction of the same caps (not of the loaded, already halved τ),
    # kept within what each layer stores: the same coefficients as loading at "0.5"
    full = AdaptiveRuntimeBTF(coded)
    cut = full.with_tau("0.5")
    for p, layer in cut.layers.items():
        assert layer.tau == {ch: min(v, full.layers[p].tau[ch])
                             for ch, v in half.layers[p].tau.items()}  # fmt: skip
        assert layer.meta["nnz"] == half.layers[p].meta["nnz"]
    three = AdaptiveRuntimeBTF(coded, 3)
    assert all(layer.tau == {"Y": 3, "U": 3, "V": 3} for layer in three.layers.values())
