// Rasteriser step 1, one invocation per primitive: derived parameters (rotation from the
// normalised quaternion, scales, opacity, beta), the whitened-ray data for the view, visibility,
// the tile rectangle from the bounding-Gaussian culling ellipsoid's silhouette, and the number
// of tiles the primitive is listed in (scanned next for the key offsets), and the bands in view
// form (BandView) for the rasterisers.
//
// The silhouette box solves the tangent planes x = u' z of the ellipsoid (centre mu_cam, matrix
// M = r^2 Sigma_cam) in the expanded form whose mu^4 terms cancel analytically, so f32 keeps
// its precision for small, far primitives (the CPU reference uses the equivalent dual conic in
// f64). Pixels are padded by CULL_PAD_PX as on the CPU.
//
// Compiled twice: raster_project.comp (thermal and G-buffers) and raster_project_rgb.comp
// (USE_COLOUR: also each primitive's RGB colour for the view, c = max(0, sum_k Y_k(d) sh_k + 1/2),
// d = (mu - camera centre) / |mu - camera centre|, as trainer/src/sh.rs, into `colours`).
#include "raster_common.glsl"
#ifdef USE_COLOUR
#include "raster_sh.glsl"
#endif

layout(local_size_x = 128) in;

layout(std430, set = 0, binding = 0) readonly buffer Camera { float cam[]; };
layout(std430, set = 0, binding = 1) readonly buffer Params { float params[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Views { PrimView views[]; };
layout(std430, set = 0, binding = 3) writeonly buffer TileCounts { uint tile_counts[]; };
layout(std430, set = 0, binding = 4) writeonly buffer Bands { BandView bands[]; };
layout(std430, set = 0, binding = 5) readonly buffer BandCount { uint band_count[]; };
#ifdef USE_COLOUR
layout(std430, set = 0, binding = 6) writeonly buffer Colours { vec4 colours[]; };
#endif

layout(push_constant) uniform Push {
    uint n;
    uint m;
    uint tiles_x;
    uint tiles_y;
#ifdef USE_COLOUR
    uint sh_k;  // SH coefficients per channel, (degree + 1)^2
#endif
} pc;

mat3 row_major(uint base) {
    // GLSL matrices are column-major: transpose the row-major floats.
    return transpose(mat3(cam[base], cam[base + 1], cam[base + 2],
                          cam[base + 3], cam[base + 4], cam[base + 5],
                          cam[base + 6], cam[base + 7], cam[base + 8]));
}

// Tangent range of the ellipsoid along one image axis: returns (lo, hi) of x/z, or false.
bool tangent_range(float mx, float mz, float mxx, float mxz, float mzz, out vec2 range) {
    float a = mz * mz - mzz;
    float half_b = mx * mz - mxz;
    float disc = mz * mz * mxx + mx * mx * mzz - 2.0 * mx * mz * mxz + mxz * mxz - mxx * mzz;
    if (!(a > 0.0)) {
        return false;
    }
    float root = sqrt(max(disc, 0.0));
    range = vec2((half_b - root) / a, (half_b + root) / a);
    return !(isinf(range.x) || isinf(range.y) || isnan(range.x) || isnan(range.y));
}

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.n) {
        return;
    }
    uint n = pc.n;
    uint m = pc.m;
    vec3 mu = vec3(params[off_means(n, m) + 3u * i], params[off_means(n, m) + 3u * i + 1u],
                   params[off_means(n, m) + 3u * i + 2u]);
    vec3 s = exp(vec3(params[off_log_scales(n, m) + 3u * i], params[off_log_scales(n, m) + 3u * i + 1u],
                      params[off_log_scales(n, m) + 3u * i + 2u]));
    vec4 q = vec4(params[off_quats(n, m) + 4u * i], params[off_quats(n, m) + 4u * i + 1u],
                  params[off_quats(n, m) + 4u * i + 2u], params[off_quats(n, m) + 4u * i + 3u]);
    float qn2 = dot(q, q);
    vec4 u = qn2 > QUAT_NORM_MIN * QUAT_NORM_MIN ? q / sqrt(qn2) : vec4(1.0, 0.0, 0.0, 0.0);
    float w = u.x, x = u.y, y = u.z, z = u.w;
    // Row-major rotation as in primitive.rs, stored column-major for GLSL.
    mat3 R = transpose(mat3(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
                            2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
                            2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)));
    float logit = params[off_opacity(n, m) + i];
    float opacity = 1.0 / (1.0 + exp(-logit));
    float raw = params[off_beta(n, m) + i];
    float beta = min(2.0 + max(raw, 0.0) + log(1.0 + exp(-abs(raw))), BETA_MAX);
    // Live bands (capacity adaptation drops the others: they hold zeros and take no part).
    uint live = min(band_count[i], m);
    // beta_raw of a primitive frozen on the Gaussian path (primitive.rs BETA_RAW_FROZEN, -1e30):
    // beta = 2 exactly and no beta gradient; the backward pass skips that term.
    bool frozen = raw <= -5.0e29;
    float psi_high = 0.0;
    for (uint j = 0u; j < live; ++j) {
        psi_high += abs(params[off_band_amp(n, m) + m * i + j]);
    }

    vec3 c = vec3(cam[CAM_C], cam[CAM_C + 1], cam[CAM_C + 2]);
    mat3 W = row_major(CAM_W);
    mat3 Rcw = row_major(CAM_R);
    vec3 tcw = vec3(cam[CAM_T], cam[CAM_T + 1], cam[CAM_T + 2]);
    // N = diag(1/s) R^T
    mat3 N = transpose(R);
    N = mat3(vec3(N[0]) / s, vec3(N[1]) / s, vec3(N[2]) / s);  // scale row k by 1/s_k
    vec3 a = N * (c - mu);
    mat3 B = N * W;
    vec3 mu_cam = Rcw * mu + tcw;
    float near_m = cam[CAM_NEAR];

    bool finite = !(any(isnan(a)) || any(isinf(a)) || any(isnan(B[0])) || any(isinf(B[0])) ||
                    any(isnan(B[1])) || any(isinf(B[1])) || any(isnan(B[2])) || any(isinf(B[2])) ||
                    isnan(opacity) || isnan(beta));
    bool visible = finite && mu_cam.z > near_m && opacity >= ALPHA_MIN;

    uvec4 rect = uvec4(0u);
    if (visible) {
        uint width = uint(cam[CAM_WIDTH]);
        uint height = uint(cam[CAM_HEIGHT]);
        bool cull = cam[CAM_CULL] != 0.0;
        rect = uvec4(0u, 0u, pc.tiles_x, pc.tiles_y);
        if (cull) {
            float r2 = max(log(255.0 * opacity), 1.0);
            mat3 Mrot = Rcw * R;  // camera from primitive axes
            mat3 S2 = mat3(0.0);
            S2[0][0] = s.x * s.x;
            S2[1][1] = s.y * s.y;
            S2[2][2] = s.z * s.z;
            mat3 E = r2 * (Mrot * S2 * transpose(Mrot));
            float z_extent = sqrt(E[2][2]);
            vec2 ur, vr;
            if (mu_cam.z - z_extent > near_m &&
                tangent_range(mu_cam.x, mu_cam.z, E[0][0], E[2][0], E[2][2], ur) &&
                tangent_range(mu_cam.y, mu_cam.z, E[1][1], E[2][1], E[2][2], vr)) {
                float fx = cam[CAM_FX], fy = cam[CAM_FY], cx = cam[CAM_CX], cy = cam[CAM_CY];
                float u0 = fx * ur.x + cx, u1 = fx * ur.y + cx;
                float v0 = fy * vr.x + cy, v1 = fy * vr.y + cy;
                float pad_u = CULL_PAD_PX + 1e-6 * max(abs(u0), abs(u1));
                float pad_v = CULL_PAD_PX + 1e-6 * max(abs(v0), abs(v1));
                u0 -= pad_u; u1 += pad_u; v0 -= pad_v; v1 += pad_v;
                float wmax = float(width - 1u), hmax = float(height - 1u);
                if (u1 < 0.0 || v1 < 0.0 || u0 > wmax || v0 > hmax) {
                    rect = uvec4(0u);
                } else {
                    float t = float(TILE_SIZE);
                    rect = uvec4(uint(floor(max(u0, 0.0) / t)), uint(floor(max(v0, 0.0) / t)),
                                 min(uint(floor(min(u1, wmax) / t)) + 1u, pc.tiles_x),
                                 min(uint(floor(min(v1, hmax) / t)) + 1u, pc.tiles_y));
                }
            }
        }
    }
    PrimView v;
    // Rows of B for B p: store B's rows (B is column-major: row k = (B[0][k], B[1][k], B[2][k])).
    v.b0 = vec4(B[0][0], B[1][0], B[2][0], params[off_omega_low(n, m) + i]);
    v.b1 = vec4(B[0][1], B[1][1], B[2][1], float(live));
    v.b2 = vec4(B[0][2], B[1][2], B[2][2], frozen ? 1.0 : 0.0);
    v.a_opacity = vec4(a, opacity);
    v.cmm_beta = vec4(c - mu, beta);
    float cut = log(255.0 * opacity);
    float q_max = cut > 0.0 ? pow(cut, 2.0 / beta) : 0.0;
    v.misc = vec4(psi_high, mu_cam.z, visible ? 1.0 : 0.0, q_max);
    v.rect = rect;
    views[i] = v;
    // Bands in view form (BandView): g = 2 pi W^T f, theta0 = 2 pi f . (c - mu) + phase.
    const float TWO_PI = 6.28318530717958647692;
    for (uint j = 0u; j < m; ++j) {
        uint bj = m * i + j;
        vec3 f = vec3(params[off_band_freq(n, m) + 3u * bj], params[off_band_freq(n, m) + 3u * bj + 1u],
                      params[off_band_freq(n, m) + 3u * bj + 2u]);
        vec3 g = TWO_PI * (f * W);  // row vector f^T W = (W^T f)^T
        float theta0 = TWO_PI * dot(f, c - mu) + params[off_band_phase(n, m) + bj];
        bands[bj] = BandView(vec4(g, theta0), vec4(params[off_band_amp(n, m) + bj], 0.0, 0.0, 0.0));
    }
    tile_counts[i] = visible ? (rect.z - rect.x) * (rect.w - rect.y) : 0u;
#ifdef USE_COLOUR
    // The colour seen from this view (sh.rs eval): (r, g, b, 0).
    float y_sh[16];
    float norm;
    sh_basis(sh_direction(mu - c, norm), y_sh);
    uint k_eval = min(pc.sh_k, 16u);
    uint sh_base = off_sh(n, m) + 3u * pc.sh_k * i;
    vec3 pre = vec3(0.5);
    for (uint k = 0u; k < k_eval; ++k) {
        pre += y_sh[k] * vec3(params[sh_base + 3u * k], params[sh_base + 3u * k + 1u],
                           params[sh_base + 3u * k + 2u]);
    }
    colours[i] = vec4(max(pre, vec3(0.0)), 0.0);
#endif
}
