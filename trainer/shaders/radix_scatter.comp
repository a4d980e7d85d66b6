// Radix sort, pass step 2: stable scatter. Each item's rank among the items of its block with
// the same digit comes from one Hillis–Steele scan of packed counters: 16 digits x 8 bits in a
// uvec4 (a block has 128 items, so no field overflows). Output position = scanned histogram
// offset of (digit, block) + rank. Uses only u32 shared memory: runs on every Vulkan 1.2 device.
#version 450
#include "radix_common.glsl"

layout(local_size_x = RADIX_WG) in;

layout(std430, set = 0, binding = 0) readonly buffer KeysIn { uvec2 keys_in[]; };
layout(std430, set = 0, binding = 1) readonly buffer ValuesIn { uint values_in[]; };
layout(std430, set = 0, binding = 2) readonly buffer Offsets { uint offsets[]; };
layout(std430, set = 0, binding = 3) writeonly buffer KeysOut { uvec2 keys_out[]; };
layout(std430, set = 0, binding = 4) writeonly buffer ValuesOut { uint values_out[]; };

layout(push_constant) uniform Push {
    uint count;
    uint shift;
    uint num_blocks;
} pc;

shared uvec4 packed_counts[2][RADIX_WG];

void main() {
    uint lid = gl_LocalInvocationID.x;
    uint i = gl_WorkGroupID.x * RADIX_WG + lid;
    bool valid = i < pc.count;
    uvec2 key = valid ? keys_in[i] : uvec2(0u);
    uint digit = radix_digit(key, pc.shift);
    uvec4 flag = uvec4(0u);
    if (valid) {
        flag[digit >> 2] = 1u << ((digit & 3u) * 8u);
    }
    packed_counts[0][lid] = flag;
    barrier();
    uint src = 0u;
    for (uint off = 1u; off < RADIX_WG; off <<= 1) {
        uvec4 v = packed_counts[src][lid];
        if (lid >= off) {
            v += packed_counts[src][lid - off];
        }
        packed_counts[1u - src][lid] = v;
        src = 1u - src;
        barrier();
    }
    if (valid) {
        uvec4 inclusive = packed_counts[src][lid];
        uint rank = ((inclusive[digit >> 2] >> ((digit & 3u) * 8u)) & 255u) - 1u;
        uint pos = offsets[digit * pc.num_blocks + gl_WorkGroupID.x] + rank;
        keys_out[pos] = key;
        values_out[pos] = values_in[i];
    }
}
