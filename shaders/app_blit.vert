// Full-screen triangle (no vertex buffer) sampling the scene texture; u_flip_y picks whether
// texture row 0 is the image top (read-back convention) or the bottom (GL convention).
uniform int u_flip_y;
out vec2 v_uv;
void main() {
    vec2 corner = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
    v_uv = corner;
    if (u_flip_y != 0) {
        v_uv.y = 1.0 - v_uv.y;
    }
    gl_Position = vec4(corner * 2.0 - 1.0, 0.0, 1.0);
}
