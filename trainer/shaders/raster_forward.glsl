// Rasteriser step 4, one workgroup per 8-column half of a 16x16 tile, one invocation per
// column of it: evaluates each
// primitive of the tile (front to back) at the point of the pixel ray where its support peaks,
// and blends the thermal image and the G-buffers exactly as the CPU reference's forward pass
// (trainer/src/render/forward.rs): alpha = min(0.99, o exp(-q^(beta/2))), samples below 1/255 or
// behind the near plane skipped, early stop before T would fall below 1e-4.
// Output planes (each width*height floats, row-major): thermal, psi_low, psi_high, psi_beta,
// depth (alpha-weighted camera depth), alpha, and the end plane (see raster_common.glsl).
// With pc.thermal = 0 (a view whose G-buffers alone are needed, e.g. the consistency partner)
// the band cosines are not evaluated and the thermal plane is written as zeros; every other
// plane is unchanged.
//
// The tile's list is walked in batches of FWD_BATCH samples, in two phases per batch:
//   1. screen: every pixel tests every sample of the batch with the cheap part of the
//      evaluation (ray point in front of the near plane, q <= q_max) and keeps a bit per sample
//      that passes;
//   2. blend: every pixel walks only its own bits, in order, through the expensive part (pow,
//      exp, the band cosines, the blend).
// Why: SIMD implementations run both sides of every branch with lanes masked off (lavapipe's
// gallivm in Mesa 22.3 never skips an `if`), so a test-and-skip inside one loop still pays the
// expensive part for every (pixel, sample); only a loop's trip count skips work. Most samples
// of a tile's list miss most of its pixels, so phase 2 runs a fraction of the iterations.
// Both phases make exactly the decisions of the single-loop evaluation, so results are unchanged.
// A column stops when all its pixels are done.
//
// Compiled twice: raster_forward.comp, and raster_forward_rgb.comp (USE_COLOUR), which blends
// each primitive's colour (raster_project_rgb) into three more planes, R, G, B, with the same
// weights, as the CPU reference's RGB buffer.
#include "raster_common.glsl"

// Each invocation renders the PIX = 16 pixels of its tile column. A workgroup of 8 invocations
// is one SIMD batch on lavapipe (its barriers are free) and its screening loads serve 16 rows;
// two workgroups per tile split a tile's work between threads.
#define PIX 16u
#define HALF_TILE 8u
layout(local_size_x = HALF_TILE) in;

layout(std430, set = 0, binding = 0) readonly buffer Camera { float cam[]; };
RASTER_TEXELS(1, 2, 3)
layout(std430, set = 0, binding = 4) readonly buffer Ranges { uvec2 ranges[]; };
layout(std430, set = 0, binding = 5) writeonly buffer Out { float planes[]; };
#ifdef USE_COLOUR
COLOUR_TEXELS(6)
#define BLENDED 9u
#else
#define BLENDED 6u
#endif

layout(push_constant) uniform Push {
    uint n;
    uint m;
    uint width;
    uint height;
    uint tiles_x;
    uint thermal;  // 1: the thermal image too; 0: the G-buffers only (thermal plane zero)
} pc;

// Samples per batch: one bit each in a uint.
#define FWD_BATCH 32u

// The state of one pixel.
struct Pixel {
    vec3 p;        // (x, y, 1)
    bool open;     // still blending (inside the image, T not yet below T_MIN)
    float trans;   // T
    uint end;      // one past the last sample blended
    float acc[BLENDED];  // thermal, psi_low, psi_high, psi_beta, depth, alpha (, R, G, B)
};

// Phase 2 for one pixel: blends the batch's samples whose bits are set, front to back.
void blend(inout Pixel px, uint bits, uint start, float near_m, uint m, bool thermal) {
    while (bits != 0u) {
        uint k = start + uint(findLSB(bits));
        bits &= bits - 1u;
        uint i = sorted_prim(k);
        vec4 a_o = view_field(i, PV_A_OPACITY);
        vec4 b0 = view_field(i, PV_B0), b1 = view_field(i, PV_B1), b2 = view_field(i, PV_B2);
        vec4 misc = view_field(i, PV_MISC);
        vec3 b, rr;
        float t;
        float q = ray_point(px.p, a_o.xyz, b0.xyz, b1.xyz, b2.xyz, b, t, rr);
        float beta = view_field(i, PV_CMM_BETA).w;
        // beta == 2 (Gaussian): q^1 exactly, no pow.
        float mb = support_power(q, log2(q), beta);
        float alpha = min(a_o.w * exp(-mb), ALPHA_MAX);
        if (!(alpha >= ALPHA_MIN)) {
            continue;
        }
        float next = px.trans * (1.0 - alpha);
        if (next < T_MIN) {
            px.open = false;
            bits = 0u;
            continue;
        }
        float omega = b0.w;
        // Without the thermal image no band is evaluated (psi_high comes from misc.x).
        uint live = thermal ? uint(b1.w) : 0u;
        float pre = omega;
        for (uint j = 0u; j < live; ++j) {
            vec4 g_theta0 = band_field(m * i + j, BV_G_THETA0);
            float amp = band_field(m * i + j, BV_AMP).x;
            pre += amp * cos(g_theta0.w + t * dot(g_theta0.xyz, px.p));
        }
        float w = px.trans * alpha;
        px.acc[0] += thermal ? w * max(pre, 0.0) : 0.0;
        px.acc[1] += w * omega;
        px.acc[2] += w * misc.x;
        px.acc[3] += w * beta;
        px.acc[4] += w * t;
        px.acc[5] += w;
#ifdef USE_COLOUR
        vec3 colour = prim_colour(i);
        px.acc[6] += w * colour.r;
        px.acc[7] += w * colour.g;
        px.acc[8] += w * colour.b;
#endif
        px.trans = next;
        px.end = k + 1u;
    }
}

void main() {
    uint x = gl_GlobalInvocationID.x;
    uint y0 = gl_WorkGroupID.y * TILE_SIZE;
    uint tile = gl_WorkGroupID.y * pc.tiles_x + gl_WorkGroupID.x / 2u;
    uvec2 range = ranges[tile];
    float near_m = cam[CAM_NEAR];
    uint m = pc.m;
    bool thermal = pc.thermal != 0u;

    Pixel px[PIX];
    bool any_open = false;
    for (uint r = 0u; r < PIX; ++r) {
        uint y = y0 + r;
        px[r].p = vec3(float(x), float(y), 1.0);
        px[r].open = x < pc.width && y < pc.height;
        any_open = any_open || px[r].open;
        px[r].trans = 1.0;
        px[r].end = range.x;
        for (uint c = 0u; c < BLENDED; ++c) {
            px[r].acc[c] = 0.0;
        }
    }
    for (uint start = range.x; start < range.y; start += FWD_BATCH) {
        // A column whose pixels are all done stops (all of them: its SIMD batch stops).
        if (!any_open) {
            break;
        }
        uint stop = min(start + FWD_BATCH, range.y);

        // Phase 1: the bits of the samples each pixel may blend.
        uint cand[PIX];
        for (uint r = 0u; r < PIX; ++r) {
            cand[r] = 0u;
        }
        for (uint k = start; k < stop; ++k) {
            uint i = sorted_prim(k);
            vec4 a_o = view_field(i, PV_A_OPACITY);
            vec3 b0 = view_field(i, PV_B0).xyz, b1 = view_field(i, PV_B1).xyz, b2 = view_field(i, PV_B2).xyz;
            float q_cut = q_cut_of(view_field(i, PV_MISC).w);
            uint bit = 1u << (k - start);
            for (uint r = 0u; r < PIX; ++r) {
                vec3 b, rr;
                float t;
                float q = ray_point(px[r].p, a_o.xyz, b0, b1, b2, b, t, rr);
                bool hit = t > near_m && q <= q_cut;
                cand[r] |= (hit && px[r].open) ? bit : 0u;
            }
        }
        // Phase 2, one row at a time (constant indices: no indexed register access).
        blend(px[0], cand[0], start, near_m, m, thermal);
        blend(px[1], cand[1], start, near_m, m, thermal);
        blend(px[2], cand[2], start, near_m, m, thermal);
        blend(px[3], cand[3], start, near_m, m, thermal);
        blend(px[4], cand[4], start, near_m, m, thermal);
        blend(px[5], cand[5], start, near_m, m, thermal);
        blend(px[6], cand[6], start, near_m, m, thermal);
        blend(px[7], cand[7], start, near_m, m, thermal);
        blend(px[8], cand[8], start, near_m, m, thermal);
        blend(px[9], cand[9], start, near_m, m, thermal);
        blend(px[10], cand[10], start, near_m, m, thermal);
        blend(px[11], cand[11], start, near_m, m, thermal);
        blend(px[12], cand[12], start, near_m, m, thermal);
        blend(px[13], cand[13], start, near_m, m, thermal);
        blend(px[14], cand[14], start, near_m, m, thermal);
        blend(px[15], cand[15], start, near_m, m, thermal);
        any_open = false;
        for (uint r = 0u; r < PIX; ++r) {
            any_open = any_open || px[r].open;
        }
    }
    uint npix = pc.width * pc.height;
    for (uint r = 0u; r < PIX; ++r) {
        uint y = y0 + r;
        if (x < pc.width && y < pc.height) {
            uint pidx = y * pc.width + x;
            for (uint c = 0u; c < 6u; ++c) {
                planes[c * npix + pidx] = px[r].acc[c];
            }
            planes[END_PLANE * npix + pidx] = uintBitsToFloat(px[r].end);
#ifdef USE_COLOUR
            for (uint c = 0u; c < 3u; ++c) {
                planes[(RGB_PLANE + c) * npix + pidx] = px[r].acc[6u + c];
            }
#endif
        }
    }
}
