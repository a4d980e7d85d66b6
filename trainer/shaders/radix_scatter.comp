// Radix sort, pass step 2: stable scatter. An item's rank among the items of its block with the
// same digit = the count of that digit in the invocations before its own (invocation 0 scans
// the invocations' packed counters serially in shared memory) + the count before it among its
// invocation's RADIX_PER items. Output position = scanned histogram offset of (digit, block) +
// rank. Uses only u32 shared memory: runs on every Vulkan 1.2 device.
#version 450
#include "radix_common.glsl"

layout(local_size_x = RADIX_WG) in;

layout(std430, set = 0, binding = 0) readonly buffer KeysIn { uvec2 keys_in[]; };
layout(std430, set = 0, binding = 1) readonly buffer ValuesIn { uint values_in[]; };
layout(std430, set = 0, binding = 2) readonly buffer Offsets { uint offsets[]; };
layout(std430, set = 0, binding = 3) writeonly buffer KeysOut { uvec2 keys_out[]; };
layout(std430, set = 0, binding = 4) writeonly buffer ValuesOut { uint values_out[]; };
layout(std430, set = 0, binding = 5) readonly buffer Count { uint counts[]; };

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
    uvec2 key[RADIX_PER];
    uint digit[RADIX_PER];
    uint before[RADIX_PER];  // same-digit items before this one in this invocation
    uvec4 mine = uvec4(0u);
    for (uint j = 0u; j < RADIX_PER; ++j) {
        bool valid = base + j < count;
        key[j] = valid ? keys_in[base + j] : uvec2(0u);
        digit[j] = radix_digit(key[j], pc.shift);
        before[j] = radix_unpack(mine, digit[j]);
        mine += valid ? radix_flag(digit[j]) : uvec4(0u);
    }
    packed_counts[lid] = mine;
    barrier();
    if (lid == 0u) {
        uvec4 run = uvec4(0u);
        for (uint k = 0u; k < RADIX_WG; ++k) {
            uvec4 c = packed_counts[k];
            packed_counts[k] = run;
            run += c;
        }
    }
    barrier();
    uvec4 earlier = packed_counts[lid];
    for (uint j = 0u; j < RADIX_PER; ++j) {
        if (base + j < count) {
            uint rank = radix_unpack(earlier, digit[j]) + before[j];
            uint pos = offsets[digit[j] * pc.num_blocks + gl_WorkGroupID.x] + rank;
            keys_out[pos] = key[j];
            values_out[pos] = values_in[base + j];
        }
    }
}
