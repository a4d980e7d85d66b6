// Loss step 3, per pixel: the gradient of the single-view loss w.r.t. the rendered buffers
// (loss/mod.rs view_loss) written as the backward rasteriser's upstream planes, and the
// per-pixel terms for the loss values:
//   thermal:  (1 - lambda)/n sign(x - y) - lambda/n (B[g_mu] + 2x B[g_exx] + y B[g_exy])
//   psi_high: lambda_s/n sign(psi_high)
//   psi_beta: lambda_g/n d/dpsi sum sqrt(dx^2 + dy^2 + eps) (forward differences, gathered)
//   psi_low, depth, alpha: 0 (the consistency term adds to psi_high/psi_beta when it runs).
// x is the rendered thermal value seen through the view's response (loss/response.rs):
// x = gain (r - pivot) + pivot + offset, so the thermal upstream is gain * dL/dx, and the
// response's gradient is summed from two more terms planes.
// Terms planes: 0 |x - y|, 1 SSIM (written by loss_ssim_map), 2 |psi_high|, 3 TV norm,
// 4 dL/dx (r - pivot) (-> dL/dgain), 5 dL/dx (-> dL/doffset).
#version 450
#include "loss_common.glsl"

layout(local_size_x = 16, local_size_y = 16) in;

layout(std430, set = 0, binding = 0) readonly buffer Rendered { float rendered[]; };
layout(std430, set = 0, binding = 1) readonly buffer Target { float target_px[]; };
layout(std430, set = 0, binding = 2) readonly buffer BlurredMaps { float bm[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Upstream { float upstream[]; };
layout(std430, set = 0, binding = 4) buffer Terms { float terms[]; };

layout(push_constant) uniform Push {
    uint width;
    uint height;
    float lambda_dssim;
    float lambda_sparse;
    float lambda_smooth;
    float gain;
    float offset;
    float pivot;
} pc;

float sign0(float v) {
    return v > 0.0 ? 1.0 : (v < 0.0 ? -1.0 : 0.0);
}

float beta_at(uint npix, int x, int y) {
    return rendered[3u * npix + uint(y) * pc.width + uint(x)];
}

// Forward differences of psi_beta at (x, y) and their norm.
vec3 tv_at(uint npix, int x, int y) {
    int w = int(pc.width), h = int(pc.height);
    float v = beta_at(npix, x, y);
    float dx = x + 1 < w ? beta_at(npix, x + 1, y) - v : 0.0;
    float dy = y + 1 < h ? beta_at(npix, x, y + 1) - v : 0.0;
    return vec3(dx, dy, sqrt(dx * dx + dy * dy + TV_EPSILON));
}

void main() {
    uint ux = gl_GlobalInvocationID.x;
    uint uy = gl_GlobalInvocationID.y;
    if (ux >= pc.width || uy >= pc.height) {
        return;
    }
    uint npix = pc.width * pc.height;
    uint p = uy * pc.width + ux;
    float inv_n = 1.0 / float(npix);
    float r = rendered[p];
    float x = pc.gain * (r - pc.pivot) + pc.pivot + pc.offset;
    float y = target_px[p];
    float g_thermal = (1.0 - pc.lambda_dssim) * inv_n * sign0(x - y) -
                      pc.lambda_dssim * inv_n * (bm[p] + 2.0 * x * bm[npix + p] + y * bm[2u * npix + p]);
    float psi_high = rendered[2u * npix + p];
    float g_high = pc.lambda_sparse * inv_n * sign0(psi_high);
    // TV: own term contributes -(dx + dy)/norm; left and upper neighbours contribute dx/norm, dy/norm.
    int ix = int(ux), iy = int(uy);
    int w = int(pc.width), h = int(pc.height);
    vec3 own = tv_at(npix, ix, iy);
    float g_tv = 0.0;
    if (ix + 1 < w) {
        g_tv -= own.x / own.z;
    }
    if (iy + 1 < h) {
        g_tv -= own.y / own.z;
    }
    if (ix > 0) {
        vec3 left = tv_at(npix, ix - 1, iy);
        g_tv += left.x / left.z;
    }
    if (iy > 0) {
        vec3 up = tv_at(npix, ix, iy - 1);
        g_tv += up.y / up.z;
    }
    upstream[p] = pc.gain * g_thermal;
    upstream[npix + p] = 0.0;
    upstream[2u * npix + p] = g_high;
    upstream[3u * npix + p] = pc.lambda_smooth * inv_n * g_tv;
    upstream[4u * npix + p] = 0.0;
    upstream[5u * npix + p] = 0.0;
    terms[p] = abs(x - y);
    terms[2u * npix + p] = abs(psi_high);
    terms[3u * npix + p] = own.z;
    terms[4u * npix + p] = g_thermal * (r - pc.pivot);
    terms[5u * npix + p] = g_thermal;
}
