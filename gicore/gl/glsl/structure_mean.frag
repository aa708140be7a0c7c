#version 330 core
// gigan_local.warp.fallback_level's mean over all hit texels (0 without any), from structure_coarse's block
// sums: the fallback behind the GI camera and on untextured surfaces. Drawn into one texel.
uniform sampler2D u_sums;  // per block: the sum over its hit texels, their count
layout(location = 0) out vec4 o;
void main() {
    ivec2 size = textureSize(u_sums, 0);
    vec4 s = vec4(0.0);
    for (int y = 0; y < size.y; ++y) {
        for (int x = 0; x < size.x; ++x) s += texelFetch(u_sums, ivec2(x, y), 0);
    }
    o = vec4(s.rgb / max(s.a, 1.0), 1.0);
}
