// Scene of the SparseBTF WebGL2 viewer: a ray-cast sphere or plane on a full-screen triangle,
// shaded with sb_evaluate (sparsebtf_lookup.glsl, prepended unless SB_TRIVIAL is defined).
//
// World: z up. Sphere: unit radius at the origin, u = azimuth / 2pi, v = (pi - theta) / pi,
// tangent x = dp/du, bitangent y = n x t (= dp/dv direction), so the local frame is the BTF's
// (z = normal, azimuth from +u toward +v). Plane: z = 0, |x|, |y| <= 1.5, x = +u, y = +v.
// Test scene (u_scene == 2): the whole viewport is the texture, uv = gl_FragCoord.xy / size
// · u_testZoom (v grows upward: readPixels row j has v = (j + 0.5) / height · zoom), with fixed
// local wi and wo; u_testRamp = 1 sets tau' per fragment to the fraction (x + 0.5) / width of
// the cap. Level of detail (u_footprint = 1): tau' per fragment from its footprint (the
// fraction sb_footprint_fraction of sb_texels_per_pixel of the uv derivatives), else the cap
// (sb_tau, or a node's for adaptive patch sizes; sb_evaluate_lod applies the fraction to it).

uniform vec2 u_resolution;
uniform int u_scene;          // 0 sphere, 1 plane, 2 test plane
uniform vec3 u_camPos;
uniform vec3 u_camRight;
uniform vec3 u_camUp;
uniform vec3 u_camFwd;
uniform float u_tanHalfFov;
uniform vec3 u_lightDir;      // world direction towards the (distant) light, unit
uniform float u_uvRepeat;     // texture repeats across the object
uniform float u_exposure;
uniform int u_linearOut;      // 1: raw linear RGB for a float framebuffer, 0: display sRGB
uniform vec3 u_testWi;
uniform vec3 u_testWo;
uniform float u_testZoom;     // test scene: uv per viewport (1: the texture once)
uniform int u_testRamp;       // test scene: 1 = tau' fraction (x + 0.5) / width per fragment
uniform int u_footprint;      // 1: tau' per fragment by its screen-space footprint

out vec4 fragColor;

#ifdef SB_TRIVIAL
// The benchmark's reference: same geometry and frames, a checker albedo instead of the lookup.
float footprint(vec2 uv, float period) {
    return 0.0;
}

vec3 shade(vec2 uv, vec3 wi, vec3 wo, float rho) {
    vec2 c = floor(fract(uv) * 8.0);
    float a = mod(c.x + c.y, 2.0) < 0.5 ? 0.7 : 0.3;
    return vec3(a, 0.8 * a, 0.6 * a) * max(wi.z, 0.0) * (0.5 + 0.5 * wo.z);
}
#else
// Texels per pixel side at uv (0 when the footprint is off); u jumps by `period` at a seam
// (0: none), removed from the derivative. Call in uniform control flow (derivatives).
float footprint(vec2 uv, float period) {
    vec2 dx = dFdx(uv), dy = dFdy(uv);
    if (period > 0.0) {
        dx.x -= period * round(dx.x / period);
        dy.x -= period * round(dy.x / period);
    }
    return u_footprint == 1 ? sb_texels_per_pixel(dx, dy) : 0.0;
}

vec3 shade(vec2 uv, vec3 wi, vec3 wo, float rho) {
    return sb_evaluate_lod(uv, wi, wo, sb_footprint_fraction(rho));
}
#endif

// Ray hit: uv and local frame (columns tangent, bitangent, normal).
bool hit(vec3 ro, vec3 rd, out vec2 uv, out mat3 frame) {
    const float PI = 3.141592653589793;
    if (u_scene == 0) {
        float b = dot(ro, rd);
        float c = dot(ro, ro) - 1.0;
        float disc = b * b - c;
        if (disc < 0.0) return false;
        float t = -b - sqrt(disc);
        if (t <= 0.0) return false;
        vec3 p = normalize(ro + t * rd);
        float phi = atan(p.y, p.x);
        float theta = acos(clamp(p.z, -1.0, 1.0));
        uv = vec2((phi / (2.0 * PI) + 0.5) * 2.0, (PI - theta) / PI) * u_uvRepeat;
        vec3 tg = vec3(-p.y, p.x, 0.0);
        tg = dot(tg, tg) > 1e-12 ? normalize(tg) : vec3(1.0, 0.0, 0.0);
        frame = mat3(tg, cross(p, tg), p);
        return true;
    }
    if (abs(rd.z) < 1e-8) return false;
    float t = -ro.z / rd.z;
    if (t <= 0.0) return false;
    vec3 p = ro + t * rd;
    if (abs(p.x) > 1.5 || abs(p.y) > 1.5) return false;
    uv = (p.xy + 1.5) / 3.0 * u_uvRepeat;
    frame = mat3(vec3(1.0, 0.0, 0.0), vec3(0.0, 1.0, 0.0), vec3(0.0, 0.0, 1.0));
    return true;
}

void main() {
    if (u_scene == 2) {
        vec2 uv = gl_FragCoord.xy / u_resolution * u_testZoom;
        float rho = footprint(uv, 0.0);
#ifndef SB_TRIVIAL
        if (u_testRamp == 1) {
            float f = gl_FragCoord.x / u_resolution.x;
            fragColor = vec4(sb_evaluate_lod(uv, u_testWi, u_testWo, f), 1.0);
            return;
        }
#endif
        fragColor = vec4(shade(uv, u_testWi, u_testWo, rho), 1.0);
        return;
    }
    vec2 ndc = (2.0 * gl_FragCoord.xy - u_resolution) / u_resolution.y;
    vec3 rd = normalize(u_camFwd + u_tanHalfFov * (ndc.x * u_camRight + ndc.y * u_camUp));
    vec2 uv = vec2(0.0);
    mat3 frame;
    vec3 rgb = vec3(0.06, 0.065, 0.075);
    bool onObject = hit(u_camPos, rd, uv, frame);
    // derivatives need uniform control flow: before the branch; the sphere's u wraps by 2·repeat
    float rho = footprint(uv, u_scene == 0 ? 2.0 * u_uvRepeat : 0.0);
    if (onObject) {
        mat3 toLocal = transpose(frame);
        vec3 wi = toLocal * u_lightDir;
        vec3 wo = toLocal * (-rd);
        if (wi.z > 0.0 && wo.z > 0.0) {
            rgb = u_exposure * shade(uv, wi, wo, rho);
        } else {
            rgb = vec3(0.0);
        }
    }
    if (u_linearOut == 1) {
        fragColor = vec4(rgb, 1.0);
    } else {
        vec3 c = clamp(rgb, 0.0, 1.0);
        vec3 srgb = mix(12.92 * c, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(0.0031308, c));
        fragColor = vec4(srgb, 1.0);
    }
}
