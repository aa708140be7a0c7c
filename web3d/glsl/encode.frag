#version 330 core
// The page's port of gigan_local.preprocess.frame_to_input: the network input's channels from the GI camera's
// DI and G-buffers, four per target (TARGETS targets; WRITES, made by web3d.shaders from the model's buffers,
// assigns o0.. from the encoded buffers e_NAME).
uniform sampler2D u_di;
uniform sampler2D u_albedo;
uniform sampler2D u_normal;
uniform sampler2D u_depth;
uniform float u_depth_scale;
layout(location = 0) out vec4 o0;
#if TARGETS > 1
layout(location = 1) out vec4 o1;
#endif
#if TARGETS > 2
layout(location = 2) out vec4 o2;
#endif
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
    float d = max(texelFetch(u_depth, p, 0).r, 0.0);
    vec3 e_di = 2.0 * tonemap(texelFetch(u_di, p, 0).rgb / divisor(texelFetch(u_albedo, p, 0).rgb)) - 1.0;
    vec3 e_albedo = 2.0 * clamp(texelFetch(u_albedo, p, 0).rgb, 0.0, 1.0) - 1.0;
    vec3 e_normal = texelFetch(u_normal, p, 0).rgb;
    vec3 e_depth = vec3(2.0 * (d / (d + u_depth_scale)) - 1.0);
    vec3 e_mask = vec3(d > 0.0 ? 1.0 : -1.0);
    WRITES
}
