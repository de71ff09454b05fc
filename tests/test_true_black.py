"""True black and high dynamic range (issue "Never a firework"): the true-black synthetic
variant, the per-material log offset, the bound kept with the statistics, and the codec on a
material with exact zeros at every level."""

import itertools
from dataclasses import replace

import numpy as np
import pytest

from sparsebtf.codec import encode, encode_levels
from sparsebtf.data.btf import ArrayBTF
from sparsebtf.data.synth import MATERIAL_CLASSES, cached, synthesize
from sparsebtf.errors import BTFInputError
from sparsebtf.evaluation.benchmark_set import FLOOR
from sparsebtf.evaluation.runner import floored
from sparsebtf.metrics import compare, top_k_largest
from sparsebtf.open import parse_synth_spec
from sparsebtf.points.preprocessing import BOUND_STEP, resolve_log_offset, round_up_bound
from sparsebtf.points.preprocessing import RELEASE_LOG_OFFSET as OFFSET
from sparsebtf.points.statistics import LOG_OFFSET_FRACTION, choose_log_offset, gather_statistics
from sparsebtf.runtime import RuntimeBTF, coded_btf_view, kernels
from sparsebtf.storage import load_coded, save_coded

from .conftest import smooth_btf, tight_bound, tiny_model

ALL = (slice(None),) * 4
#: The benchmark's four levels (SparseBTF(16), (32), (64), (128)).
LEVELS = [(326, 24, 24), (885, 64, 64), (2001, 145, 145), (4478, 324, 324)]


def _full(btf):
    return btf.read(*ALL).astype(np.float64)


# -- the synthetic variant ----------------------------------------------------------------------
def test_black_variant_has_exact_zeros_and_high_dynamic_range():
    metal = _full(synthesize("metal", 12, "tiny13", seed=1, black=True))
    assert (metal == 0).mean() >= 0.05 and metal.max() >= 10
    for cls in ("carpet", "stone"):
        soft = _full(synthesize(cls, 12, "tiny13", seed=1))
        black = _full(synthesize(cls, 12, "tiny13", seed=1, black=True))
        # the default variant keeps its stray-light floor and its 1.5 ceiling
        assert soft.min() > 0 and soft.max() <= 1.5
        assert (black == 0).any() and np.all(black >= 0)
        # shadows are black, lit values are not dimmed: only the bounce term went away
        assert np.all(black <= np.maximum(soft, 1.5) + 1e-6) or black.max() > 1.5


def test_black_variant_is_cached_apart_and_named():
    a = cached("stone", 8, "tiny13", seed=2)
    b = cached("stone", 8, "tiny13", seed=2, black=True)
    assert a.path != b.path and "black" in b.name
    assert not np.array_equal(_full(a), _full(b))
    assert parse_synth_spec("synth:stone+black:8:2:tiny13") == {
        "material": "stone", "black": True, "size": 8, "seed": 2, "directions": "tiny13"
    }
    with pytest.raises(Exception, match="unknown variant"):
        parse_synth_spec("synth:stone+shiny:8")
    assert "metal" not in MATERIAL_CLASSES  # the benchmark's seven classes are unchanged


# -- the log offset -----------------------------------------------------------------------------
def test_log_offset_rules():
    btf = ArrayBTF(np.full((4, 4, 13, 13, 3), 0.2, np.float32), *[smooth_btf(0).lights] * 2)
    assert choose_log_offset(btf, "release") == OFFSET
    assert choose_log_offset(btf, 0.003) == 0.003
    # 1 % of the median positive value (to the histogram's 64 bins per decade)
    assert choose_log_offset(btf, "auto") == pytest.approx(LOG_OFFSET_FRACTION * 0.2, rel=0.04)
    data = np.zeros((4, 4, 13, 13, 3), np.float32)
    assert choose_log_offset(ArrayBTF(data, btf.lights, btf.views), "auto") == OFFSET  # all black
    data[:2] = 1e-6  # a dark material never goes below the release's offset
    assert choose_log_offset(ArrayBTF(data, btf.lights, btf.views), "auto") == OFFSET
    for bad in ("big", 0.0, 1e-9, float("nan"), 1e9, "-1"):
        with pytest.raises(BTFInputError, match="log offset"):
            resolve_log_offset(bad)


def test_exact_zeros_do_not_move_the_offset_of_the_lit_values():
    """The offset follows the material's lit values; zeros only add black."""
    lit = _full(synthesize("stone", 12, "tiny13", seed=3))
    with_zeros = lit.copy()
    with_zeros[:, :4] = 0
    d = smooth_btf(0).lights
    a = choose_log_offset(ArrayBTF(lit.astype(np.float32), d, d), "auto")
    b = choose_log_offset(ArrayBTF(with_zeros.astype(np.float32), d, d), "auto")
    assert a > OFFSET and b == pytest.approx(a, rel=0.15)


# -- the bound ----------------------------------------------------------------------------------
def test_bound_is_the_brightest_log_value_of_each_angular_image_rounded_up():
    btf = smooth_btf(4)
    data = _full(btf)
    st = gather_statistics(btf, log_offset=1e-3, progress=False)
    true = np.log(data.astype(np.float32) + np.float32(1e-3)).max(axis=(0, 1, 4))
    assert st.bound.shape == true.shape
    assert np.all(st.bound >= true)
    assert np.all(st.bound - true <= BOUND_STEP + 1e-6)  # at most one step above
    x = np.array([1.0001, -11.51, 3.3, 2.0, 39.99])
    r = round_up_bound(x)
    assert np.all(r >= x) and r.dtype == np.float32 and r[3] == 2.0
    assert np.array_equal(r.astype(np.float16).astype(np.float32), r)  # exact in binary16


@pytest.fixture(scope="module")
def coded():
    return encode(smooth_btf(9), tiny_model(), tau=(40, 8, 8), eps=0.0, progress=False)


def test_dense_decoder_clamps_to_the_bound(coded):
    tight = tight_bound(coded)
    free = coded_btf_view(replace(coded, stats=replace(coded.stats, bound=None))).read(*ALL)
    got = coded_btf_view(tight).read(*ALL)
    cap = np.exp(tight.stats.bound.astype(np.float64)) - tight.stats.log_offset
    assert np.all(got <= cap[None, None, :, :, None] * (1 + 1e-6) + 1e-7)
    clamped = free > cap[None, None, :, :, None] * (1 + 1e-5)
    assert 0.1 < clamped.mean() < 0.9  # the test clamps for real
    below = free < cap[None, None, :, :, None] * (1 - 1e-5)
    np.testing.assert_array_equal(got[below], free[below])


@pytest.mark.parametrize("backend", ["numpy"] + (["numba"] if kernels.HAVE_NUMBA else []))
@pytest.mark.parametrize("domain", ["standardized", "log"])
def test_runtime_clamps_like_the_dense_decoder(coded, backend, domain):
    tight = tight_bound(coded)
    rt = RuntimeBTF(tight, dtype=np.float64)
    rng = np.random.default_rng(0)
    n = 300
    tex = np.stack([rng.integers(0, 8, n), rng.integers(0, 8, n)], 1)
    li, vi = rng.integers(0, 13, n), rng.integers(0, 13, n)
    got = rt.evaluate(coded.lights.xyz[li], coded.views.xyz[vi], texel=tex,
                      interpolation="nearest", backend=backend, domain=domain)  # fmt: skip
    ref = coded_btf_view(tight).read(*ALL)[tex[:, 0], tex[:, 1], li, vi]
    np.testing.assert_allclose(got, ref, rtol=2e-5, atol=1e-7)
    # between sampled directions: below the bound interpolated with the angular weights
    wi = rng.normal(size=(n, 3))
    wi[:, 2] = np.abs(wi[:, 2]) + 0.1
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    got = rt.evaluate(wi, wi[::-1], texel=tex, backend=backend, domain=domain)
    from sparsebtf.runtime import angular_weights

    li2, lw = angular_weights(coded.lights, wi, "linear")
    vi2, vw = angular_weights(coded.views, wi[::-1], "linear")
    w2 = lw[:, :, None] * vw[:, None, :]
    cap = np.exp(np.einsum("nab,nab->n", w2, tight.stats.bound[li2[:, :, None], vi2[:, None, :]]))
    assert np.all(got <= (cap - tight.stats.log_offset)[:, None] * (1 + 1e-5) + 1e-7)
    free = RuntimeBTF(coded, dtype=np.float64).evaluate(
        wi, wi[::-1], texel=tex, backend=backend, domain=domain
    )
    assert (free > got * (1 + 1e-4)).any()  # the clamp is active here too


def test_bound_round_trips_through_the_file_and_old_files_have_none(coded, tmp_path):
    save_coded(coded, tmp_path / "c.h5")
    back = load_coded(tmp_path / "c.h5")
    assert np.array_equal(back.stats.bound, coded.stats.bound)
    assert back.stats.log_offset == coded.stats.log_offset
    old = replace(coded, stats=replace(coded.stats, bound=None))
    save_coded(old, tmp_path / "old.h5")
    assert load_coded(tmp_path / "old.h5").stats.bound is None
    meta = RuntimeBTF(load_coded(tmp_path / "old.h5").attach(coded.model)).meta
    assert meta["bounded"] is False


def test_top_error_share_and_largest_value(coded):
    view = coded_btf_view(coded)
    m = compare(smooth_btf(9), view, ssim_images=0, progress=False)
    assert m["max_decoded"] == pytest.approx(float(view.read(*ALL).max()))
    assert 0 < m["top_error_share"] < 1
    kept = top_k_largest(np.empty(0), np.arange(10.0), 3)
    kept = top_k_largest(kept, np.array([4.0, 20.0]), 3)
    assert sorted(kept) == [8.0, 9.0, 20.0]


# -- the codec on true black at every level (the bundled model, UBO2014 directions) ----------------
@pytest.fixture(scope="module")
def firework_case():
    from sparsebtf.storage.bundled import load_bundled

    # one 10x10 patch of the release model (a point at UBO2014's 151 x 151 directions): without
    # the bound its decodes exceed the brightest value of their angular images at every level
    btf = cached("metal", 10, "ubo2014", seed=1, black=True)
    ref = _full(btf)
    model = load_bundled()
    out = {}
    # the floored copy is compared at level 32 only: coded up to it (the levels are nested,
    # level 32 is the same coded with or without the levels above)
    for way, src, rule, taus in (("auto", btf, "auto", LEVELS), ("release", btf, "release", LEVELS),
                                 ("floored", floored(btf, FLOOR), "release", LEVELS[:2])):
        levels = encode_levels(src, model, taus, eps=0.0, allow_below_training=True,
                               log_offset=rule, progress=False)  # fmt: skip
        # each level's decode reduced at once (a float64 copy of a 20x20 material is 219 MiB;
        # twelve of them held together made this the test suite's 4 GiB peak)
        out[way] = [_summary(coded_btf_view(c).read(*ALL).astype(np.float64), ref)
                    for c in levels]  # fmt: skip
    return ref, out


def _summary(d, ref):
    """What the test needs of a decode ``d``: its MSE against ``ref``, its largest value and
    whether every angular image stays below the bound on its brightest reference value."""
    step = np.exp(BOUND_STEP) * (1 + 1e-5)  # the bound is kept rounded up to 1/32
    per_image = (ref.max(axis=(0, 1, 4))[None, None, :, :, None] + 1e-3) * step
    return {"mse": float(np.mean((d - ref) ** 2)), "max": float(d.max()),
            "bounded": bool(np.all(d <= per_image))}  # fmt: skip


@pytest.mark.slow
def test_exact_zeros_at_every_level(firework_case):
    ref, out = firework_case
    assert (ref == 0).mean() >= 0.05 and ref.max() >= 10
    mse = [d["mse"] for d in out["auto"]]
    assert all(a > b for a, b in itertools.pairwise(mse)), mse  # strictly decreasing in τ
    # level 32 within 1.25x of the copy floored at 1e-3 (both against the unfloored material)
    assert mse[1] <= 1.25 * out["floored"][1]["mse"]
    for d in out["auto"] + out["release"]:
        # the bound: no decoded value above the brightest of its angular image
        step = np.exp(BOUND_STEP) * (1 + 1e-5)  # the bound is kept rounded up to 1/32
        assert d["max"] <= (ref.max() + 1e-3) * step
        assert d["bounded"]


def test_training_records_its_log_offset():
    from sparsebtf.codec import train

    kw = dict(n_dictionaries=2, tau_train=(8, 4, 4), patch=4, sample=1.0, max_iter=1,
              progress=False)  # fmt: skip
    black = ArrayBTF(np.where(_full(smooth_btf(1)) > 0.2, _full(smooth_btf(1)), 0)
                     .astype(np.float32), smooth_btf(1).lights, smooth_btf(1).views)
    a = train([black], log_offset="auto", **kw)
    b = train([black], log_offset="release", **kw)
    assert a.params["log_offset"] == "auto" and b.params["log_offset"] == "release"
    assert not np.allclose(a.dictionaries["Y"][0], b.dictionaries["Y"][0])
    with pytest.raises(BTFInputError, match="log offset"):
        train([black], log_offset="never", **kw)


def test_cli_log_offset(tmp_path, capsys):
    from sparsebtf.cli.main import main
    from sparsebtf.storage import save_model

    model = tiny_model()
    save_model(model, tmp_path / "m.h5")
    src = "synth:stone+black:8:3:tiny13"
    for rule, eps in (("release", OFFSET), ("0.002", 0.002)):
        out = tmp_path / f"{rule}.h5"
        assert main(["encode", src, "-m", str(tmp_path / "m.h5"), "-o", str(out),
                     "--tau", "16,4,4", "--log-offset", rule]) == 0  # fmt: skip
        assert load_coded(out).stats.log_offset == eps
    capsys.readouterr()
    assert main(["encode", src, "-m", str(tmp_path / "m.h5"), "-o", str(tmp_path / "x.h5"),
                 "--log-offset", "1e9"]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--log-offset" in err[0] and "1e+09" in err[0]
    assert not (tmp_path / "x.h5").exists()
    assert main(["eval", str(tmp_path / "release.h5"), "-m", str(tmp_path / "m.h5"),
                 "--reference", src, "--ssim-images", "1"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert "largest decoded value" in out and "worst 0.01 %" in out


def test_blend_carries_offsets_and_bounds_and_decodes_bounded():
    from sparsebtf.runtime import blend

    model = tiny_model()
    a = encode(smooth_btf(9), model, tau=(40, 8, 8), eps=0.0, progress=False)
    b = encode(smooth_btf(5), model, tau=(40, 8, 8), eps=0.0, log_offset="release",
               progress=False)  # fmt: skip
    # different offsets blend (they were refused before)
    assert a.stats.log_offset != b.stats.log_offset
    mix = blend([a, b], alpha=0.3, progress=False)
    want = round_up_bound((1 - 0.3) * a.stats.bound.astype(np.float64)
                         + 0.3 * b.stats.bound.astype(np.float64))
    assert np.array_equal(mix.stats.bound, want)
    assert mix.stats.log_offset == pytest.approx(
        0.7 * a.stats.log_offset + 0.3 * b.stats.log_offset)
    same = blend([a, b], alpha=0.0, progress=False)
    assert np.array_equal(same.stats.bound, a.stats.bound)
    assert same.stats.log_offset == a.stats.log_offset
    got = coded_btf_view(mix).read(*ALL)
    cap = np.exp(mix.stats.bound.astype(np.float64)) - mix.stats.log_offset
    assert np.all(got <= cap[None, None, :, :, None] * (1 + 1e-5) + 1e-7)
