#version 330 core
// gicore.fill.push_pull's push, one level, coarse to fine: the level's own premultiplied colour plus
// (1 - weight) x its coarser parent (repeated 2 x 2); at the top the parent is the pull's last level, divided by
// its weight. With u_masked at the finest level, pixels off the mask (its alpha) are background: valid, 0.
uniform sampler2D u_level;    // this level of the pull (premultiplied colour, weight)
uniform sampler2D u_coarser;  // the filled coarser level; at the top, the pull's last level
uniform sampler2D u_mask;     // alpha: where the frame sees a surface (u_masked)
uniform bool u_top;
uniform bool u_masked;
layout(location = 0) out vec4 o;
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    vec4 own = texelFetch(u_level, p, 0);
    vec4 up = texelFetch(u_coarser, p / 2, 0);
    vec3 coarse = u_top ? up.rgb / max(up.a, 1e-12) : up.rgb;
    o = vec4(own.rgb + (1.0 - own.a) * coarse, own.a);
    if (u_masked && !(texelFetch(u_mask, p, 0).a > 0.0)) o = vec4(0.0, 0.0, 0.0, 1.0);
}
