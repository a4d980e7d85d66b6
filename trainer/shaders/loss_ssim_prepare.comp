// SSIM step 1: the five planes whose blurs give the local statistics: x, y, x^2, y^2, xy.
// x is the rendered thermal plane (plane 0 of the renderer's output) seen through the view's
// response (loss/response.rs: gain (x - pivot) + pivot + offset; identity: 1, 0), y the target.
#version 450

layout(local_size_x = 256) in;

layout(std430, set = 0, binding = 0) readonly buffer Rendered { float rendered[]; };
layout(std430, set = 0, binding = 1) readonly buffer Target { float target_px[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Stats { float stats[]; };

layout(push_constant) uniform Push {
    uint npix;
    float gain;
    float offset;
    float pivot;
} pc;

void main() {
    uint p = gl_GlobalInvocationID.x;
    if (p >= pc.npix) {
        return;
    }
    float x = pc.gain * (rendered[p] - pc.pivot) + pc.pivot + pc.offset;
    float y = target_px[p];
    stats[p] = x;
    stats[pc.npix + p] = y;
    stats[2u * pc.npix + p] = x * x;
    stats[3u * pc.npix + p] = y * y;
    stats[4u * pc.npix + p] = x * y;
}
