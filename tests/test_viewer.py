"""The WebGL2 viewer (issue 6): texture packing, export, server, and the page in headless Chromium.

The browser tests drive Debian's ``/usr/bin/chromium`` (SwiftShader WebGL2) with Playwright's
Python package, without ``playwright install``; they skip when either is missing (CI installs
both, see ``.ci/run``). The page's test scene fills a 64×64 float framebuffer with the texture
(uv = pixel centre / 64) at fixed local light and view directions; its ``readPixels`` values
must match :meth:`RuntimeBTF.evaluate` at the same uv and directions within
``|gl − py| ≤ 1e-4·|py| + 1e-5`` (float32 shader vs float64 reference; measured ≤ 1e-6
relative).
"""

from __future__ import annotations

import contextlib
import functools
import http.server
import json
import os
import signal
import subprocess
import sys
import threading
import urllib.request
from pathlib import Path

import numpy as np
import pytest

import sparsebtf
from sparsebtf.codec import encode
from sparsebtf.errors import BTFInputError, FileFormatError
from sparsebtf.rendering import viewer
from sparsebtf.rendering.viewer import (
    HEADLESS_CHROMIUM_FLAGS,
    build_bundle,
    export,
    pack_textures,
    serve,
)
from sparsebtf.runtime import RuntimeBTF
from sparsebtf.storage import save_coded, save_model

from .conftest import smooth_btf, tight_bound, tiny_model

CHROMIUM = "/usr/bin/chromium"
FLAGS = list(HEADLESS_CHROMIUM_FLAGS)
SIZE = 64
RTOL, ATOL = 1e-4, 1e-5
WI = np.array([0.3, -0.2, 0.9]) / np.linalg.norm([0.3, -0.2, 0.9])
WO = np.array([-0.1, 0.4, 0.8]) / np.linalg.norm([-0.1, 0.4, 0.8])


@pytest.fixture(scope="module")
def model():
    return tiny_model()


@pytest.fixture(scope="module")
def coded(model):
    return encode(smooth_btf(8), model, tau=(40, 8, 8), eps=0.0, progress=False)


@pytest.fixture(scope="module")
def rt(coded):
    return RuntimeBTF(coded)


def saved(folder: Path, model, coded) -> Path:
    """``folder`` holding ``model.h5`` and ``coded.h5``: what the ``view`` command reads."""
    save_model(model, folder / "model.h5")
    save_coded(coded, folder / "coded.h5")
    return folder


@pytest.fixture(scope="module")
def files(model, coded, tmp_path_factory):
    return saved(tmp_path_factory.mktemp("viewer"), model, coded)


@pytest.fixture(scope="module")
def browser():
    if not Path(CHROMIUM).exists():
        pytest.skip(f"{CHROMIUM} is missing (Debian package chromium; .ci/run installs it)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("the playwright Python package is missing (pip install playwright)")
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=FLAGS)
        yield b
        b.close()


def open_page(browser, url: str):
    page = browser.new_page()
    page.goto(url)
    page.wait_for_function(
        "window.sparsebtf && (window.sparsebtf.ready || window.sparsebtf.error)", timeout=60_000
    )
    err = page.evaluate("window.sparsebtf.error")
    assert err is None, f"the page reports: {err}"
    return page


def _vec(v: np.ndarray) -> str:
    return ",".join(f"{x:.9f}" for x in v)


def open_test_scene(browser, url: str):
    """The page at ``url`` in its SIZE×SIZE test scene at the fixed directions WI, WO."""
    return open_page(browser, f"{url}?scene=test&size={SIZE}&wi={_vec(WI)}&wo={_vec(WO)}")


def served_test_scene(browser, rt):
    """The test scene of ``rt``'s bundle, served for as long as the generator runs (the body
    of a ``test_page`` fixture)."""
    with serve(build_bundle(rt)) as srv:
        page = open_test_scene(browser, srv.url)
        yield page
        page.close()


@pytest.fixture(scope="module")
def test_page(browser, rt):
    yield from served_test_scene(browser, rt)


def read_image(page, **state) -> np.ndarray:
    """(SIZE, SIZE, 3) linear RGB of the test scene; row j is v = (j + 0.5) / SIZE."""
    if state:
        page.evaluate("s => window.sparsebtf.set(s)", state)
    flat = page.evaluate("window.sparsebtf.readFloat()")
    return np.asarray(flat, dtype=np.float32).reshape(SIZE, SIZE, 4)[..., :3]


def reference(rt: RuntimeBTF, **kwargs) -> np.ndarray:
    j, i = np.meshgrid(np.arange(SIZE), np.arange(SIZE), indexing="ij")
    uv = np.stack([(i.ravel() + 0.5) / SIZE, (j.ravel() + 0.5) / SIZE], axis=1)
    n = uv.shape[0]
    out = rt.evaluate(np.tile(WI, (n, 1)), np.tile(WO, (n, 1)), uv=uv, **kwargs)
    return out.reshape(SIZE, SIZE, 3)


def assert_close(gl: np.ndarray, py: np.ndarray) -> None:
    assert np.all(np.isfinite(gl))
    bad = np.abs(gl - py) > RTOL * np.abs(py) + ATOL
    assert not bad.any(), (
        f"{bad.sum()} of {bad.size} values differ; max |gl - py| = {np.abs(gl - py).max():.3g}"
    )


#: (interpolation, domain, candidate tables) of the page's checks against the runtime
PAGE_CASES = [
    ("nearest", "standardized", True),
    ("linear", "standardized", True),
    ("linear", "standardized", False),
    ("linear", "log", True),
    ("barycentric", "standardized", True),
    ("gaussian", "log", False),
]


def check_page(page, rt, interp: str, domain: str, neigh: bool) -> None:
    """The test scene at full τ equals ``rt.evaluate`` (a RuntimeBTF or AdaptiveRuntimeBTF)."""
    gl = read_image(page, interp=interp, domain=domain, neigh=neigh, lod=1.0)
    py = reference(rt, interpolation=interp, domain=domain)
    assert py.std() > 0.05 * py.mean()  # a textured image, not a constant
    assert_close(gl, py)


@contextlib.contextmanager
def static_server(folder: Path):
    """A plain ``http.server`` of ``folder`` on a free port; yields its ``index.html`` URL."""

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    handler = functools.partial(Quiet, directory=str(folder))
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    t = threading.Thread(target=httpd.serve_forever, daemon=True)
    t.start()
    try:
        yield f"http://127.0.0.1:{httpd.server_address[1]}/index.html"
    finally:
        with contextlib.suppress(Exception):
            httpd.shutdown()
            httpd.server_close()


# -- packing, export and server (no browser) ----------------------------------------------------
def test_textures_hold_the_runtime_arrays(rt):
    arr = rt.arrays()
    part, data = pack_textures(arr, rt.meta)
    tex = part["textures"]
    assert len(data) == max(t["offset"] + t["width"] * t["height"] * 4 * (
        4 if t["format"].startswith("RGBA") else 1) for t in tex.values())  # fmt: skip
    for t in tex.values():
        assert t["width"] == viewer.TEX_WIDTH and t["offset"] % 16 == 0
    # entry i of a 1D array is at texel (i % 4096, i // 4096): read back the V values
    v = tex["sb_values"]
    vals = np.frombuffer(data, "<f4", v["entries"], v["offset"])
    nnz = rt.meta["nnz"]
    assert np.array_equal(vals[nnz["Y"] + nnz["U"] :], arr["values_V"])
    pts = tex["sb_points"]
    rec = np.frombuffer(data, "<i4", 4 * pts["entries"], pts["offset"]).reshape(-1, 4)
    p = rt.meta["n_points"]
    assert np.array_equal(rec[p : 2 * p, 0] - nnz["Y"], arr["offsets_U"][:-1])
    assert np.array_equal(rec[2 * p :, 2], arr["membership_V"])
    assert part["tau_max"] == [40, 8, 8]
    assert part["uniforms"]["sb_size"] == [8, 8, 4, 2]


def test_packing_errors_name_what_is_wrong(rt, monkeypatch):
    arr = rt.arrays(neighbours=False)
    del arr["values_U"], arr["dict3_V"]
    with pytest.raises(BTFInputError, match="values_U, dict3_V"):
        pack_textures(arr, rt.meta, "stone.h5")
    monkeypatch.setattr(viewer, "MAX_TEX_HEIGHT", 2)
    with pytest.raises(BTFInputError, match=r"stone.h5: texture sb_neigh needs 262144 texels"):
        pack_textures(rt.arrays(), rt.meta, "stone.h5")


def test_export_is_atomic_and_refuses_foreign_folders(rt, tmp_path):
    bundle = build_bundle(rt)
    out = export(bundle, tmp_path / "site")
    names = {p.name for p in out.iterdir()}
    assert {
        "index.html",
        "viewer.js",
        "sparsebtf_lookup.glsl",
        "manifest.json",
        "data.bin",
    } <= names
    assert (out / "data.bin").read_bytes() == bundle.data
    export(bundle, out)  # an earlier export is replaced
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no leftovers
    foreign = tmp_path / "docs"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(FileFormatError, match="not empty"):
        export(bundle, foreign)
    assert (foreign / "notes.txt").read_text() == "mine"


def _env() -> dict[str, str]:
    src = str(Path(sparsebtf.__file__).resolve().parents[1])
    return {**os.environ, "PYTHONPATH": src + os.pathsep + os.environ.get("PYTHONPATH", "")}


def test_view_command_serves_until_ctrl_c(files):
    proc = subprocess.Popen(
        [sys.executable, "-m", "sparsebtf.cli.main", "view", str(files / "coded.h5"),
         "-m", str(files / "model.h5"), "--no-browser", "--tau", "20,8,8"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(),
        # Ctrl-C as at a terminal, also when this run was started in the background (a
        # shell's background job ignores SIGINT and its children inherit that)
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    try:
        line = proc.stdout.readline()
        assert "http://127.0.0.1:" in line, line + proc.stderr.read()
        url = line.split(" at ")[1].strip()
        with urllib.request.urlopen(url + "manifest.json", timeout=10) as r:
            manifest = json.load(r)
        assert manifest["tau_max"] == [20, 8, 8]
        with urllib.request.urlopen(url + "sparsebtf_lookup.glsl", timeout=10) as r:
            assert b"vec3 sb_evaluate(vec2 uv, vec3 wi, vec3 wo)" in r.read()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_view_command_errors(files, tmp_path, capsys):
    from sparsebtf.cli.main import main

    assert main(["view", str(files / "coded.h5"), "-m", str(files / "model.h5"),
                 "--tau", "x.y", "--no-browser"]) == 2  # fmt: skip
    assert "--tau: tau 'x.y': not a number" in capsys.readouterr().err
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "a.txt").write_text("a")
    assert main(["view", str(files / "coded.h5"), "-m", str(files / "model.h5"),
                 "--export", str(tmp_path / "busy")]) == 2  # fmt: skip
    assert "not empty" in capsys.readouterr().err


# -- the page in headless Chromium --------------------------------------------------------------
@pytest.mark.parametrize(("interp", "domain", "neigh"), PAGE_CASES)
def test_page_matches_runtime_decoder(test_page, rt, interp, domain, neigh):
    check_page(test_page, rt, interp, domain, neigh)


@pytest.mark.parametrize("domain", ["standardized", "log"])
def test_page_clamps_to_the_bound_like_the_runtime_decoder(browser, rt, domain):
    tight = RuntimeBTF(tight_bound(rt.coded))
    with serve(build_bundle(tight)) as srv:
        page = open_test_scene(browser, srv.url)
        gl = read_image(page, interp="linear", domain=domain, neigh=True, lod=1.0)
        page.close()
    py = reference(tight, interpolation="linear", domain=domain)
    assert_close(gl, py)
    free = reference(rt, interpolation="linear", domain=domain)
    assert (free > py * (1 + 1e-3) + 1e-6).mean() > 0.1  # the clamp is at work


def test_tau_slider_changes_the_image(test_page, rt):
    full = read_image(test_page, interp="linear", domain="standardized", lod=1.0)
    test_page.locator("#tau").fill("100")  # the slider, as a user drags it: 10 %
    tau = test_page.evaluate("window.sparsebtf.state.tau")
    assert tau == [4, 1, 1]  # the runtime's fractional tau: ceil(0.1 * (40, 8, 8))
    low = read_image(test_page)
    assert np.abs(low - full).max() > 0.01 * np.abs(full).max()
    assert_close(low, reference(rt, interpolation="linear", tau=dict(zip("YUV", tau, strict=True))))
    assert "4, 1, 1" in test_page.locator("#tauText").inner_text()


def test_per_fragment_tau_matches_runtime_decoder(test_page, rt):
    """Fractional τ' per fragment (the ramp: f = (x + ½)/64 of the cap across the image) and
    τ' by footprint (the texture zoomed: ρ = zoom·8/64 texels per pixel side) equal
    RuntimeBTF.evaluate with the per-query τ of sparsebtf.runtime.lod."""
    from sparsebtf.runtime.lod import footprint_fraction, lod_tau

    j, i = np.meshgrid(np.arange(SIZE), np.arange(SIZE), indexing="ij")
    frac = ((i + 0.5) / SIZE).ravel()
    gl = read_image(test_page, interp="linear", domain="standardized", lod=1.0, ramp=True,
                    zoom=1.0)  # fmt: skip
    py = reference(rt, interpolation="linear", tau=lod_tau(rt.tau, frac))
    assert_close(gl, py)
    full = reference(rt, interpolation="linear")
    assert np.abs(py - full)[:, : SIZE // 2].max() > 0.01 * np.abs(full).max()
    for zoom in (9.0, 11.0, 41.0):  # rho = 1.125, 1.375, 5.125: no pixel centre on a texel edge
        gl = read_image(test_page, ramp=False, zoom=zoom, footprint=True)
        j, i = np.meshgrid(np.arange(SIZE), np.arange(SIZE), indexing="ij")
        uv = np.stack([(i.ravel() + 0.5) / SIZE, (j.ravel() + 0.5) / SIZE], axis=1) * zoom
        f = np.full(uv.shape[0], footprint_fraction(zoom * rt.meta["width"] / SIZE))
        n = uv.shape[0]
        py = rt.evaluate(np.tile(WI, (n, 1)), np.tile(WO, (n, 1)), uv=uv,
                         tau=lod_tau(rt.tau, f)).reshape(SIZE, SIZE, 3)  # fmt: skip
        assert_close(gl, py)
    off = read_image(test_page, footprint=False)
    n = uv.shape[0]
    assert_close(off, rt.evaluate(np.tile(WI, (n, 1)), np.tile(WO, (n, 1)), uv=uv)
                 .reshape(SIZE, SIZE, 3))  # fmt: skip
    read_image(test_page, zoom=1.0, footprint=True)


def test_sphere_view_and_benchmark_api(browser, rt):
    with serve(build_bundle(rt)) as srv:
        page = open_page(browser, f"{srv.url}?size=96&animate=0&repeat=1")
        info = page.evaluate("window.sparsebtf.info")
        assert info["meta"]["height"] == 8
        shot = page.locator("canvas").screenshot()
        from io import BytesIO

        from PIL import Image

        img = np.asarray(Image.open(BytesIO(shot)).convert("RGB"), dtype=np.float32)
        sphere = np.abs(img - img[0, 0]).max(axis=2) > 8  # differs from the background
        assert 0.2 < sphere.mean() < 0.8, sphere.mean()
        lit = img[sphere].max(axis=1) > 60
        assert 0.2 < lit.mean() < 0.95, lit.mean()  # lit and self-shadowed sides
        assert img[sphere][lit].std(axis=0).min() > 5  # textured
        bench = page.evaluate("window.sparsebtf.benchmark({frames: 2})")
        assert bench["ms_per_frame"] > 0 and bench["width"] == 96
        page.close()


def test_static_export_loads_from_a_plain_http_server(browser, rt, tmp_path):
    out = export(build_bundle(rt), tmp_path / "site")
    with static_server(out) as url:
        page = open_test_scene(browser, url)
        assert_close(read_image(page, interp="nearest"), reference(rt, interpolation="nearest"))
        page.close()
