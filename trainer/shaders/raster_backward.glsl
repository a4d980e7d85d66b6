// Backward rasteriser body, compiled twice: raster_backward_atomic.comp (USE_FLOAT_ATOMICS:
// atomicAdd(float)) and raster_backward_cas.comp (compare-and-swap loop on the bits, for drivers
// without float atomics). One workgroup per 16x16 tile, one invocation per pixel.
//
// Mirrors the CPU reference (trainer/src/render/backward.rs) sample by sample. The CPU walks the
// samples back to front with S_after; here each pixel replays its samples twice front to back:
// pass 1 sums W = sum_l T_l alpha_l w_l (w = upstream-weighted values), pass 2 uses
//   dL/dalpha_i = T_i w_i - (W - W_{<=i}) / (1 - alpha_i),   1 - alpha_i >= 0.01,
// which equals T_i (w_i - S_after_i) and needs no per-pixel sample list.
//
// Per sample it accumulates, per primitive, the view-space gradients (dL/da, dL/dB p^T, the
// direct dL/dmu, dL/dopacity, dL/dbeta: 17 floats, ACC_STRIDE) and the spectrum parameters'
// gradients (omega_low, band amp/phase/freq) straight into the gradient buffer (the parameter
// layout of raster_common.glsl). raster_backward_finish chains the view-space sums to the
// primitive parameters.

#include "raster_common.glsl"

layout(local_size_x = 16, local_size_y = 16) in;

layout(std430, set = 0, binding = 0) readonly buffer Camera { float cam[]; };
layout(std430, set = 0, binding = 1) readonly buffer Params { float params[]; };
layout(std430, set = 0, binding = 2) readonly buffer Views { PrimView views[]; };
layout(std430, set = 0, binding = 3) readonly buffer Values { uint sorted_prims[]; };
layout(std430, set = 0, binding = 4) readonly buffer Ranges { uvec2 ranges[]; };
layout(std430, set = 0, binding = 5) readonly buffer Upstream { float upstream[]; };
#ifdef USE_FLOAT_ATOMICS
layout(std430, set = 0, binding = 6) buffer Acc { float acc[]; };
layout(std430, set = 0, binding = 7) buffer Grads { float grads[]; };
void acc_add_raw(uint idx, float v) {
    if (v != 0.0) {
        atomicAdd(acc[idx], v);
    }
}
void grad_add_raw(uint idx, float v) {
    if (v != 0.0) {
        atomicAdd(grads[idx], v);
    }
}
#else
layout(std430, set = 0, binding = 6) buffer Acc { uint acc[]; };
layout(std430, set = 0, binding = 7) buffer Grads { uint grads[]; };
void acc_add_raw(uint idx, float v) {
    if (v == 0.0) {
        return;
    }
    uint seen = acc[idx];
    for (;;) {
        uint expected = seen;
        seen = atomicCompSwap(acc[idx], expected, floatBitsToUint(uintBitsToFloat(expected) + v));
        if (seen == expected) {
            break;
        }
    }
}
void grad_add_raw(uint idx, float v) {
    if (v == 0.0) {
        return;
    }
    uint seen = grads[idx];
    for (;;) {
        uint expected = seen;
        seen = atomicCompSwap(grads[idx], expected, floatBitsToUint(uintBitsToFloat(expected) + v));
        if (seen == expected) {
            break;
        }
    }
}
#endif

#ifdef USE_SUBGROUP_REDUCE
// Every invocation of a subgroup walks the same tile list in lockstep (see main), so at each
// call all active invocations add to the same index: sum across the subgroup first, then one
// atomic per subgroup instead of one per pixel.
void acc_add(uint idx, float v) {
    float total = subgroupAdd(v);
    if (subgroupElect()) {
        acc_add_raw(idx, total);
    }
}
void grad_add(uint idx, float v) {
    float total = subgroupAdd(v);
    if (subgroupElect()) {
        grad_add_raw(idx, total);
    }
}
#else
void acc_add(uint idx, float v) {
    acc_add_raw(idx, v);
}
void grad_add(uint idx, float v) {
    grad_add_raw(idx, v);
}
#endif

#define ACC_STRIDE 17u  // g_a (3), g_bp (9, row-major: row = component of b), g_mu (3), g_o, g_beta

layout(push_constant) uniform Push {
    uint n;
    uint m;
    uint width;
    uint height;
    uint tiles_x;
} pc;

const float TWO_PI = 6.28318530717958647692;

struct Sample {
    float alpha;
    float s;
    bool clamped;
    float q;
    float mb;
    float t;
    vec3 r;
    vec3 b;
    float bb;
    vec3 delta;
    float pre;  // spectrum before the ReLU
};

bool eval_sample(uint i, PrimView v, vec3 p, vec3 d, float near_m, out Sample smp) {
    vec3 b = vec3(dot(v.b0.xyz, p), dot(v.b1.xyz, p), dot(v.b2.xyz, p));
    float bb = dot(b, b);
    float t = -dot(v.a_opacity.xyz, b) / bb;
    if (!(t > near_m)) {
        return false;
    }
    vec3 r = v.a_opacity.xyz + t * b;
    float q = dot(r, r);
    if (q > v.misc.w * (1.0 + QMAX_MARGIN) + 1e-7) {
        return false;
    }
    float mb = pow(q, 0.5 * v.cmm_beta.w);
    float s = exp(-mb);
    float os = v.a_opacity.w * s;
    bool clamped = os > ALPHA_MAX;
    float alpha = clamped ? ALPHA_MAX : os;
    if (!(alpha >= ALPHA_MIN)) {
        return false;
    }
    uint n = pc.n, m = pc.m;
    vec3 delta = v.cmm_beta.xyz + t * d;
    float pre = params[off_omega_low(n, m) + i];
    for (uint j = 0u; j < m; ++j) {
        uint bj = m * i + j;
        vec3 f = vec3(params[off_band_freq(n, m) + 3u * bj], params[off_band_freq(n, m) + 3u * bj + 1u],
                      params[off_band_freq(n, m) + 3u * bj + 2u]);
        pre += params[off_band_amp(n, m) + bj] * cos(TWO_PI * dot(f, delta) + params[off_band_phase(n, m) + bj]);
    }
    smp = Sample(alpha, s, clamped, q, mb, t, r, b, bb, delta, pre);
    return true;
}

// Upstream-weighted value of a sample: sum_k g_k v_k over thermal, psi_low, psi_high, psi_beta,
// depth, alpha.
float weighted(float g[6], Sample smp, uint i, PrimView v) {
    return g[0] * max(smp.pre, 0.0) + g[1] * params[off_omega_low(pc.n, pc.m) + i] + g[2] * v.misc.x +
           g[3] * v.cmm_beta.w + g[4] * smp.t + g[5];
}

void main() {
    uint x = gl_GlobalInvocationID.x;
    uint y = gl_GlobalInvocationID.y;
    if (x >= pc.width || y >= pc.height) {
        return;
    }
    uint npix = pc.width * pc.height;
    uint pidx = y * pc.width + x;
    float g[6];
    bool any_g = false;
    for (uint c = 0u; c < 6u; ++c) {
        g[c] = upstream[c * npix + pidx];
        any_g = any_g || g[c] != 0.0;
    }
    if (!any_g) {
        return;
    }
    uint tile = gl_WorkGroupID.y * pc.tiles_x + gl_WorkGroupID.x;
    uvec2 range = ranges[tile];
    vec3 p = vec3(float(x), float(y), 1.0);
    mat3 W = transpose(mat3(cam[CAM_W], cam[CAM_W + 1], cam[CAM_W + 2], cam[CAM_W + 3], cam[CAM_W + 4],
                            cam[CAM_W + 5], cam[CAM_W + 6], cam[CAM_W + 7], cam[CAM_W + 8]));
    vec3 d = W * p;
    float near_m = cam[CAM_NEAR];
    uint n = pc.n, m = pc.m;

    // Pass 1: the total upstream-weighted blend W and where the pixel stopped.
    float trans = 1.0;
    float w_total = 0.0;
    uint end = range.x;
    for (uint k = range.x; k < range.y; ++k) {
        uint i = sorted_prims[k];
        PrimView v = views[i];
        Sample smp;
        if (!eval_sample(i, v, p, d, near_m, smp)) {
            continue;
        }
        float next = trans * (1.0 - smp.alpha);
        if (next < T_MIN) {
            break;
        }
        w_total += trans * smp.alpha * weighted(g, smp, i, v);
        trans = next;
        end = k + 1u;
    }

    // Pass 2: per-sample gradients, front to back. The loop runs to the last sample of any
    // invocation of the subgroup and every accumulation is called by every invocation (zero
    // where its pixel has no sample), so the subgroup-reducing variant sums the same index.
#ifdef USE_SUBGROUP_REDUCE
    uint loop_end = subgroupMax(end);
#else
    uint loop_end = end;
#endif
    trans = 1.0;
    float w_upto = 0.0;
    for (uint k = range.x; k < loop_end; ++k) {
        uint i = sorted_prims[k];
        PrimView v = views[i];
        Sample smp;
        bool valid = k < end && eval_sample(i, v, p, d, near_m, smp);
        float wt = 0.0;
        float d_alpha = 0.0;
        float g_f = 0.0;
        if (valid) {
            float w_i = weighted(g, smp, i, v);
            w_upto += trans * smp.alpha * w_i;
            d_alpha = trans * w_i - (w_total - w_upto) / (1.0 - smp.alpha);
            wt = trans * smp.alpha;
            trans *= 1.0 - smp.alpha;
            g_f = smp.pre > 0.0 ? wt * g[0] : 0.0;
        } else {
            smp = Sample(0.0, 0.0, true, 0.0, 0.0, 0.0, vec3(0.0), vec3(0.0), 1.0, vec3(0.0), 0.0);
        }

        // Spectrum.
        grad_add(off_omega_low(n, m) + i, wt * g[1] + g_f);
        vec3 g_delta = vec3(0.0);
        for (uint j = 0u; j < m; ++j) {
            uint bj = m * i + j;
            float amp = params[off_band_amp(n, m) + bj];
            vec3 f = vec3(params[off_band_freq(n, m) + 3u * bj], params[off_band_freq(n, m) + 3u * bj + 1u],
                          params[off_band_freq(n, m) + 3u * bj + 2u]);
            float theta = TWO_PI * dot(f, smp.delta) + params[off_band_phase(n, m) + bj];
            float g_theta = -g_f * amp * sin(theta);
            grad_add(off_band_amp(n, m) + bj, wt * g[2] * sign(amp) + g_f * cos(theta));
            grad_add(off_band_phase(n, m) + bj, g_theta);
            for (uint a = 0u; a < 3u; ++a) {
                grad_add(off_band_freq(n, m) + 3u * bj + a, g_theta * TWO_PI * smp.delta[a]);
            }
            g_delta += g_theta * TWO_PI * f;
        }
        uint base = ACC_STRIDE * i;
        // delta = (c - mu) + t d
        for (uint a = 0u; a < 3u; ++a) {
            acc_add(base + 12u + a, -g_delta[a]);
        }
        float g_t = dot(g_delta, d) + wt * g[4];
        // Support and opacity (no gradient through a clamped alpha).
        float g_beta = wt * g[3];
        float g_q = 0.0;
        float g_o = 0.0;
        if (!smp.clamped) {
            g_o = d_alpha * smp.s;
            float g_s = d_alpha * v.a_opacity.w;
            float half_beta = 0.5 * v.cmm_beta.w;
            g_q = -g_s * smp.s * half_beta * pow(smp.q, half_beta - 1.0);
            if (smp.q > 0.0) {
                g_beta += -g_s * smp.s * smp.mb * 0.5 * log(smp.q);
            }
        }
        acc_add(base + 15u, g_o);
        acc_add(base + 16u, g_beta);
        // (q*, t*) -> (a, b)
        float inv_bb = 1.0 / smp.bb;
        vec3 a_vec = v.a_opacity.xyz;
        for (uint c = 0u; c < 3u; ++c) {
            acc_add(base + c, g_q * 2.0 * smp.r[c] - g_t * smp.b[c] * inv_bb);
            float g_b = g_q * 2.0 * smp.t * smp.r[c] - g_t * (a_vec[c] + 2.0 * smp.t * smp.b[c]) * inv_bb;
            acc_add(base + 3u + 3u * c, g_b * p.x);
            acc_add(base + 3u + 3u * c + 1u, g_b * p.y);
            acc_add(base + 3u + 3u * c + 2u, g_b * p.z);
        }
    }
}
