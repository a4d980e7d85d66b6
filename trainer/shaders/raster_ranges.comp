// Rasteriser step 3: the [start, end) range of every tile in the sorted key list. Tiles with no
// entry keep the (0, 0) the host cleared them to. The list holds min(total[0], max_count) keys
// (total: the key total the GPU computed, so the host need not read it).
#version 450

layout(local_size_x = 256) in;

layout(std430, set = 0, binding = 0) readonly buffer Keys { uvec2 keys[]; };
layout(std430, set = 0, binding = 1) buffer Ranges { uvec2 ranges[]; };
layout(std430, set = 0, binding = 2) readonly buffer Total { uint total[]; };

layout(push_constant) uniform Push {
    uint max_count;
} pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    uint count = min(total[0], pc.max_count);
    if (i >= count) {
        return;
    }
    uint tile = keys[i].y;
    if (i == 0u || keys[i - 1u].y != tile) {
        ranges[tile].x = i;
    }
    if (i + 1u == count || keys[i + 1u].y != tile) {
        ranges[tile].y = i + 1u;
    }
}
