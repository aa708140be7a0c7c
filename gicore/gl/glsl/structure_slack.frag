#version 330 core
// gigan_local.warp.depth_slack texel by texel, in its float32 operations: per GI texel the depth planes
// depth - slack, depth + slack the depth test reads (the map's own view: texel rows are image rows).
uniform sampler2D u_depth;  // the GI camera's linear view depth (0: background)
layout(location = 0) out vec2 o;  // depth - slack, depth + slack; +inf, -inf on background

const float INF = uintBitsToFloat(0x7f800000u);

float axis_step(ivec2 p, ivec2 along, float d) {  // depth_slack along one axis: 0 on the frame's border
    ivec2 a = p - along, b = p + along;
    if (any(lessThan(a, ivec2(0))) || any(greaterThanEqual(b, textureSize(u_depth, 0)))) return 0.0;
    float da = texelFetch(u_depth, a, 0).r, db = texelFetch(u_depth, b, 0).r;
    float s = min(da > 0.0 ? abs(d - da) : INF, db > 0.0 ? abs(db - d) : INF);  // a background neighbour: none
    return s == INF ? 0.0 : s;
}

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    float d = texelFetch(u_depth, p, 0).r;
    if (!(d > 0.0)) { o = vec2(INF, -INF); return; }
    float slack = axis_step(p, ivec2(1, 0), d) + axis_step(p, ivec2(0, 1), d);
    o = vec2(d - slack, d + slack);
}
