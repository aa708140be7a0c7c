#version 330 core
// One triangle over the whole viewport: a fullscreen pass draws 3 vertices and no buffer.
void main() {
    gl_Position = vec4(float((gl_VertexID & 1) << 2) - 1.0, float((gl_VertexID & 2) << 1) - 1.0, 0.0, 1.0);
}
