"""Mitsuba 3 BSDF plugins: ``sparsebtf`` (coded BTFs, Eq. 5/6) and ``sparsebtf_dense`` (reference).

Use :mod:`sparsebtf.mitsuba` (``import sparsebtf.mitsuba``), which picks a variant and calls
:func:`register`. Importing this package does not import Mitsuba or Dr.Jit. Its modules:

* :mod:`.materials` — material sources (files, :func:`add_material`), per-process caches, the
  parameter checks, :func:`preload`; plain Python/NumPy,
* :mod:`.kernels` — the lookups and the sampler: Dr.Jit kernels (neighbour search, Eq. 5/6,
  the dense reference, BTF-driven sampling) and their scalar NumPy counterparts,
* :mod:`.sampling` — the sampling tables from a material's angular response, and a NumPy
  reference of the sampler (no Mitsuba),
* :mod:`.plugins` — the Mitsuba BSDF classes, built for the variant active when it is imported
  (only :func:`register` imports it),
* :mod:`.variant` — :func:`setup` (choose and set the variant) and :func:`register`.

``sparsebtf`` — a coded material
--------------------------------
Evaluates a coded BTF locally at each shading point, never reconstructing a data point: the
texel's data point p, its dictionary k = M[p] and its stored coefficients (v_s, l_s), then per
YUV channel (paper Eq. 5, with Eq. 6's coefficient-space angular interpolation)::

    X_c = Σ_s v_s U1[i1,l1] U2[i2,l2] (Σ_a wl_a U3[L_a,l3]) (Σ_b wv_b U4[V_b,l4])

followed by the inverse preprocessing (de-standardisation with μ, σ blended by the same
weights, YUV → RGB, exp). On the ``llvm_ad_*``/``cuda_ad_*`` variants everything is Dr.Jit:
``dr.gather`` from flat arrays (:meth:`sparsebtf.runtime.RuntimeBTF.arrays`; value and location
of a coefficient in one 8-byte gather, U1·U2 from one product table), a symbolic
``dr.while_loop`` over the coefficients of each channel and one over the candidate directions
of the query's grid cell (k-nearest by chord distance, as
:func:`sparsebtf.runtime.angular_weights`; the lists of
:func:`sparsebtf.runtime.angular.candidate_lists` are provably complete). On ``scalar_rgb``
the lookup calls :meth:`RuntimeBTF.evaluate` per ray (tiny renders only).

Evaluated mode. By default Dr.Jit records Mitsuba's virtual calls and loops into one
megakernel, and the lookup above runs per lane inside it. Within :func:`evaluated` (Dr.Jit's
``SymbolicCalls``/``SymbolicLoops`` off) each step of the path tracer is its own kernel over
the whole wavefront, and the plugin hands its active lanes to the runtime's compiled lookup
(``backend`` auto): the batch is grouped by data point and texel and summed in vector
registers, several times faster than the per-lane Dr.Jit loop in a render
(``benchmarks/bench_render.py``). :func:`sparsebtf.rendering.render.render_material` (and
``sparsebtf render``) renders a ``sparsebtf`` material this way by default (``mode``).

A material coded with adaptive patch sizes (``sparsebtf encode --adaptive-patches``; a
:class:`sparsebtf.runtime.AdaptiveRuntimeBTF`) renders the same way: its data points are the
tree's nodes (:meth:`AdaptiveRuntimeBTF.arrays`), the texel's node comes from a table of the
finest grid's cells and (i1, i2) from the node's own size p (row % p, col % p); the spatial
dictionaries of every size are padded to the largest, so the lookup is the one above with one
more gather. A level-of-detail fraction multiplies the loaded τ of each node's own size;
the sampling response is per node (``sampling_tables = "patch"``: one table per node), and
its mean over the material weighs each node by its texels. On ``scalar_rgb`` the lookup is
:meth:`AdaptiveRuntimeBTF.evaluate`.

Convention (what ``eval`` returns). Mitsuba calls ``eval(ctx, si, wo)`` with ``si.wi`` towards
the camera (the previous path vertex) and ``wo`` towards the light, both in the local shading
frame, and expects f·cos θ_o. A BTF value is reflected radiance times π per unit irradiance,
π·f·cos θ_light (docs/format.md, Conventions): it *includes* the foreshortening of the light.
So::

    eval(ctx, si, wo) = BTF(uv, ω_light = wo, ω_view = si.wi) / π        (no extra cosine)

i.e. :meth:`RuntimeBTF.evaluate(wi=wo, wo=si.wi, uv=si.uv·uv_scale)` / π (the runtime's ``wi`` is
the light). In ``TransportMode.Importance`` (light tracing) the roles swap. The decoder's floor
of −1e-5 (exp(·) − 1e-5) is clamped to 0. Directions below the horizon give 0 unless
``two_sided`` is set, which mirrors both directions to the upper side on back-face hits.

Local frame. The BTF's azimuth is measured from the +u texture axis towards +v (z = normal).
Mitsuba's shading frame has s = ∂p/∂u (Gram–Schmidt against n) and t = n × s; where the surface
parametrisation is left-handed (t points along −∂p/∂v, e.g. Mitsuba's built-in sphere, whose v
runs from the north pole down) the local y of both directions is negated, so the material's
angular behaviour stays consistent with its texture (a mirror image of the sample, as the
texture itself is mirrored there).

Sampling (``sampling``): ``btf`` (default) draws the unknown direction (the light in radiance
transport, the view in importance transport) from tables built from the material's own mean
angular response (:mod:`.sampling`: per bin of the known direction a distribution over
equal-area cells, mixed over the known direction's angular neighbours, with a share
``sampling_mix`` of cosine sampling so the density is positive over the whole hemisphere);
``cosine`` samples cos θ/π. ``pdf`` is the density ``sample`` draws from, bit for bit, and
``sample`` returns eval/pdf (checked with ``mitsuba.chi2`` in ``tests/test_mitsuba.py``).

Parameters (``mi.load_dict({"type": "sparsebtf", ...})``):

================ ========= ==============================================================
filename         string    coded file (``sparsebtf encode``, fixed or adaptive patch sizes,
                           / ``import-release``)
model            string    model file or bundled model name; default: the coded file's
                           (a bundled model by hash, else the model file it recorded)
key              string    instead of ``filename``: a material added with
                           :func:`sparsebtf.mitsuba.add_material` (a RuntimeBTF/CodedBTF
                           or an AdaptiveRuntimeBTF/AdaptiveCodedBTF)
tau              string    level of detail τ' at load time: "885,64,64", "32" or a fraction
                           "0.25" of the coded τ (default: every stored coefficient)
uv_scale         float     texture tiling: uv ↦ uv·uv_scale (default 1; wraps)
interpolation    string    nearest | linear (release 2-NN, default) | barycentric | gaussian
domain           string    standardized (Eq. 6, default) | log (the release shader)
k                integer   neighbours of the gaussian scheme (default 4)
beta             float     gaussian sharpness β in exp(−β d²) (default 20)
two_sided        boolean   shade back faces like front faces (default false)
sampling         string    btf (default) | cosine
sampling_tables  string    material (default: one table) | patch (one per data point, per
                           node of an adaptive material)
sampling_grid    integer   cells per side of the equal-area grid (32; 16 for patch tables)
sampling_mix     float     share of cosine sampling in the mixture (default 0.2)
lod              string    auto (default: τ' per lookup from the path depth and the pixel
                           footprint, :mod:`sparsebtf.runtime.lod`) | off (every lookup at
                           ``tau``)
lod_camera       string    "x,y,z": the camera's position (first-vertex test); without it
                           ``auto`` is off. ``render_material`` passes its scene's camera
lod_near         float     the camera's near clip (default 0.01, Mitsuba's)
lod_pixel        float     one pixel's angle in radians (default 0: no footprint)
lod_later        float     fraction of τ at later path vertices (default 0.1)
lod_sampled      float     at most this fraction for sample() at the first vertex (0.3)
lod_min          float     the least fraction the footprint gives (default 0.5)
lod_stats        boolean   count lookups and loop iterations per class (``lod_stats()``)
backend          string    auto (default) | drjit | numba: who answers the lookups. drjit:
                           the Dr.Jit kernel above, in any mode; numba: the runtime's
                           compiled lookup (:meth:`RuntimeBTF.evaluate`: texel groups,
                           register sums) on the active lanes of an *evaluated* call, so
                           it needs Dr.Jit's evaluated mode (:func:`evaluated`); auto:
                           numba where a call is evaluated on an LLVM variant with numba
                           installed and no gradient is tracked, else Dr.Jit. The two agree
                           within float32 rounding; an adaptive material's level of detail
                           and ``lod_stats`` stay on Dr.Jit
================ ========= ==============================================================

``sparsebtf_dense`` — the uncompressed reference
------------------------------------------------
The same lookup from a dense (H, W, L, V, 3) table: texel by uv, the same angular neighbours
and weights, the weighted blend taken of ln(x + 1e-5) (the log domain of the coded decoder,
so ``nearest`` is an exact table lookup and the blends are comparable), then exp(·) − 1e-5.
Parameters: ``filename`` (any BTF: dense ``.h5``, ``synth:…``, UBO2014 ``.btf``, a coded file)
or ``key``, ``uv_scale``, ``interpolation``, ``k``, ``beta``, ``two_sided``, ``sampling``,
``sampling_grid``, ``sampling_mix`` as above (tables from the mean over texels of the table),
``sampling_key`` (use the sampling tables of that coded material, so a coded render and its
reference draw the same directions from the same random numbers) and ``max_gib`` (float,
default 2): larger tables are refused with an error (crop the BTF first,
``sparsebtf convert --crop``).
"""

from __future__ import annotations

from .materials import (
    DENSE_PLUGIN,
    PLUGIN,
    add_material,
    dense_table,
    load_runtime,
    preload,
    remove_material,
)
from .variant import evaluated, register, setup

__all__ = [
    "DENSE_PLUGIN",
    "PLUGIN",
    "add_material",
    "dense_table",
    "evaluated",
    "load_runtime",
    "preload",
    "register",
    "remove_material",
    "setup",
]
