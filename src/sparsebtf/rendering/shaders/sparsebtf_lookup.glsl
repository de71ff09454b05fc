// SparseBTF lookup: one BTF value per fragment from the sparse codes (paper Eq. 5 and Eq. 6).
//
// GLSL ES 3.00 compatible function set (also valid GLSL 3.30+). The host prepends the
// #version line and the precision statements (highp float, int, sampler2D, usampler2D,
// isampler2D), then this file, then its own main(). It mirrors
// sparsebtf.runtime.RuntimeBTF.evaluate (src/sparsebtf/runtime/decoder.py) exactly:
//
//   texel    col = floor(fract(u) W), row = floor(fract(v) H); point p = row/P + (H/P)(col/P),
//            i1 = row % P, i2 = col % P
//   angular  k nearest sampled directions by chord distance |q - x| (ties: lower index first)
//            with the weights of runtime/angular.py (nearest, linear = release 2-NN,
//            barycentric, gaussian)
//   Eq. 6    X_c = sum_s v_s U1[i1,l1] U2[i2,l2] (sum_a wl_a U3[L_a,l3]) (sum_b wv_b U4[V_b,l4])
//            over the first min(count, tau'_c) coefficients (stored by decreasing |v|; a
//            fractional tau' weighs coefficient s by min(1, tau' - s), runtime/kernels.py
//            prefix_weights), then
//            log_c = X_c sd + mu with mu, sd blended by wl_a wv_b ("standardized" domain), or
//            log_c = sum_ab wl_a wv_b (sd_ab X_c(L_a,V_b) + mu_ab) ("log" domain, release shader)
//   colour   rgb = exp(min(YUV_TO_RGB [log_Y, log_U, log_V], bound)) - eps
//   LOD      tau'_c = max(f tau_c, min(1, tau_c)) with f = clamp(1 / rho^2, sb_lodMin, 1), rho
//            the texels per pixel side from the screen-space derivatives of uv
//            (runtime/lod.py: lod_tau, footprint_fraction)
//
// Adaptive patch sizes (sb_adaptive.x == 1; runtime/adaptive.py, AdaptiveRuntimeBTF.arrays):
// the points are the nodes of the material's quadtree. The node of a texel comes from a table,
// node = sb_tree[row/s + (H/s)(col/s)] with s = sb_adaptive.y the smallest size, not from
// arithmetic; its class j = sb_points[node].w gives its size p = sb_class[j].x, so i1 = row % p,
// i2 = col % p. The spatial dictionaries are zero-padded to the largest size P = sb_size.z, one
// stride for every node. The cap of a node's channel c is sb_class[j][1 + c], which the page sets
// to max(1, ceil(f tau_node)) for the slider's fraction f (the runtime's per-query tau), and the
// footprint's fraction applies to that cap as above. With sb_adaptive.x == 0 (one patch size)
// none of this runs and the cap is sb_tau.
//
// Texture layout (built by sparsebtf.rendering.viewer.pack_textures): every 1D array of n
// entries lies in a SB_TEX_WIDTH-wide 2D texture, entry i at texel (i % W, i / W).
//   sb_values     R32F     values_Y | values_U | values_V
//   sb_locations  R32UI    packed l1 | l2<<8 | l3<<16 | l4<<24, same order
//   sb_points     RGBA32I  at c*P + p: (first coefficient in sb_values, count, dictionary k,
//                          0; adaptive: the node's class)
//   sb_dicts      R32F     per channel dict1, dict2, dict3, dict4 (K, m, m) C order;
//                          sb_dictBase[c] = their four start offsets
//   sb_stats      R32F     mean (S, L, V), std (S, L, V), bound (L, V); std starts at
//                          sb_stdBase, bound (the clamp on ln(RGB + eps)) at sb_boundBase
//   sb_dirs       RGBA32F  lights (xyz) then views
//   sb_neigh      R32I     optional candidate tables (64 elevation x 256 azimuth x 8), lights
//                          then views (runtime.angular.neighbour_table)
//   sb_tree       R32I     adaptive only: the node of each cell of the smallest size's grid
//   sb_hlOffsets  R32UI    highlight store only (sb_highlights == 1): point p's entries are
//                          [sb_hlOffsets[p], sb_hlOffsets[p + 1]) (P + 1 values)
//   sb_hlKeys     R32UI    node keys ((i1 P + i2) L + light) V + view, increasing per point
//   sb_hlRgb      RGB16F   the linear-RGB correction of each entry (binary16)
//   sb_hlLobes    RGBA16F  lobes only (sb_lobes == 1): lobe r = point P^2 + i1 P + i2 at texels
//                          2r = (w_x, w_y, w_z, ln ax), 2r + 1 = (ln ay, A_r, A_g, A_b)
//
// Highlight store (sparsebtf.learning.highlights): with sb_highlights == 1 the value is
// max(rgb + sum_ab wl_a wv_b c(p, key(i1, i2, L_a, V_b)), 0), c = 0 at nodes without an entry,
// with the same neighbours and weights as the coefficients; with 0 (the default) rgb as is.
// With sb_lobes == 1 (sparsebtf.learning.lobes) the texel's lobe at the query's own wi, wo is
// added too, before the clamp: A D(h) / max(n.wo, SB_NV_FLOOR) where n.wi > 0 and n.wo > 0.

#define SB_TEX_WIDTH 4096
#define SB_TEX_SHIFT 12
#define SB_MAX_NN 4
#define SB_NEIGH_ELEV 64
#define SB_NEIGH_PHI 256
#define SB_NEIGH_K 8
#define SB_MAX_CLASSES 16
#define SB_HL_STEPS 32
#define SB_NV_FLOOR 0.05
#define SB_PI 3.14159265358979
#define SB_ROT_TERMS 11

#define SB_NEAREST 0
#define SB_LINEAR 1
#define SB_BARYCENTRIC 2
#define SB_GAUSSIAN 3

uniform sampler2D sb_values;
uniform usampler2D sb_locations;
uniform isampler2D sb_points;
uniform sampler2D sb_dicts;
uniform sampler2D sb_stats;
uniform sampler2D sb_dirs;
uniform isampler2D sb_neigh;
uniform isampler2D sb_tree;
uniform usampler2D sb_hlOffsets;
uniform usampler2D sb_hlKeys;
uniform sampler2D sb_hlRgb;
uniform sampler2D sb_hlLobes;

uniform ivec4 sb_size;        // H, W, patch P, n_rb = H / P
uniform ivec4 sb_counts;      // n_points, n_lights, n_views, S (1 shared or 3 per-channel stats)
uniform ivec4 sb_dictBase[3]; // start of dict1..dict4 of channel Y, U, V in sb_dicts
uniform ivec4 sb_dictSize;    // K is per channel, so only m: (P, P, L, V) as stored
uniform int sb_stdBase;       // start of std in sb_stats
uniform int sb_boundBase;     // start of the bound in sb_stats
uniform ivec3 sb_tau;         // run-time level of detail tau' per channel (Y, U, V)
uniform float sb_lodMin;      // least fraction of tau the footprint gives (runtime.lod)
uniform vec3 sb_yuvToRgb[3];  // rows of the YUV -> RGB matrix
uniform float sb_eps;         // log offset
uniform int sb_interp;        // SB_NEAREST .. SB_GAUSSIAN
uniform int sb_knn;           // neighbours of the gaussian scheme (1..SB_MAX_NN)
uniform float sb_beta;        // gaussian sharpness
uniform int sb_domain;        // 0 standardized (Eq. 6), 1 log (release)
uniform int sb_useNeigh;      // 1: rank the 8 candidates of sb_neigh instead of all directions
uniform ivec4 sb_adaptive;    // adaptive patch sizes: (1, smallest size s, H / s, classes); 0: one size
uniform ivec4 sb_class[SB_MAX_CLASSES]; // adaptive: (size p, tau'_Y, tau'_U, tau'_V) per class
uniform int sb_highlights;    // 1: add the highlight store's corrections; 0: no entries
uniform int sb_lobes;         // 1: add the store's per-texel lobes; 0: no lobes

ivec2 sb_coord(int i) {
    return ivec2(i & (SB_TEX_WIDTH - 1), i >> SB_TEX_SHIFT);
}

float sb_f(sampler2D t, int i) {
    return texelFetch(t, sb_coord(i), 0).r;
}

// Insert candidate `i` at squared distance d2 into the ascending list (ties: lower index first,
// provided candidates arrive by increasing index, as in the full scan).
void sb_insert(int i, float d2, inout int idx[SB_MAX_NN], inout float dist[SB_MAX_NN]) {
    if (d2 < dist[SB_MAX_NN - 1] || (d2 == dist[SB_MAX_NN - 1] && i < idx[SB_MAX_NN - 1])) {
        int j = SB_MAX_NN - 1;
        while (j > 0 && (d2 < dist[j - 1] || (d2 == dist[j - 1] && i < idx[j - 1]))) {
            dist[j] = dist[j - 1];
            idx[j] = idx[j - 1];
            j--;
        }
        dist[j] = d2;
        idx[j] = i;
    }
}

// The SB_MAX_NN nearest of the n directions starting at `base` in sb_dirs (table `table`
// of sb_neigh when sb_useNeigh is set): indices relative to base, squared chord distances.
void sb_nearest(vec3 q, int base, int n, int table, out int idx[SB_MAX_NN],
                out float dist[SB_MAX_NN]) {
    for (int j = 0; j < SB_MAX_NN; ++j) {
        idx[j] = 0;
        dist[j] = 1e30;
    }
    if (sb_useNeigh != 0) {
        float el = asin(clamp(q.z, 0.0, 1.0));
        float ph = atan(q.y, q.x);
        int ie = clamp(int(floor(el / 1.5707963267948966 * float(SB_NEIGH_ELEV))), 0,
                       SB_NEIGH_ELEV - 1);
        int ia = clamp(int(floor((ph + 3.141592653589793) / 6.283185307179586 *
                                 float(SB_NEIGH_PHI))), 0, SB_NEIGH_PHI - 1);
        int cell = ((table * SB_NEIGH_ELEV + ie) * SB_NEIGH_PHI + ia) * SB_NEIGH_K;
        for (int j = 0; j < SB_NEIGH_K; ++j) {
            int i = texelFetch(sb_neigh, sb_coord(cell + j), 0).r;
            vec3 d = q - texelFetch(sb_dirs, sb_coord(base + i), 0).xyz;
            sb_insert(i, dot(d, d), idx, dist);
        }
    } else {
        for (int i = 0; i < n; ++i) {
            vec3 d = q - texelFetch(sb_dirs, sb_coord(base + i), 0).xyz;
            sb_insert(i, dot(d, d), idx, dist);
        }
    }
}

void sb_linear(float d0, float d1, out float w[SB_MAX_NN]) {
    w[0] = d1 > 0.0 ? 0.5 + 0.5 * (d1 - d0) / d1 : 0.5;
    w[1] = 1.0 - w[0];
    w[2] = 0.0;
    w[3] = 0.0;
}

// Neighbours and weights of direction q (runtime.angular.angular_weights); returns k.
int sb_weights(vec3 q, int base, int n, int table, out int idx[SB_MAX_NN],
               out float w[SB_MAX_NN]) {
    q = normalize(q);
    float dist[SB_MAX_NN];
    sb_nearest(q, base, n, table, idx, dist);
    for (int j = 0; j < SB_MAX_NN; ++j) w[j] = 0.0;
    if (sb_interp == SB_NEAREST || n < 2) {
        w[0] = 1.0;
        return 1;
    }
    if (sb_interp == SB_LINEAR || (sb_interp == SB_BARYCENTRIC && n < 3)) {
        sb_linear(sqrt(dist[0]), sqrt(dist[1]), w);
        return 2;
    }
    if (sb_interp == SB_BARYCENTRIC) {
        // central (gnomonic) projection of q onto the neighbours' triangle: solve
        // [x0 x1 x2] b = q (Cramer), normalise b to sum 1, clip negatives, renormalise;
        // a degenerate triangle falls back to the 2-NN weights
        vec3 x0 = texelFetch(sb_dirs, sb_coord(base + idx[0]), 0).xyz;
        vec3 x1 = texelFetch(sb_dirs, sb_coord(base + idx[1]), 0).xyz;
        vec3 x2 = texelFetch(sb_dirs, sb_coord(base + idx[2]), 0).xyz;
        vec3 c12 = cross(x1, x2);
        float det = dot(x0, c12);
        bool ok = abs(det) > 1e-9;
        vec3 b = vec3(dot(q, c12), dot(q, cross(x2, x0)), dot(q, cross(x0, x1))) /
                 (ok ? det : 1.0);
        float s = b.x + b.y + b.z;
        ok = ok && s > 0.0;
        vec3 bw = max(b / (ok ? s : 1.0), 0.0);
        float t = bw.x + bw.y + bw.z;
        ok = ok && t > 0.0;
        if (ok) {
            bw /= t;
            w[0] = bw.x;
            w[1] = bw.y;
            w[2] = bw.z;
        } else {
            sb_linear(sqrt(dist[0]), sqrt(dist[1]), w);
        }
        return 3;
    }
    // gaussian: w ~ exp(-beta d^2), shifted by the nearest for range
    int k = clamp(sb_knn, 1, min(n, SB_MAX_NN));
    float s = 0.0;
    for (int j = 0; j < SB_MAX_NN; ++j) {
        if (j >= k) break;
        w[j] = exp(-sb_beta * (dist[j] - dist[0]));
        s += w[j];
    }
    for (int j = 0; j < SB_MAX_NN; ++j) w[j] /= s;
    return k;
}

// Data point (node), in-patch row and column of a texture coordinate (wrapping), and the
// node's class (adaptive; 0 for one patch size).
ivec4 sb_node(vec2 uv) {
    vec2 f = uv - floor(uv);
    int col = min(int(f.x * float(sb_size.y)), sb_size.y - 1);
    int row = min(int(f.y * float(sb_size.x)), sb_size.x - 1);
    if (sb_adaptive.x == 0) {
        int P = sb_size.z;
        return ivec4(row / P + sb_size.w * (col / P), row % P, col % P, 0);
    }
    int s = sb_adaptive.y;
    int node = texelFetch(sb_tree, sb_coord(row / s + sb_adaptive.z * (col / s)), 0).r;
    int cls = texelFetch(sb_points, sb_coord(node), 0).w;
    int p = sb_class[cls].x;
    return ivec4(node, row % p, col % p, cls);
}

// Data point, in-patch row and column of a texture coordinate (wrapping).
ivec3 sb_texel(vec2 uv) {
    return sb_node(uv).xyz;
}

// Per-channel cap of class `cls` (adaptive: the node's, set by the page) or sb_tau.
vec3 sb_cap(int cls) {
    return sb_adaptive.x == 0 ? vec3(sb_tau) : vec3(sb_class[cls].yzw);
}

// Coefficient i: its value times its two spatial dictionary entries (rows b1, b2 already
// offset to the texel), and its angular atom indices l3, l4 (packed l1 | l2<<8 | l3<<16 | l4<<24).
float sb_spatial_term(int i, int b1, int b2, out int l3, out int l4) {
    uint code = texelFetch(sb_locations, sb_coord(i), 0).r;
    int l1 = int(code & 255u), l2 = int((code >> 8) & 255u);
    l3 = int((code >> 16) & 255u);
    l4 = int(code >> 24);
    return sb_f(sb_values, i) * sb_f(sb_dicts, b1 + l1) * sb_f(sb_dicts, b2 + l2);
}

// Log-domain value of channel c at point/in-patch texel t (Eq. 5 summed with Eq. 6 weights)
// at level of detail tau (fractional: the last coefficient weighted by tau - floor(tau)).
float sb_channel(int c, ivec3 t, float tau, int nl, int il[SB_MAX_NN], float wl[SB_MAX_NN],
                 int nv, int iv[SB_MAX_NN], float wv[SB_MAX_NN]) {
    int P = sb_size.z, L = sb_dictSize.z, V = sb_dictSize.w;
    int nL = sb_counts.y, nV = sb_counts.z;
    ivec4 pt = texelFetch(sb_points, sb_coord(c * sb_counts.x + t.x), 0);
    int start = pt.x;
    int count = min(pt.y, int(ceil(tau - 1e-4)));
    int k = pt.z;
    ivec4 db = sb_dictBase[c];
    int b1 = db.x + (k * P + t.y) * P;
    int b2 = db.y + (k * P + t.z) * P;
    int b3[SB_MAX_NN];
    int b4[SB_MAX_NN];
    for (int a = 0; a < SB_MAX_NN; ++a) {
        b3[a] = db.z + (k * L + il[a]) * L;
        b4[a] = db.w + (k * V + iv[a]) * V;
    }
    int sidx = (sb_counts.w == 3 ? c : 0) * nL * nV;
    if (sb_domain == 0) {
        float acc = 0.0;
        for (int s = 0; s < count; ++s) {
            int l3, l4;
            float a = sb_spatial_term(start + s, b1, b2, l3, l4) * min(1.0, tau - float(s));
            float s3 = 0.0, s4 = 0.0;
            for (int j = 0; j < SB_MAX_NN; ++j) {
                if (j >= nl) break;
                s3 += wl[j] * sb_f(sb_dicts, b3[j] + l3);
            }
            for (int j = 0; j < SB_MAX_NN; ++j) {
                if (j >= nv) break;
                s4 += wv[j] * sb_f(sb_dicts, b4[j] + l4);
            }
            acc += a * s3 * s4;
        }
        float mu = 0.0, sd = 0.0;
        for (int a = 0; a < SB_MAX_NN; ++a) {
            if (a >= nl) break;
            for (int b = 0; b < SB_MAX_NN; ++b) {
                if (b >= nv) break;
                int j = sidx + il[a] * nV + iv[b];
                float ww = wl[a] * wv[b];
                mu += ww * sb_f(sb_stats, j);
                sd += ww * sb_f(sb_stats, sb_stdBase + j);
            }
        }
        return acc * sd + mu;
    }
    // log domain: one accumulator per (light, view) neighbour pair
    float x[SB_MAX_NN * SB_MAX_NN];
    for (int j = 0; j < SB_MAX_NN * SB_MAX_NN; ++j) x[j] = 0.0;
    for (int s = 0; s < count; ++s) {
        int l3, l4;
        float a = sb_spatial_term(start + s, b1, b2, l3, l4) * min(1.0, tau - float(s));
        float g4[SB_MAX_NN];
        for (int b = 0; b < SB_MAX_NN; ++b) {
            if (b >= nv) break;
            g4[b] = sb_f(sb_dicts, b4[b] + l4);
        }
        for (int ja = 0; ja < SB_MAX_NN; ++ja) {
            if (ja >= nl) break;
            float g = a * sb_f(sb_dicts, b3[ja] + l3);
            for (int jb = 0; jb < SB_MAX_NN; ++jb) {
                if (jb >= nv) break;
                x[ja * SB_MAX_NN + jb] += g * g4[jb];
            }
        }
    }
    float lg = 0.0;
    for (int a = 0; a < SB_MAX_NN; ++a) {
        if (a >= nl) break;
        for (int b = 0; b < SB_MAX_NN; ++b) {
            if (b >= nv) break;
            int j = sidx + il[a] * nV + iv[b];
            lg += wl[a] * wv[b] *
                  (sb_f(sb_stats, sb_stdBase + j) * x[a * SB_MAX_NN + b] + sb_f(sb_stats, j));
        }
    }
    return lg;
}

// Entry of node `key` among the sorted keys [lo, hi) of sb_hlKeys, or -1. A lower-bound binary
// search; SB_HL_STEPS halvings cover any range of 2^32 entries, so the loop bound never cuts it.
int sb_hl_find(uint key, int lo, int hi) {
    int end = hi;
    for (int s = 0; s < SB_HL_STEPS; ++s) {
        if (lo >= hi) break;
        int mid = lo + ((hi - lo) >> 1);
        if (texelFetch(sb_hlKeys, sb_coord(mid), 0).r < key) {
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    return lo < end && texelFetch(sb_hlKeys, sb_coord(lo), 0).r == key ? lo : -1;
}

// The interpolated correction sum_ab wl_a wv_b c(p, key(i1, i2, L_a, V_b)) at point/in-patch
// texel t (sparsebtf.learning.highlights.correction): one search per neighbour pair, none at
// a point without entries.
vec3 sb_highlight(ivec3 t, int nl, int il[SB_MAX_NN], float wl[SB_MAX_NN], int nv,
                  int iv[SB_MAX_NN], float wv[SB_MAX_NN]) {
    int lo = int(texelFetch(sb_hlOffsets, sb_coord(t.x), 0).r);
    int hi = int(texelFetch(sb_hlOffsets, sb_coord(t.x + 1), 0).r);
    vec3 c = vec3(0.0);
    if (lo >= hi) return c;
    // uint: keys reach 2^32 - 1 (P^2 L V nodes), beyond int
    uint nL = uint(sb_counts.y), nV = uint(sb_counts.z);
    uint texel = uint(t.y * sb_size.z + t.z);
    for (int a = 0; a < SB_MAX_NN; ++a) {
        if (a >= nl) break;
        uint kl = (texel * nL + uint(il[a])) * nV;
        for (int b = 0; b < SB_MAX_NN; ++b) {
            if (b >= nv) break;
            int j = sb_hl_find(kl + uint(iv[b]), lo, hi);
            if (j >= 0) c += wl[a] * wv[b] * texelFetch(sb_hlRgb, sb_coord(j), 0).rgb;
        }
    }
    return c;
}

// The lobe of point/in-patch texel t at light wi and view wo (any length; sparsebtf.learning.
// lobes.lobe_values). The frame (t, b, n) = R(w) e is never built: a vector's components in it
// are R^T v = v - a (w x v) + b w x (w x v), Rodrigues' rotation by -w.
vec3 sb_lobe(ivec3 t, vec3 wi, vec3 wo) {
    int r = 2 * ((t.x * sb_size.z + t.y) * sb_size.z + t.z);
    vec4 p0 = texelFetch(sb_hlLobes, sb_coord(r), 0);
    vec4 p1 = texelFetch(sb_hlLobes, sb_coord(r + 1), 0);
    vec3 w = p0.xyz;  // rotation vector
    float th2 = dot(w, w);
    if (th2 > SB_PI * SB_PI) {  // the same rotation by an angle in [-pi, pi]: the series below
        float th = sqrt(th2);
        float tw = mod(th + SB_PI, 2.0 * SB_PI) - SB_PI;
        w *= tw / th;
        th2 = tw * tw;
    }
    // a = sin th / th, b = (1 - cos th) / th^2 by their Taylor series (SB_ROT_TERMS terms leave
    // < 1e-11 at th = pi): GPUs' sin and cos are not float32-accurate (GLSL ES leaves their
    // precision open; headless Chromium's errs by about 1e-5), and a sharp lobe's flank
    // amplifies that into relative errors of 1e-4 and more; the series is float32-accurate, and
    // near 0 it is lobe_frame's 1 - th^2/6, 0.5 - th^2/24.
    float a = 0.0, b = 0.0;
    float ta = 1.0, tb = 0.5;
    for (int k = 0; k < SB_ROT_TERMS; ++k) {
        a += ta;
        b += tb;
        ta *= -th2 / float((2 * k + 2) * (2 * k + 3));
        tb *= -th2 / float((2 * k + 3) * (2 * k + 4));
    }
    vec3 l = normalize(wi), v = normalize(wo);
    vec3 hv = l + v;
    hv /= max(length(hv), 1e-12);
    vec3 cl = cross(w, l), cv = cross(w, v), ch = cross(w, hv);
    float nl = l.z - a * cl.z + b * cross(w, cl).z;
    float nv = v.z - a * cv.z + b * cross(w, cv).z;
    if (nl <= 0.0 || nv <= 0.0) return vec3(0.0);
    vec3 h = hv - a * ch + b * cross(w, ch);  // (h.t, h.b, h.n)
    vec2 al = exp(vec2(p0.w, p1.x));
    vec2 hs = h.xy / al;
    float q = dot(hs, hs) + h.z * h.z;
    float d = 1.0 / (SB_PI * al.x * al.y * q * q);
    return p1.yzw * (d / max(nv, SB_NV_FLOOR));
}

// Texels per pixel side from the screen-space derivatives dx = dFdx(uv), dy = dFdy(uv) (the
// caller removes the jumps of its parametrisation's seams): sqrt(|det J|) of the Jacobian of
// the texel coordinates, the side of a square of the pixel's footprint area.
float sb_texels_per_pixel(vec2 dx, vec2 dy) {
    vec2 size = vec2(float(sb_size.y), float(sb_size.x));  // (W, H): u along columns
    dx *= size;
    dy *= size;
    return sqrt(abs(dx.x * dy.y - dx.y * dy.x));
}

// Fraction of tau for a footprint of rho texels per pixel side (runtime.lod.footprint_fraction).
float sb_footprint_fraction(float rho) {
    float r = max(rho, 1.0);
    return clamp(1.0 / (r * r), sb_lodMin, 1.0);
}

// Per-channel tau' of a fraction f of the cap sb_tau (runtime.lod.lod_tau).
vec3 sb_lod_tau(float f) {
    vec3 t = vec3(sb_tau);
    return max(f * t, min(vec3(1.0), t));
}

// Linear RGB of the BTF at point/in-patch texel t (sb_texel) for light wi and view wo, both in
// the local frame (z = normal, x = +u / texture columns, y = +v / texture rows), at level of
// detail tau (Y, U, V; fractional). Eq. 5 at sampled directions, Eq. 6 between them. Masking
// below the horizon is the caller's business.
vec3 sb_evaluate_at(ivec3 t, vec3 wi, vec3 wo, vec3 tau) {
    int il[SB_MAX_NN], iv[SB_MAX_NN];
    float wl[SB_MAX_NN], wv[SB_MAX_NN];
    int nl = sb_weights(wi, 0, sb_counts.y, 0, il, wl);
    int nv = sb_weights(wo, sb_counts.y, sb_counts.z, 1, iv, wv);
    vec3 lg = vec3(sb_channel(0, t, tau.x, nl, il, wl, nv, iv, wv),
                   sb_channel(1, t, tau.y, nl, il, wl, nv, iv, wv),
                   sb_channel(2, t, tau.z, nl, il, wl, nv, iv, wv));
    vec3 ln = vec3(dot(sb_yuvToRgb[0], lg), dot(sb_yuvToRgb[1], lg), dot(sb_yuvToRgb[2], lg));
    // The material's bound on ln(RGB + eps), interpolated like the statistics.
    float bound = 0.0;
    for (int a = 0; a < SB_MAX_NN; ++a) {
        if (a >= nl) break;
        for (int b = 0; b < SB_MAX_NN; ++b) {
            if (b >= nv) break;
            bound += wl[a] * wv[b] * sb_f(sb_stats, sb_boundBase + il[a] * sb_counts.z + iv[b]);
        }
    }
    vec3 rgb = exp(min(ln, vec3(bound))) - sb_eps;
    if (sb_highlights == 0 && sb_lobes == 0) return rgb;  // no store: the decode as is, no clamp
    vec3 c = vec3(0.0);
    if (sb_highlights != 0) c += sb_highlight(t, nl, il, wl, nv, iv, wv);
    if (sb_lobes != 0) c += sb_lobe(t, wi, wo);
    return max(rgb + c, 0.0);
}

// The same at texture coordinate uv (wrapping), tau the same for every point.
vec3 sb_evaluate_tau(vec2 uv, vec3 wi, vec3 wo, vec3 tau) {
    return sb_evaluate_at(sb_texel(uv), wi, wo, tau);
}

// The same at a fraction f of the point's cap (sb_lod_tau of its cap; runtime.lod.lod_tau).
vec3 sb_evaluate_lod(vec2 uv, vec3 wi, vec3 wo, float f) {
    ivec4 t = sb_node(uv);
    vec3 cap = sb_cap(t.w);
    return sb_evaluate_at(t.xyz, wi, wo, max(f * cap, min(vec3(1.0), cap)));
}

// The same at the cap (sb_tau, or the node's for adaptive patch sizes).
vec3 sb_evaluate(vec2 uv, vec3 wi, vec3 wo) {
    return sb_evaluate_lod(uv, wi, wo, 1.0);
}
