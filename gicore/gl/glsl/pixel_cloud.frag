#version 330 core
// A cloud map as the pixel-level warp's splat reads it (baseline_cloudbaking.warp.PointCloud, on the GPU): per
// texel of the map (image rows) its world point and its pixel's world size over its depth (0: background, no
// point), and its colour decoded from the payload's 8-bit tone-mapped values (baseline_cloudbaking.codecs).
uniform sampler2D u_depth;  // the GI camera's linear view depth (0: background)
uniform sampler2D u_gi;     // the 8-bit tone-mapped map
uniform mat4 u_inv_view;    // GI camera: eye -> world
uniform vec2 u_focal;       // GI camera: proj[0][0], proj[1][1]
layout(location = 0) out vec4 o_point;
layout(location = 1) out vec4 o_colour;
#include "tonemap.glsl"
void main() {
    ivec2 t = ivec2(gl_FragCoord.xy);
    vec2 size = vec2(textureSize(u_depth, 0));
    float d = texelFetch(u_depth, t, 0).r;
    vec2 ndc = vec2(2.0 * (float(t.x) + 0.5) / size.x - 1.0, 1.0 - 2.0 * (float(t.y) + 0.5) / size.y);
    vec4 world = u_inv_view * vec4(ndc.x * d / u_focal.x, ndc.y * d / u_focal.y, -d, 1.0);
    o_point = d > 0.0 ? vec4(world.xyz, d / (u_focal.x * size.x * 0.5)) : vec4(0.0);
    o_colour = vec4(inverse_tonemap(min(texelFetch(u_gi, t, 0).rgb, vec3(254.5 / 255.0))), 1.0);
}
