// One quad (two indexed triangles) per Gaussian. The element buffer lists, in draw order,
// 4 * gaussian + corner for corners (0, 1, 2, 2, 1, 3), so gl_VertexID carries both and a
// vertex cache shades each corner once; one plain draw call instead of N instances keeps
// software GL (llvmpipe) from paying its per-instance pipeline cost. The quad is the
// footprint box computed by the preprocess pass.
uniform sampler2D splats;      // SPLAT_TEXELS texels per Gaussian (see splat_preprocess.vert)
uniform int splat_count;
uniform vec4 pixel_to_ndc;     // ndc = pixel * xy + zw
uniform vec2 image_size;

flat out vec2 f_mean;
flat out vec3 f_conic;
flat out float f_opacity;
flat out vec3 f_value;

void main() {
    int index = gl_VertexID >> 2;
    int corner_id = gl_VertexID & 3;
    vec4 conic = index < splat_count ? fetch_texel(splats, SPLAT_TEXELS * index + 1) : vec4(0.0);
    if (conic.w <= 0.0) {
        // Culled: a zero-area triangle outside the clip volume, rasterises nothing.
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
        return;
    }
    vec4 screen = fetch_texel(splats, SPLAT_TEXELS * index);
    vec2 major = screen.zw;
    vec2 minor = fetch_texel(splats, SPLAT_TEXELS * index + 3).xy;
    vec2 corner = vec2(float(corner_id & 1), float(corner_id >> 1)) * 2.0 - 1.0;
    vec2 pixel;
    if (max(abs(major.x), abs(major.y)) < QUAD_AXIS_MAX) {
        pixel = screen.xy + corner.x * major + corner.y * minor;  // oriented footprint box
    } else {
        // Huge footprint: its axis-aligned box clamped to just beyond the image keeps the
        // corners in a sane float range; clamping a box does not cut the ellipse's in-image
        // part, clamping rotated corners could.
        vec2 extent = sqrt(major * major + minor * minor);
        pixel = clamp(screen.xy + corner * extent, vec2(-1.0), image_size + 1.0);
    }
    gl_Position = vec4(pixel * pixel_to_ndc.xy + pixel_to_ndc.zw, 0.0, 1.0);
    f_mean = screen.xy;
    f_conic = conic.xyz;
    f_opacity = conic.w;
    f_value = fetch_texel(splats, SPLAT_TEXELS * index + 2).xyz;
}
