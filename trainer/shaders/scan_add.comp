// Exclusive prefix sum of u32, second level: adds each block's scanned offset to its values.
#version 450

#define WG 256
#define BLOCK 2048

layout(local_size_x = WG) in;

layout(std430, set = 0, binding = 0) buffer Data { uint data[]; };
layout(std430, set = 0, binding = 1) readonly buffer Offsets { uint block_offsets[]; };

layout(push_constant) uniform Push {
    uint count;
} pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i < pc.count) {
        data[i] += block_offsets[i / BLOCK];
    }
}
