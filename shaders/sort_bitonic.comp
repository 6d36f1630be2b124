// Bitonic sort of (key, index) pairs: ascending key; ties by ascending index for the
// front-to-back order (the torch rasterizer's stable order), by descending index for the
// back-to-front order (its exact reverse). Three modes:
//   0: sort every BLOCK-element block in shared memory (stages k = 2 .. BLOCK);
//   1: one global compare-exchange step (stage k, distance j >= BLOCK);
//   2: finish stage k (> BLOCK) in shared memory (distances BLOCK/2 .. 1).
layout(local_size_x = BLOCK_HALF) in;
layout(std430, binding = 1) buffer Pairs { uvec2 pairs[]; };
uniform int sort_mode;
uniform uint stage;      // k
uniform uint distance;   // j (mode 1)

shared uvec2 tile[2 * BLOCK_HALF];

bool before(uvec2 a, uvec2 b) {
#ifdef FRONT_TO_BACK
    return a.x < b.x || (a.x == b.x && a.y < b.y);
#else
    return a.x < b.x || (a.x == b.x && a.y > b.y);
#endif
}

void exchange_local(uint lo, uint hi, uint global_lo, uint k) {
    uvec2 a = tile[lo], b = tile[hi];
    bool ascending = (global_lo & k) == 0u;
    if (ascending ? before(b, a) : before(a, b)) { tile[lo] = b; tile[hi] = a; }
}

void local_steps(uint k, uint j_start) {
    uint t = gl_LocalInvocationID.x;
    uint block_base = gl_WorkGroupID.x * uint(2 * BLOCK_HALF);
    for (uint j = j_start; j > 0u; j >>= 1) {
        uint lo = 2u * j * (t / j) + (t % j);
        exchange_local(lo, lo + j, block_base + lo, k);
        barrier();
    }
}

void main() {
    if (sort_mode == 1) {
        uint t = gl_GlobalInvocationID.x;
        uint lo = 2u * distance * (t / distance) + (t % distance);
        uint hi = lo + distance;
        uvec2 a = pairs[lo], b = pairs[hi];
        bool ascending = (lo & stage) == 0u;
        if (ascending ? before(b, a) : before(a, b)) { pairs[lo] = b; pairs[hi] = a; }
        return;
    }
    uint t = gl_LocalInvocationID.x;
    uint block_base = gl_WorkGroupID.x * uint(2 * BLOCK_HALF);
    tile[t] = pairs[block_base + t];
    tile[t + uint(BLOCK_HALF)] = pairs[block_base + t + uint(BLOCK_HALF)];
    barrier();
    if (sort_mode == 0) {
        for (uint k = 2u; k <= uint(2 * BLOCK_HALF); k <<= 1) local_steps(k, k >> 1);
    } else {
        local_steps(stage, uint(BLOCK_HALF));
    }
    pairs[block_base + t] = tile[t];
    pairs[block_base + t + uint(BLOCK_HALF)] = tile[t + uint(BLOCK_HALF)];
}
