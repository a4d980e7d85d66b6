// Sum of a float array, one pass, with subgroup arithmetic: each subgroup adds its values with
// subgroupAdd, the first subgroup adds the per-subgroup sums. Same interface as reduce_shared.
#version 450
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require

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

shared float subgroup_sums[WG];  // enough for any subgroup size >= 1

void main() {
    uint lid = gl_LocalInvocationID.x;
    uint base = gl_WorkGroupID.x * WG * ITEMS;
    float acc = 0.0;
    for (uint i = 0; i < ITEMS; ++i) {
        uint idx = base + i * WG + lid;
        if (idx < pc.count) {
            acc += values_in[pc.in_offset + idx];
        }
    }
    acc = subgroupAdd(acc);
    if (subgroupElect()) {
        subgroup_sums[gl_SubgroupID] = acc;
    }
    barrier();
    if (gl_SubgroupID == 0) {
        float total = 0.0;
        for (uint s = gl_SubgroupInvocationID; s < gl_NumSubgroups; s += gl_SubgroupSize) {
            total += subgroup_sums[s];
        }
        total = subgroupAdd(total);
        if (subgroupElect()) {
            values_out[pc.out_offset + gl_WorkGroupID.x] = total;
        }
    }
}
