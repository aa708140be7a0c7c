#version 330 core
// gicore.blend: eq. 1's blend tau * DI + (1 - tau) * GI or, with RESIDUAL, the residual composition DI + the
// warped indirect layer (its di_of_gi is 0); with TONEMAP, tone-mapped for a screen (the page's canvas).
uniform sampler2D u_di;      // the frame's DI (rgb)
uniform sampler2D u_warped;  // the warped layer (rgb), valid in alpha
uniform float u_tau;         // eq. 1's weights: tau and 1 - tau, each rounded to float32 as numpy rounds them
uniform float u_one_minus_tau;
layout(location = 0) out vec4 o;
#include "tonemap.glsl"
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    vec3 di = texelFetch(u_di, p, 0).rgb;
    vec4 gi = texelFetch(u_warped, p, 0);
#ifdef RESIDUAL
    vec3 c = di + max(gi.rgb, 0.0);
#else
    vec3 c = u_tau * di + u_one_minus_tau * gi.rgb;
#endif
#ifdef TONEMAP
    o = vec4(tonemap(c), 1.0);
#else
    o = vec4(c, gi.a);
#endif
}
