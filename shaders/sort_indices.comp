// Sorted (key, index) pairs -> the draw pass's element buffer: six indices per Gaussian,
// 4 * gaussian + (0, 1, 2, 2, 1, 3). Padding (index >= count) becomes six zeros, a triangle
// pair of one repeated vertex, which has no area.
layout(local_size_x = 256) in;
layout(std430, binding = 1) readonly buffer Pairs { uvec2 pairs[]; };
layout(std430, binding = 2) writeonly buffer Elements { uint elements[]; };
uniform uint splat_count;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= splat_count) return;
    uint gaussian = pairs[i].y;
    uint base = gaussian < splat_count ? 4u * gaussian : 0u;
    uint corner_step = gaussian < splat_count ? 1u : 0u;
    elements[6u * i + 0u] = base;
    elements[6u * i + 1u] = base + corner_step;
    elements[6u * i + 2u] = base + 2u * corner_step;
    elements[6u * i + 3u] = base + 2u * corner_step;
    elements[6u * i + 4u] = base + corner_step;
    elements[6u * i + 5u] = base + 3u * corner_step;
}
