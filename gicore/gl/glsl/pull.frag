#version 330 core
// gicore.fill.push_pull's pull, one level: weight-normalised 2x2 sums of the finer level (zero-padded where its
// size is odd), the weight clipped to 1, in push_pull's order of operations. Levels hold colour premultiplied
// by the weight, the weight in alpha; texel rows are image rows.
uniform sampler2D u_finer;
layout(location = 0) out vec4 o;
vec4 at(ivec2 t, ivec2 size) { return all(lessThan(t, size)) ? texelFetch(u_finer, t, 0) : vec4(0.0); }
void main() {
    ivec2 p = 2 * ivec2(gl_FragCoord.xy), size = textureSize(u_finer, 0);
    vec4 s = at(p, size) + at(p + ivec2(0, 1), size) + at(p + ivec2(1, 0), size) + at(p + ivec2(1, 1), size);
    float w = min(s.a, 1.0);
    o = vec4(s.rgb * (w / max(s.a, 1e-12)), w);
}
