// SparseBTF WebGL2 viewer: uploads the renderer arrays of a coded BTF as textures and evaluates
// Eq. 5/6 per fragment (shaders/sparsebtf_lookup.glsl) on a sphere or a plane.
//
// Files next to this page: manifest.json (texture layout and uniforms, written by
// sparsebtf.rendering.viewer), the binary it names (all textures, little endian), and the
// shaders sparsebtf_lookup.glsl and viewer_scene.glsl. They are fetched, so the page needs an
// HTTP server (`sparsebtf view`, or any static server for an --export folder); file:// is
// refused by the browser's fetch.
//
// Query parameters (tests, benchmarks, bookmarks): scene=sphere|plane|test, size=N (square
// canvas), tau=a,b,c or lod=f (fraction), interp=nearest|linear|barycentric|gaussian,
// domain=standardized|log, wi=x,y,z and wo=x,y,z (local directions of the test scene),
// animate=0|1, neigh=0|1 (candidate tables), exposure=e, repeat=r, footprint=0|1 (tau' per
// fragment by its screen-space footprint, default 1), zoom=z and ramp=0|1 (test scene).
// A material coded with adaptive patch sizes (manifest.adaptive) has one cap per node class
// (size, tau): the level of detail is a fraction f of each, max(1, ceil(f tau)), set as the
// uniform sb_class; tau=a,b,c then caps every node besides. A material with a highlight store
// (manifest.highlights: its entry count) has the textures sb_hl* and the uniform sb_highlights;
// one with lobes (manifest.lobes: their count) the texture sb_hlLobes and the uniform sb_lobes.
// Script API: window.sparsebtf = {ready, error, info, set(state), readFloat(), benchmark(opts)}.
"use strict";

(function () {
  const api = { ready: false, error: null, info: null };
  window.sparsebtf = api;
  const $ = (id) => document.getElementById(id);
  const INTERP = { nearest: 0, linear: 1, barycentric: 2, gaussian: 3 };
  const DOMAIN = { standardized: 0, log: 1 };
  const SCENE = { sphere: 0, plane: 1, test: 2 };

  function fail(msg) {
    api.error = String(msg);
    $("error").textContent = api.error;
    document.documentElement.dataset.error = api.error;
    throw new Error(api.error);
  }

  async function load(url, kind) {
    let r;
    try {
      r = await fetch(url);
    } catch (e) {
      const hint = location.protocol === "file:"
        ? " (pages opened from file:// cannot fetch their data: serve the folder, e.g. " +
          "`python -m http.server` in it, or use `sparsebtf view`)"
        : "";
      fail(`could not load ${url}: ${e}${hint}`);
    }
    if (!r.ok) fail(`could not load ${url}: HTTP ${r.status}`);
    return kind === "json" ? r.json() : kind === "text" ? r.text() : r.arrayBuffer();
  }

  function parseVec(text, n) {
    const v = text.split(",").map(Number);
    if (v.length !== n || v.some((x) => !Number.isFinite(x))) fail(`bad vector ${text}`);
    return v;
  }

  function normalize(v) {
    const n = Math.hypot(v[0], v[1], v[2]);
    return [v[0] / n, v[1] / n, v[2] / n];
  }

  function cross(a, b) {
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  }

  async function main() {
    const q = new URLSearchParams(location.search);
    const manifest = await load("manifest.json", "json");
    const [lookupSrc, sceneSrc, blob] = await Promise.all([
      load(manifest.shaders.lookup, "text"),
      load(manifest.shaders.scene, "text"),
      load(manifest.data, "bin"),
    ]);
    if (blob.byteLength !== manifest.bytes) {
      fail(`${manifest.data}: ${blob.byteLength} bytes, the manifest announces ${manifest.bytes}`);
    }

    const canvas = $("view");
    const size = q.has("size") ? parseInt(q.get("size"), 10) : 512;
    canvas.width = canvas.height = size;
    const gl = canvas.getContext("webgl2", { antialias: false, preserveDrawingBuffer: true });
    if (!gl) fail("WebGL2 is not available in this browser");
    const floatTarget = !!gl.getExtension("EXT_color_buffer_float");
    const maxTex = gl.getParameter(gl.MAX_TEXTURE_SIZE);

    // -- textures ------------------------------------------------------------------------------
    const FORMATS = {
      R32F: [gl.R32F, gl.RED, gl.FLOAT, Float32Array, 1],
      R32UI: [gl.R32UI, gl.RED_INTEGER, gl.UNSIGNED_INT, Uint32Array, 1],
      R32I: [gl.R32I, gl.RED_INTEGER, gl.INT, Int32Array, 1],
      RGBA32I: [gl.RGBA32I, gl.RGBA_INTEGER, gl.INT, Int32Array, 4],
      RGBA32F: [gl.RGBA32F, gl.RGBA, gl.FLOAT, Float32Array, 4],
      // binary16 as stored (the highlight store's corrections): no rounding on upload
      RGB16F: [gl.RGB16F, gl.RGB, gl.HALF_FLOAT, Uint16Array, 3],
      // binary16 as stored (the store's lobes: two texels of 4 parameters per lobe)
      RGBA16F: [gl.RGBA16F, gl.RGBA, gl.HALF_FLOAT, Uint16Array, 4],
    };
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
    const units = {};
    let unit = 0;
    for (const [name, t] of Object.entries(manifest.textures)) {
      const f = FORMATS[t.format];
      if (!f) fail(`texture ${name}: unknown format ${t.format}`);
      if (t.width > maxTex || t.height > maxTex) {
        fail(`texture ${name} is ${t.width}x${t.height}, above this device's ` +
             `MAX_TEXTURE_SIZE ${maxTex}`);
      }
      const arr = new f[3](blob, t.offset, t.width * t.height * f[4]);
      const tex = gl.createTexture();
      gl.activeTexture(gl.TEXTURE0 + unit);
      gl.bindTexture(gl.TEXTURE_2D, tex);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
      gl.texImage2D(gl.TEXTURE_2D, 0, f[0], t.width, t.height, 0, f[1], f[2], arr);
      const err = gl.getError();
      if (err !== gl.NO_ERROR) fail(`texture ${name} (${t.width}x${t.height} ${t.format}): GL error ${err}`);
      units[name] = unit++;
    }

    // -- programs ------------------------------------------------------------------------------
    const header = "#version 300 es\nprecision highp float;\nprecision highp int;\n" +
      "precision highp sampler2D;\nprecision highp usampler2D;\nprecision highp isampler2D;\n";
    const vsSrc = "#version 300 es\nvoid main() {\n" +
      "  vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));\n" +
      "  gl_Position = vec4(2.0 * p - 1.0, 0.0, 1.0);\n}\n";

    function compile(type, src, what) {
      const s = gl.createShader(type);
      gl.shaderSource(s, src);
      gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) {
        fail(`${what} shader does not compile:\n${gl.getShaderInfoLog(s)}`);
      }
      return s;
    }

    function program(trivial) {
      const fs = trivial
        ? header + "#define SB_TRIVIAL 1\n" + sceneSrc
        : header + lookupSrc + "\n" + sceneSrc;
      const p = gl.createProgram();
      gl.attachShader(p, compile(gl.VERTEX_SHADER, vsSrc, "vertex"));
      gl.attachShader(p, compile(gl.FRAGMENT_SHADER, fs, trivial ? "trivial" : "lookup"));
      gl.linkProgram(p);
      if (!gl.getProgramParameter(p, gl.LINK_STATUS)) {
        fail(`program does not link:\n${gl.getProgramInfoLog(p)}`);
      }
      const uni = {};
      const n = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
      for (let i = 0; i < n; i++) {
        const a = gl.getActiveUniform(p, i);
        const name = a.name.replace(/\[0\]$/, "");
        uni[name] = { loc: gl.getUniformLocation(p, a.name), type: a.type };
      }
      return { p, uni };
    }

    function setUniform(prog, name, value) {
      const u = prog.uni[name];
      if (!u) return;
      const v = Array.isArray(value) ? value.flat(2) : [value];
      switch (u.type) {
        case gl.FLOAT: gl.uniform1fv(u.loc, v); break;
        case gl.FLOAT_VEC2: gl.uniform2fv(u.loc, v); break;
        case gl.FLOAT_VEC3: gl.uniform3fv(u.loc, v); break;
        case gl.FLOAT_VEC4: gl.uniform4fv(u.loc, v); break;
        case gl.INT: gl.uniform1iv(u.loc, v); break;
        case gl.INT_VEC2: gl.uniform2iv(u.loc, v); break;
        case gl.INT_VEC3: gl.uniform3iv(u.loc, v); break;
        case gl.INT_VEC4: gl.uniform4iv(u.loc, v); break;
        default: gl.uniform1i(u.loc, v[0]); // samplers
      }
    }

    const progs = { lookup: program(false), trivial: program(true) };
    // A sampler with no texture in this export (sb_tree of a fixed-size material, sb_neigh
    // without tables) still needs a texture of its type on a unit of its own: WebGL refuses to
    // draw when samplers of different types share a unit, even where the branch never reads it.
    const DUMMY = {
      [gl.SAMPLER_2D]: [gl.R32F, gl.RED, gl.FLOAT, new Float32Array(1)],
      [gl.INT_SAMPLER_2D]: [gl.R32I, gl.RED_INTEGER, gl.INT, new Int32Array(1)],
      [gl.UNSIGNED_INT_SAMPLER_2D]: [gl.R32UI, gl.RED_INTEGER, gl.UNSIGNED_INT, new Uint32Array(1)],
    };
    for (const prog of Object.values(progs)) {
      for (const [name, u] of Object.entries(prog.uni)) {
        const d = DUMMY[u.type];
        if (!d || name in units) continue;
        const tex = gl.createTexture();
        gl.activeTexture(gl.TEXTURE0 + unit);
        gl.bindTexture(gl.TEXTURE_2D, tex);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
        gl.texImage2D(gl.TEXTURE_2D, 0, d[0], 1, 1, 0, d[1], d[2], d[3]);
        units[name] = unit++;
      }
    }
    for (const prog of Object.values(progs)) {
      gl.useProgram(prog.p);
      for (const [name, u] of Object.entries(units)) setUniform(prog, name, u);
      for (const [name, v] of Object.entries(manifest.uniforms)) setUniform(prog, name, v);
    }
    const vao = gl.createVertexArray();

    // -- state ---------------------------------------------------------------------------------
    const tauMax = manifest.tau_max;
    const adaptive = manifest.adaptive || null; // {sizes, smallest, nodes, classes}
    const state = {
      scene: q.get("scene") || "sphere",
      interp: q.get("interp") || "linear",
      domain: q.get("domain") || "standardized",
      tau: tauMax.slice(),
      lod: 1.0,
      exposure: q.has("exposure") ? parseFloat(q.get("exposure")) : 1.0,
      repeat: q.has("repeat") ? parseFloat(q.get("repeat")) : 2.0,
      yaw: -0.6, pitch: 0.7, dist: 4.0,
      lightAz: 0.8, lightEl: 0.9,
      wi: [0, 0, 1], wo: [0, 0, 1],
      animate: q.get("animate") !== "0" && q.get("scene") !== "test",
      neigh: q.has("neigh") ? q.get("neigh") === "1" : manifest.has_neighbours,
      trivial: false,
      footprint: q.get("footprint") !== "0",
      zoom: q.has("zoom") ? parseFloat(q.get("zoom")) : 1.0,
      ramp: q.get("ramp") === "1",
    };
    if (!(state.scene in SCENE)) fail(`unknown scene ${state.scene}`);
    if (!(state.interp in INTERP)) fail(`unknown interpolation ${state.interp}`);
    if (!(state.domain in DOMAIN)) fail(`unknown domain ${state.domain}`);
    if (q.has("wi")) state.wi = parseVec(q.get("wi"), 3);
    if (q.has("wo")) state.wo = parseVec(q.get("wo"), 3);
    if (q.has("lod")) setLod(parseFloat(q.get("lod")));
    if (q.has("tau")) state.tau = parseVec(q.get("tau"), 3).map((x) => Math.round(x));
    const MAX_CLASSES = 16; // the shader's SB_MAX_CLASSES
    if (adaptive && adaptive.classes.length > MAX_CLASSES) {
      fail(`${adaptive.classes.length} node classes, the shader holds ${MAX_CLASSES}`);
    }
    if (state.neigh && !manifest.has_neighbours) fail("this export has no neighbour tables");

    function setLod(f) {
      // the runtime's fractional tau: max(1, ceil(f * tau)) per channel (adaptive: of each
      // node's tau, classCaps; state.tau stays the cap of every node)
      state.lod = Math.min(Math.max(f, 0.001), 1.0);
      if (!adaptive) state.tau = tauMax.map((t) => Math.max(1, Math.ceil(state.lod * t - 1e-9)));
    }

    // Adaptive: (size, tau'_Y, tau'_U, tau'_V) of each node class at the slider's fraction,
    // in double precision so that the shader's integers are the runtime's ceil(f tau).
    function classCaps() {
      return adaptive.classes.map(([p, ...tau]) => [p, ...tau.map((t, c) =>
        Math.min(state.tau[c], Math.max(1, Math.ceil(state.lod * t - 1e-9))))]);
    }

    function camera() {
      const cp = Math.cos(state.pitch);
      const pos = [state.dist * cp * Math.cos(state.yaw), state.dist * cp * Math.sin(state.yaw),
                   state.dist * Math.sin(state.pitch)];
      const fwd = normalize([-pos[0], -pos[1], -pos[2]]);
      const right = normalize(cross(fwd, [0, 0, 1]));
      return { pos, fwd, right, up: cross(right, fwd) };
    }

    let dirty = true;
    function draw(target) {
      const prog = state.trivial ? progs.trivial : progs.lookup;
      gl.useProgram(prog.p);
      const cam = camera();
      const ce = Math.cos(state.lightEl);
      const uniforms = {
        u_resolution: [canvas.width, canvas.height],
        u_scene: SCENE[state.scene],
        u_camPos: cam.pos, u_camRight: cam.right, u_camUp: cam.up, u_camFwd: cam.fwd,
        u_tanHalfFov: Math.tan((40 * Math.PI) / 360),
        u_lightDir: [ce * Math.cos(state.lightAz), ce * Math.sin(state.lightAz),
                     Math.sin(state.lightEl)],
        u_uvRepeat: state.repeat,
        u_exposure: state.exposure,
        u_linearOut: target ? 1 : 0,
        u_testWi: state.wi, u_testWo: state.wo,
        u_testZoom: state.zoom, u_testRamp: state.ramp ? 1 : 0,
        u_footprint: state.footprint ? 1 : 0,
        sb_tau: state.tau,
        sb_interp: INTERP[state.interp],
        sb_knn: 4,
        sb_beta: 20.0,
        sb_domain: DOMAIN[state.domain],
        // the tables hold 8 candidates that provably contain the 3 nearest: not for gaussian (4)
        sb_useNeigh: state.neigh && state.interp !== "gaussian" ? 1 : 0,
      };
      if (adaptive) uniforms.sb_class = classCaps();
      for (const [name, v] of Object.entries(uniforms)) setUniform(prog, name, v);
      gl.bindFramebuffer(gl.FRAMEBUFFER, target || null);
      gl.viewport(0, 0, canvas.width, canvas.height);
      gl.bindVertexArray(vao);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
      dirty = false;
    }

    // -- float readback (tests) ----------------------------------------------------------------
    let fbo = null;
    function floatTargetFbo() {
      if (!floatTarget) fail("EXT_color_buffer_float is missing: no float readback");
      if (fbo && fbo.w === canvas.width && fbo.h === canvas.height) return fbo.fb;
      const tex = gl.createTexture();
      gl.activeTexture(gl.TEXTURE0 + unit);
      gl.bindTexture(gl.TEXTURE_2D, tex);
      gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGBA32F, canvas.width, canvas.height);
      const fb = gl.createFramebuffer();
      gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
      gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, tex, 0);
      if (gl.checkFramebufferStatus(gl.FRAMEBUFFER) !== gl.FRAMEBUFFER_COMPLETE) {
        fail("the RGBA32F framebuffer is incomplete");
      }
      fbo = { fb, w: canvas.width, h: canvas.height };
      return fb;
    }

    // Linear RGB of every pixel, rows bottom to top (readPixels order), as a flat RGBA array.
    api.readFloat = function () {
      const fb = floatTargetFbo();
      draw(fb);
      const out = new Float32Array(canvas.width * canvas.height * 4);
      gl.readPixels(0, 0, canvas.width, canvas.height, gl.RGBA, gl.FLOAT, out);
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      dirty = true;
      return Array.from(out);
    };

    // Milliseconds per frame of `frames` draws to the canvas, synchronised by a 1-pixel
    // readPixels after the first (warm-up) frame and after the last.
    api.benchmark = function (opts) {
      const o = Object.assign({ frames: 5, trivial: false }, opts || {});
      const saved = state.animate;
      state.animate = false;
      state.trivial = !!o.trivial;
      const px = new Uint8Array(4);
      draw(null);
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
      const t0 = performance.now();
      for (let i = 0; i < o.frames; i++) {
        state.yaw += 1e-3; // a changing view, as when the user drags
        draw(null);
      }
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
      const ms = (performance.now() - t0) / o.frames;
      state.trivial = false;
      state.animate = saved;
      dirty = true;
      return { ms_per_frame: ms, fps: 1000 / ms, frames: o.frames, width: canvas.width,
               height: canvas.height, trivial: !!o.trivial };
    };

    api.set = function (s) {
      for (const [k, v] of Object.entries(s)) {
        if (k === "lod") setLod(v);
        else if (k in state) state[k] = v;
        else fail(`unknown state ${k}`);
      }
      syncControls();
      dirty = true;
    };
    api.state = state;

    // -- controls ------------------------------------------------------------------------------
    function syncControls() {
      $("tau").value = Math.round(state.lod * 1000);
      $("tauText").textContent = adaptive
        ? `${Math.round(state.lod * 100)} % of each node's: ` +
          classCaps().map(([p, ...t]) => `${p}×${p} ${t.join(", ")}`).join("; ") + " (Y, U, V)"
        : `${state.tau.join(", ")} of ${tauMax.join(", ")} (Y, U, V)`;
      $("interp").value = state.interp;
      $("domain").value = state.domain;
      if (state.scene !== "test") $("scene").value = state.scene;
      $("exposure").value = Math.round(10 * Math.log2(state.exposure));
      $("exposureText").textContent = `×${state.exposure.toPrecision(3)}`;
      $("repeat").value = state.repeat;
      $("repeatText").textContent = String(state.repeat);
      $("animate").checked = state.animate;
      $("footprint").checked = state.footprint;
    }
    $("tau").addEventListener("input", (e) => { setLod(e.target.value / 1000); syncControls(); dirty = true; });
    $("interp").addEventListener("change", (e) => { state.interp = e.target.value; dirty = true; });
    $("domain").addEventListener("change", (e) => { state.domain = e.target.value; dirty = true; });
    $("scene").addEventListener("change", (e) => {
      state.scene = e.target.value;
      if (state.scene === "plane") state.pitch = Math.max(state.pitch, 0.15);
      dirty = true;
    });
    $("exposure").addEventListener("input", (e) => {
      state.exposure = Math.pow(2, e.target.value / 10); syncControls(); dirty = true;
    });
    $("repeat").addEventListener("input", (e) => { state.repeat = +e.target.value; syncControls(); dirty = true; });
    $("animate").addEventListener("change", (e) => { state.animate = e.target.checked; dirty = true; });
    $("footprint").addEventListener("change", (e) => { state.footprint = e.target.checked; dirty = true; });

    let drag = null;
    canvas.addEventListener("contextmenu", (e) => e.preventDefault());
    canvas.addEventListener("pointerdown", (e) => {
      drag = { x: e.clientX, y: e.clientY, light: e.shiftKey || e.button === 2 };
      canvas.setPointerCapture(e.pointerId);
    });
    canvas.addEventListener("pointerup", () => { drag = null; });
    canvas.addEventListener("pointermove", (e) => {
      if (!drag) return;
      const dx = (e.clientX - drag.x) / canvas.clientWidth;
      const dy = (e.clientY - drag.y) / canvas.clientHeight;
      drag.x = e.clientX;
      drag.y = e.clientY;
      const minPitch = state.scene === "plane" ? 0.15 : -1.5;
      if (drag.light) {
        state.lightAz -= 4 * dx;
        state.lightEl = Math.min(1.55, Math.max(0.02, state.lightEl - 3 * dy));
      } else {
        state.yaw -= 4 * dx;
        state.pitch = Math.min(1.5, Math.max(minPitch, state.pitch + 3 * dy));
      }
      dirty = true;
    });
    canvas.addEventListener("wheel", (e) => {
      e.preventDefault();
      state.dist = Math.min(12, Math.max(1.3, state.dist * Math.exp(e.deltaY * 0.001)));
      dirty = true;
    }, { passive: false });

    // -- loop and fps --------------------------------------------------------------------------
    let frames = 0;
    let since = performance.now();
    let lastDraw = 0;
    function frame(now) {
      if (state.animate || dirty) {
        draw(null);
        frames++;
        lastDraw = now;
      }
      if (now - since >= 1000) {
        const fps = (frames * 1000) / (now - since);
        $("fps").textContent = frames ? `${fps.toFixed(1)} fps` : "idle";
        $("ms").textContent = frames ? `${(1000 / fps).toFixed(1)} ms` : "";
        api.fps = fps;
        frames = 0;
        since = now;
      }
      requestAnimationFrame(frame);
    }

    const m = manifest.meta;
    const dbg = gl.getExtension("WEBGL_debug_renderer_info");
    api.info = {
      renderer: gl.getParameter(dbg ? dbg.UNMASKED_RENDERER_WEBGL : gl.RENDERER),
      version: gl.getParameter(gl.VERSION),
      max_texture_size: maxTex,
      float_readback: floatTarget,
      textures: Object.keys(units),
      meta: m,
    };
    const patch = adaptive
      ? `adaptive patches ${adaptive.sizes.map((p) => `${adaptive.nodes[p]} of ${p}x${p}`).join(", ")}`
      : `patch ${m.patch}`;
    $("info").textContent =
      `${m.name}: ${m.height}x${m.width} texels, ${patch}, ` +
      `${m.n_lights} lights x ${m.n_views} views\n` +
      `coefficients ${Object.values(m.nnz).join(" / ")} (Y/U/V)\n` +
      (manifest.highlights ? `highlight store: ${manifest.highlights} nodes\n` : "") +
      (manifest.lobes ? `highlight lobes: ${manifest.lobes} texels\n` : "") +
      `${(manifest.bytes / 1048576).toFixed(1)} MiB of textures\n${api.info.renderer}`;
    // On a CPU rasteriser a full-tau frame takes seconds: redraw only on change there.
    if (!q.has("animate") && /SwiftShader|llvmpipe|softpipe/i.test(api.info.renderer)) {
      state.animate = false;
    }
    syncControls();
    if (state.scene !== "test") requestAnimationFrame(frame);
    else draw(null);
    api.ready = true;
    document.documentElement.dataset.ready = "1";
  }

  main().catch((e) => {
    if (!api.error) {
      api.error = String(e && e.stack ? e.stack : e);
      document.documentElement.dataset.error = api.error;
      const el = document.getElementById("error");
      if (el) el.textContent = api.error;
    }
  });
})();
