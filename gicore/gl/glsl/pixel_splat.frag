#version 330 core
// The splat's two passes, each MIN-blended into a float32 target cleared to EMPTY: the nearest point's depth per
// pixel, then (u_index) the smallest index among the points at that depth: the numpy warp's packed key.
uniform sampler2D u_nearest;  // the first pass's nearest depth (the second pass)
uniform bool u_index;
flat in float v_depth;
flat in float v_index;
layout(location = 0) out vec4 o;
void main() {
    if (!u_index) { o = vec4(v_depth); return; }
    if (v_depth != texelFetch(u_nearest, ivec2(gl_FragCoord.xy), 0).r) discard;
    o = vec4(v_index);
}
