#version 330 core
// The bound map as the pixel-level warp's splat reads it (baseline_cloudbaking.warp.PointCloud, on the GPU): per
// texel of the map (image rows) its world point and its pixel's world size over its depth (0: background, no
// point), and its colour. With DISPLAY, u_gi holds an 8-bit codec's display values (a normalised 8-bit texture)
// and each channel is looked up in u_linear_of_u8 (gicore.tonemap.LINEAR_OF_U8: the host decode's own values);
// without, u_gi holds linear radiance.
uniform sampler2D u_depth;         // the GI camera's linear view depth (0: background)
uniform sampler2D u_gi;            // the map: display values (DISPLAY) or linear radiance
uniform sampler2D u_linear_of_u8;  // DISPLAY: 256 x 1, the linear value of each byte
uniform mat4 u_inv_view;           // GI camera: eye -> world
uniform vec2 u_focal;              // GI camera: proj[0][0], proj[1][1]
layout(location = 0) out vec4 o_point;
layout(location = 1) out vec4 o_colour;
void main() {
    ivec2 t = ivec2(gl_FragCoord.xy);
    vec2 size = vec2(textureSize(u_depth, 0));
    float d = texelFetch(u_depth, t, 0).r;
    vec2 ndc = vec2(2.0 * (float(t.x) + 0.5) / size.x - 1.0, 1.0 - 2.0 * (float(t.y) + 0.5) / size.y);
    vec4 world = u_inv_view * vec4(ndc.x * d / u_focal.x, ndc.y * d / u_focal.y, -d, 1.0);
    o_point = d > 0.0 ? vec4(world.xyz, d / (u_focal.x * size.x * 0.5)) : vec4(0.0);
    vec3 gi = texelFetch(u_gi, t, 0).rgb;
#ifdef DISPLAY
    ivec3 q = ivec3(gi * 255.0 + 0.5);
    gi = vec3(texelFetch(u_linear_of_u8, ivec2(q.r, 0), 0).r, texelFetch(u_linear_of_u8, ivec2(q.g, 0), 0).r,
              texelFetch(u_linear_of_u8, ivec2(q.b, 0), 0).r);
#endif
    o_colour = vec4(gi, 1.0);
}
