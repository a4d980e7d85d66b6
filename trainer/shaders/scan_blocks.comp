// Exclusive prefix sum of u32, first level: each workgroup scans one block of 512 values in
// place (Blelloch up/down sweep in shared memory) and writes the block's total to block_sums.
// The host scans block_sums recursively and adds them back with scan_add.
#version 450

#define WG 256
#define BLOCK 512

layout(local_size_x = WG) in;

layout(std430, set = 0, binding = 0) buffer Data { uint data[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Sums { uint block_sums[]; };

layout(push_constant) uniform Push {
    uint count;
} pc;

shared uint tmp[BLOCK];

void main() {
    uint lid = gl_LocalInvocationID.x;
    uint base = gl_WorkGroupID.x * BLOCK;
    uint i0 = base + 2 * lid;
    uint i1 = i0 + 1;
    tmp[2 * lid] = i0 < pc.count ? data[i0] : 0u;
    tmp[2 * lid + 1] = i1 < pc.count ? data[i1] : 0u;

    uint offset = 1;
    for (uint d = BLOCK >> 1; d > 0; d >>= 1) {
        barrier();
        if (lid < d) {
            uint ai = offset * (2 * lid + 1) - 1;
            uint bi = offset * (2 * lid + 2) - 1;
            tmp[bi] += tmp[ai];
        }
        offset <<= 1;
    }
    barrier();
    if (lid == 0) {
        block_sums[gl_WorkGroupID.x] = tmp[BLOCK - 1];
        tmp[BLOCK - 1] = 0u;
    }
    for (uint d = 1; d < BLOCK; d <<= 1) {
        offset >>= 1;
        barrier();
        if (lid < d) {
            uint ai = offset * (2 * lid + 1) - 1;
            uint bi = offset * (2 * lid + 2) - 1;
            uint t = tmp[ai];
            tmp[ai] = tmp[bi];
            tmp[bi] += t;
        }
    }
    barrier();
    if (i0 < pc.count) {
        data[i0] = tmp[2 * lid];
    }
    if (i1 < pc.count) {
        data[i1] = tmp[2 * lid + 1];
    }
}
