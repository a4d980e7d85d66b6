// SSIM step 2: per pixel, from the blurred statistics, the SSIM value and the three maps whose
// blurs give d(mean SSIM)/dx (photometric.rs: g_mu, g_exx, g_exy). Writes the SSIM value into
// terms plane 1 for the reduction.
#version 450
#include "loss_common.glsl"

layout(local_size_x = 256) in;

layout(std430, set = 0, binding = 0) readonly buffer Blurred { float st[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Maps { float maps[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Terms { float terms[]; };

layout(push_constant) uniform Push {
    uint npix;
} pc;

void main() {
    uint p = gl_GlobalInvocationID.x;
    uint n = pc.npix;
    if (p >= n) {
        return;
    }
    float mx = st[p], my = st[n + p], exx = st[2u * n + p], eyy = st[3u * n + p], exy = st[4u * n + p];
    float a1 = 2.0 * mx * my + SSIM_C1;
    float a2 = 2.0 * (exy - mx * my) + SSIM_C2;
    float b1 = mx * mx + my * my + SSIM_C1;
    float b2 = (exx - mx * mx) + (eyy - my * my) + SSIM_C2;
    float s = a1 * a2 / (b1 * b2);
    maps[p] = s * (2.0 * my / a1 - 2.0 * my / a2 - 2.0 * mx / b1 + 2.0 * mx / b2);
    maps[n + p] = -s / b2;
    maps[2u * n + p] = s * 2.0 / a2;
    terms[n + p] = s;
}
