#version 330 core
// The page's port of gigan_local.preprocess.output_to_radiance: the generator's output planes (stacked, in
// [-1, 1], image rows) to the GI map's linear radiance and its indirect light max(radiance - DI, 0) (GIMap's),
// both with image rows, as the structure-aware warp reads a map; a demodulated model's output times the divisor of
// the GI camera's albedo. The GI camera's DI and albedo have GL's rows.
uniform sampler2D u_y;   // n x 3n: the three output planes
uniform sampler2D u_di;  // the GI camera's DI (GL rows: row 0 at the bottom)
uniform sampler2D u_albedo;  // its albedo (GL rows)
layout(location = 0) out vec4 o_radiance;
layout(location = 1) out vec4 o_indirect;
#include "tonemap.glsl"
// gigan_local.preprocess.albedo_divisor: what a demodulated model's radiance is divided by (ALBEDO_FLOOR defined)
#ifdef ALBEDO_FLOOR
vec3 divisor(vec3 a) {
    a = clamp(a, 0.0, 1.0);
    return max(a.r, max(a.g, a.b)) > 0.0 ? max(a, vec3(ALBEDO_FLOOR)) : vec3(1.0);
}
#else
vec3 divisor(vec3 a) { return vec3(1.0); }
#endif
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    int n = textureSize(u_y, 0).x;
    vec3 y = vec3(texelFetch(u_y, p, 0).r, texelFetch(u_y, ivec2(p.x, n + p.y), 0).r,
                  texelFetch(u_y, ivec2(p.x, 2 * n + p.y), 0).r);
    ivec2 flipped = ivec2(p.x, n - 1 - p.y);
    vec3 radiance = inverse_tonemap(clamp((y + 1.0) * 0.5, 0.0, 1.0)) * divisor(texelFetch(u_albedo, flipped, 0).rgb);
    vec3 di = texelFetch(u_di, flipped, 0).rgb;
    o_radiance = vec4(radiance, 1.0);
    o_indirect = vec4(max(radiance - di, 0.0), 1.0);
}
