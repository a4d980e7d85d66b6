// Multi-view frequency consistency (the CPU reference: trainer/src/loss/consistency.rs, paper
// eq. 4-5 with the documented differences), one invocation per pixel u of the reference view i:
// the surface point X = c_i + D_i(u) W_i u (D = depth / alpha where alpha >= min_alpha) is
// projected into the source view j; the pixel is masked when X is behind j's near plane, lands
// outside j's image, any of the four bilinear source pixels has no depth, or X is occluded in j
// (z_j(X) > D_j(u_j) (1 + depth_rel_tol), D_j bilinear). Otherwise
//   term(u) = |psi_high_i(u) - psi_high_j(u_j)| + |psi_beta_i(u) - psi_beta_j(u_j)|
// and the gradients k sign(diff) go to view i's upstream plane at u and, through the bilinear
// weights, to view j's (scatter-add: float atomics or a CAS loop, as the backward rasteriser)
// unless grad_j is 0 (view j's planes were kept from an earlier step: stop-gradient).
// The warp and the mask are under stop-gradient. The CPU reference warps in f64, this kernel in
// f32: a pixel whose footprint lies on a mask boundary may be decided differently.
//
// Buffers: the camera blocks of raster_common.glsl; view planes in raster_forward's layout
// (psi_high 2, psi_beta 3, depth 4, alpha 5); upstream planes in the backward rasteriser's
// 6-plane layout (psi_high 2, psi_beta 3); terms: term(u) then valid(u) (1 or 0), 2 planes of i.

#include "raster_common.glsl"

layout(local_size_x = 16, local_size_y = 16) in;

layout(std430, set = 0, binding = 0) readonly buffer CamI { float cam_i[]; };
layout(std430, set = 0, binding = 1) readonly buffer CamJ { float cam_j[]; };
layout(std430, set = 0, binding = 2) readonly buffer PlanesI { float planes_i[]; };
layout(std430, set = 0, binding = 3) readonly buffer PlanesJ { float planes_j[]; };
layout(std430, set = 0, binding = 4) buffer UpI { float up_i[]; };
#ifdef USE_FLOAT_ATOMICS
layout(std430, set = 0, binding = 5) buffer UpJ { float up_j[]; };
void add_j(uint idx, float v) {
    if (v != 0.0) {
        atomicAdd(up_j[idx], v);
    }
}
#else
layout(std430, set = 0, binding = 5) buffer UpJ { uint up_j[]; };
void add_j(uint idx, float v) {
    if (v == 0.0) {
        return;
    }
    uint seen = up_j[idx];
    for (;;) {
        uint expected = seen;
        seen = atomicCompSwap(up_j[idx], expected, floatBitsToUint(uintBitsToFloat(expected) + v));
        if (seen == expected) {
            break;
        }
    }
}
#endif
layout(std430, set = 0, binding = 6) writeonly buffer Terms { float terms[]; };

layout(push_constant) uniform Push {
    uint wi;
    uint hi;
    uint wj;
    uint hj;
    float min_alpha;
    float depth_rel_tol;
    float near_m;
    float k;  // weight / (wi hi)
    uint grad_j;  // 0: view j is under stop-gradient (kept from an earlier step), up_j untouched
} pc;

// Expected depth of pixel q of view j, or -1 when it has none.
float depth_j(uint q) {
    uint npix = pc.wj * pc.hj;
    float a = planes_j[5u * npix + q];
    return (a >= pc.min_alpha && a > 0.0) ? planes_j[4u * npix + q] / a : -1.0;
}

void main() {
    uint x = gl_GlobalInvocationID.x;
    uint y = gl_GlobalInvocationID.y;
    if (x >= pc.wi || y >= pc.hi) {
        return;
    }
    uint npix_i = pc.wi * pc.hi;
    uint npix_j = pc.wj * pc.hj;
    uint p = y * pc.wi + x;
    terms[p] = 0.0;
    terms[npix_i + p] = 0.0;
    float a_i = planes_i[5u * npix_i + p];
    if (!(a_i >= pc.min_alpha && a_i > 0.0)) {
        return;
    }
    float d_i = planes_i[4u * npix_i + p] / a_i;
    // X = c_i + d_i W_i (x, y, 1): W's rays have camera-z 1, so d_i is the camera depth.
    vec3 pix = vec3(float(x), float(y), 1.0);
    vec3 ray = vec3(dot(vec3(cam_i[CAM_W], cam_i[CAM_W + 1], cam_i[CAM_W + 2]), pix),
                    dot(vec3(cam_i[CAM_W + 3], cam_i[CAM_W + 4], cam_i[CAM_W + 5]), pix),
                    dot(vec3(cam_i[CAM_W + 6], cam_i[CAM_W + 7], cam_i[CAM_W + 8]), pix));
    vec3 world = vec3(cam_i[CAM_C], cam_i[CAM_C + 1], cam_i[CAM_C + 2]) + d_i * ray;
    vec3 pc_j = vec3(dot(vec3(cam_j[CAM_R], cam_j[CAM_R + 1], cam_j[CAM_R + 2]), world),
                     dot(vec3(cam_j[CAM_R + 3], cam_j[CAM_R + 4], cam_j[CAM_R + 5]), world),
                     dot(vec3(cam_j[CAM_R + 6], cam_j[CAM_R + 7], cam_j[CAM_R + 8]), world)) +
                vec3(cam_j[CAM_T], cam_j[CAM_T + 1], cam_j[CAM_T + 2]);
    if (!(pc_j.z > pc.near_m)) {
        return;
    }
    float u = cam_j[CAM_FX] * pc_j.x / pc_j.z + cam_j[CAM_CX];
    float v = cam_j[CAM_FY] * pc_j.y / pc_j.z + cam_j[CAM_CY];
    if (!(u >= 0.0 && v >= 0.0 && u <= float(pc.wj - 1u) && v <= float(pc.hj - 1u))) {
        return;
    }
    uint x0 = uint(floor(u)), y0 = uint(floor(v));
    uint x1 = min(x0 + 1u, pc.wj - 1u), y1 = min(y0 + 1u, pc.hj - 1u);
    float fx = u - float(x0), fy = v - float(y0);
    uint q[4] = uint[4](y0 * pc.wj + x0, y0 * pc.wj + x1, y1 * pc.wj + x0, y1 * pc.wj + x1);
    float wgt[4] = float[4]((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy);
    float d_j = 0.0;
    for (uint c = 0u; c < 4u; ++c) {
        float dq = depth_j(q[c]);
        if (dq < 0.0) {
            return;
        }
        d_j += wgt[c] * dq;
    }
    if (pc_j.z > d_j * (1.0 + pc.depth_rel_tol)) {
        return;
    }
    float term = 0.0;
    for (uint which = 2u; which <= 3u; ++which) {
        float warped = 0.0;
        for (uint c = 0u; c < 4u; ++c) {
            warped += wgt[c] * planes_j[which * npix_j + q[c]];
        }
        float diff = planes_i[which * npix_i + p] - warped;
        term += abs(diff);
        float g = pc.k * sign(diff);
        up_i[which * npix_i + p] += g;
        if (pc.grad_j != 0u) {
            for (uint c = 0u; c < 4u; ++c) {
                add_j(which * npix_j + q[c], -g * wgt[c]);
            }
        }
    }
    terms[p] = term;
    terms[npix_i + p] = 1.0;
}
