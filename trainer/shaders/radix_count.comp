// Radix sort, pass step 1: per-block digit histogram, written digit-major
// (hist[digit * num_blocks + block]) so one exclusive scan gives every block's output offsets.
#version 450
#include "radix_common.glsl"

layout(local_size_x = RADIX_WG) in;

layout(std430, set = 0, binding = 0) readonly buffer Keys { uvec2 keys[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Hist { uint hist[]; };

layout(push_constant) uniform Push {
    uint count;
    uint shift;
    uint num_blocks;
} pc;

shared uint counts[RADIX_BINS];

void main() {
    uint lid = gl_LocalInvocationID.x;
    if (lid < RADIX_BINS) {
        counts[lid] = 0u;
    }
    barrier();
    uint i = gl_WorkGroupID.x * RADIX_WG + lid;
    if (i < pc.count) {
        atomicAdd(counts[radix_digit(keys[i], pc.shift)], 1u);
    }
    barrier();
    if (lid < RADIX_BINS) {
        hist[lid * pc.num_blocks + gl_WorkGroupID.x] = counts[lid];
    }
}
