// Exclusive prefix sum of u32, first level: each workgroup scans one block of 2048 values in
// place and writes the block's total to block_sums. The host scans block_sums recursively and
// adds them back with scan_add.
//
// Each invocation scans PER consecutive values in registers; invocation 0 then scans the WG
// invocation totals serially in shared memory. Two barriers in all: a barrier is what costs on
// CPU implementations (lavapipe switches between the workgroup's SIMD batches at each one), and
// a tree scan over the 2048 values needs 22.
#version 450

#define WG 64
#define PER 32
#define BLOCK 2048

layout(local_size_x = WG) in;

layout(std430, set = 0, binding = 0) buffer Data { uint data[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Sums { uint block_sums[]; };

layout(push_constant) uniform Push {
    uint count;
} pc;

shared uint partial[WG];

void main() {
    uint lid = gl_LocalInvocationID.x;
    uint base = gl_WorkGroupID.x * BLOCK + lid * PER;
    uint prefix[PER];
    uint sum = 0u;
    for (uint j = 0u; j < PER; ++j) {
        uint idx = base + j;
        uint v = 0u;
        if (idx < pc.count) {
            v = data[idx];
        }
        prefix[j] = sum;
        sum += v;
    }
    partial[lid] = sum;
    barrier();
    if (lid == 0u) {
        uint run = 0u;
        for (uint k = 0u; k < WG; ++k) {
            uint s = partial[k];
            partial[k] = run;
            run += s;
        }
        block_sums[gl_WorkGroupID.x] = run;
    }
    barrier();
    uint offset = partial[lid];
    for (uint j = 0u; j < PER; ++j) {
        uint idx = base + j;
        if (idx < pc.count) {
            data[idx] = prefix[j] + offset;
        }
    }
}
