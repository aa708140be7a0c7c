#version 330 core
// The page's port of gigan_local.preprocess.output_to_radiance: the generator's output planes (stacked, in
// [-1, 1], image rows) to the GI map's linear radiance and its indirect light max(radiance - DI, 0) (GIMap's),
// both with image rows, as the structure-aware warp reads a map. The GI camera's DI has GL's rows.
uniform sampler2D u_y;   // n x 3n: the three output planes
uniform sampler2D u_di;  // the GI camera's DI (GL rows: row 0 at the bottom)
layout(location = 0) out vec4 o_radiance;
layout(location = 1) out vec4 o_indirect;
#include "tonemap.glsl"
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    int n = textureSize(u_y, 0).x;
    vec3 y = vec3(texelFetch(u_y, p, 0).r, texelFetch(u_y, ivec2(p.x, n + p.y), 0).r,
                  texelFetch(u_y, ivec2(p.x, 2 * n + p.y), 0).r);
    vec3 radiance = inverse_tonemap(clamp((y + 1.0) * 0.5, 0.0, 1.0));
    vec3 di = texelFetch(u_di, ivec2(p.x, n - 1 - p.y), 0).rgb;
    o_radiance = vec4(radiance, 1.0);
    o_indirect = vec4(max(radiance - di, 0.0), 1.0);
}
