// Sort keys for the bitonic depth sort: (key, index) with key = ~bits(camera z), so an
// ascending sort of keys is a far-to-near order (z >= NEAR_PLANE > 0, and the bits of a
// positive float grow with it). Culled Gaussians and padding get key 0xFFFFFFFF (last).
layout(local_size_x = 256) in;
layout(std430, binding = 0) readonly buffer Splats { vec4 splats[]; };
layout(std430, binding = 1) writeonly buffer Pairs { uvec2 pairs[]; };
uniform uint splat_count;
uniform uint padded_count;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= padded_count) return;
    uvec2 pair = uvec2(0xFFFFFFFFu, 0u);
    if (i < splat_count && splats[SPLAT_TEXELS * i + 1u].w > 0.0) {
        pair = uvec2(~floatBitsToUint(splats[SPLAT_TEXELS * i + 2u].w), i);
    } else if (i < splat_count) {
        pair = uvec2(0xFFFFFFFFu, i);
    }
    pairs[i] = pair;
}
