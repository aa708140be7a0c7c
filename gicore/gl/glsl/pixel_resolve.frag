#version 330 core
// The splat's winners' colours where the frame sees a surface: push_pull's finest level (colour x valid, valid).
uniform sampler2D u_index;    // the winning point per pixel (EMPTY: none)
uniform sampler2D u_colours;  // point i's colour at texel (i % width, i / width)
uniform sampler2D u_mask;     // alpha: where the frame sees a surface
layout(location = 0) out vec4 o;
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    float i = texelFetch(u_index, p, 0).r;
    if (i >= EMPTY || !(texelFetch(u_mask, p, 0).a > 0.0)) { o = vec4(0.0); return; }
    int n = int(i), width = textureSize(u_colours, 0).x;
    o = vec4(texelFetch(u_colours, ivec2(n % width, n / width), 0).rgb, 1.0);
}
