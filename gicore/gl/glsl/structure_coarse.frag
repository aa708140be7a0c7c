#version 330 core
// gigan_local.warp.fallback_level's blocks: per coarse texel, the sum of the indirect light over the hit texels
// of its u_step x u_step block (zero-padded at the far edges) and their count. o_level is push_pull's finest
// level of the block means (premultiplied by the weight min(hits, 1)); o_sum feeds the mean (structure_mean).
uniform sampler2D u_indirect;  // what the fallback extrapolates: the map's indirect light
uniform sampler2D u_depth;     // the GI camera's linear view depth (0: background)
uniform int u_step;            // GI texels per coarse texel
layout(location = 0) out vec4 o_level;
layout(location = 1) out vec4 o_sum;
void main() {
    ivec2 size = textureSize(u_depth, 0), origin = ivec2(gl_FragCoord.xy) * u_step;
    vec3 sum = vec3(0.0);
    float hits = 0.0;
    for (int y = 0; y < u_step; ++y) {
        for (int x = 0; x < u_step; ++x) {
            ivec2 t = origin + ivec2(x, y);
            if (all(lessThan(t, size)) && texelFetch(u_depth, t, 0).r > 0.0) {
                sum += texelFetch(u_indirect, t, 0).rgb;
                hits += 1.0;
            }
        }
    }
    float w = min(hits, 1.0);
    o_level = vec4(sum / max(hits, 1.0) * w, w);
    o_sum = vec4(sum, hits);
}
