// Rasteriser step 4, one workgroup per 16x16 tile, one invocation per pixel: evaluates each
// primitive of the tile (front to back) at the point of the pixel ray where its support peaks,
// and blends the thermal image and the G-buffers exactly as the CPU reference's forward pass
// (trainer/src/render/forward.rs): alpha = min(0.99, o exp(-q^(beta/2))), samples below 1/255 or
// behind the near plane skipped, early stop before T would fall below 1e-4.
// Output planes (each width*height floats, row-major): thermal, psi_low, psi_high, psi_beta,
// depth (alpha-weighted camera depth), alpha.
#version 450
#include "raster_common.glsl"

layout(local_size_x = 16, local_size_y = 16) in;

layout(std430, set = 0, binding = 0) readonly buffer Camera { float cam[]; };
layout(std430, set = 0, binding = 1) readonly buffer Params { float params[]; };
layout(std430, set = 0, binding = 2) readonly buffer Views { PrimView views[]; };
layout(std430, set = 0, binding = 3) readonly buffer Values { uint sorted_prims[]; };
layout(std430, set = 0, binding = 4) readonly buffer Ranges { uvec2 ranges[]; };
layout(std430, set = 0, binding = 5) writeonly buffer Out { float planes[]; };

layout(push_constant) uniform Push {
    uint n;
    uint m;
    uint width;
    uint height;
    uint tiles_x;
} pc;

const float TWO_PI = 6.28318530717958647692;

void main() {
    uint x = gl_GlobalInvocationID.x;
    uint y = gl_GlobalInvocationID.y;
    if (x >= pc.width || y >= pc.height) {
        return;
    }
    uint tile = gl_WorkGroupID.y * pc.tiles_x + gl_WorkGroupID.x;
    uvec2 range = ranges[tile];
    vec3 p = vec3(float(x), float(y), 1.0);
    mat3 W = transpose(mat3(cam[CAM_W], cam[CAM_W + 1], cam[CAM_W + 2], cam[CAM_W + 3], cam[CAM_W + 4],
                            cam[CAM_W + 5], cam[CAM_W + 6], cam[CAM_W + 7], cam[CAM_W + 8]));
    vec3 d = W * p;
    float near_m = cam[CAM_NEAR];
    uint n = pc.n;
    uint m = pc.m;

    float trans = 1.0;
    float acc[6] = float[6](0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for (uint k = range.x; k < range.y; ++k) {
        uint i = sorted_prims[k];
        // Fields are read as needed: most samples are rejected after the first 64 bytes.
        vec4 a_o = views[i].a_opacity;
        vec3 b = vec3(dot(views[i].b0.xyz, p), dot(views[i].b1.xyz, p), dot(views[i].b2.xyz, p));
        float bb = dot(b, b);
        float t = -dot(a_o.xyz, b) / bb;
        if (!(t > near_m)) {
            continue;
        }
        vec3 r = a_o.xyz + t * b;
        float q = dot(r, r);
        vec4 misc = views[i].misc;
        if (q > misc.w * (1.0 + QMAX_MARGIN) + 1e-7) {
            continue;
        }
        vec4 cmm_beta = views[i].cmm_beta;
        float beta = cmm_beta.w;
        float mb = pow(q, 0.5 * beta);
        float alpha = min(a_o.w * exp(-mb), ALPHA_MAX);
        if (!(alpha >= ALPHA_MIN)) {
            continue;
        }
        float next = trans * (1.0 - alpha);
        if (next < T_MIN) {
            break;
        }
        vec3 delta = cmm_beta.xyz + t * d;
        float pre = params[off_omega_low(n, m) + i];
        for (uint j = 0u; j < m; ++j) {
            uint bj = m * i + j;
            vec3 f = vec3(params[off_band_freq(n, m) + 3u * bj], params[off_band_freq(n, m) + 3u * bj + 1u],
                          params[off_band_freq(n, m) + 3u * bj + 2u]);
            pre += params[off_band_amp(n, m) + bj] * cos(TWO_PI * dot(f, delta) + params[off_band_phase(n, m) + bj]);
        }
        float w = trans * alpha;
        acc[0] += w * max(pre, 0.0);
        acc[1] += w * params[off_omega_low(n, m) + i];
        acc[2] += w * misc.x;
        acc[3] += w * beta;
        acc[4] += w * t;
        acc[5] += w;
        trans = next;
    }
    uint npix = pc.width * pc.height;
    uint pidx = y * pc.width + x;
    for (uint c = 0u; c < 6u; ++c) {
        planes[c * npix + pidx] = acc[c];
    }
}
