"""Mitsuba 3 renders of coded materials: BTF-driven vs cosine sampling, and the lookup's cost.

Measured in one run (``sparsebtf`` plugin, path tracer with max depth 4, the built-in sphere on
a floor, both carrying the material with ``uv_scale`` 2, linear angular interpolation):

**Noise** (``--size``², default 48²). Two synthetic materials at UBO2014 directions (151 × 151,
20×20 texels, seed 7): a glossy one (``--glossy``, default leather) and a diffuse one (felt),
and an analytic mirror-lobe BTF (:func:`lobe_btf`; ``--no-lobe`` skips it), coded at
τ = (885, 64, 64) with a K = 2 model trained on them (cached in
``$SPARSEBTF_CACHE/bench_render``). The two synthetic ones are lit by the procedural sky and by
a small bright emitter (``light="emitter"`` of :func:`sparsebtf.rendering.scenes.scene_dict`),
the lobe by the sky. The reference
is the mean of a cosine-sampled and a BTF-sampled render of ``--ref-spp``/2 samples each (the
two halves also check that both samplers converge to the same image). Then, per sampler, the
relative MSE ‖img − ref‖²/‖ref‖² of ``--spp`` renders (``--seeds`` seeds, averaged) and their
time (samplers: cosine, BTF with one table per material, BTF with one table per data point);
at equal time, cosine sampling with the spp the BTF sampler's time buys (time per sample from
the two reference halves, long renders). Before rendering, a
BSDF-level check: the relative variance of sample()'s weight eval/pdf at three incidences.

**Time per sample** (``--time-size``², ``--time-spp``), in Dr.Jit's symbolic mode (one
megakernel; the coded lookups by the plugin's Dr.Jit kernel, ``backend = drjit``) and in its
evaluated mode (``sparsebtf.mitsuba.evaluated()``; the coded lookups by the runtime's compiled
kernel, ``backend = auto``; what ``render_material`` uses by default): the benchmark material of
``_common.synthetic_coded`` (K = 8 random dictionaries, 40×40 texels; ``--time-material
captured``: ``_common.captured_coded``, the woven sample coded with the release model) at
τ = (885, 64, 64) and a quarter of it, and the dense reference plugin on a 20×20-texel
table, each with both samplers; best of ``--repeat`` interleaved rounds after one render each
that compiles the kernels.

**Level of detail** (``--lod``, alone): ``lod = off`` vs ``auto`` on the glossy class, felt
(the noise part's trained codes) and a synthetic carpet coded on the bundled model:
``--lod-size``² (64) images; CPU time per sample of a ``--lod-ref-spp`` (1024) render each, the
off one being the reference; the bias (relative MSE of the two, same seed); the relative MSE
at ``--lod-spp`` (16) and, for auto, at the spp that off's time buys; the τ' used per lookup
class (``lod_stats``); ``--lod-sweep`` other fractions against the same reference;
``--out``: ``lod.png`` [off | auto | |auto − off| × 10].

``--integrator bsdf`` renders the noise part with Mitsuba's ``direct`` integrator taking BSDF
samples only (no emitter sampling, so no MIS): the image-level effect of the sampler alone.

    python benchmarks/bench_render.py [--json] [--out docs/rendering]
    python benchmarks/bench_render.py --lod [--lod-sweep 0.1:1:1,...] [--out docs/rendering]
    python benchmarks/bench_render.py --backend cuda      # on a machine with an NVIDIA GPU
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from _common import TAU, captured_coded, cpu_seconds, machine, report, synthetic_coded
from sparsebtf.data.btf import ArrayBTF
from sparsebtf.data.directions import ubo2014

CODED_TAU = (885, 64, 64)
LIGHTS = ("sky", "emitter")
SAMPLERS = ("cosine", "btf")
#: The noise renders also try per-patch tables (one per data point).
NOISE_SAMPLERS = {"cosine": {"sampling": "cosine"}, "btf": {"sampling": "btf"},
                  "btf_patch": {"sampling": "btf", "sampling_tables": "patch"}}
#: ``--integrator``: the path tracer of the scenes (emitter sampling + MIS), or direct lighting
#: from BSDF samples alone
INTEGRATORS = {"path": None, "bsdf": {"type": "direct", "emitter_samples": 0, "bsdf_samples": 1}}
INCIDENCES = {"normal": (0.0, 0.0, 1.0), "45 deg": (0.5, 0.5, 0.7071), "75 deg": (0.9, 0.25, 0.26)}


def log(message: str) -> None:
    """Progress on stderr (stdout carries the table or the JSON)."""
    print(message, file=sys.stderr, flush=True)


def lobe_btf(size: int = 20, width: float = 0.03) -> ArrayBTF:
    """An analytic glossy BTF at UBO2014 directions: cos θ_light · (a dim diffuse texture + a
    mirror lobe exp(−(1 − r·v)/``width``), r the mirrored light, of spatially varying weight).
    What the synthetic classes lack: a material-wide lobe that cosine sampling misses."""
    rng = np.random.default_rng(7)
    d = ubo2014()
    x = d.xyz
    lobe = np.exp(-(1.0 - (x * np.array([-1.0, -1.0, 1.0])) @ x.T) / width)  # (L, V)
    base = rng.uniform(0.3, 1.0, (size, size, 1, 1, 3))
    spec = rng.uniform(0.6, 1.0, (size, size, 1, 1, 1))
    data = x[:, 2][None, None, :, None, None] * (0.05 * base + 1.5 * spec * lobe[..., None])
    return ArrayBTF(data.astype(np.float32), d, d, name="lobe")


def coded_materials(glossy: str, lobe: bool) -> dict[str, Any]:
    """{name: RuntimeBTF} of the glossy class, felt (and the analytic lobe), trained together
    (K = 2) and coded once (cached)."""
    from sparsebtf.codec import encode, train
    from sparsebtf.data.synth import resolve_cache_dir, synthesize
    from sparsebtf.runtime import RuntimeBTF
    from sparsebtf.storage import load_coded_with_model, save_coded, save_model

    names = (glossy, "felt", "lobe") if lobe else (glossy, "felt")
    folder = resolve_cache_dir() / "bench_render" / f"{'-'.join(names)}-v1"
    paths = {n: folder / f"{n}.coded.h5" for n in names}
    if not all(p.exists() for p in paths.values()):
        btfs = [lobe_btf() if n == "lobe" else synthesize(n, size=20, directions="ubo2014",
                                                          seed=7) for n in names]  # fmt: skip
        log(f"training a K = 2 model on {', '.join(names)} (once, then cached in {folder})")
        model = train(btfs, n_dictionaries=2, tau_train=(256, 32, 32), patch=10, sample=1.0,
                      max_iter=2, progress=False)  # fmt: skip
        folder.mkdir(parents=True, exist_ok=True)
        save_model(model, folder / "model.h5")
        for n, b in zip(names, btfs, strict=True):
            coded = encode(b, model, tau=CODED_TAU, progress=False)
            coded.params["model_file"] = str(folder / "model.h5")
            save_coded(coded, paths[n])
    return {n: RuntimeBTF(load_coded_with_model(p, folder / "model.h5")) for n, p in paths.items()}


class Renderer:
    """Renders of the built-in sphere scene with one light, timed after ``dr.sync_thread``."""

    def __init__(self, backend: str, integrator: str = "path") -> None:
        import sparsebtf.mitsuba as sbm

        self.integrator = INTEGRATORS[integrator]
        self.variant = sbm.setup(backend)
        self.why = sbm.variant_message
        import drjit as dr
        import mitsuba as mi

        self.mi, self.dr = mi, dr

    def __call__(self, bsdf: dict, light: str, size: int, spp: int, seed: int,
                 max_pass: int = 256, evaluated: bool = False) -> tuple[np.ndarray, float]:
        """(linear RGB image, render seconds); spp above ``max_pass`` in passes (new seeds);
        ``evaluated``: in Dr.Jit's evaluated mode (the plugin's lookups then go to the runtime's
        compiled kernel). ``self.cpu_seconds``: the CPU time of this process's threads during
        the render (less at the mercy of other processes' load than the wall time)."""
        from contextlib import nullcontext

        from sparsebtf.rendering.mitsuba import evaluated as evaluated_mode
        from sparsebtf.rendering.mitsuba import preload
        from sparsebtf.rendering.scenes import scene_dict

        mi, dr = self.mi, self.dr
        preload(bsdf)
        desc = scene_dict(mi, bsdf, "sphere", size, size, light=light)
        if self.integrator is not None:
            desc["integrator"] = dict(self.integrator)
        scene = mi.load_dict(desc)
        acc, seconds, done, k = 0.0, 0.0, 0, 0
        self.cpu_seconds = 0.0
        while done < spp:
            n = min(max_pass, spp - done)
            t, c = time.perf_counter(), cpu_seconds()
            with evaluated_mode() if evaluated else nullcontext():
                img = mi.render(scene, spp=n, seed=seed + 7919 * k)
                dr.eval(img)
                dr.sync_thread()
            seconds += time.perf_counter() - t
            self.cpu_seconds += cpu_seconds() - c
            acc = acc + np.array(img, dtype=np.float64)[..., :3] * n
            done, k = done + n, k + 1
        return acc / spp, seconds


def rel_mse(img: np.ndarray, ref: np.ndarray) -> float:
    return float(np.mean((img - ref) ** 2) / np.mean(ref**2))


def noise(render: Renderer, rts: dict[str, Any], args: argparse.Namespace) -> tuple[dict, dict]:
    """Relative MSE and time of both samplers per (material, light); the images."""
    import sparsebtf.mitsuba as sbm

    out: dict[str, Any] = {}
    images: dict[tuple[str, str], dict[str, np.ndarray]] = {}
    for name, rt in rts.items():
        key = sbm.add_material(rt, f"bench-{name}")
        for light in LIGHTS if name != "lobe" else ("sky",):
            t0 = time.perf_counter()

            def bsdf(sampler: str, key: str = key) -> dict:
                return {"type": "sparsebtf", "key": key, "uv_scale": 2.0,
                        "interpolation": "linear", **NOISE_SAMPLERS[sampler]}  # fmt: skip

            half = max(1, args.ref_spp // 2)
            refs, ref_secs = {}, {}
            for i, s in enumerate(SAMPLERS):
                refs[s], ref_secs[s] = render(bsdf(s), light, args.size, half, 100_000 + 1000 * i)
            ref = 0.5 * (refs["cosine"] + refs["btf"])
            row: dict[str, Any] = {"reference_halves_rel_mse": rel_mse(refs["cosine"],
                                                                       refs["btf"]),
                                   "reference_half_seconds": ref_secs}  # fmt: skip
            # the reference's own error: each half has variance s², their difference 2s²,
            # their mean s²/2, i.e. a quarter of the halves' difference
            row["reference_noise_rel_mse"] = row["reference_halves_rel_mse"] / 4
            for s in NOISE_SAMPLERS:
                render(bsdf(s), light, args.size, 1, 0)  # compile the kernels
            mses: dict[str, list] = {s: [] for s in NOISE_SAMPLERS}
            secs: dict[str, list] = {s: [] for s in NOISE_SAMPLERS}
            for seed in range(args.seeds):  # samplers interleaved: load drift hits all alike
                for s in NOISE_SAMPLERS:
                    img, sec = render(bsdf(s), light, args.size, args.spp, seed)
                    mses[s].append(rel_mse(img, ref))
                    secs[s].append(sec)
                    if seed == 0:
                        images.setdefault((name, light), {"reference": ref})[s] = img
            for s in NOISE_SAMPLERS:
                sec = float(np.median(secs[s]))
                row[s] = {"rel_mse": float(np.mean(mses[s])), "rel_mse_per_seed": mses[s],
                          "seconds": sec,
                          "ns_per_sample_per_pixel": sec / (args.size**2 * args.spp) * 1e9}
            # equal time: the spp cosine sampling gets in the BTF sampler's time, timed on the
            # long reference halves (a short render's time is at the mercy of the load)
            spp_eq = max(1, round(args.spp * ref_secs["btf"] / ref_secs["cosine"]))
            eq = [rel_mse(render(bsdf("cosine"), light, args.size, spp_eq, seed)[0], ref)
                  for seed in range(args.seeds)]  # fmt: skip
            row["cosine_equal_time"] = {"spp": spp_eq, "rel_mse": float(np.mean(eq))}
            row["mse_ratio_cosine_over_btf"] = row["cosine"]["rel_mse"] / row["btf"]["rel_mse"]
            row["mse_ratio_cosine_over_btf_patch"] = (row["cosine"]["rel_mse"]
                                                      / row["btf_patch"]["rel_mse"])  # fmt: skip
            row["mse_ratio_equal_time"] = row["cosine_equal_time"]["rel_mse"] / row["btf"][
                "rel_mse"]
            noise_free = [row[s]["rel_mse"] - row["reference_noise_rel_mse"] for s in SAMPLERS]
            row["mse_ratio_less_reference_noise"] = noise_free[0] / max(noise_free[1], 1e-30)
            row["seconds_total"] = time.perf_counter() - t0
            out[f"{name}/{light}"] = row
            log(f"  {name:9s} {light:8s} cosine {row['cosine']['rel_mse']:.4g}  btf "
                  f"{row['btf']['rel_mse']:.4g}  ratio {row['mse_ratio_cosine_over_btf']:.2f} "
                  f"(equal time {row['mse_ratio_equal_time']:.2f})  "
                  f"[{row['seconds_total']:.0f} s]")  # fmt: skip
    return out, images


def weight_variance(render: Renderer, rts: dict[str, Any], n: int = 200_000) -> dict:
    """BSDF-level check: relative variance var/mean² of the luminance of sample()'s weight
    eval/pdf (random uv, radiance transport) per sampler, material and incidence; what the
    sampler changes before lighting and MIS dilute it in an image."""
    import sparsebtf.mitsuba as sbm

    mi, dr = render.mi, render.dr
    rng = np.random.default_rng(0)
    out: dict[str, Any] = {}
    for name, rt in rts.items():
        key = sbm.add_material(rt, f"bench-{name}")
        for inc, wi in INCIDENCES.items():
            w = np.array(wi) / np.linalg.norm(wi)
            si = dr.zeros(mi.SurfaceInteraction3f, n)
            si.wi = mi.Vector3f(*(float(x) for x in w))
            si.uv = mi.Point2f(rng.uniform(size=(2, n)).astype(np.float32))
            u1 = mi.Float(rng.uniform(size=n).astype(np.float32))
            u2 = mi.Point2f(rng.uniform(size=(2, n)).astype(np.float32))
            row = {}
            for s, extra in NOISE_SAMPLERS.items():
                b = mi.load_dict({"type": "sparsebtf", "key": key, "interpolation": "linear",
                                  **extra})  # fmt: skip
                _, weight = b.sample(mi.BSDFContext(), si, u1, u2)
                lum = np.array(weight).reshape(3, -1).T @ [0.2126, 0.7152, 0.0722]
                row[s] = float(np.var(lum) / np.mean(lum) ** 2)
            out[f"{name}/{inc}"] = row
            log(f"  {name:9s} {inc:7s} " + "  ".join(f"{s} {v:.3f}" for s, v in row.items()))
    return out


def timing(render: Renderer, args: argparse.Namespace) -> dict[str, Any]:
    """Time per sample per pixel: full and quarter τ vs the dense reference, both samplers."""
    import sparsebtf.mitsuba as sbm
    from sparsebtf.runtime import RuntimeBTF

    full = RuntimeBTF(captured_coded(40) if args.time_material == "captured"
                      else synthetic_coded(40))  # fmt: skip
    quarter_tau = {ch: t // 4 for ch, t in TAU.items()}
    rng = np.random.default_rng(1)
    d = ubo2014()
    table = rng.uniform(0.05, 0.6, (20, 20, 151, 151, 3)).astype(np.float32)
    plugins = {
        "full_tau": {"type": "sparsebtf", "key": sbm.add_material(full, "bench-full")},
        "quarter_tau": {"type": "sparsebtf",
                        "key": sbm.add_material(full.with_tau(quarter_tau), "bench-quarter")},
        "dense_20x20": {"type": "sparsebtf_dense",
                        "key": sbm.add_material(ArrayBTF(table, d, d, name="dense20"),
                                                "bench-dense")},
    }  # fmt: skip
    n = args.time_size**2 * args.time_spp
    out: dict[str, Any] = {"tau": TAU, "quarter_tau": quarter_tau, "ns_per_sample_per_pixel": {},
                           "all_seconds": {}, "first_render_seconds": {}}  # fmt: skip
    # symbolic: one megakernel, the coded lookups in Dr.Jit (backend drjit); evaluated: Dr.Jit's
    # wavefront mode, the coded lookups through the runtime's compiled kernel (backend auto)
    runs = {f"{name}/{s}{'/evaluated' if ev else ''}": (
                {**p, "uv_scale": 2.0, "interpolation": "linear", "sampling": s,
                 **({"backend": "drjit"} if p["type"] == "sparsebtf" and not ev else {})}, ev)
            for ev in (False, True) for s in SAMPLERS for name, p in plugins.items()}  # fmt: skip
    for k, (b, ev) in runs.items():  # trace and compile every kernel first
        out["first_render_seconds"][k] = render(b, "sky", args.time_size, args.time_spp, 0,
                                                evaluated=ev)[1]  # fmt: skip
    for _ in range(args.repeat):  # interleaved rounds: a load change hits every setting alike
        for k, (b, ev) in runs.items():
            sec = render(b, "sky", args.time_size, args.time_spp, 0, evaluated=ev)[1]
            out["all_seconds"].setdefault(k, []).append(sec)
    for k, secs in out["all_seconds"].items():
        out["ns_per_sample_per_pixel"][k] = min(secs) / n * 1e9
    t = out["ns_per_sample_per_pixel"]
    for s in SAMPLERS:
        # the dense table in its faster mode: the coded render against the best dense one
        dense = min(t[f"dense_20x20/{s}"], t[f"dense_20x20/{s}/evaluated"])
        out[f"ratio_full_over_dense/{s}"] = t[f"full_tau/{s}"] / t[f"dense_20x20/{s}"]
        out[f"ratio_quarter_over_dense/{s}"] = t[f"quarter_tau/{s}"] / t[f"dense_20x20/{s}"]
        out[f"ratio_full_evaluated_over_best_dense/{s}"] = t[f"full_tau/{s}/evaluated"] / dense
        out[f"ratio_quarter_evaluated_over_best_dense/{s}"] = (t[f"quarter_tau/{s}/evaluated"]
                                                               / dense)  # fmt: skip
        out[f"speedup_evaluated_over_symbolic/{s}"] = (t[f"full_tau/{s}"]
                                                       / t[f"full_tau/{s}/evaluated"])  # fmt: skip
        for mode, suffix in (("symbolic (Dr.Jit kernel)", ""),
                             ("evaluated (runtime)", "/evaluated")):
            log(f"  {s}, {mode}: full {t[f'full_tau/{s}{suffix}']:.0f} ns, quarter "
                f"{t[f'quarter_tau/{s}{suffix}']:.0f} ns, dense "
                f"{t[f'dense_20x20/{s}{suffix}']:.0f} ns per sample per pixel")
        log(f"  {s}: full tau evaluated / best dense "
            f"{out[f'ratio_full_evaluated_over_best_dense/{s}']:.2f}x; symbolic / dense "
            f"{out[f'ratio_full_over_dense/{s}']:.2f}x")
    t = out["ns_per_sample_per_pixel"]
    out["ratio_btf_over_cosine_time/full_tau"] = t["full_tau/btf"] / t["full_tau/cosine"]
    return out


def bundled_material(cls: str = "carpet", size: int = 20) -> Any:
    """A synthetic ``cls`` material coded on the bundled (trained) release model at its τ
    (cached): the trained coded material of the level-of-detail benchmark."""
    from sparsebtf.codec import encode
    from sparsebtf.data.synth import resolve_cache_dir, synthesize
    from sparsebtf.runtime import RuntimeBTF
    from sparsebtf.storage import load_coded_with_model, save_coded
    from sparsebtf.storage.bundled import load_bundled

    path = resolve_cache_dir() / "bench_render" / f"{cls}{size}-bundled.coded.h5"
    if not path.exists():
        log(f"coding {cls} {size}x{size} on the bundled model (once, cached in {path})")
        btf = synthesize(cls, size=size, directions="ubo2014", seed=7)
        path.parent.mkdir(parents=True, exist_ok=True)
        save_coded(encode(btf, load_bundled(), tau=CODED_TAU, progress=False), path)
    return RuntimeBTF(load_coded_with_model(path))


def lod_bsdf(key: str, lod: str, size: int, **extra: Any) -> dict:
    """The ``sparsebtf`` dict of the level-of-detail renders (sphere scene's camera)."""
    from sparsebtf.rendering.render import with_lod

    base = {"type": "sparsebtf", "key": key, "uv_scale": 2.0, "interpolation": "linear",
            **extra}  # fmt: skip
    return with_lod(base, lod, "sphere", size)


def lod_counts(render: Renderer, key: str, size: int) -> dict:
    """The τ' the plugin used per depth class in a 1-spp render (``lod_stats``)."""
    from sparsebtf.rendering.scenes import scene_dict

    mi, dr = render.mi, render.dr
    bsdf = mi.load_dict(lod_bsdf(key, "auto", size, lod_stats=True))
    img = mi.render(mi.load_dict(scene_dict(mi, bsdf, "sphere", size, size)), spp=1)
    dr.eval(img)
    dr.sync_thread()
    return bsdf.lod_stats()


def level_of_detail(render: Renderer, rts: dict[str, Any], args: argparse.Namespace
                    ) -> tuple[dict, dict]:
    """lod = off vs auto per material: time per sample, relative MSE against the high-spp
    off (full τ) reference at equal spp and at equal time, and the bias ‖auto_ref − off_ref‖²
    / ‖off_ref‖² of the two high-spp renders (same seed: the same directions are sampled,
    only the lookups' τ differ, so this is nearly free of noise) against the noise."""
    import sparsebtf.mitsuba as sbm

    size, spp, ref_spp = args.lod_size, args.lod_spp, args.lod_ref_spp
    out: dict[str, Any] = {}
    images: dict[str, dict[str, np.ndarray]] = {}
    for name, rt in rts.items():
        key = sbm.add_material(rt, f"bench-lod-{name}")
        t0 = time.perf_counter()
        b = {lod: lod_bsdf(key, lod, size) for lod in ("off", "auto")}
        for lod in b:
            render(b[lod], "sky", size, 1, 0)  # compile the kernels
        refs, ref_secs, ref_cpu = {}, {}, {}
        for lod in b:  # one seed for both: correlated noise
            refs[lod], ref_secs[lod] = render(b[lod], "sky", size, ref_spp, 100_000)
            ref_cpu[lod] = render.cpu_seconds
        n = size * size * ref_spp
        per = {lod: ref_cpu[lod] / n * 1e6 for lod in b}
        row: dict[str, Any] = {
            "us_per_sample_per_pixel": per,
            "wall_us_per_sample_per_pixel": {lod: ref_secs[lod] / n * 1e6 for lod in b},
            "speedup": per["off"] / per["auto"],
            "bias_rel_mse": rel_mse(refs["auto"], refs["off"]),
            "tau_used": lod_counts(render, key, size),
        }
        row["sweep"] = lod_sweep(render, key, refs["off"], ref_cpu["off"], args)
        mses: dict[str, list] = {lod: [] for lod in b}
        for seed in range(args.seeds):
            for lod in b:
                mses[lod].append(rel_mse(render(b[lod], "sky", size, spp, seed)[0], refs["off"]))
        for lod in b:
            row[f"rel_mse_{spp}spp"] = row.get(f"rel_mse_{spp}spp", {})
            row[f"rel_mse_{spp}spp"][lod] = float(np.mean(mses[lod]))
        row["noise_rel_mse"] = row[f"rel_mse_{spp}spp"]["off"]
        spp_eq = max(1, round(spp * row["speedup"]))
        eq = [rel_mse(render(b["auto"], "sky", size, spp_eq, seed)[0], refs["off"])
              for seed in range(args.seeds)]  # fmt: skip
        row["auto_equal_time"] = {"spp": spp_eq, "rel_mse": float(np.mean(eq))}
        row["bias_below_noise"] = row["bias_rel_mse"] < row["noise_rel_mse"]
        row["seconds_total"] = time.perf_counter() - t0
        out[name] = row
        images[name] = refs
        log(f"  {name:9s} off {per['off']:.1f} CPU us, auto {per['auto']:.1f} CPU us per sample "
            f"({row['speedup']:.2f}x); bias {row['bias_rel_mse']:.3g} vs {spp}-spp noise "
            f"{row['noise_rel_mse']:.3g}; equal time ({spp_eq} spp) "
            f"{row['auto_equal_time']['rel_mse']:.3g}  [{row['seconds_total']:.0f} s]")
    return out, images


def lod_sweep(render: Renderer, key: str, ref: np.ndarray, ref_cpu: float,
              args: argparse.Namespace) -> list[dict]:
    """``--lod-sweep later:min:sampled,...``: the CPU-time speed-up over lod = off and the bias
    against the off reference of ``lod = auto`` with those fractions (``lod_later``,
    ``lod_min``, ``lod_sampled``), at the reference's spp and seed."""
    out = []
    for spec in filter(None, (args.lod_sweep or "").split(",")):
        later, low, sampled = (float(v) for v in spec.split(":"))
        b = lod_bsdf(key, "auto", args.lod_size, lod_later=later, lod_min=low,
                     lod_sampled=sampled)  # fmt: skip
        render(b, "sky", args.lod_size, 1, 0)
        img, _ = render(b, "sky", args.lod_size, args.lod_ref_spp, 100_000)
        out.append({"later": later, "min": low, "sampled": sampled,
                    "speedup": ref_cpu / render.cpu_seconds, "bias_rel_mse": rel_mse(img, ref)})
        log(f"    sweep later {later:g} min {low:g} sampled {sampled:g}: "
            f"{out[-1]['speedup']:.2f}x, bias {out[-1]['bias_rel_mse']:.3g}")
    return out


def save_lod_images(images: dict, results: dict, path: Path, ref_spp: int) -> Path:
    """One row per material: [off | auto | |auto − off| × 10], the high-spp renders."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from sparsebtf.figures import save_figure
    from sparsebtf.rendering.render import auto_exposure, tonemap_srgb

    fig, axes = plt.subplots(len(images), 3, figsize=(6.6, 2.3 * len(images)), squeeze=False)
    for r, (name, im) in enumerate(images.items()):
        ex = auto_exposure(im["off"])
        res = results[name]
        diff = np.abs(im["auto"] - im["off"]) * 10
        cols = [(im["off"], f"{name}: lod off, {ref_spp} spp\n"
                            f"{res['us_per_sample_per_pixel']['off']:.1f} CPU us/sample"),
                (im["auto"], f"lod auto ({res['speedup']:.2f}x faster)\n"
                             f"{res['us_per_sample_per_pixel']['auto']:.1f} CPU us/sample"),
                (diff, f"|auto - off| x 10\nbias {res['bias_rel_mse']:.2g} "
                       f"(noise {res['noise_rel_mse']:.2g})")]  # fmt: skip
        for c, (img, title) in enumerate(cols):
            ax = axes[r, c]
            ax.imshow(tonemap_srgb(img, ex), interpolation="nearest")
            ax.set_title(title, fontsize=7)
            ax.set_xticks([])
            ax.set_yticks([])
    fig.tight_layout()
    return save_figure(fig, path, dpi=100)


def save_images(images: dict, results: dict, path: Path, spp: int, ref_spp: int) -> Path:
    """One row per (material, light): [cosine | BTF sampling | reference], same exposure."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from sparsebtf.figures import save_figure
    from sparsebtf.rendering.render import auto_exposure, tonemap_srgb

    rows = list(images)
    fig, axes = plt.subplots(len(rows), 3, figsize=(6.6, 2.3 * len(rows)), squeeze=False)
    for r, (name, light) in enumerate(rows):
        im = images[(name, light)]
        ex = auto_exposure(im["reference"])
        res = results[f"{name}/{light}"]
        cols = [("cosine", f"cosine, {spp} spp\nrel. MSE {res['cosine']['rel_mse']:.3g}"),
                ("btf", f"BTF sampling, {spp} spp\nrel. MSE {res['btf']['rel_mse']:.3g}"),
                ("reference", f"{name}, {light}\nreference, {ref_spp} spp")]  # fmt: skip
        for c, (k, title) in enumerate(cols):
            ax = axes[r, c]
            ax.imshow(tonemap_srgb(im[k], ex), interpolation="nearest")
            ax.set_title(title, fontsize=7)
            ax.set_xticks([])
            ax.set_yticks([])
    fig.tight_layout()
    return save_figure(fig, path, dpi=100)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backend", default="llvm", choices=["llvm", "cuda", "auto"],
                    help="Mitsuba variant: llvm_ad_rgb (default) or cuda_ad_rgb")
    ap.add_argument("--glossy", default="leather", choices=["leather", "wallpaper"])
    ap.add_argument("--size", type=int, default=48, help="noise renders: image side")
    ap.add_argument("--spp", type=int, default=16, help="noise renders: samples per pixel")
    ap.add_argument("--ref-spp", type=int, default=1024, help="reference samples per pixel")
    ap.add_argument("--seeds", type=int, default=2, help="noise renders per sampler")
    ap.add_argument("--time-size", type=int, default=128, help="timing renders: image side")
    ap.add_argument("--time-spp", type=int, default=8, help="timing renders: spp")
    ap.add_argument("--repeat", type=int, default=3, help="timed renders per setting")
    ap.add_argument("--time-material", default="synthetic", choices=["synthetic", "captured"],
                    help="timing renders: the coded material (synthetic: random coefficient "
                    "locations; captured: the woven sample coded with the release model)")
    ap.add_argument("--no-lobe", action="store_true",
                    help="skip the analytic glossy material (a mirror lobe, sky only)")
    ap.add_argument("--integrator", default="path", choices=sorted(INTEGRATORS),
                    help="noise renders: path tracer (default) or BSDF samples only (direct)")
    ap.add_argument("--lod", action="store_true",
                    help="only the level-of-detail comparison (lod off vs auto)")
    ap.add_argument("--lod-size", type=int, default=64,
                    help="level of detail: image side (default 64; the issue's full size: "
                    "--lod-size 1024)")
    ap.add_argument("--lod-spp", type=int, default=16, help="level of detail: spp (16)")
    ap.add_argument("--lod-ref-spp", type=int, default=1024,
                    help="level of detail: spp of the full-tau reference and of the bias "
                    "renders (1024)")
    ap.add_argument("--lod-sweep", default=None, metavar="LATER:MIN:SAMPLED,...",
                    help="level of detail: also time and measure the bias of these fractions "
                    "(lod_later, lod_min, lod_sampled), e.g. 0.1:1:1,0.1:0.5:0.3")
    ap.add_argument("--skip-noise", action="store_true")
    ap.add_argument("--skip-timing", action="store_true")
    ap.add_argument("--out", default=None, help="folder for the side-by-side PNG")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    t0 = time.perf_counter()
    load0 = os.getloadavg()
    render = Renderer(args.backend)
    noise_render = render if args.integrator == "path" else Renderer(args.backend, args.integrator)
    data: dict[str, Any] = {"machine": machine(), "variant": render.variant, "llvm": render.why,
                            "load_average_start": load0}  # fmt: skip
    keys = ("glossy", "size", "spp", "ref_spp", "seeds", "time_size", "time_spp", "repeat",
            "integrator")
    data["settings"] = {k: getattr(args, k) for k in keys}
    rows = [("variant", f"{render.variant} ({render.why})")]
    if args.lod:
        log("level of detail: lod off vs auto")
        base = coded_materials(args.glossy, lobe=False)
        rts = {args.glossy: base[args.glossy], "felt": base["felt"],
               "carpet/bundled": bundled_material()}  # fmt: skip
        data["settings"].update(lod_size=args.lod_size, lod_spp=args.lod_spp,
                                lod_ref_spp=args.lod_ref_spp)  # fmt: skip
        data["lod"], images = level_of_detail(render, rts, args)
        if args.out:
            png = Path(args.out) / "lod.png"
            data["lod_png"] = str(save_lod_images(images, data["lod"], png, args.lod_ref_spp))
        for k, r in data["lod"].items():
            us = r["us_per_sample_per_pixel"]
            rows.append((f"{k}: CPU us/sample/pixel off / auto",
                         f"{us['off']:.2f} / {us['auto']:.2f} = {r['speedup']:.2f}x"))
            rows.append((f"{k}: rel MSE {args.lod_spp} spp off / auto",
                         " / ".join(f"{v:.4g}" for v in r[f"rel_mse_{args.lod_spp}spp"].values())))
            rows.append((f"{k}: auto at equal time ({r['auto_equal_time']['spp']} spp)",
                         f"{r['auto_equal_time']['rel_mse']:.4g}"))
            rows.append((f"{k}: bias (auto vs off, {args.lod_ref_spp} spp) < noise",
                         f"{r['bias_rel_mse']:.3g} < {r['noise_rel_mse']:.3g}: "
                         f"{r['bias_below_noise']}"))
            for sw in r["sweep"]:
                rows.append((f"{k}: sweep later {sw['later']:g} min {sw['min']:g} sampled "
                             f"{sw['sampled']:g}", f"{sw['speedup']:.2f}x, bias "
                             f"{sw['bias_rel_mse']:.3g}"))  # fmt: skip
            tu = r["tau_used"]
            rows.append((f"{k}: mean tau Y used: first eval / first sample / later",
                         " / ".join(f"{tu[c]['tau'][0]:.0f} ({tu[c]['lookups']})"
                                    for c in ("first", "first_sampled", "later"))
                         + " (lookups in a 1-spp render)"))  # fmt: skip
        args.skip_noise = args.skip_timing = True
    if not args.skip_noise:
        log("noise: relative MSE against the reference")
        rts = coded_materials(args.glossy, not args.no_lobe)
        data["coded_tau"] = CODED_TAU
        log("relative variance of the sample weight (BSDF only)")
        data["weight_relative_variance"] = weight_variance(render, rts)
        data["noise"], images = noise(noise_render, rts, args)
        if args.out:
            png = Path(args.out) / "sampling.png"
            data["png"] = str(save_images(images, data["noise"], png, args.spp, args.ref_spp))
        for k, r in data["noise"].items():
            rows.append((f"{k}: rel MSE cosine / btf ({args.spp} spp)",
                         f"{r['cosine']['rel_mse']:.4g} / {r['btf']['rel_mse']:.4g} = "
                         f"{r['mse_ratio_cosine_over_btf']:.2f}x"))  # fmt: skip
            rows.append((f"{k}: rel MSE cosine / btf, per-patch tables",
                         f"{r['mse_ratio_cosine_over_btf_patch']:.2f}x"))  # fmt: skip
            rows.append((f"{k}: equal time (cosine {r['cosine_equal_time']['spp']} spp)",
                         f"{r['mse_ratio_equal_time']:.2f}x"))  # fmt: skip
            rows.append((f"{k}: reference halves rel MSE", f"{r['reference_halves_rel_mse']:.3g}"))
    if not args.skip_timing:
        log("time per sample per pixel")
        data["timing"] = tm = timing(render, args)
        for k, v in tm["ns_per_sample_per_pixel"].items():
            rows.append((f"ns/sample/pixel {k}", f"{v:.0f}"))
        for s in SAMPLERS:
            rows.append((f"ratio full tau / dense ({s})",
                         f"{tm[f'ratio_full_over_dense/{s}']:.2f}"))  # fmt: skip
            rows.append((f"ratio quarter tau / dense ({s})",
                         f"{tm[f'ratio_quarter_over_dense/{s}']:.2f}"))  # fmt: skip
            rows.append((f"ratio full tau, evaluated (runtime) / best dense ({s})",
                         f"{tm[f'ratio_full_evaluated_over_best_dense/{s}']:.2f}"))  # fmt: skip
            rows.append((f"ratio quarter tau, evaluated (runtime) / best dense ({s})",
                         f"{tm[f'ratio_quarter_evaluated_over_best_dense/{s}']:.2f}"))  # fmt: skip
            rows.append((f"full tau: symbolic (Dr.Jit) / evaluated (runtime) ({s})",
                         f"{tm[f'speedup_evaluated_over_symbolic/{s}']:.2f}x"))  # fmt: skip
    data["load_average_end"] = os.getloadavg()
    data["seconds"] = time.perf_counter() - t0
    rows.append(("load average start / end", f"{load0[0]:.1f} / {data['load_average_end'][0]:.1f}"))
    rows.append(("benchmark seconds", f"{data['seconds']:.0f}"))
    report(rows, data, args.json)


if __name__ == "__main__":
    main()
