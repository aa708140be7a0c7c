"""GLSL (``#version 330 core``) of the GL renderer's passes; see :mod:`gicore.gl.renderer`.

The scene program is one source compiled per pass with ``#define``s: ``PASS_GBUFFER`` (albedo, view
normal, world position, view depth), ``PASS_DI`` (direct light with shadows), ``PASS_UV`` (the structure-
aware warp's interpolated coordinates, position and a surface code) and ``PASS_DEPTH`` (view depth). Each
output holds one buffer in its leading components, so it reads back as it is (no channel split). The
light (point or area, and its K x K sample points), the shadow layout (fitted frustum or cube faces) and the
number of materials are compiled in too: llvmpipe runs a loop with a constant bound 18 % faster.

The materials' tables are a uniform array of vec4 (:data:`MATERIAL_VEC4S` per material, indexed per pixel:
on llvmpipe 7 % faster than ``texelFetch`` from a texture for the whole DI + G-buffer pass, same values);
the shadow map is read with ``texelFetch`` and a depth-comparison sampler with bilinear filtering (no
float filtering, no ``textureGather``): all of it exists in GLSL ES 3.0, so the code ports to WebGL2 by
changing the version line and adding precision qualifiers.
"""

from __future__ import annotations

import numpy as np

#: Vertex attribute ``in_mat.w`` (the material row) of a diffuse surface and of the area light's quad.
DIFFUSE_ROW, EMITTER_ROW = -1, -2
#: Largest PCF / blocker-search radius in shadow-map texels, and the PCF taps of an area light.
MAX_RADIUS = 48.0
PCF_TAPS = 32
#: vec4s per material row of the tables (64 transmittance entries, alpha, 1 / (1 - internal), 2 unused).
MATERIAL_VEC4S = 17


def mat_bytes(m: np.ndarray) -> bytes:
    """A 4x4 row-major numpy matrix as the column-major float32 bytes of a GLSL ``mat4`` uniform."""
    return np.ascontiguousarray(np.asarray(m, dtype=np.float64).T, dtype=np.float32).tobytes()


SCENE_VERTEX = """
#version 330 core
uniform mat4 u_view_proj;
uniform mat4 u_uv_proj;
uniform bool u_project_uv;
in vec3 in_pos;
in vec3 in_nrm;
in vec4 in_mat;
in vec2 in_uv;
out vec3 v_pos;
out vec3 v_nrm;
out vec2 v_uv;
flat out vec4 v_mat;
void main() {
    v_pos = in_pos;
    v_nrm = in_nrm;
    v_mat = in_mat;
    v_uv = u_project_uv ? (u_uv_proj * vec4(in_pos, 1.0)).xy : in_uv;
    gl_Position = u_view_proj * vec4(in_pos, 1.0);
}
"""

# The DI functions: Mitsuba's roughplastic / diffuse BSDF times cos (gicore.gl.brdf), a point light or a
# square area light facing down, and a shadow-map lookup with PCF (PCSS for an area light).
_DI_FUNCTIONS = """
const float PI = 3.14159265358979;
uniform vec3 u_light;
uniform float u_intensity;     // per light sample point: I (point) or I / K^2 (area light, K x K points)
uniform float u_radiance;      // the area light's radiance, seen on its emitting side
uniform float u_light_size;    // side of the area light; 0 for a point light
uniform float u_eta;
uniform vec4 u_materials[MATERIAL_ROWS * MATERIAL_VEC4S];  // row r: transmittance table [0, 64), alpha at 64,
                                                          // 1 / (1 - internal) at 65
uniform sampler2DShadow u_shadow;  // atlas of light distance / u_shadow_far, one tile per view (1: nothing)
uniform sampler2D u_shadow_raw;    // the same texture read without comparison (PCSS blocker search)
uniform float u_shadow_far;
uniform mat4 u_shadow_vp[6];     // one frustum fitted around the casters, or cube faces (+x -x +y -y +z -z)
uniform float u_shadow_texel[6];  // tangent-plane size of one texel at the tile's centre
uniform int u_shadow_size;     // texels per tile side
uniform float u_blocker_min;   // nearest distance a blocker can have from the light

float mat_texel(int row, int i) { return u_materials[row * MATERIAL_VEC4S + (i >> 2)][i & 3]; }

float transmittance(int row, float c) {
    float x = c * 63.0;
    int i = min(int(x), 62);
    return mix(mat_texel(row, i), mat_texel(row, i + 1), x - float(i));
}

float fresnel(float cos_i, float eta) {
    float eta_it = cos_i >= 0.0 ? eta : 1.0 / eta;
    float eta_ti = 1.0 / eta_it;
    float ct2 = 1.0 - eta_ti * eta_ti * (1.0 - cos_i * cos_i);
    float ci = abs(cos_i), ct = sqrt(max(ct2, 0.0));
    if (ci == 0.0) return 1.0;
    float a_s = (ci - eta_it * ct) / (ci + eta_it * ct);
    float a_p = (ct - eta_it * ci) / (ct + eta_it * ci);
    return 0.5 * (a_s * a_s + a_p * a_p);
}

float smith_g1(float vz, float vm, float a2) {
    if (vm * vz <= 0.0) return 0.0;
    float xy = a2 * max(1.0 - vz * vz, 0.0);
    return xy == 0.0 ? 1.0 : 2.0 / (1.0 + sqrt(1.0 + xy / (vz * vz)));
}

vec3 bsdf_cos(vec3 albedo, int row, vec3 n, vec3 wi, vec3 wo, float ci, float co) {
    if (row < 0) return albedo * (co / PI);
    float alpha = mat_texel(row, 64);
    float a2 = alpha * alpha;
    vec3 h = normalize(wi + wo);
    float hn = dot(h, n);
    float q = (1.0 - hn * hn) / a2 + hn * hn;
    float d = 1.0 / (PI * a2 * q * q);
    if (d * hn <= 1e-20) d = 0.0;
    float spec = fresnel(dot(wi, h), u_eta) * d * smith_g1(ci, dot(wi, h), a2) * smith_g1(co, dot(wo, h), a2);
    float t = transmittance(row, ci) * transmittance(row, co);
    return vec3(spec / (4.0 * ci)) + albedo * (mat_texel(row, 65) * t * co / (PI * u_eta * u_eta));
}

vec2 disc(int k, int n, float turn) {
    float r = sqrt((float(k) + 0.5) / float(n));
    float a = float(k) * 2.39996323 + turn;
    return r * vec2(cos(a), sin(a));
}

float pcf_tap(vec2 st, ivec2 tile, float ref) {  // the sampler's bilinearly weighted comparison of 4 texels
    vec2 uv = (vec2(tile) + clamp(st, vec2(0.5), vec2(float(u_shadow_size) - 0.5))) / vec2(textureSize(u_shadow, 0));
    return texture(u_shadow, vec3(uv, ref / u_shadow_far));
}

float visibility(vec3 p, vec3 n) {
    vec3 d = p - u_light;
#ifdef CUBE_SHADOW
    vec3 a = abs(d);
    int face;
    if (a.x >= a.y && a.x >= a.z) face = d.x > 0.0 ? 0 : 1;
    else face = a.y >= a.z ? (d.y > 0.0 ? 2 : 3) : (d.z > 0.0 ? 4 : 5);
#else
    const int face = 0;
#endif
    float r = length(d);
    float tan_texel = u_shadow_texel[face];
    float texel = tan_texel * r;  // world size of one texel at the receiver
    vec3 q = p + n * (1.5 * texel);          // normal offset (n faces the light here)
    vec4 c = u_shadow_vp[face] * vec4(q, 1.0);
    if (c.w <= 0.0) return 1.0;
    vec2 ndc = c.xy / c.w;
#ifndef CUBE_SHADOW
    if (abs(ndc.x) > 1.0 || abs(ndc.y) > 1.0) return 1.0;  // no caster outside the fitted frustum
#endif
    vec2 st = (ndc * 0.5 + 0.5) * float(u_shadow_size);
    ivec2 tile = ivec2(face % 3, face / 3) * u_shadow_size;
    float rq = length(q - u_light);
    float cos_l = clamp(dot(n, -d) / r, 0.05, 1.0);
    float slope = min(sqrt(1.0 - cos_l * cos_l) / cos_l, 4.0);
#ifdef AREA_LIGHT
    // PCSS: blocker search, then a penumbra sized by the light (taps turned per pixel against banding)
    float turn = 6.2831853 * fract(52.9829189 * fract(dot(gl_FragCoord.xy, vec2(0.06711056, 0.00583715))));
    float search = 0.5 * u_light_size * (rq - u_blocker_min) / (rq * u_blocker_min) / tan_texel;
    search = clamp(search, 1.0, MAX_RADIUS);
    float ref = rq - texel * (1.0 + search * slope);
    float sum = 0.0, count = 0.0;
    for (int k = 0; k < 16; ++k) {
        ivec2 t = clamp(ivec2(floor(st + disc(k, 16, turn) * search)), ivec2(0), ivec2(u_shadow_size - 1));
        float b = texelFetch(u_shadow_raw, tile + t, 0).r * u_shadow_far;
        if (b < ref) { sum += b; count += 1.0; }
    }
    if (count == 0.0) return 1.0;
    float b = sum / count;
    float radius = clamp(0.5 * u_light_size * (rq - b) / (rq * b) / tan_texel, 1.0, MAX_RADIUS);
    ref = rq - texel * (1.0 + radius * slope);
    float lit = 0.0;
    for (int k = 0; k < PCF_TAPS; ++k) lit += pcf_tap(st + disc(k, PCF_TAPS, turn) * radius, tile, ref);
    return lit / float(PCF_TAPS);
#else
    // point light: four bilinear taps, a tent over 3 x 3 texels
    float ref = rq - texel * (1.0 + slope);
    return 0.25 * (pcf_tap(st + vec2(-0.5, -0.5), tile, ref) + pcf_tap(st + vec2(0.5, -0.5), tile, ref)
                 + pcf_tap(st + vec2(-0.5, 0.5), tile, ref) + pcf_tap(st + vec2(0.5, 0.5), tile, ref));
#endif
}

vec3 direct(vec3 p, vec3 albedo, int row, vec3 n, vec3 wi) {
    float ci = dot(n, wi);
    if (ci <= 0.0) return vec3(0.0);
    vec3 sum = vec3(0.0);
    const int k = LIGHT_SAMPLES;  // compiled in: a uniform loop bound costs 18 % of the DI + G-buffer pass
    for (int a = 0; a < k; ++a) {
        for (int b = 0; b < k; ++b) {
            vec2 o = (vec2(float(a), float(b)) + 0.5) / float(k) - 0.5;
            vec3 l = u_light + vec3(o.x, 0.0, o.y) * u_light_size;
            vec3 d = l - p;
            float dist2 = dot(d, d);
            vec3 wo = d * inversesqrt(dist2);
            float co = dot(n, wo);
            float ce = u_light_size > 0.0 ? wo.y : 1.0;  // the quad emits downwards
            if (co > 0.0 && ce > 0.0) sum += bsdf_cos(albedo, row, n, wi, wo, ci, co) * (ce / dist2);
        }
    }
    if (sum == vec3(0.0)) return sum;
    return sum * u_intensity * visibility(p, n);
}
"""

SCENE_FRAGMENT = (
    """
#version 330 core
uniform mat4 u_view;
uniform vec3 u_eye;
in vec3 v_pos;
in vec3 v_nrm;
in vec2 v_uv;
flat in vec4 v_mat;  // albedo, material row
#ifdef PASS_GBUFFER
layout(location = 0) out vec4 o_albedo;    // albedo
layout(location = 1) out vec4 o_normal;    // view-space normal
layout(location = 2) out vec4 o_position;  // world position
layout(location = 3) out vec4 o_depth;     // linear view depth (> 0 on every surface: the mask)
#endif
#ifdef PASS_DI
layout(location = DI_LOCATION) out vec4 o_di;
"""
    + _DI_FUNCTIONS
    + f"""
#endif
#ifdef PASS_UV
layout(location = 0) out vec4 o_uv;        // interpolated coordinates
layout(location = 1) out vec4 o_position;
layout(location = 2) out vec4 o_code;      // 0 background, 1 an untextured surface (the light's quad), 2 textured
#endif
#ifdef PASS_DEPTH
layout(location = 0) out vec4 o_depth;     // linear view depth
#endif
void main() {{
    vec3 n = normalize(v_nrm);
    int row = int(v_mat.w);
    float depth = -(u_view * vec4(v_pos, 1.0)).z;
#ifdef PASS_GBUFFER
    o_albedo = vec4(v_mat.rgb, 1.0);
    o_normal = vec4(mat3(u_view) * n, 0.0);
    o_position = vec4(v_pos, 1.0);
    o_depth = vec4(depth);
#endif
#ifdef PASS_DI
    vec3 wi = normalize(u_eye - v_pos);
    vec3 di = row == {EMITTER_ROW} ? vec3(dot(n, wi) > 0.0 ? u_radiance : 0.0) : direct(v_pos, v_mat.rgb, row, n, wi);
    o_di = vec4(di, 1.0);
#endif
#ifdef PASS_UV
    bool textured = row != {EMITTER_ROW};
    o_uv = vec4(textured ? v_uv : vec2(0.0), 0.0, 0.0);
    o_position = vec4(v_pos, 1.0);
    o_code = vec4(textured ? 2.0 : 1.0);
#endif
#ifdef PASS_DEPTH
    o_depth = vec4(depth);
#endif
}}
"""
)

SHADOW_VERTEX = """
#version 330 core
uniform mat4 u_vp;
in vec3 in_pos;
out vec3 v_pos;
void main() {
    v_pos = in_pos;
    gl_Position = u_vp * vec4(in_pos, 1.0);
}
"""

SHADOW_FRAGMENT = """
#version 330 core
uniform vec3 u_light;
uniform float u_far;
in vec3 v_pos;
void main() { gl_FragDepth = length(v_pos - u_light) / u_far; }
"""


def scene_fragment(
    *passes: str,
    di_location: int = 0,
    area_light: bool = False,
    cube_shadow: bool = False,
    material_rows: int = 1,
    light_samples: int = 1,
) -> str:
    """The scene fragment shader for ``passes`` (``GBUFFER``, ``DI``, ``UV``, ``DEPTH``), for a point or an
    area light sampled at ``light_samples`` x ``light_samples`` points, a fitted or a cube-face shadow map and
    ``material_rows`` materials (compiled in: no per-pixel branch or loop bound on them)."""
    head, rest = SCENE_FRAGMENT.lstrip().split("\n", 1)
    defines = [f"#define PASS_{p}" for p in passes] + [f"#define DI_LOCATION {di_location}"]
    defines += [f"#define MAX_RADIUS {MAX_RADIUS:.1f}", f"#define PCF_TAPS {PCF_TAPS}"]
    defines += [f"#define MATERIAL_ROWS {max(1, int(material_rows))}", f"#define MATERIAL_VEC4S {MATERIAL_VEC4S}"]
    defines += [f"#define LIGHT_SAMPLES {max(1, int(light_samples))}"]
    defines += ["#define AREA_LIGHT"] * area_light + ["#define CUBE_SHADOW"] * cube_shadow
    return "\n".join([head, *defines, rest])
