"""Tests of the synthetic material generator (sparsebtf.data.synth).

Small shapes (24×24 texels, 13 directions) keep the file fast. The physical checks compare a
material with its own flat (relief = 0) twin or with analytic expectations (cos θ), never with
numbers taken from the implementation.
"""

from __future__ import annotations

import numpy as np
import pytest

from sparsebtf.data.btf import BTF
from sparsebtf.data.directions import from_angles, tiny
from sparsebtf.data.synth import (
    GENERATOR_VERSION,
    MATERIAL_CLASSES,
    SyntheticMaterial,
    cached,
    contact_sheet,
    synthesize,
    tone_map,
)
from sparsebtf.errors import BTFInputError

SIZE = 24
DIRS = tiny(13)
RING30 = np.flatnonzero(np.isclose(np.degrees(DIRS.theta), 30.0))
RING60 = np.flatnonzero(np.isclose(np.degrees(DIRS.theta), 60.0))
NORMAL = int(np.flatnonzero(DIRS.theta == 0)[0])


def _lum(x: np.ndarray) -> np.ndarray:
    return x.mean(axis=-1)


def _ring60_at(phi_deg: float) -> int:
    phi = np.degrees(DIRS.phi[RING60])
    diff = np.abs((phi - phi_deg + 180.0) % 360.0 - 180.0)
    return int(RING60[np.argmin(diff)])


# -- API, shapes, determinism -----------------------------------------------------------------


def test_classes_are_the_seven_ubo2014_classes() -> None:
    assert MATERIAL_CLASSES == (
        "carpet",
        "fabric",
        "felt",
        "leather",
        "stone",
        "wallpaper",
        "wood",
    )


@pytest.mark.parametrize("material", MATERIAL_CLASSES)
def test_every_class_renders_finite_nonnegative_float32(material: str) -> None:
    btf = synthesize(material, SIZE, DIRS, seed=3)
    assert isinstance(btf, BTF)
    assert btf.shape == (SIZE, SIZE, 13, 13, 3)
    for v in (NORMAL, int(RING60[0])):
        block = btf.view_block(v)
        assert block.shape == (SIZE, SIZE, 13, 3)
        assert block.dtype == np.float32
        assert np.all(np.isfinite(block))
        assert block.min() >= 0.0
        assert block.max() <= 1.5 + 1e-6
        assert block.mean() > 0.005  # not black
        assert block.std() > 0.0  # not constant


def test_non_square_tile() -> None:
    btf = synthesize("fabric", (12, 20), "tiny7", seed=0)
    assert btf.shape[:2] == (12, 20)
    assert btf.angular_image(0, 3).shape == (12, 20, 3)


def test_synthesize_is_lazy_and_records_provenance() -> None:
    calls: list[int] = []
    btf = synthesize("wood", 16, DIRS, seed=5)
    original = btf._fn
    btf._fn = lambda v: calls.append(v) or original(v)  # type: ignore[method-assign]
    assert calls == []
    btf.angular_image(2, 4)
    assert calls == [4]
    assert btf.attrs["material"] == "wood"
    assert btf.attrs["seed"] == 5
    assert btf.attrs["size"] == [16, 16]
    assert btf.attrs["generator_version"] == GENERATOR_VERSION
    assert btf.lights.equals(DIRS) and btf.views.equals(DIRS)


def test_same_inputs_give_identical_values() -> None:
    a = synthesize("leather", 20, "tiny13", seed=7)
    b = synthesize("leather", 20, "tiny13", seed=7)
    for v in (0, 5, 12):
        np.testing.assert_array_equal(a.view_block(v), b.view_block(v))
    ma, mb = SyntheticMaterial("leather", 20, 7).maps, SyntheticMaterial("leather", 20, 7).maps
    np.testing.assert_array_equal(ma.height, mb.height)
    np.testing.assert_array_equal(ma.albedo, mb.albedo)


def test_different_seed_or_class_gives_different_values() -> None:
    base = synthesize("stone", 20, DIRS, seed=1).view_block(3)
    other_seed = synthesize("stone", 20, DIRS, seed=2).view_block(3)
    other_class = synthesize("leather", 20, DIRS, seed=1).view_block(3)
    assert np.abs(base - other_seed).mean() > 0.01
    assert np.abs(base - other_class).mean() > 0.01


def test_classes_look_different() -> None:
    """Normal-view, normal-light images of different classes are not near-copies."""
    imgs = {
        m: _lum(SyntheticMaterial(m, 32, 0).view_block(DIRS, DIRS.xyz[NORMAL])[:, :, NORMAL])
        for m in MATERIAL_CLASSES
    }
    for i, a in enumerate(MATERIAL_CLASSES):
        for b in MATERIAL_CLASSES[i + 1 :]:
            x, y = imgs[a].ravel(), imgs[b].ravel()
            corr = np.corrcoef(x, y)[0, 1]
            assert abs(corr) < 0.9, (a, b, corr)


def test_maps_are_tileable_and_sane() -> None:
    maps = SyntheticMaterial("fabric", 30, 0).maps
    assert maps.height.shape == (30, 30)
    assert abs(float(maps.height.mean())) < 1e-4
    assert np.ptp(maps.height) > 0.5  # a real relief, in texels
    np.testing.assert_allclose(np.linalg.norm(maps.normal, axis=-1), 1.0, atol=1e-5)
    assert np.all((maps.albedo >= 0) & (maps.albedo <= 1))
    # Periodic: the jump across the tile edge is no larger than jumps inside the tile.
    inner = np.abs(np.diff(maps.height, axis=0)).max()
    edge = np.abs(maps.height[0] - maps.height[-1]).max()
    assert edge <= inner + 1e-6


# -- BTF effects -------------------------------------------------------------------------------


@pytest.mark.parametrize("material", ["carpet", "fabric"])
def test_valley_darkens_at_grazing_light(material: str) -> None:
    """Self-shadowing: the deepest texel loses much more light at 60° than its flat twin.

    Values are divided by cos θ_i so foreshortening is taken out; a flat surface (relief 0)
    keeps the same normalised value up to its BRDF's angular variation, which the ratio of
    ratios cancels.
    """
    ratios = []
    for relief in (1.0, 0.0):
        mat = SyntheticMaterial(material, SIZE, 0, relief=relief)
        r, c = np.unravel_index(
            np.argmin(SyntheticMaterial(material, SIZE, 0).height), (SIZE, SIZE)
        )
        vals = _lum(mat.view_block(DIRS, DIRS.xyz[NORMAL])[r, c])
        grazing = (vals[RING60] / np.cos(DIRS.theta[RING60])).mean()
        ratios.append(grazing / vals[NORMAL])
    assert ratios[0] < 0.6 * ratios[1], ratios
    vis = SyntheticMaterial(material, SIZE, 0).shadow_maps(DIRS)
    assert vis.shape == (SIZE, SIZE, 13)
    assert np.all(vis[:, :, NORMAL] == 1.0)  # nothing shadows a light straight above
    assert vis[r, c, RING60].mean() < 0.5
    assert 0.0 <= vis.min() and vis.max() <= 1.0
    # Soft shadows: some texels are partly lit.
    assert np.any((vis > 0.05) & (vis < 0.95))


def test_flat_surface_has_no_shadows() -> None:
    vis = SyntheticMaterial("stone", SIZE, 0, relief=0.0).shadow_maps(DIRS)
    assert np.all(vis == 1.0)


def _opposite_view_shift(render, phi_deg: float = 90.0) -> tuple[float, float]:
    """Registration shift (along, across the view azimuth) between the images seen from
    (60°, φ) and (60°, φ + 180°) under a light at the normal."""
    from skimage.registration import phase_cross_correlation

    a, b = _ring60_at(phi_deg), _ring60_at(phi_deg + 180.0)
    phi = DIRS.phi[a]
    axis = np.array([-np.sin(phi), np.cos(phi)])  # image (row, col) of the view azimuth
    perp = np.array([-axis[1], axis[0]])
    img_a, img_b = render(DIRS.xyz[a]), render(DIRS.xyz[b])
    # Plain cross-correlation weighs the coarse relief, not the fine periodic detail.
    shift, _, _ = phase_cross_correlation(img_a, img_b, upsample_factor=20, normalization=None)
    return float(shift @ axis), float(shift @ perp)


def test_bright_tops_slide_away_from_the_viewer() -> None:
    """Parallax, sign and size, on a diffuse-only surface whose tall bumps are bright.

    A point at height h appears at u = p − h·tan θ·(cos φ, sin φ) in the rectified image, so
    between two opposite 60° views the bright bumps move by about 2·h·tan 60° *against* the
    view azimuth. Specular and sheen are off so shading cannot fake a shift.
    """
    from scipy.ndimage import gaussian_filter

    from sparsebtf.data.synth.shading import pack, prepare_lights, shade_view
    from sparsebtf.data.synth.surface import SurfaceMaps

    rng = np.random.default_rng(0)
    bumps = gaussian_filter((rng.random((32, 32)) < 0.03).astype(float), 2.0, mode="wrap")
    bumps /= bumps.max()
    zeros = np.zeros((32, 32))
    results = {}
    for depth in (3.0, 0.0):
        maps = SurfaceMaps(
            height=depth * bumps,
            albedo=(0.1 + 0.8 * bumps)[..., None],
            specular=zeros[..., None],
            roughness=zeros + 0.5,
            sheen=zeros,
            fibre_angle=zeros,
        )
        normal_light = from_angles(np.array([0.0]), np.array([0.0]))
        table = prepare_lights(maps, normal_light.xyz)
        packed = pack(maps, table)
        results[depth] = _opposite_view_shift(
            lambda v, m=maps, t=table, p=packed: _lum(shade_view(m, t, p, v)[:, :, 0])
        )
    along, across = results[3.0]
    assert along < -0.5, results
    assert abs(across) < 0.25 * abs(along), results
    assert max(abs(x) for x in results[0.0]) < 0.05, results


def test_texture_shifts_with_view_direction() -> None:
    """Parallax on a real class: carpet loops slide along the view azimuth, the flat twin
    does not move."""
    shifts = {}
    for relief in (1.0, 0.0):
        mat = SyntheticMaterial("carpet", SIZE, 0, relief=relief)
        shifts[relief] = _opposite_view_shift(
            lambda v, m=mat: _lum(m.view_block(DIRS, v)[:, :, NORMAL])
        )
    along, across = shifts[1.0]
    assert abs(along) > 0.5, shifts
    assert abs(across) < abs(along) / 2, shifts
    assert max(abs(x) for x in shifts[0.0]) < 0.05, shifts


def test_parallax_lookup_follows_height_times_tan_theta() -> None:
    from sparsebtf.data.synth.sampling import bilinear_wrap
    from sparsebtf.data.synth.shading import parallax_lookup

    h = SyntheticMaterial("stone", SIZE, 2).height
    theta, phi = np.radians(60.0), np.radians(30.0)
    v = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    rows, cols = parallax_lookup(h, v)
    rr, cc = np.mgrid[0:SIZE, 0:SIZE]
    seen_h = bilinear_wrap(h, rows, cols)
    step = np.tan(theta) * np.array([-np.sin(phi), np.cos(phi)])
    np.testing.assert_allclose(rows - rr, seen_h * step[0], atol=0.35)
    np.testing.assert_allclose(cols - cc, seen_h * step[1], atol=0.35)
    assert np.abs(rows - rr).max() > 0.5  # it does move


def test_grazing_views_see_the_tops_not_the_valleys() -> None:
    """Masking: from 75° the camera sees mostly the upper relief; valleys are hidden."""
    from sparsebtf.data.synth.sampling import bilinear_wrap
    from sparsebtf.data.synth.shading import parallax_lookup

    h = SyntheticMaterial("fabric", 32, 1).height
    seen = {}
    for theta in (0.0, 75.0):
        t = np.radians(theta)
        rows, cols = parallax_lookup(h, np.array([np.sin(t), 0.0, np.cos(t)]))
        seen[theta] = bilinear_wrap(h, rows, cols)
    spread = float(h.std())
    assert abs(seen[0.0].mean() - h.mean()) < 1e-6
    assert seen[75.0].mean() > h.mean() + 0.15 * spread
    # The gaps between yarns drop out of sight: the lowest decile of what is seen is higher.
    assert np.quantile(seen[75.0], 0.1) > np.quantile(h, 0.1) + 0.4 * spread


def test_foreshortening_follows_cos_theta_light() -> None:
    """Measured BTF values include cos θ_i: a flat, mostly diffuse stone dims like cos θ."""
    mat = SyntheticMaterial("stone", SIZE, 0, relief=0.0)
    lum = _lum(mat.view_block(DIRS, DIRS.xyz[NORMAL]))
    r30 = np.median(lum[:, :, RING30].mean(-1) / lum[:, :, NORMAL])
    r60 = np.median(lum[:, :, RING60].mean(-1) / lum[:, :, NORMAL])
    assert abs(r30 - np.cos(np.radians(30))) < 0.08
    assert abs(r60 - np.cos(np.radians(60))) < 0.08


def test_felt_has_retro_reflective_sheen() -> None:
    """Felt (flat, so no geometric shadow hiding) is brighter lit from the viewer's side."""
    v = _ring60_at(90.0)
    side = [_ring60_at(30.0), _ring60_at(150.0)]
    ratio = {}
    for material in ("felt", "stone"):
        mat = SyntheticMaterial(material, SIZE, 0, relief=0.0)
        lum = _lum(mat.view_block(DIRS, DIRS.xyz[v])).mean(axis=(0, 1))
        ratio[material] = lum[v] / lum[side].mean()
    assert ratio["felt"] > 1.2, ratio
    assert abs(ratio["stone"] - 1.0) < 0.1, ratio  # isotropic, non-sheen control


def test_fabric_sheen_is_anisotropic() -> None:
    """Warp and weft yarns swap brightness when the light turns by 90° about the normal."""
    mat = SyntheticMaterial("fabric", SIZE, 0, relief=0.0)
    angle = mat.maps.fibre_angle
    warp, weft = np.isclose(angle, np.pi / 2), np.isclose(angle, 0.0)
    assert warp.any() and weft.any()
    rel = []
    for phi in (0.0, np.pi / 2):
        light = from_angles(np.array([np.radians(60.0)]), np.array([phi]))
        img = _lum(mat.view_block(light, np.array([0.0, 0.0, 1.0]))[:, :, 0])
        rel.append(img[warp].mean() / img[weft].mean())
    # Albedo cancels in the ratio of ratios; an isotropic BRDF would give 1.
    assert rel[0] / rel[1] > 1.5, rel


# -- cache and contact sheet --------------------------------------------------------------


def test_cached_renders_once_then_reads_the_file(tmp_path, monkeypatch) -> None:
    first = cached("wallpaper", 12, "tiny7", seed=4, cache_dir=tmp_path)
    files = list(tmp_path.glob("*.h5"))
    assert len(files) == 1
    expect = synthesize("wallpaper", 12, "tiny7", seed=4).to_array()
    np.testing.assert_array_equal(first.to_array(), expect)

    def boom(*args, **kwargs):
        raise AssertionError("cached() rendered again instead of reading the file")

    monkeypatch.setattr(SyntheticMaterial, "view_block", boom)
    second = cached("wallpaper", 12, "tiny7", seed=4, cache_dir=tmp_path)
    np.testing.assert_array_equal(second.to_array(), expect)
    assert second.attrs["material"] == "wallpaper"
    assert list(tmp_path.glob("*.h5")) == files
    for btf in (first, second):
        btf.close()


def test_cache_key_separates_inputs(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("SPARSEBTF_CACHE", str(tmp_path))
    a = cached("felt", 8, "tiny7", seed=0)
    b = cached("felt", 8, "tiny7", seed=1)
    c = cached("felt", 8, "tiny13", seed=0)
    assert len(list(tmp_path.glob("*.h5"))) == 3
    assert np.abs(a.view_block(0) - b.view_block(0)).max() > 0
    assert c.shape[2] == 13
    for btf in (a, b, c):
        btf.close()


def test_contact_sheet_writes_a_png(tmp_path) -> None:
    from skimage import io

    btf = synthesize("fabric", 16, DIRS, seed=0)
    out = contact_sheet(btf, tmp_path / "sheet.png")
    assert out == tmp_path / "sheet.png"
    img = io.imread(out)
    assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100
    assert img.std() > 5  # not a blank canvas
    assert not list(tmp_path.glob(".*part"))  # no temporary left behind
    custom = contact_sheet(btf, tmp_path / "two.png", lights=[0, 1], views=[0])
    assert io.imread(custom).shape[1] < img.shape[1]


def test_tone_map_matches_the_paper_operator() -> None:
    x = np.array([0.0, 0.1, 0.5, 1.0, 4.0, -1.0, np.nan])
    y = tone_map(x)
    np.testing.assert_allclose(y[:4], np.clip(1.3 * x[:4] ** (1 / 1.8), 0, 1))
    assert y[4] == 1.0 and y[5] == 0.0 and y[6] == 0.0


# -- bad input -------------------------------------------------------------------------------


def test_unknown_class_lists_the_known_ones() -> None:
    with pytest.raises(BTFInputError, match=r"carpet.*wood"):
        synthesize("velvet", 16, DIRS)
    with pytest.raises(BTFInputError):
        cached(3, 16, DIRS)  # type: ignore[arg-type]


@pytest.mark.parametrize("size", [3, 0, -5, (16, 2), 16.0, 12.5, "16", True, (16,), (4, 4, 4)])
def test_bad_size(size) -> None:
    with pytest.raises(BTFInputError, match="size"):
        synthesize("stone", size, DIRS)


def test_unknown_direction_set() -> None:
    with pytest.raises(BTFInputError, match="ubo2014"):
        synthesize("stone", 16, "ubo2099")
    with pytest.raises(BTFInputError):
        synthesize("stone", 16, 151)  # type: ignore[arg-type]


@pytest.mark.parametrize("seed", [-1, 1.5, "0", None])
def test_bad_seed(seed) -> None:
    with pytest.raises(BTFInputError, match="seed"):
        synthesize("stone", 16, DIRS, seed=seed)


def test_bad_view_and_contact_sheet_indices(tmp_path) -> None:
    mat = SyntheticMaterial("stone", 8, 0)
    with pytest.raises(BTFInputError):
        mat.view_block(DIRS, np.array([0.0, 0.0, -1.0]))
    with pytest.raises(BTFInputError):
        mat.view_block(DIRS, np.array([0.0, 0.0]))
    with pytest.raises(BTFInputError):
        contact_sheet(synthesize("stone", 8, DIRS), tmp_path / "x.png", lights=[99])
    with pytest.raises(BTFInputError):
        contact_sheet(np.zeros((8, 8, 3)), tmp_path / "x.png")  # type: ignore[arg-type]
