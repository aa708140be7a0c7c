#version 330 core
// baseline_cloudbaking.warp.PointCloud.splat's projection and footprint: instance i, the map's point i, is drawn
// as its k x k square, a quad whose corners lie on pixel edges (every covered pixel centre is half a pixel inside
// it), clipped to the frame. Window rows are image rows (row 0 at the top).
uniform sampler2D u_points;  // point i at texel (i % width, i / width): world position, and its source pixel's
                             // world size over its depth (0: no point)
uniform mat4 u_vp;           // the target camera's M_p . M_v
uniform float u_near;
uniform float u_focal_px;    // the target camera's focal length in pixels
uniform vec2 u_size;         // target width, height
flat out float v_depth;
flat out float v_index;
void main() {
    int width = textureSize(u_points, 0).x;
    vec4 point = texelFetch(u_points, ivec2(gl_InstanceID % width, gl_InstanceID / width), 0);
    vec4 clip = u_vp * vec4(point.xyz, 1.0);
    v_depth = clip.w;
    v_index = float(gl_InstanceID);
    if (!(point.w > 0.0 && clip.w > u_near)) { gl_Position = vec4(2.0, 2.0, 0.0, 1.0); return; }  // dropped
    float half_w = 0.5 / clip.w;
    float col = (clip.x * half_w + 0.5) * u_size.x;
    float row = (0.5 - clip.y * half_w) * u_size.y;
    float scale = point.w * u_focal_px / clip.w;
    float k = max(ceil(min(scale, MAX_FOOTPRINT) - FOOTPRINT_EPS), 1.0);
    vec2 origin = floor(vec2(col, row) + (0.5 - 0.5 * k));
    vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1));  // a triangle strip
    vec2 xy = clamp(origin + corner * k, vec2(0.0), u_size);  // window x, y = image column, row
    gl_Position = vec4(2.0 * xy / u_size - 1.0, 0.0, 1.0);
}
