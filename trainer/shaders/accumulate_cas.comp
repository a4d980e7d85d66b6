// Scatter-add of float contributions without float atomics: a compare-and-swap loop on the
// bins' bit patterns (u32 atomics are core Vulkan). The fallback for drivers without
// shaderBufferFloat32AtomicAdd (e.g. Raspberry Pi 5's V3DV). Same buffers as accumulate_atomic;
// binding 2 holds the floats' bits.
#version 450

layout(local_size_x = 256) in;

layout(std430, set = 0, binding = 0) readonly buffer Indices { uint bin_of[]; };
layout(std430, set = 0, binding = 1) readonly buffer Values { float contribution[]; };
layout(std430, set = 0, binding = 2) buffer Accum { uint accum_bits[]; };

layout(push_constant) uniform Push {
    uint count;
} pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.count) {
        return;
    }
    uint bin = bin_of[i];
    float v = contribution[i];
    uint seen = accum_bits[bin];
    for (;;) {
        uint expected = seen;
        uint desired = floatBitsToUint(uintBitsToFloat(expected) + v);
        seen = atomicCompSwap(accum_bits[bin], expected, desired);
        if (seen == expected) {
            break;
        }
    }
}
