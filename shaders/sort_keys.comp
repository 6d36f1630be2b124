// Sort keys for the bitonic depth sort: (key, index) with key = bits(camera z) (near to far)
// or ~bits(camera z) (far to near): z >= NEAR_PLANE > 0 and the bits of a positive float grow
// with it. Culled Gaussians and padding get key 0xFFFFFFFF (last); padding gets index
// 0xFFFFFFFF, which the draw pass treats as nothing.
layout(local_size_x = 256) in;
layout(std430, binding = 0) readonly buffer Splats { vec4 splats[]; };
layout(std430, binding = 1) writeonly buffer Pairs { uvec2 pairs[]; };
uniform uint splat_count;
uniform uint padded_count;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= padded_count) return;
    uvec2 pair = uvec2(0xFFFFFFFFu, 0xFFFFFFFFu);
    if (i < splat_count && splats[SPLAT_TEXELS * i + 1u].w > 0.0) {
        uint bits = floatBitsToUint(splats[SPLAT_TEXELS * i + 2u].w);
#ifdef FRONT_TO_BACK
        pair = uvec2(bits, i);
#else
        pair = uvec2(~bits, i);
#endif
    } else if (i < splat_count) {
        pair = uvec2(0xFFFFFFFFu, i);
    }
    pairs[i] = pair;
}
