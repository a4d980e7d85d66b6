// Scatter-add of float contributions into bins with atomicAdd(float)
// (VK_EXT_shader_atomic_float shaderBufferFloat32AtomicAdd): the gradient-accumulation path on
// devices that have it. accumulate_cas is the same operation for devices that do not.
#version 450
#extension GL_EXT_shader_atomic_float : require

layout(local_size_x = 256) in;

layout(std430, set = 0, binding = 0) readonly buffer Indices { uint bin_of[]; };
layout(std430, set = 0, binding = 1) readonly buffer Values { float contribution[]; };
layout(std430, set = 0, binding = 2) buffer Accum { float accum[]; };

layout(push_constant) uniform Push {
    uint count;
} pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i < pc.count) {
        atomicAdd(accum[bin_of[i]], contribution[i]);
    }
}
