"""``sparsebtf capture``: BTFs of Mitsuba scenes checked against physics (tiny: 8x8 texels or
so, 13 directions or a handful, low spp).

* a Lambertian plane gives rho*cos(theta_l) in every view (the value convention of
  docs/format.md), and the built-in chart gives its patches' albedos;
* a rough-conductor plane equals Mitsuba's own BSDF evaluation (times pi) at the same
  directions, in the BTF's tangent frame (azimuth from +x towards +y: an anisotropic one);
* a V-groove is black exactly where its geometry shadows it, and lit elsewhere;
* one height field through capture and through synth's ray-marcher agrees (Lambertian, no
  inter-reflection) within the tolerance stated below;
* outputs open with info / train / encode / eval like any BTF; every built-in sample runs;
  an interrupted capture resumes to the very values of an uninterrupted one; bad scenes and
  options are one line.
"""

from __future__ import annotations

import json
import math
import textwrap

import h5py
import numpy as np
import pytest

from sparsebtf.cli.main import main
from sparsebtf.data.directions import from_angles
from sparsebtf.errors import SparseBTFError
from sparsebtf.llvm import configure
from sparsebtf.open import open_btf

pytestmark = pytest.mark.skipif(
    not configure().ok, reason="capture renders with Mitsuba's LLVM backend: apt-get install "
    "libllvm19")  # fmt: skip


def capture(*args, **kw):
    from sparsebtf.data.capture import capture as run

    return run(*args, progress=False, **kw)


def scene_file(tmp_path, name, body):
    """A Python scene file defining ``scene(seed)`` (``body`` is its function body)."""
    path = tmp_path / f"{name}.py"
    path.write_text("import numpy as np\nimport mitsuba as mi\n\n\ndef scene(seed):\n"
                    + textwrap.indent(textwrap.dedent(body), "    "))  # fmt: skip
    return str(path)


def read(path):
    with open_btf(path) as b:
        return b.to_array().astype(np.float64), b.lights.xyz, b.views.xyz


def plane(tmp_path, bsdf):
    return scene_file(tmp_path, "plane", f"return {{'type': 'scene', 'plane': "
                                         f"{{'type': 'rectangle', 'bsdf': {bsdf!r}}}}}\n")


# --------------------------------------------------------------------------- physics


def test_lambertian_plane_is_rho_cos_theta_light_in_every_view(tmp_path):
    rho = [0.2, 0.5, 0.8]
    src = plane(tmp_path, {"type": "diffuse", "reflectance": {"type": "rgb", "value": rho}})
    out = capture(src, tmp_path / "p.h5", size=8, directions="tiny13", spp=4)
    a, lights, _ = read(out)
    expected = np.asarray(rho)[None, :] * lights[:, 2:3]  # (L, 3): rho * cos(theta_l)
    # A flat diffuse plane under a directional light has no Monte Carlo noise at all.
    assert np.allclose(a, expected[None, None, :, None, :], rtol=1e-5, atol=1e-6)


def test_builtin_chart_gives_its_albedos(tmp_path):
    from sparsebtf.data.capture.samples import chart_albedo

    out = capture("plane", tmp_path / "c.h5", size=8, directions="tiny13", spp=4, seed=3)
    a, lights, _ = read(out)
    albedo = a / lights[None, None, :, None, 2:3]
    chart = np.repeat(np.repeat(chart_albedo(3), 2, axis=0), 2, axis=1)  # 4x4 patches, 2 texels
    assert np.allclose(albedo, chart[:, :, None, None, :], rtol=1e-5, atol=1e-6)


def test_rough_conductor_plane_equals_mitsubas_bsdf(tmp_path):
    import drjit as dr
    import mitsuba as mi

    bsdf = {"type": "roughconductor", "distribution": "ggx", "material": "Cu",
            "alpha_u": 0.1, "alpha_v": 0.35}  # fmt: skip
    src = plane(tmp_path, bsdf)
    out = capture(src, tmp_path / "m.h5", size=4, directions="tiny13", spp=2)
    a, lights, views = read(out)
    # Mitsuba's own evaluation in the BTF's frame: s = +x (texture u), t = +y, n = +z.
    b = mi.load_dict(bsdf)
    si = dr.zeros(mi.SurfaceInteraction3f)
    si.sh_frame = mi.Frame3f(mi.Vector3f(1, 0, 0), mi.Vector3f(0, 1, 0), mi.Vector3f(0, 0, 1))
    ref = np.zeros((len(lights), len(views), 3))
    for v, wv in enumerate(views):
        si.wi = mi.Vector3f(*map(float, wv))
        for li, wl in enumerate(lights):
            value = b.eval(mi.BSDFContext(), si, mi.Vector3f(*map(float, wl)))
            ref[li, v] = math.pi * np.asarray(value).ravel()
    assert ref.max() > 3  # the highlight is there (an anisotropic, HDR lobe)
    assert np.allclose(a, ref[None, None], rtol=2e-4, atol=1e-5)


VGROOVE = """
grooves, a = {grooves}, {depth}
w = 2.0 / grooves
xs = -1.0 + 0.5 * w * np.arange(2 * grooves + 1)
zs = np.where(np.arange(2 * grooves + 1) % 2 == 0, a, -a)  # ridges at x = -1 + k w
pos, nrm, faces = [], [], []
for k in range(2 * grooves):  # one flat facet per strip, its own vertices and normal
    x0, x1, z0, z1 = xs[k], xs[k + 1], zs[k], zs[k + 1]
    n = np.array([-(z1 - z0), 0.0, x1 - x0]); n /= np.linalg.norm(n)
    base = len(pos)
    pos += [[x0, -1, z0], [x1, -1, z1], [x1, 1, z1], [x0, 1, z0]]
    nrm += [n] * 4
    faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
pos, nrm = np.array(pos, dtype=np.float32), np.array(nrm, dtype=np.float32)
props = mi.Properties()
props["bsdf"] = mi.load_dict({{"type": "diffuse", "reflectance": {{"type": "rgb", "value": 0.5}}}})
mesh = mi.Mesh("vgroove", len(pos), len(faces), has_vertex_normals=True, props=props)
p = mi.traverse(mesh)
p["vertex_positions"] = mi.Float(pos.ravel())
p["vertex_normals"] = mi.Float(nrm.ravel())
p["faces"] = mi.UInt32(np.array(faces, dtype=np.uint32).ravel())
p.update()
return {{"type": "scene", "vgroove": mesh}}
"""


def test_v_groove_shadows_where_geometry_says(tmp_path):
    grooves, size = 4, 64
    w = 2.0 / grooves
    a = w / 4  # facets at alpha = 45 degrees
    src = scene_file(tmp_path, "vgroove", VGROOVE.format(grooves=grooves, depth=a))
    th = np.radians([0.0, 30.0, 60.0, 60.0])
    ph = np.radians([0.0, 0.0, 0.0, 180.0])
    dirs = from_angles(th, ph, name="vgroove")
    out = capture(src, tmp_path / "v.h5", size=size, directions=dirs, spp=8, max_depth=2)
    img, _, _ = read(out)
    top = img[:, :, :, 0, 0].mean(axis=0)  # view from the normal; (cols, lights)
    alpha = math.radians(45.0)
    step = 2.0 / size
    edges = -1.0 + step * np.arange(size + 1)
    for li in (1, 2, 3):
        theta, toward_plus_x = float(th[li]), ph[li] == 0
        elev = math.pi / 2 - theta
        # distance from the ridge measured away from the light, in one groove
        lit = np.zeros(size)
        fine = np.linspace(0, 1, 201)
        for c in range(size):
            x = edges[c] + step * fine
            d = np.mod(x + 1.0, w) if toward_plus_x else np.mod(-(x + 1.0), w)
            facing = d < w / 2  # the facet whose normal leans towards the light
            reach = w * math.tan(elev) / (math.tan(alpha) + math.tan(elev))
            value = np.where(facing, np.cos(theta - alpha) * (d <= reach),
                             max(math.cos(theta + alpha), 0.0))  # fmt: skip
            lit[c] = 0.5 * value.mean()
        whole = np.isclose(lit, 0) | np.isclose(lit, 0.5 * math.cos(theta - alpha)) | (
            np.isclose(lit, 0.5 * max(math.cos(theta + alpha), 0.0)))
        assert whole.sum() >= size // 2 and (lit[whole] > 0).any()
        assert np.allclose(top[whole, li], lit[whole], atol=1e-5), (li, top[:, li], lit)
        # texels that straddle a shadow edge hold the lit share, within Monte Carlo noise
        assert np.allclose(top[~whole, li], lit[~whole], atol=0.1)
        if elev < alpha:
            assert (top[:, li] == 0).sum() >= size // 2  # back-facing facets and cast shadows


def test_capture_and_synth_ray_marcher_agree_on_one_height_field(tmp_path):
    """Lambertian, max depth 2: the same periodic height field (texel units, zero mean) as a
    mesh in capture, and through synth's parallax ray-marcher and horizon shadows.

    Stated tolerance (16x16 texels, relief 1.2 + 0.6 texels over a 16-texel period): over
    all texels the mean absolute difference is below 3 % of the mean value (measured 2.0 %);
    per (light, view) pair the means differ by under 5 % (measured at most 3.3 %) and the mean
    absolute difference is under 12 % of the mean (measured 9 %, at 60-degree light and view
    where shadow edges cross texels). Synth samples each texel at its centre (bilinear maps,
    horizon-map shadows); capture averages 16 jittered paths over the texel on the triangle
    mesh; the difference halves at 32x32 texels (1.0 %), so it is the texel scale, not a
    convention: a flipped parallax or shadow direction moves features by 2 texels at 60 deg.
    """
    from sparsebtf.data.synth.sampling import bilinear_wrap
    from sparsebtf.data.synth.shading import BLACK_PENUMBRA, parallax_lookup, prepare_lights
    from sparsebtf.data.synth.surface import SurfaceMaps

    n = 16
    rr, cc = np.mgrid[0:n, 0:n] * (2 * np.pi / n)
    height = 1.2 * np.sin(cc) * np.cos(rr) + 0.6 * np.cos(2 * cc + rr)
    height -= height.mean()
    np.save(tmp_path / "height.npy", height)
    src = scene_file(tmp_path, "hf", f"""
        from sparsebtf.data.capture.samples import _mesh, heightfield_mesh
        h = np.load({str(tmp_path / 'height.npy')!r})
        bsdf = {{"type": "diffuse", "reflectance": {{"type": "rgb", "value": 0.6}}}}
        return {{"type": "scene", "hf": _mesh("hf", heightfield_mesh(h, 2.0 / {n}), bsdf)}}
    """)
    out = capture(src, tmp_path / "hf.h5", size=n, directions="tiny13", spp=16, max_depth=2)
    got, lights, views = read(out)
    maps = SurfaceMaps(height=height, albedo=0.6, specular=0.0, roughness=1.0, sheen=0.0,
                       fibre_angle=0.0)  # fmt: skip
    table = prepare_lights(maps, lights, BLACK_PENUMBRA)
    packed = np.concatenate([maps.normal, table.visibility], axis=-1)
    ref = np.zeros_like(got)
    for v, wv in enumerate(views):
        rows, cols = parallax_lookup(maps.height, wv)
        s = bilinear_wrap(packed, rows, cols)
        nrm = s[..., :3] / np.linalg.norm(s[..., :3], axis=-1, keepdims=True)
        ref[:, :, :, v, :] = (0.6 * np.maximum(nrm @ lights.T, 0) * s[..., 3:])[..., None]
    diff = np.abs(got - ref).mean(axis=(0, 1, 4)) / ref.mean(axis=(0, 1, 4))
    bias = (got - ref).mean(axis=(0, 1, 4)) / ref.mean(axis=(0, 1, 4))
    assert np.abs(got - ref).mean() / ref.mean() < 0.03
    assert np.abs(bias).max() < 0.05, np.abs(bias).max()
    assert diff.max() < 0.12, diff.max()


# --------------------------------------------------------------------------- the command


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_the_issue_command_and_the_output_is_a_btf_like_any(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, _ = run(["capture", "plane", "-o", "p.h5", "--size", "8", "--directions",
                        "tiny13", "--spp", "16"], capsys)  # fmt: skip
    assert code == 0 and "wrote p.h5: 8x8 texels, 13 lights x 13 views" in out
    assert not (tmp_path / "p.h5.partial").exists()
    code, out, _ = run(["info", "p.h5", "--json"], capsys)
    info = json.loads(out)
    assert code == 0 and info["shape"] == [8, 8, 13, 13, 3]
    code, _, _ = run(["capture", "woven", "-o", "w.h5", "--size", "8", "--directions", "tiny13",
                      "--spp", "2"], capsys)  # fmt: skip
    assert code == 0
    train = ["train", "p.h5", "w.h5", "-o", "m.h5", "--dicts", "2", "--tau-train", "16,4,4",
             "--patch", "4", "--sample", "1", "--iters", "1"]  # fmt: skip
    code, _, _ = run(train, capsys)
    assert code == 0
    code, _, _ = run(["encode", "w.h5", "-m", "m.h5", "-o", "w.coded.h5", "--tau", "32,8,8"],
                     capsys)  # fmt: skip
    assert code == 0
    code, out, _ = run(["eval", "w.coded.h5", "--reference", "w.h5", "--json"], capsys)
    assert code == 0 and json.loads(out)["psnr_rgb"] > 10


@pytest.mark.parametrize("name", ["plane", "woven", "pebbles", "leather", "metal", "copper",
                                  "copper-mirror", "copper-rough", "brushed"])  # fmt: skip
def test_every_builtin_sample_runs(tmp_path, name):
    from sparsebtf.data.capture import SAMPLES

    assert name in SAMPLES and len(SAMPLES) == 9
    out = capture(name, tmp_path / f"{name}.h5", size=4, directions="tiny7", spp=2, seed=1)
    a, _, _ = read(out)
    assert a.shape == (4, 4, 7, 7, 3) and np.isfinite(a).all() and a.max() > 0.01
    assert a.min() >= 0


def test_sample_geometry_follows_its_seed(tmp_path):
    a = read(capture("pebbles", tmp_path / "a.h5", size=4, directions="tiny7", spp=1))[0]
    c = read(capture("pebbles", tmp_path / "c.h5", size=4, directions="tiny7", spp=1,
                     seed=5))[0]  # fmt: skip
    assert not np.allclose(a, c)  # (same seed, same values: the resume test)


def test_noise_seed_reseeds_the_paths_alone(tmp_path):
    # pebbles: random geometry from --seed, Monte Carlo noise (1 path per texel) from the paths
    def cap(name, **kw):
        return read(capture("pebbles", tmp_path / name, size=4, directions="tiny7", spp=1,
                            seed=5, **kw))[0]  # fmt: skip

    a, same, twin = cap("a.h5"), cap("s.h5", noise_seed=5), cap("t.h5", noise_seed=6)
    assert np.array_equal(a, same)  # the noise seed defaults to the seed
    assert not np.allclose(a, twin)  # other paths ...
    many = [read(capture("pebbles", tmp_path / f"m{k}.h5", size=4, directions="tiny7",
                         spp=16, seed=5, noise_seed=k))[0] for k in (1, 2)]  # fmt: skip
    other = read(capture("pebbles", tmp_path / "o.h5", size=4, directions="tiny7", spp=16,
                         seed=6))[0]  # fmt: skip
    # ... over the same sample: two noise seeds converge to each other, not to another sample
    assert np.square(many[0] - many[1]).mean() < 0.5 * np.square(many[0] - other).mean()
    assert "capture-pebbles-4x4-s5-n2" in h5py.File(tmp_path / "m2.h5")["/"].attrs["name"].decode()


def test_crop_renders_a_window_of_the_full_capture(tmp_path):
    # the flat chart has no Monte Carlo noise: a window equals the full capture's texels
    full = read(capture("plane", tmp_path / "f.h5", size=8, directions="tiny7", spp=2))[0]
    part = read(capture("plane", tmp_path / "c.h5", size=8, directions="tiny7", spp=2,
                        crop=(slice(2, 6), slice(3, 8))))[0]  # fmt: skip
    assert part.shape == (4, 5, 7, 7, 3)
    assert np.allclose(part, full[2:6, 3:8], rtol=1e-6, atol=1e-7)


def _dies_after_three(writer, calls):
    """A render_block that records each view and is interrupted at the fourth (a kill)."""
    real = writer.render_block

    def render(spec, view):
        calls.append(view)
        if len(calls) > 3:
            raise KeyboardInterrupt
        return real(spec, view)

    return render


def test_interrupted_capture_resumes_to_the_same_values(tmp_path, monkeypatch, capsys):
    from sparsebtf.data.capture import writer

    whole = read(capture("pebbles", tmp_path / "whole.h5", size=4, directions="tiny7", spp=2))[0]
    out = tmp_path / "cut.h5"
    real = writer.render_block
    calls = []
    monkeypatch.setattr(writer, "render_block", _dies_after_three(writer, calls))
    with pytest.raises(KeyboardInterrupt):
        capture("pebbles", out, size=4, directions="tiny7", spp=2)
    assert not out.exists() and (tmp_path / "cut.h5.partial").exists()
    assert "3 of 7 views are kept" in capsys.readouterr().err
    monkeypatch.setattr(writer, "render_block", real)
    with pytest.raises(SparseBTFError, match="add --resume"):
        capture("pebbles", out, size=4, directions="tiny7", spp=2)
    with pytest.raises(SparseBTFError, match="differs in spp"):
        capture("pebbles", out, size=4, directions="tiny7", spp=3, resume=True)
    calls.clear()
    monkeypatch.setattr(writer, "render_block", lambda spec, v: calls.append(v) or real(spec, v))
    capture("pebbles", out, size=4, directions="tiny7", spp=2, resume=True)
    assert calls == [3, 4, 5, 6]
    assert np.array_equal(read(out)[0], whole) and not (tmp_path / "cut.h5.partial").exists()


def test_interrupted_capture_in_the_cache_is_continued(tmp_path, monkeypatch):
    """A benchmark killed mid-capture: the next run continues the cached capture (no error
    asking for a --resume the benchmark does not pass on)."""
    from sparsebtf.data.capture import cached_capture, writer

    whole = read(capture("pebbles", tmp_path / "whole.h5", size=4, directions="tiny7", spp=2))[0]
    real = writer.render_block
    calls = []
    monkeypatch.setattr(writer, "render_block", _dies_after_three(writer, calls))
    cache = tmp_path / "cache"
    with pytest.raises(KeyboardInterrupt):
        cached_capture("pebbles", 4, "tiny7", spp=2, cache_dir=cache)
    assert len(list(cache.glob("*.partial"))) == 1
    calls.clear()
    monkeypatch.setattr(writer, "render_block", lambda spec, v: calls.append(v) or real(spec, v))
    got = cached_capture("pebbles", 4, "tiny7", spp=2, cache_dir=cache)
    assert calls == [3, 4, 5, 6] and not list(cache.glob("*.partial"))
    assert np.array_equal(got.to_array(), whole)


def test_bad_scenes_and_options_are_one_line(tmp_path, capsys):
    def err(*argv):
        code, _, e = run(["capture", *argv], capsys)
        assert code == 2 and e.count("\n") == 1 and e.startswith("sparsebtf: error:"), e
        return e

    o = tmp_path / "x.h5"
    assert "not a built-in sample (plane, woven" in err("velvet", "-o", o)
    assert "no such file" in err(str(tmp_path / "nope.xml"), "-o", o)
    bad = scene_file(tmp_path, "bad", "raise RuntimeError('boom')\n")
    assert "scene(0) failed: RuntimeError: boom" in err(bad, "-o", o)
    empty = scene_file(tmp_path, "empty", "return {'type': 'scene'}\n")
    assert "has no shapes" in err(empty, "-o", o)
    big = scene_file(tmp_path, "big", "return {'type': 'scene', 'r': {'type': 'rectangle', "
                     "'to_world': mi.ScalarTransform4f().scale(5)}}\n")  # fmt: skip
    assert "one period of the sample" in err(big, "-o", o)
    typo = scene_file(tmp_path, "typo", "return {'type': 'scene', 'r': {'type': 'rectangel'}}\n")
    assert "Mitsuba could not load the scene" in err(typo, "-o", o)
    xml = tmp_path / "broken.xml"
    xml.write_text("<scene version='3.0.0'><shape type='rectangle'>")
    assert "Mitsuba could not load the scene" in err(xml, "-o", o)
    assert "--size must be an integer" in err("plane", "-o", o, "--size", "0")
    assert "--max-depth must be" in err("plane", "-o", o, "--max-depth", "1")
    assert "crop rows 0:9" in err("plane", "-o", o, "--size", "8", "--crop", "0:9,0:8")
    assert "give .h5" in err("plane", "-o", tmp_path / "x.btf")
    assert "unknown direction set" in err("plane", "-o", o, "--directions", "tiny5")
    assert "--noise-seed must be an integer" in err("plane", "-o", o, "--noise-seed", "-1")
    assert not list(tmp_path.glob("x.h5*"))


@pytest.mark.slow
def test_readme_make_a_btf_from_geometry_runs(tmp_path):
    from .test_first_hour import readme_block, shell

    block = readme_block("Make a BTF from geometry")
    shell(block, tmp_path)
    for f in ("plane.h5", "woven.h5", "pebbles.h5", "leather.h5", "metal.h5", "bumps.h5",
              "pebbles.png", "geo-model.h5", "leather.coded.h5", "leather-viewer/index.html"):
        assert (tmp_path / f).exists(), f
    assert not list(tmp_path.glob("*.partial"))


def test_without_a_vectorised_backend_one_line(tmp_path):
    import os
    import subprocess
    import sys

    env = {**os.environ, "SPARSEBTF_NO_LLVM": "1", "SPARSEBTF_PROGRESS": "0"}
    r = subprocess.run([sys.executable, "-m", "sparsebtf.cli.main", "capture", "plane", "-o",
                        str(tmp_path / "p.h5"), "--size", "4", "--directions", "tiny7"],
                       env=env, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "needs Mitsuba's LLVM or CUDA backend" in r.stderr and "libllvm19" in r.stderr
    assert not list(tmp_path.iterdir())


@pytest.mark.slow
def test_views_on_a_local_dask_cluster_equal_a_run_in_process(tmp_path):
    here = read(capture("pebbles", tmp_path / "here.h5", size=4, directions="tiny7", spp=2))[0]
    there = read(capture("pebbles", tmp_path / "dask.h5", size=4, directions="tiny7", spp=2,
                         workers=2))[0]  # fmt: skip
    assert np.array_equal(here, there)


@pytest.mark.slow
def test_quality_benchmark_on_captured_materials(tmp_path, monkeypatch):
    from sparsebtf.evaluation.benchmark_set import CAPTURE_CLASSES
    from sparsebtf.evaluation.runner import run_quality

    from .test_evaluation import TINY_METHODS, tiny_config

    monkeypatch.setenv("SPARSEBTF_CACHE", str(tmp_path / "cache"))
    cfg = tiny_config().captured()
    assert cfg.source == "capture" and cfg.classes == CAPTURE_CLASSES
    result = run_quality(tmp_path / "run", cfg, log=lambda m: None, methods=TINY_METHODS)
    captured = sorted(p.name for p in (tmp_path / "cache").glob("capture-*.h5"))
    # 2 training, 8 test, 1 Table-5 (true black: the test metal12)
    assert len(captured) == 11
    rows = {r["material"] for r in result["rows"]}
    assert {"woven12", "pebbles12", "leather12", "metal12", "copper12", "brushed12",
            "copper-mirror12", "copper-rough12", "metal12+black"} <= rows  # fmt: skip
    assert (tmp_path / "run" / "results.md").exists()


def test_noise_variance_from_a_twin(tmp_path):
    from sparsebtf.data.capture.noise import noise_variance

    def cap(name, scene="pebbles", **kw):
        kw = {"size": 6, "directions": "tiny7", "spp": 2, "seed": 5, **kw}
        return str(capture(scene, tmp_path / name, **kw))

    a = cap("a.h5")
    twin = noise_variance(a, cap("t.h5", noise_seed=1, crop=(slice(0, 3), slice(1, 6))))
    assert twin["window"] == [[0, 3], [1, 6]] and twin["values"] == 3 * 5 * 7 * 7 * 3
    assert twin["noise_variance"] == pytest.approx(twin["mse"] / 2)
    # a twin at 4× the paths: σ²_a = MSE · 8 / (2 + 8); the same σ² within sampling error
    fine = noise_variance(a, cap("f.h5", noise_seed=2, spp=8))
    assert fine["noise_variance"] == pytest.approx(0.8 * fine["mse"])
    assert 0.5 < fine["noise_variance"] / twin["noise_variance"] < 2
    assert 0 < fine["noise_variance"] < fine["variance"]
    # a uniform Lambertian plane has no Monte Carlo noise (every path sees ρ cos θ)
    uniform = str(plane(tmp_path, {"type": "diffuse"}))
    flat = noise_variance(cap("p.h5", uniform), cap("q.h5", uniform, noise_seed=3))
    assert flat["noise_variance"] < 1e-12 < twin["noise_variance"]
    for other, why in [(cap("s.h5", noise_seed=5), "same noise seed"),
                       (cap("o.h5", seed=6, noise_seed=1), "not a twin"),
                       (cap("w.h5", size=8, noise_seed=1), "not a twin")]:  # fmt: skip
        with pytest.raises(SparseBTFError, match=why):
            noise_variance(a, other)
