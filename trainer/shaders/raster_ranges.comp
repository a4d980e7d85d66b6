// Rasteriser step 3: the [start, end) range of every tile in the sorted key list. Tiles with no
// entry keep the (0, 0) the host cleared them to.
#version 450

layout(local_size_x = 256) in;

layout(std430, set = 0, binding = 0) readonly buffer Keys { uvec2 keys[]; };
layout(std430, set = 0, binding = 1) buffer Ranges { uvec2 ranges[]; };

layout(push_constant) uniform Push {
    uint count;
} pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.count) {
        return;
    }
    uint tile = keys[i].y;
    if (i == 0u || keys[i - 1u].y != tile) {
        ranges[tile].x = i;
    }
    if (i + 1u == pc.count || keys[i + 1u].y != tile) {
        ranges[tile].y = i + 1u;
    }
}
