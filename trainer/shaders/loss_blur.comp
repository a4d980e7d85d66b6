// Separable 11x11 Gaussian blur (sigma 1.5, zero padding) of `channels` planes, one direction
// per dispatch (axis 0: along x, 1: along y). The blur is self-adjoint, so the SSIM backward
// pass uses the same kernel on its per-pixel maps.
#version 450
#include "loss_common.glsl"

layout(local_size_x = 16, local_size_y = 16) in;

layout(std430, set = 0, binding = 0) readonly buffer Src { float src[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Dst { float dst[]; };

layout(push_constant) uniform Push {
    uint width;
    uint height;
    uint channels;
    uint axis;
} pc;

void main() {
    uint x = gl_GlobalInvocationID.x;
    uint y = gl_GlobalInvocationID.y;
    if (x >= pc.width || y >= pc.height) {
        return;
    }
    uint npix = pc.width * pc.height;
    float weights[2 * SSIM_RADIUS + 1];
    ssim_window(weights);
    for (uint c = 0u; c < pc.channels; ++c) {
        float acc = 0.0;
        for (int k = -SSIM_RADIUS; k <= SSIM_RADIUS; ++k) {
            int xx = int(x) + (pc.axis == 0u ? k : 0);
            int yy = int(y) + (pc.axis == 1u ? k : 0);
            if (xx >= 0 && xx < int(pc.width) && yy >= 0 && yy < int(pc.height)) {
                acc += weights[k + SSIM_RADIUS] * src[c * npix + uint(yy) * pc.width + uint(xx)];
            }
        }
        dst[c * npix + y * pc.width + x] = acc;
    }
}
