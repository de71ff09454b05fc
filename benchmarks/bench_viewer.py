"""WebGL2 viewer frame rate under SwiftShader (headless Chromium), against a trivial shader.

A coded BTF at UBO2014 resolution (10×10 patches, 151 lights × 151 views) with K = 8 random
orthonormal dictionaries per channel and random sparse codes (τ = 885, 64, 64 coefficients per
point, sorted by decreasing |v| like real codes) is loaded in the viewer page
(``sparsebtf.rendering.viewer``). The page's ``benchmark()`` draws ``--frames`` frames at a
512×512 canvas after a warm-up frame, synchronised by a 1-pixel ``readPixels`` before and after,
once with the SparseBTF lookup shader (Eq. 5/6 per fragment) and once with the trivial shader
(same geometry, a checker albedo), in the same browser and run; the ratio is printed.

Scenes: ``test`` — every pixel evaluates the BTF (a flat texture filling the canvas, the
worst case); ``sphere`` — the viewer's default view (the sphere covers about 40 % of the
canvas; background pixels are cheap).

    python benchmarks/bench_viewer.py [--size 400] [--canvas 512] [--frames 3] [--json]

Needs /usr/bin/chromium and the playwright Python package (no `playwright install`).
"""

from __future__ import annotations

import argparse
import time

from _common import machine, report, synthetic_coded
from sparsebtf.model import CHANNELS
from sparsebtf.rendering.viewer import HEADLESS_CHROMIUM_FLAGS, build_bundle, serve
from sparsebtf.runtime import RuntimeBTF

FLAGS = [
    *HEADLESS_CHROMIUM_FLAGS,
    "--disable-gpu-watchdog",  # one full-canvas frame at tau = 885 takes seconds on a CPU
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=400, help="texels per side (multiple of 10)")
    ap.add_argument("--dicts", type=int, default=8)
    ap.add_argument("--tau", default="885,64,64")
    ap.add_argument("--canvas", type=int, default=512)
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--scenes", default="test,sphere", help="comma list of test, sphere")
    ap.add_argument("--interp", default="linear")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    from playwright.sync_api import sync_playwright

    tau = tuple(int(x) for x in a.tau.split(","))
    t0 = time.perf_counter()
    rt = RuntimeBTF(synthetic_coded(a.size, a.dicts, dict(zip(CHANNELS, tau, strict=True))))
    bundle = build_bundle(rt)
    prep = time.perf_counter() - t0
    results: dict[str, dict] = {}
    with serve(bundle) as srv, sync_playwright() as p:
        browser = p.chromium.launch(executable_path="/usr/bin/chromium", headless=True, args=FLAGS)
        for scene in a.scenes.split(","):
            page = browser.new_page(viewport={"width": a.canvas + 400, "height": a.canvas + 50})
            page.set_default_timeout(600_000)
            t = time.perf_counter()
            page.goto(f"{srv.url}?scene={scene}&size={a.canvas}&animate=0&interp={a.interp}")
            page.wait_for_function(
                "window.sparsebtf && (window.sparsebtf.ready || window.sparsebtf.error)"
            )
            err = page.evaluate("window.sparsebtf.error")
            if err:
                raise SystemExit(f"the page reports: {err}")
            load = time.perf_counter() - t
            trivial = page.evaluate(
                f"window.sparsebtf.benchmark({{frames: {10 * a.frames}, trivial: true}})"
            )
            lookup = page.evaluate(f"window.sparsebtf.benchmark({{frames: {a.frames}}})")
            results[scene] = {
                "load_seconds": load,
                "lookup": lookup,
                "trivial": trivial,
                "fps_ratio_lookup_over_trivial": lookup["fps"] / trivial["fps"],
            }
            renderer = page.evaluate("window.sparsebtf.info.renderer")
            page.close()
        browser.close()
    data = {
        "machine": machine(),
        "renderer": renderer,
        "size": a.size,
        "dicts": a.dicts,
        "tau": list(tau),
        "canvas": a.canvas,
        "interp": a.interp,
        "texture_bytes": bundle.manifest["bytes"],
        "prepare_seconds": prep,
        "scenes": results,
    }
    rows: list[tuple[str, object]] = [
        ("renderer", renderer),
        ("material", f"{a.size}x{a.size} texels, 151x151 directions, K = {a.dicts}, tau = {a.tau}"),
        ("textures", f"{bundle.manifest['bytes'] / 2**20:.1f} MiB (prepared in {prep:.1f} s)"),
    ]
    for scene, r in results.items():
        lk, tr = r["lookup"], r["trivial"]
        rows.append(
            (
                f"{scene} {a.canvas}x{a.canvas}",
                f"lookup {lk['fps']:.3g} fps ({lk['ms_per_frame']:.0f} ms), trivial "
                f"{tr['fps']:.3g} fps ({tr['ms_per_frame']:.1f} ms), ratio "
                f"{r['fps_ratio_lookup_over_trivial']:.4f}",
            )
        )
    report(rows, data, a.json)


if __name__ == "__main__":
    main()
