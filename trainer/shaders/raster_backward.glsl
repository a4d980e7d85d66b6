// Backward rasteriser body, compiled four times (raster_backward_{atomic,cas}{,_sg}.comp), and
// four more with USE_COLOUR (raster_backward_*_rgb.comp):
//   USE_FLOAT_ATOMICS  global sums with atomicAdd(float); otherwise a compare-and-swap loop on
//                      the bits, for drivers without float atomics (Raspberry Pi 5).
//   USE_SUBGROUP_REDUCE each subgroup sums its pixels' contributions (subgroupAdd) and one
//                      invocation adds the sum to global memory; without it every pixel adds
//                      its own. (Batching the subgroup sums in shared memory and adding them per
//                      tile was measured 2.8x slower on lavapipe: its barriers are expensive.)
//   USE_COLOUR         the RGB planes too: their upstream dL/d(R, G, B) enters w (each
//                      sample's colour from raster_project_rgb) and each primitive gets the sums
//                      dL/dc = sum T alpha dL/d(R, G, B) (ACC_COLOUR), which
//                      raster_backward_finish_rgb chains through the ReLU and the SH basis.
// One workgroup per 8-column half of a 16x16 tile, one invocation per column of it.
//
// Mirrors the CPU reference (trainer/src/render/backward.rs) sample by sample. The CPU walks the
// samples back to front with S_after; here each pixel walks them front to back using what the
// forward pass of the same view left in its planes: the upstream-weighted blend
//   W = sum_l T_l alpha_l w_l = sum_c g_c plane_c   (w = upstream-weighted values)
// and the end of the pixel's samples (END_PLANE). Then
//   dL/dalpha_i = T_i w_i - (W - W_{<=i}) / (1 - alpha_i),   1 - alpha_i >= 0.01,
// which equals T_i (w_i - S_after_i) and needs no per-pixel sample list.
//
// Per sample it accumulates, per primitive, the view-space sums of raster_common.glsl
// (acc_fields(m) floats: ACC_GEOM geometry/spectrum-base fields, ACC_BAND per band);
// raster_backward_finish chains them to the primitive parameters.
//
// With subgroup sums, the walk over the tile's list is uniform across the subgroup (it runs to
// the last sample of any of its pixels; a pixel past its own end contributes zeros, and the
// phase-1 bits are OR-ed over the subgroup), so every subgroup operation sees all its
// invocations.

#include "raster_common.glsl"

// Each invocation handles the PIX = 16 pixels of its tile column: a sample's view data is
// loaded once for a group of ROWS of them and their contributions are summed in registers
// before the subgroup sum. The per-pixel arithmetic is the CPU reference's.
#define PIX 16u
#define HALF_TILE 8u
// Rows per group of the walk's phase 2 (see main), and groups per column.
#define ROWS 4u
#define GROUPS (PIX / ROWS)
// Samples per batch of the walk: one bit each in a uint.
#define BWD_BATCH 32u
layout(local_size_x = HALF_TILE) in;

layout(std430, set = 0, binding = 0) readonly buffer Camera { float cam[]; };
RASTER_TEXELS(1, 2, 3)
layout(std430, set = 0, binding = 4) readonly buffer Ranges { uvec2 ranges[]; };
layout(std430, set = 0, binding = 5) readonly buffer Upstream { float upstream[]; };
layout(std430, set = 0, binding = 6) readonly buffer Planes { float planes[]; };
#ifdef USE_FLOAT_ATOMICS
layout(std430, set = 0, binding = 7) buffer Acc { float acc[]; };
void global_add(uint idx, float v) {
    if (v != 0.0) {
        atomicAdd(acc[idx], v);
    }
}
#else
layout(std430, set = 0, binding = 7) buffer Acc { uint acc[]; };
void global_add(uint idx, float v) {
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
#endif
#ifdef USE_COLOUR
COLOUR_TEXELS(8)
#endif

layout(push_constant) uniform Push {
    uint n;
    uint m;
    uint width;
    uint height;
    uint tiles_x;
    uint thermal;  // 0: the thermal upstream is taken as zero (see main)
} pc;

// Where the current sample's sums go: fields [g_prim * g_fields, (g_prim + 1) * g_fields).
uint g_fields;  // acc_fields(m)
uint g_prim;    // primitive of the current sample
#ifdef USE_SUBGROUP_REDUCE
// The subgroup sums of N fields are dealt out one per invocation (invocation l holds field
// first + l), so one atomic instruction adds up to gl_SubgroupSize fields. SIMD implementations
// run every atomic instruction as a loop over the lanes (lavapipe's gallivm does), so adding 8
// fields per instruction instead of 1 cuts that loop 8-fold.
#define PUT_FIELDS(N)                                                                        \
    float tot[N];                                                                            \
    for (uint f = 0u; f < N; ++f) {                                                          \
        tot[f] = subgroupAdd(v[f]);                                                          \
    }                                                                                        \
    uint lane = gl_SubgroupInvocationID;                                                     \
    for (uint first = 0u; first < N; first += gl_SubgroupSize) {                             \
        float mine = 0.0;                                                                    \
        for (uint f = 0u; f < N; ++f) {                                                      \
            mine = f == first + lane ? tot[f] : mine;                                        \
        }                                                                                    \
        if (first + lane < N) {                                                              \
            global_add(g_prim * g_fields + base + first + lane, mine);                       \
        }                                                                                    \
    }
#else
#define PUT_FIELDS(N)                                                                        \
    for (uint f = 0u; f < N; ++f) {                                                          \
        global_add(g_prim * g_fields + base + f, v[f]);                                      \
    }
#endif
// The ACC_GEOM geometry/spectrum-base fields, and the ACC_BAND fields of one band at `base`.
void put_geom(float v[ACC_GEOM]) {
    uint base = 0u;
    PUT_FIELDS(ACC_GEOM)
}
void put_band(uint base, float v[ACC_BAND]) {
    PUT_FIELDS(ACC_BAND)
}

// Per pixel of this invocation's column (private to the invocation): upstream gradients, W =
// sum_c g_c plane_c (see the top), end of its samples, ray, and the walk's running T and W.
float g[PIX * UP_PLANES];
float w_total[PIX];
uint end[PIX];
vec3 p[PIX];
float trans[PIX];
float w_upto[PIX];

// Phase 2 for rows [rows, rows + ROWS) of this invocation's column: the full gradient
// evaluation of the batch's samples whose bits are set, front to back. Called with constant
// `rows`, so every row index is a constant (no indexed register access).
void walk(uint rows, uint todo, uint start, float near_m, uint m, bool thermal) {
    while (todo != 0u) {
        uint k = start + uint(findLSB(todo));
        todo &= todo - 1u;
        uint i = sorted_prim(k);
        g_prim = i;
        vec4 a_o = view_field(i, PV_A_OPACITY);
        vec3 b0 = view_field(i, PV_B0).xyz, b1 = view_field(i, PV_B1).xyz, b2 = view_field(i, PV_B2).xyz;
        vec4 misc = view_field(i, PV_MISC);
        float beta = view_field(i, PV_CMM_BETA).w;
        float omega = view_field(i, PV_B0).w;
        float half_beta = 0.5 * beta;
        // Without thermal upstream the bands get gradient through psi_high only (sum_psi_high
        // below): no band phase is evaluated.
        uint live = thermal ? uint(view_field(i, PV_B1).w) : 0u;
        bool frozen = view_field(i, PV_B2).w != 0.0;

        // The sample of each pixel, as raster_forward evaluates it (same decisions).
        bool valid[PIX];
        float t[PIX], q[PIX], log2_q[PIX], sv[PIX], mb[PIX], alpha[PIX], pre[PIX];
        vec3 rv[PIX], bv3[PIX];
        bool clamped[PIX];
        for (uint r = rows; r < rows + ROWS; ++r) {
            bool ok = k < end[r];
            vec3 b = vec3(0.0, 0.0, 1.0);
            float tt = 0.0;
            vec3 rr = vec3(0.0);
            float qq = 0.0;
            if (ok) {
                qq = ray_point(p[r], a_o.xyz, b0, b1, b2, b, tt, rr);
                ok = tt > near_m && qq <= q_cut_of(misc.w);
            }
            float mbb = 0.0, ss = 0.0, al = 0.0, lq = 0.0;
            bool cl = true;
            if (ok) {
                lq = log2(qq);
                mbb = support_power(qq, lq, beta);
                ss = exp(-mbb);
                float os = a_o.w * ss;
                cl = os > ALPHA_MAX;
                al = cl ? ALPHA_MAX : os;
                ok = al >= ALPHA_MIN;
            }
            valid[r] = ok;
            t[r] = ok ? tt : 0.0;
            q[r] = qq;
            log2_q[r] = lq;
            rv[r] = rr;
            bv3[r] = b;
            mb[r] = mbb;
            sv[r] = ss;
            alpha[r] = al;
            clamped[r] = cl || !ok;
            pre[r] = omega;
        }
        // Nothing to add when no pixel of the subgroup (invocation) has this sample.
        bool any_valid = false;
        for (uint r = rows; r < rows + ROWS; ++r) {
            any_valid = any_valid || valid[r];
        }
#ifdef USE_SUBGROUP_REDUCE
        any_valid = subgroupMax(any_valid ? 1u : 0u) != 0u;
#endif
        if (!any_valid) {
            continue;
        }
        // The spectrum at each pixel's sample. The band phases' cosines are evaluated again with
        // their sines for the gradients below: caching them in an array indexed by the band is
        // slower on lavapipe, whose indexed register access costs a gather per lane.
        for (uint j = 0u; j < live; ++j) {
            vec4 g_theta0 = band_field(m * i + j, BV_G_THETA0);
            float amp = band_field(m * i + j, BV_AMP).x;
            for (uint r = rows; r < rows + ROWS; ++r) {
                float theta = g_theta0.w + t[r] * dot(g_theta0.xyz, p[r]);
                pre[r] += valid[r] ? amp * cos(theta) : 0.0;
            }
        }
        float wt[PIX], d_alpha[PIX], g_f[PIX], g_t[PIX];
        float sum_omega = 0.0, sum_psi_high = 0.0;
#ifdef USE_COLOUR
        vec3 colour = prim_colour(i);
        vec3 sum_colour = vec3(0.0);
#endif
        for (uint r = rows; r < rows + ROWS; ++r) {
            wt[r] = 0.0;
            d_alpha[r] = 0.0;
            g_f[r] = 0.0;
            if (valid[r]) {
                float w_i = g[UP_PLANES * r] * max(pre[r], 0.0) + g[UP_PLANES * r + 1u] * omega +
                            g[UP_PLANES * r + 2u] * misc.x + g[UP_PLANES * r + 3u] * beta +
                            g[UP_PLANES * r + 4u] * t[r] + g[UP_PLANES * r + 5u];
#ifdef USE_COLOUR
                w_i += g[UP_PLANES * r + UP_RGB] * colour.r + g[UP_PLANES * r + UP_RGB + 1u] * colour.g +
                       g[UP_PLANES * r + UP_RGB + 2u] * colour.b;
#endif
                w_upto[r] += trans[r] * alpha[r] * w_i;
                d_alpha[r] = trans[r] * w_i - (w_total[r] - w_upto[r]) / (1.0 - alpha[r]);
                wt[r] = trans[r] * alpha[r];
                trans[r] *= 1.0 - alpha[r];
                g_f[r] = pre[r] > 0.0 ? wt[r] * g[UP_PLANES * r] : 0.0;
            }
            g_t[r] = wt[r] * g[UP_PLANES * r + 4u];
            sum_omega += wt[r] * g[UP_PLANES * r + 1u] + g_f[r];
            sum_psi_high += wt[r] * g[UP_PLANES * r + 2u];
#ifdef USE_COLOUR
            sum_colour += wt[r] * vec3(g[UP_PLANES * r + UP_RGB], g[UP_PLANES * r + UP_RGB + 1u],
                                       g[UP_PLANES * r + UP_RGB + 2u]);
#endif
        }

        // Spectrum: per band amplitude (through the thermal image; psi_high's part is added in
        // raster_backward_finish), theta0 and sum g_theta t p.
        for (uint j = 0u; j < live; ++j) {
            vec4 g_theta0 = band_field(m * i + j, BV_G_THETA0);
            float amp = band_field(m * i + j, BV_AMP).x;
            float g_amp = 0.0, g_th = 0.0;
            vec3 g_tp = vec3(0.0);
            for (uint r = rows; r < rows + ROWS; ++r) {
                if (!valid[r]) {
                    continue;
                }
                float gp = dot(g_theta0.xyz, p[r]);
                vec2 sc = sin_cos(g_theta0.w + t[r] * gp);
                float sn = sc.x, c = sc.y;
                float g_theta = -g_f[r] * amp * sn;
                g_amp += g_f[r] * c;
                g_th += g_theta;
                g_tp += g_theta * t[r] * p[r];
                g_t[r] += g_theta * gp;
            }
            put_band(ACC_GEOM + ACC_BAND * j, float[ACC_BAND](g_amp, g_th, g_tp.x, g_tp.y, g_tp.z));
        }
        // Support and opacity (no gradient through a clamped alpha), then (q*, t*) -> (a, b).
        float g_o = 0.0, g_beta = 0.0;
        vec3 g_a = vec3(0.0);
        vec3 g_bp[3] = vec3[3](vec3(0.0), vec3(0.0), vec3(0.0));
        for (uint r = rows; r < rows + ROWS; ++r) {
            g_beta += wt[r] * g[UP_PLANES * r + 3u];
            float g_q = 0.0;
            if (!clamped[r]) {
                g_o += d_alpha[r] * sv[r];
                float g_s = d_alpha[r] * a_o.w;
                // d(q^(beta/2))/dq = (beta/2) q^(beta/2 - 1) = (beta/2) mb / q
                float dmb_dq = q[r] > 0.0 ? half_beta * mb[r] / q[r] : (half_beta == 1.0 ? 1.0 : 0.0);
                g_q = -g_s * sv[r] * dmb_dq;
                if (q[r] > 0.0 && !frozen) {
                    g_beta += -g_s * sv[r] * mb[r] * (0.5 * LN_2) * log2_q[r];
                }
            }
            if (valid[r]) {
                float inv_bb = 1.0 / dot(bv3[r], bv3[r]);
                vec3 ga = g_q * 2.0 * rv[r] - g_t[r] * bv3[r] * inv_bb;
                vec3 gb = g_q * 2.0 * t[r] * rv[r] - g_t[r] * (a_o.xyz + 2.0 * t[r] * bv3[r]) * inv_bb;
                g_a += ga;
                g_bp[0] += gb.x * p[r];
                g_bp[1] += gb.y * p[r];
                g_bp[2] += gb.z * p[r];
            }
        }
#ifdef USE_COLOUR
        put_geom(float[ACC_GEOM](g_a.x, g_a.y, g_a.z, g_bp[0].x, g_bp[0].y, g_bp[0].z, g_bp[1].x,
                                 g_bp[1].y, g_bp[1].z, g_bp[2].x, g_bp[2].y, g_bp[2].z, g_o, g_beta,
                                 sum_omega, sum_psi_high, sum_colour.x, sum_colour.y, sum_colour.z));
#else
        put_geom(float[ACC_GEOM](g_a.x, g_a.y, g_a.z, g_bp[0].x, g_bp[0].y, g_bp[0].z, g_bp[1].x,
                                 g_bp[1].y, g_bp[1].z, g_bp[2].x, g_bp[2].y, g_bp[2].z, g_o, g_beta,
                                 sum_omega, sum_psi_high));
#endif
    }
}

void main() {
    uint x = gl_GlobalInvocationID.x;
    uint tile = gl_WorkGroupID.y * pc.tiles_x + gl_WorkGroupID.x / 2u;
    uint y0 = gl_WorkGroupID.y * TILE_SIZE;
    uint npix = pc.width * pc.height;
    uvec2 range = ranges[tile];
    float near_m = cam[CAM_NEAR];
    uint m = pc.m;
    bool thermal = pc.thermal != 0u;
    g_fields = acc_fields(m);

    uint walk_end = range.x;
    for (uint r = 0u; r < PIX; ++r) {
        uint y = y0 + r;
        p[r] = vec3(float(x), float(y), 1.0);
        w_total[r] = 0.0;
        end[r] = range.x;
        bool any_g = false;
        for (uint c = 0u; c < UP_PLANES; ++c) {
            g[UP_PLANES * r + c] = 0.0;
        }
        if (x < pc.width && y < pc.height) {
            uint pidx = y * pc.width + x;
            for (uint c = 0u; c < 6u; ++c) {
                float gc = c == 0u && !thermal ? 0.0 : upstream[c * npix + pidx];
                g[UP_PLANES * r + c] = gc;
                any_g = any_g || gc != 0.0;
                w_total[r] += gc * planes[c * npix + pidx];
            }
#ifdef USE_COLOUR
            for (uint c = 0u; c < 3u; ++c) {
                float gc = upstream[(UP_RGB + c) * npix + pidx];
                g[UP_PLANES * r + UP_RGB + c] = gc;
                any_g = any_g || gc != 0.0;
                w_total[r] += gc * planes[(RGB_PLANE + c) * npix + pidx];
            }
#endif
            // A pixel without upstream gradient contributes nothing: give it an empty walk.
            end[r] = any_g ? floatBitsToUint(planes[END_PLANE * npix + pidx]) : range.x;
        }
        walk_end = max(walk_end, end[r]);
    }
    // The walk ends at the last sample of any pixel of the subgroup.
#ifdef USE_SUBGROUP_REDUCE
    walk_end = subgroupMax(walk_end);
#endif

    for (uint r = 0u; r < PIX; ++r) {
        trans[r] = 1.0;
        w_upto[r] = 0.0;
    }
    // The walk goes in batches of BWD_BATCH samples, in two phases (see raster_forward.comp):
    // phase 1 screens every sample of the batch with the cheap test (in front of the near plane,
    // q <= q_max) at this invocation's pixels and keeps a bit per sample and group of ROWS rows
    // that any of the group's pixels may use; phase 2 runs the full gradient evaluation of each
    // group's samples for that group's rows only. With subgroup sums the bits are OR-ed over
    // the subgroup, so its invocations walk the same samples.
    for (uint start = range.x; start < walk_end; start += BWD_BATCH) {
        uint stop = min(start + BWD_BATCH, walk_end);
        uint todo[GROUPS];
        for (uint grp = 0u; grp < GROUPS; ++grp) {
            todo[grp] = 0u;
        }
        for (uint k = start; k < stop; ++k) {
            uint i = sorted_prim(k);
            vec4 a_o = view_field(i, PV_A_OPACITY);
            vec3 b0 = view_field(i, PV_B0).xyz, b1 = view_field(i, PV_B1).xyz, b2 = view_field(i, PV_B2).xyz;
            float q_cut = q_cut_of(view_field(i, PV_MISC).w);
            uint bit = 1u << (k - start);
            for (uint r = 0u; r < PIX; ++r) {
                vec3 b, rr;
                float tt;
                float qq = ray_point(p[r], a_o.xyz, b0, b1, b2, b, tt, rr);
                bool hit = k < end[r] && tt > near_m && qq <= q_cut;
                todo[r / ROWS] |= hit ? bit : 0u;
            }
        }
#ifdef USE_SUBGROUP_REDUCE
        for (uint grp = 0u; grp < GROUPS; ++grp) {
            todo[grp] = subgroupOr(todo[grp]);
        }
#endif
        walk(0u, todo[0], start, near_m, m, thermal);
        walk(4u, todo[1], start, near_m, m, thermal);
        walk(8u, todo[2], start, near_m, m, thermal);
        walk(12u, todo[3], start, near_m, m, thermal);
    }
}
