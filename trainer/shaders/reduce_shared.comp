// Sum of a float array, one pass: each workgroup reduces 256 x ITEMS inputs to one partial
// sum through shared memory. Portable (no subgroup operations): the fallback for drivers
// without subgroup arithmetic. The host repeats passes until one value remains.
#version 450

#define WG 256
#define ITEMS 8

layout(local_size_x = WG) in;

layout(std430, set = 0, binding = 0) readonly buffer Input { float values_in[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Output { float values_out[]; };

layout(push_constant) uniform Push {
    uint count;       // number of valid inputs
    uint in_offset;   // first input element
    uint out_offset;  // element of values_out that receives workgroup 0's sum
} pc;

shared float partial[WG];

void main() {
    uint lid = gl_LocalInvocationID.x;
    uint base = gl_WorkGroupID.x * WG * ITEMS;
    float acc = 0.0;
    for (uint i = 0; i < ITEMS; ++i) {
        uint idx = base + i * WG + lid;  // strided: neighbouring invocations read neighbouring words
        if (idx < pc.count) {
            acc += values_in[pc.in_offset + idx];
        }
    }
    partial[lid] = acc;
    barrier();
    for (uint stride = WG / 2; stride > 0; stride >>= 1) {
        if (lid < stride) {
            partial[lid] += partial[lid + stride];
        }
        barrier();
    }
    if (lid == 0) {
        values_out[pc.out_offset + gl_WorkGroupID.x] = partial[0];
    }
}
