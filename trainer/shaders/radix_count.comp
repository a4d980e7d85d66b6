// Radix sort, pass step 1: per-block digit histogram, written digit-major
// (hist[digit * num_blocks + block]) so one exclusive scan gives every block's output offsets.
#version 450
#include "radix_common.glsl"

layout(local_size_x = RADIX_WG) in;

layout(std430, set = 0, binding = 0) readonly buffer Keys { uvec2 keys[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Hist { uint hist[]; };
layout(std430, set = 0, binding = 2) readonly buffer Count { uint counts[]; };

layout(push_constant) uniform Push {
    uint max_count;  // the items: min(counts[count_at], max_count)
    uint shift;
    uint num_blocks;
    uint count_at;
} pc;

shared uvec4 packed_counts[RADIX_WG];

void main() {
    uint lid = gl_LocalInvocationID.x;
    uint base = gl_WorkGroupID.x * RADIX_BLOCK + lid * RADIX_PER;
    uint count = min(counts[pc.count_at], pc.max_count);
    uvec4 mine = uvec4(0u);
    for (uint j = 0u; j < RADIX_PER; ++j) {
        if (base + j < count) {
            mine += radix_flag(radix_digit(keys[base + j], pc.shift));
        }
    }
    packed_counts[lid] = mine;
    barrier();
    // Invocation 0 adds the packed counters (the fields cannot overflow: 128 items per block),
    // then RADIX_BINS invocations unpack and write one digit each.
    if (lid == 0u) {
        uvec4 total = uvec4(0u);
        for (uint k = 0u; k < RADIX_WG; ++k) {
            total += packed_counts[k];
        }
        packed_counts[0] = total;
    }
    barrier();
    if (lid < RADIX_BINS) {
        hist[lid * pc.num_blocks + gl_WorkGroupID.x] = radix_unpack(packed_counts[0], lid);
    }
}
