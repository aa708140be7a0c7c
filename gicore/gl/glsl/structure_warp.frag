#version 330 core
// gigan_local.warp.StructureAwareWarp.resample per pixel, in its order and float32 arithmetic: project the uv
// pass's GI-camera clip coordinates, depth-test the four bilinear taps (weights rounded to 1/SUBTEXEL) against
// the depth planes, and fill invalid pixels from the coarse level. Frame textures are read at the pixel drawn;
// the map's textures have image rows (row 0 at the top).
uniform sampler2D u_uv;        // the uv pass: GI-camera clip (x, y)
uniform sampler2D u_position;  // world position
uniform sampler2D u_code;      // 0 background, 1 an untextured surface, 2 textured
uniform sampler2D u_di;        // the frame's DI (the fallback's base for the radiance layer)
uniform sampler2D u_planes;    // per GI texel: depth - slack, depth + slack (+inf, -inf on background)
uniform sampler2D u_gi;        // the bound layer
uniform sampler2D u_coarse;    // the fallback's coarse level (push-pull filled)
uniform sampler2D u_mean;      // one texel: the fallback behind the GI camera and on untextured surfaces
uniform vec4 u_w_row;          // GI-camera clip w = u_w_row . (p, 1)
uniform float u_near;
uniform float u_tol_hi;        // 1 + DEPTH_REL_TOL and 1 - DEPTH_REL_TOL
uniform float u_tol_lo;
uniform float u_inv_step;      // 1 / the coarse level's texels per coarse texel
uniform bool u_base;           // add the frame's DI to the fallback (the radiance layer)
layout(location = 0) out vec4 o;  // the layer; alpha: valid (from the map, or background)

vec3 coarse(float x, float y) {  // StructureAwareWarp._coarse
    ivec2 size = textureSize(u_coarse, 0);
    float cx = clamp((x + 0.5) * u_inv_step - 0.5, 0.0, float(size.x - 1));
    float cy = clamp((y + 0.5) * u_inv_step - 0.5, 0.0, float(size.y - 1));
    float x0 = floor(cx), y0 = floor(cy);
    float fx = cx - x0, fy = cy - y0;
    ivec2 a = ivec2(x0, y0), b = min(a + 1, size - 1);
    vec3 c = texelFetch(u_coarse, a, 0).rgb * ((1.0 - fx) * (1.0 - fy));
    c += texelFetch(u_coarse, ivec2(b.x, a.y), 0).rgb * (fx * (1.0 - fy));
    c += texelFetch(u_coarse, ivec2(a.x, b.y), 0).rgb * ((1.0 - fx) * fy);
    return c + texelFetch(u_coarse, b, 0).rgb * (fx * fy);
}

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    float code = texelFetch(u_code, p, 0).r;
    if (code <= 0.5) { o = vec4(0.0, 0.0, 0.0, 1.0); return; }  // background: nothing to warp
    vec3 base = u_base ? texelFetch(u_di, p, 0).rgb : vec3(0.0);
    vec3 mean = texelFetch(u_mean, ivec2(0), 0).rgb;
    if (code <= 1.5) { o = vec4(mean + base, 0.0); return; }
    vec2 clip = texelFetch(u_uv, p, 0).xy;
    vec3 pos = texelFetch(u_position, p, 0).xyz;
    float w = pos.x * u_w_row.x + pos.y * u_w_row.y + pos.z * u_w_row.z + u_w_row.w;
    bool front = w > u_near;
    float half_w = 0.5 / (front ? w : 1.0);
    ivec2 size = textureSize(u_gi, 0);
    vec2 last = vec2(size - 1);
    float x = (clip.x * half_w + 0.5) * float(size.x) - 0.5;
    float y = (0.5 - clip.y * half_w) * float(size.y) - 0.5;
    bool ok = front && x >= -0.5 && x <= last.x + 0.5 && y >= -0.5 && y <= last.y + 0.5;
    x = clamp(x, 0.0, last.x);  // clamp to edge (the fallback reads the clamped uv too)
    y = clamp(y, 0.0, last.y);
    float x0 = floor(x), y0 = floor(y);
    float fx = roundEven((x - x0) * SUBTEXEL) * (1.0 / SUBTEXEL);
    float fy = roundEven((y - y0) * SUBTEXEL) * (1.0 / SUBTEXEL);
    ivec2 a = ivec2(x0, y0), b = min(a + 1, size - 1);
    ivec2 taps[4] = ivec2[4](a, ivec2(b.x, a.y), ivec2(a.x, b.y), b);
    float gx = 1.0 - fx, gy = 1.0 - fy;
    float weights[4] = float[4](gx * gy, fx * gy, gx * fy, fx * fy);
    float total = 0.0;
    for (int i = 0; i < 4; ++i) {  // |d - w| <= tol * w + slack on [d - slack, d + slack]
        vec2 plane = texelFetch(u_planes, taps[i], 0).xy;
        if (!(plane.x <= w * u_tol_hi && plane.y >= w * u_tol_lo)) weights[i] = 0.0;
        total += weights[i];
    }
    if (ok && total > 0.0) {
        vec3 sum = vec3(0.0);
        for (int i = 0; i < 4; ++i) sum += texelFetch(u_gi, taps[i], 0).rgb * (weights[i] / total);
        o = vec4(sum, 1.0);
        return;
    }
    o = vec4((front ? coarse(x, y) : mean) + base, 0.0);
}
