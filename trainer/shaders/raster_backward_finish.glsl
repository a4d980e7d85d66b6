// Backward rasteriser, final step, one invocation per primitive: chains the view-space gradient
// sums of raster_backward_* (raster_common.glsl: dL/da, dL/dB p^T, dL/dopacity, dL/dbeta,
// dL/domega_low, dL/dpsi_high, per band dL/damp, dL/dtheta0, sum dL/dtheta t p) to the
// primitive parameters
// (mean, log-scales, quaternion through its normalisation, opacity logit, raw beta, the
// spectrum), as the CPU reference's final loop (trainer/src/render/backward.rs).
// Bands (BandView): theta = 2 pi f . (c - mu) + phase + t 2 pi f . (W p), so
//   dL/dphase = dL/dtheta0,  dL/df = 2 pi (dL/dtheta0 (c - mu) + W sum dL/dtheta t p),
//   and the mean gets -2 pi f dL/dtheta0 from every band.
// Compiled twice: raster_backward_finish.comp, and raster_backward_finish_rgb.comp (USE_COLOUR),
// which also chains the colour's sums dL/dc (ACC_COLOUR) through the ReLU to the SH
// coefficients (Y_k(d)) and to the mean through d = (mu - c) / |mu - c|, as trainer/src/sh.rs
// backward.
#include "raster_common.glsl"
#ifdef USE_COLOUR
#include "raster_sh.glsl"
#endif

layout(local_size_x = 128) in;

layout(std430, set = 0, binding = 0) readonly buffer Camera { float cam[]; };
layout(std430, set = 0, binding = 1) readonly buffer Params { float params[]; };
layout(std430, set = 0, binding = 2) readonly buffer Acc { float acc[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Grads { float grads[]; };
layout(std430, set = 0, binding = 4) readonly buffer Views { PrimView views[]; };

layout(push_constant) uniform Push {
    uint n;
    uint m;
#ifdef USE_COLOUR
    uint sh_k;  // SH coefficients per channel, (degree + 1)^2
#endif
} pc;

const float TWO_PI = 6.28318530717958647692;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.n) {
        return;
    }
    uint n = pc.n, m = pc.m;
    uint base = acc_fields(m) * i;
    vec3 g_a = vec3(acc[base], acc[base + 1u], acc[base + 2u]);
    float g_bp[9];
    for (uint k = 0u; k < 9u; ++k) {
        g_bp[k] = acc[base + 3u + k];
    }
    float g_o = acc[base + 12u];
    float g_beta = acc[base + 13u];

    vec3 mu = vec3(params[off_means(n, m) + 3u * i], params[off_means(n, m) + 3u * i + 1u],
                   params[off_means(n, m) + 3u * i + 2u]);
    vec3 s = exp(vec3(params[off_log_scales(n, m) + 3u * i], params[off_log_scales(n, m) + 3u * i + 1u],
                      params[off_log_scales(n, m) + 3u * i + 2u]));
    vec4 q = vec4(params[off_quats(n, m) + 4u * i], params[off_quats(n, m) + 4u * i + 1u],
                  params[off_quats(n, m) + 4u * i + 2u], params[off_quats(n, m) + 4u * i + 3u]);
    float qn2 = dot(q, q);
    bool degenerate = !(qn2 > QUAT_NORM_MIN * QUAT_NORM_MIN);
    float norm = degenerate ? 0.0 : sqrt(qn2);
    vec4 u = degenerate ? vec4(1.0, 0.0, 0.0, 0.0) : q / norm;
    float w = u.x, x = u.y, y = u.z, z = u.w;
    float R[9] = float[9](1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
                          2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
                          2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y));
    float N[9];  // N = diag(1/s) R^T, row-major
    for (uint r = 0u; r < 3u; ++r) {
        for (uint c = 0u; c < 3u; ++c) {
            N[3u * r + c] = R[3u * c + r] / s[r];
        }
    }
    vec3 c_cam = vec3(cam[CAM_C], cam[CAM_C + 1], cam[CAM_C + 2]);
    vec3 cmm = c_cam - mu;

    // Spectrum. psi_high = sum over the live bands of |amp_j| gives live band j
    // sign(amp_j) dL/dpsi_high (sign(0) = 0); dropped slots get none.
    grads[off_omega_low(n, m) + i] = acc[base + 14u];
    float g_psi_high = acc[base + 15u];
    uint live = uint(views[i].b1.w);
    vec3 acc_mu = vec3(0.0);
    for (uint j = 0u; j < m; ++j) {
        uint bj = m * i + j;
        uint f = base + ACC_GEOM + ACC_BAND * j;
        float g_theta0 = acc[f + 1u];
        vec3 s_tp = vec3(acc[f + 2u], acc[f + 3u], acc[f + 4u]);
        vec3 freq = vec3(params[off_band_freq(n, m) + 3u * bj], params[off_band_freq(n, m) + 3u * bj + 1u],
                         params[off_band_freq(n, m) + 3u * bj + 2u]);
        // W s_tp with W row-major in cam[CAM_W..]
        vec3 w_stp = vec3(dot(vec3(cam[CAM_W], cam[CAM_W + 1], cam[CAM_W + 2]), s_tp),
                          dot(vec3(cam[CAM_W + 3], cam[CAM_W + 4], cam[CAM_W + 5]), s_tp),
                          dot(vec3(cam[CAM_W + 6], cam[CAM_W + 7], cam[CAM_W + 8]), s_tp));
        vec3 g_freq = TWO_PI * (g_theta0 * cmm + w_stp);
        float amp = params[off_band_amp(n, m) + bj];
        grads[off_band_amp(n, m) + bj] = acc[f] + (j < live ? sign(amp) * g_psi_high : 0.0);
        grads[off_band_phase(n, m) + bj] = g_theta0;
        for (uint a = 0u; a < 3u; ++a) {
            grads[off_band_freq(n, m) + 3u * bj + a] = g_freq[a];
        }
        acc_mu -= TWO_PI * g_theta0 * freq;
    }

    // dL/dN = g_a (c - mu)^T + g_bp W^T
    float g_n[9];
    for (uint r = 0u; r < 3u; ++r) {
        for (uint c = 0u; c < 3u; ++c) {
            float bw = g_bp[3u * r] * cam[CAM_W + 3u * c] + g_bp[3u * r + 1u] * cam[CAM_W + 3u * c + 1u] +
                       g_bp[3u * r + 2u] * cam[CAM_W + 3u * c + 2u];
            g_n[3u * r + c] = g_a[r] * cmm[c] + bw;
        }
    }
    // mean: direct part minus N^T g_a
    vec3 nt_ga = vec3(N[0] * g_a.x + N[3] * g_a.y + N[6] * g_a.z, N[1] * g_a.x + N[4] * g_a.y + N[7] * g_a.z,
                      N[2] * g_a.x + N[5] * g_a.y + N[8] * g_a.z);
    vec3 g_mu = acc_mu - nt_ga;
#ifdef USE_COLOUR
    {
        // Colour: c = max(0, pre), pre = 1/2 + sum_k Y_k(d) sh_k (sh.rs backward).
        uint ac = base + ACC_COLOUR;
        vec3 g_colour = vec3(acc[ac], acc[ac + 1u], acc[ac + 2u]);
        float norm;
        vec3 dir = sh_direction(mu - c_cam, norm);
        float y_sh[16];
        vec3 dy_sh[16];
        sh_basis(dir, y_sh);
        sh_basis_grad(dir, dy_sh);
        uint k_all = pc.sh_k;
        uint k_eval = min(k_all, 16u);
        uint sh_base = off_sh(n, m) + 3u * k_all * i;
        vec3 pre = vec3(0.5);
        for (uint k = 0u; k < k_eval; ++k) {
            pre += y_sh[k] * vec3(params[sh_base + 3u * k], params[sh_base + 3u * k + 1u],
                               params[sh_base + 3u * k + 2u]);
        }
        vec3 g_pre = vec3(pre.x > 0.0 ? g_colour.x : 0.0, pre.y > 0.0 ? g_colour.y : 0.0,
                          pre.z > 0.0 ? g_colour.z : 0.0);
        vec3 g_dir = vec3(0.0);
        for (uint k = 0u; k < k_all; ++k) {
            // Degrees above 3 take no part (sh.rs): their coefficients get no gradient.
            bool used = k < k_eval;
            vec3 coeff = vec3(params[sh_base + 3u * k], params[sh_base + 3u * k + 1u],
                              params[sh_base + 3u * k + 2u]);
            float yk = used ? y_sh[min(k, 15u)] : 0.0;
            for (uint ch = 0u; ch < 3u; ++ch) {
                grads[sh_base + 3u * k + ch] = yk * g_pre[ch];
            }
            float gy = 0.0;
            for (uint ch = 0u; ch < 3u; ++ch) {
                gy += coeff[ch] * g_pre[ch];
            }
            g_dir += used ? gy * dy_sh[min(k, 15u)] : vec3(0.0);
        }
        if (norm != 0.0) {
            float dd = g_dir.x * dir.x + g_dir.y * dir.y + g_dir.z * dir.z;
            g_mu += vec3((g_dir.x - dd * dir.x) / norm, (g_dir.y - dd * dir.y) / norm,
                         (g_dir.z - dd * dir.z) / norm);
        }
    }
#endif
    for (uint a = 0u; a < 3u; ++a) {
        grads[off_means(n, m) + 3u * i + a] = g_mu[a];
    }
    // N_rc = R_cr / s_r
    float g[9];
    for (uint r = 0u; r < 3u; ++r) {
        float g_ls = 0.0;
        for (uint c = 0u; c < 3u; ++c) {
            g_ls -= g_n[3u * r + c] * N[3u * r + c];
            g[3u * c + r] = g_n[3u * r + c] / s[r];
        }
        grads[off_log_scales(n, m) + 3u * i + r] = g_ls;
    }
    // Quaternion through the normalisation (primitive.rs quat_backward).
    vec4 gq = vec4(0.0);
    if (!degenerate) {
        float gw = 2.0 * (-z * g[1] + y * g[2] + z * g[3] - x * g[5] - y * g[6] + x * g[7]);
        float gx = 2.0 * (y * g[1] + z * g[2] + y * g[3] - 2.0 * x * g[4] - w * g[5] + z * g[6] + w * g[7] - 2.0 * x * g[8]);
        float gy = 2.0 * (-2.0 * y * g[0] + x * g[1] + w * g[2] + x * g[3] + z * g[5] - w * g[6] + z * g[7] - 2.0 * y * g[8]);
        float gz = 2.0 * (-2.0 * z * g[0] - w * g[1] + x * g[2] + w * g[3] - 2.0 * z * g[4] + y * g[5] + x * g[6] + y * g[7]);
        vec4 gu = vec4(gw, gx, gy, gz);
        gq = (gu - dot(gu, u) * u) / norm;
    }
    for (uint a = 0u; a < 4u; ++a) {
        grads[off_quats(n, m) + 4u * i + a] = gq[a];
    }
    float logit = params[off_opacity(n, m) + i];
    float o = 1.0 / (1.0 + exp(-logit));
    grads[off_opacity(n, m) + i] = g_o * o * (1.0 - o);
    float raw = params[off_beta(n, m) + i];
    float beta = 2.0 + max(raw, 0.0) + log(1.0 + exp(-abs(raw)));
    float d_beta = beta >= BETA_MAX ? 0.0 : 1.0 / (1.0 + exp(-raw));
    grads[off_beta(n, m) + i] = g_beta * d_beta;
}
