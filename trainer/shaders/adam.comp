// Adam step of the resident optimiser, one invocation per primitive: the host optimiser
// (trainer/src/train/adam.rs) on parameters, moments and densification statistics that stay on
// the GPU between steps. Same rules, in the same order:
// - the gradient is the sum of the step's two views (grads_j is zero without a pair);
// - densification statistics first, from the mean before the update: when the mean gradient is
//   non-zero and finite, accum += |dL/dmu| * |z_i(mu)| / fx_i and count += 1 (z_i: camera depth
//   in the step's reference view);
// - a group whose step is 0 (learning rate 0) is left alone, moments included;
// - non-finite gradients count as 0;
// - held values keep moments 0 and are not updated: every slot j >= band_count[i] of the band
//   groups, and a beta_raw frozen on the Gaussian path (<= 0.5 * BETA_RAW_FROZEN);
// - beta is stepped in beta units: g_beta = g_raw / (dbeta/draw) (0 on the clamp), beta is
//   clamped to [2, BETA_MAX] and mapped back to beta_raw as primitive.rs beta_raw_from_beta.
//   In f32 the excess beta - 2 (down to 4.5e-5 at beta_raw = -10) is carried separately from the
//   2, so it keeps its relative precision;
// - a band amplitude then takes the proximal L1 step soft_threshold(x, band_shrink / (sqrt(v) + eps))
//   when band_shrink > 0 (train/adam.rs soft_threshold);
// - log-scales are clamped from below to min_log_scale after the update;
// - nothing at all when a view's key total exceeds the key buffers' capacity (its render was
//   incomplete: the host grows the buffers and repeats the step).
// The host computes each group's step size in f64, bias corrections included (Kingma & Ba's
// efficient form, each group counting its own steps: train/adam.rs AdamState::step_sizes):
// step[g] = lr_g * sqrt(1 - b2^t_g) / (1 - b1^t_g), and the update is step * m / (sqrt(v) + eps).
#version 450
#include "raster_common.glsl"

layout(local_size_x = 128) in;

layout(std430, set = 0, binding = 0) buffer Params { float params[]; };
layout(std430, set = 0, binding = 1) buffer M1 { float m1[]; };
layout(std430, set = 0, binding = 2) buffer M2 { float m2[]; };
layout(std430, set = 0, binding = 3) readonly buffer GradsI { float grads_i[]; };
layout(std430, set = 0, binding = 4) readonly buffer GradsJ { float grads_j[]; };
layout(std430, set = 0, binding = 5) readonly buffer BandCount { uint band_count[]; };
layout(std430, set = 0, binding = 6) buffer StatsAccum { float stats_accum[]; };
layout(std430, set = 0, binding = 7) buffer StatsCount { uint stats_count[]; };
layout(std430, set = 0, binding = 8) readonly buffer KeyTotals { uint key_totals[]; };

layout(push_constant) uniform Push {
    uint n;
    uint m;
    uint key_capacity;  // gate: no step if key_totals[v] > key_capacity for a v < gate_views
    uint gate_views;
    // means, log_scales, quats, opacity, beta, omega_low, band_amp, band_freq, band_phase
    float step_means;
    float step_log_scales;
    float step_quats;
    float step_opacity;
    float step_beta;
    float step_omega_low;
    float step_band_amp;
    float step_band_freq;
    float step_band_phase;
    float b1;
    float b2;
    float eps;
    float min_log_scale;
    // R_cam_from_world (row-major) and t.z of the reference view, and z-free NDC scales
    // W / (2 fx), H / (2 fy): the densification statistic (train::view_space_gradient).
    float r00;
    float r01;
    float r02;
    float r10;
    float r11;
    float r12;
    float r2x;
    float r2y;
    float r2z;
    float tz;
    float ndc_sx;
    float ndc_sy;
    // The band amplitudes' proximal L1 shrink before its division by sqrt(v) + eps
    // (train/adam.rs AdamState::band_shrink; 0: none).
    float band_shrink;
} pc;

// beta_raw at or below this is the frozen Gaussian sentinel (0.5 * BETA_RAW_FROZEN).
#define BETA_RAW_FROZEN_HALF -5e29
#define BETA_RAW_GAUSSIAN -10.0
// beta_raw_from_beta: excess beta - 2 at or below this maps to BETA_RAW_GAUSSIAN.
#define EXCESS_GAUSSIAN 4.5e-5

bool finite(float x) {
    return (floatBitsToUint(x) & 0x7f800000u) != 0x7f800000u;
}

float grad(uint k) {
    float g = grads_j[k] + grads_i[k];
    return finite(g) ? g : 0.0;
}

// Adam on value k with gradient g; returns the update (to subtract).
float adam(uint k, float g, float step) {
    float a = pc.b1 * m1[k] + (1.0 - pc.b1) * g;
    float b = pc.b2 * m2[k] + (1.0 - pc.b2) * g * g;
    m1[k] = a;
    m2[k] = b;
    return step * a / (sqrt(b) + pc.eps);
}

void update(uint k, float step) {
    params[k] -= adam(k, grad(k), step);
}

void hold(uint k) {
    m1[k] = 0.0;
    m2[k] = 0.0;
}

// log(1 + u) for u in [0, 1], accurate for small u.
float log1p_small(float u) {
    return u < 1e-3 ? u * (1.0 - u * (0.5 - u / 3.0)) : log(1.0 + u);
}

// exp(x) - 1 for x >= 0, accurate for small x.
float expm1_pos(float x) {
    return x < 1e-3 ? x * (1.0 + x * (0.5 + x / 6.0)) : exp(x) - 1.0;
}

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.n) {
        return;
    }
    for (uint v = 0u; v < pc.gate_views; ++v) {
        if (key_totals[v] > pc.key_capacity) {
            return;
        }
    }
    uint n = pc.n, m = pc.m;
    uint live = min(band_count[i], m);

    // Densification statistics (before the mean moves).
    uint km = off_means(n, m) + 3u * i;
    vec3 g_mu = vec3(grads_j[km] + grads_i[km], grads_j[km + 1u] + grads_i[km + 1u],
                     grads_j[km + 2u] + grads_i[km + 2u]);
    float norm = sqrt(g_mu.x * g_mu.x + g_mu.y * g_mu.y + g_mu.z * g_mu.z);
    if (norm > 0.0 && finite(norm)) {
        vec3 mu = vec3(params[km], params[km + 1u], params[km + 2u]);
        float z = abs(pc.r2x * mu.x + pc.r2y * mu.y + pc.r2z * mu.z + pc.tz);
        float gx = pc.r00 * g_mu.x + pc.r01 * g_mu.y + pc.r02 * g_mu.z;
        float gy = pc.r10 * g_mu.x + pc.r11 * g_mu.y + pc.r12 * g_mu.z;
        float sx = gx * z * pc.ndc_sx;
        float sy = gy * z * pc.ndc_sy;
        float stat = sqrt(sx * sx + sy * sy);
        if (finite(stat)) {
            stats_accum[i] += stat;
            stats_count[i] += 1u;
        }
    }

    if (pc.step_means != 0.0) {
        for (uint a = 0u; a < 3u; ++a) {
            update(km + a, pc.step_means);
        }
    }
    if (pc.step_log_scales != 0.0) {
        for (uint a = 0u; a < 3u; ++a) {
            update(off_log_scales(n, m) + 3u * i + a, pc.step_log_scales);
        }
    }
    for (uint a = 0u; a < 3u; ++a) {
        uint k = off_log_scales(n, m) + 3u * i + a;
        params[k] = max(params[k], pc.min_log_scale);
    }
    if (pc.step_quats != 0.0) {
        for (uint a = 0u; a < 4u; ++a) {
            update(off_quats(n, m) + 4u * i + a, pc.step_quats);
        }
    }
    if (pc.step_opacity != 0.0) {
        update(off_opacity(n, m) + i, pc.step_opacity);
    }
    if (pc.step_beta != 0.0) {
        uint k = off_beta(n, m) + i;
        float raw = params[k];
        if (raw <= BETA_RAW_FROZEN_HALF) {
            hold(k);
        } else {
            // beta = 2 + softplus(raw), clamped at BETA_MAX (derivative 0 there).
            float excess = max(raw, 0.0) + log1p_small(exp(-abs(raw)));
            float dbeta = 1.0 / (1.0 + exp(-raw));
            if (excess >= BETA_MAX - 2.0) {
                excess = BETA_MAX - 2.0;
                dbeta = 0.0;
            }
            float g = dbeta > 0.0 ? grad(k) / dbeta : 0.0;
            g = finite(g) ? g : 0.0;
            float next = clamp(excess - adam(k, g, pc.step_beta), 0.0, BETA_MAX - 2.0);
            params[k] = next <= EXCESS_GAUSSIAN ? BETA_RAW_GAUSSIAN
                        : next > 20.0            ? next
                                                 : log(expm1_pos(next));
        }
    }
    if (pc.step_omega_low != 0.0) {
        update(off_omega_low(n, m) + i, pc.step_omega_low);
    }
    for (uint j = 0u; j < m; ++j) {
        uint slot = m * i + j;
        bool held = j >= live;
        if (pc.step_band_amp != 0.0) {
            uint k = off_band_amp(n, m) + slot;
            if (held) {
                hold(k);
            } else {
                update(k, pc.step_band_amp);
                if (pc.band_shrink > 0.0) {
                    float x = params[k];
                    float t = pc.band_shrink / (sqrt(m2[k]) + pc.eps);
                    params[k] = abs(x) <= t ? 0.0 : x - sign(x) * t;
                }
            }
        }
        if (pc.step_band_freq != 0.0) {
            for (uint a = 0u; a < 3u; ++a) {
                uint k = off_band_freq(n, m) + 3u * slot + a;
                if (held) {
                    hold(k);
                } else {
                    update(k, pc.step_band_freq);
                }
            }
        }
        if (pc.step_band_phase != 0.0) {
            uint k = off_band_phase(n, m) + slot;
            if (held) {
                hold(k);
            } else {
                update(k, pc.step_band_phase);
            }
        }
    }
}
