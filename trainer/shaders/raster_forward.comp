// Rasteriser step 4, one workgroup per 16x16 tile, one invocation per PIX pixels: evaluates each
// primitive of the tile (front to back) at the point of the pixel ray where its support peaks,
// and blends the thermal image and the G-buffers exactly as the CPU reference's forward pass
// (trainer/src/render/forward.rs): alpha = min(0.99, o exp(-q^(beta/2))), samples below 1/255 or
// behind the near plane skipped, early stop before T would fall below 1e-4.
// Output planes (each width*height floats, row-major): thermal, psi_low, psi_high, psi_beta,
// depth (alpha-weighted camera depth), alpha, and the end plane (see raster_common.glsl).
//
// The walk over the tile's list is uniform across the workgroup (a finished pixel idles rather
// than leaving the loop), so the primitive index and its view data are the same for every
// invocation: one scalar load each, not a gather, on SIMD implementations such as lavapipe.
// Every FWD_BATCH samples the workgroup checks whether any pixel is still open and stops when
// none is.
#version 450
#include "raster_common.glsl"

// Each invocation renders PIX pixels of its tile column (rows ly, ly + ROW_STEP, ...), loading
// the primitive's view data once for all of them.
#define PIX 8u
#define ROW_STEP (16u / PIX)
layout(local_size_x = 16, local_size_y = 2) in;

layout(std430, set = 0, binding = 0) readonly buffer Camera { float cam[]; };
layout(std430, set = 0, binding = 1) readonly buffer Views { PrimView views[]; };
layout(std430, set = 0, binding = 2) readonly buffer Bands { BandView bands[]; };
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

#define FWD_BATCH 64u

// Open-pixel counters, used round-robin (see the loop) so one barrier per batch suffices.
shared uint s_open[3];

void main() {
    uint x = gl_GlobalInvocationID.x;
    uint y0 = gl_WorkGroupID.y * 16u + gl_LocalInvocationID.y;
    uint tile = gl_WorkGroupID.y * pc.tiles_x + gl_WorkGroupID.x;
    uvec2 range = ranges[tile];
    float near_m = cam[CAM_NEAR];
    uint m = pc.m;

    if (gl_LocalInvocationIndex == 0u) {
        s_open[0] = 0u;
        s_open[1] = 0u;
        s_open[2] = 0u;
    }
    barrier();

    vec3 p[PIX];
    bool open[PIX];
    float trans[PIX];
    uint end[PIX];
    float acc[PIX * 6u];
    bool any_open = false;
    for (uint r = 0u; r < PIX; ++r) {
        uint y = y0 + r * ROW_STEP;
        p[r] = vec3(float(x), float(y), 1.0);
        open[r] = x < pc.width && y < pc.height;
        any_open = any_open || open[r];
        trans[r] = 1.0;
        end[r] = range.x;
        for (uint c = 0u; c < 6u; ++c) {
            acc[6u * r + c] = 0.0;
        }
    }
    uint batch_no = 0u;
    for (uint start = range.x; start < range.y; start += FWD_BATCH) {
        // Counter `batch_no % 3` is read after this barrier; counter `(batch_no + 1) % 3` is
        // cleared now: it was last read before this barrier and is next incremented after the
        // next one.
        uint cur = batch_no % 3u;
        if (any_open) {
            atomicAdd(s_open[cur], 1u);
        }
        barrier();
        if (s_open[cur] == 0u) {
            break;
        }
        if (gl_LocalInvocationIndex == 0u) {
            s_open[(batch_no + 1u) % 3u] = 0u;
        }
        ++batch_no;
        uint stop = min(start + FWD_BATCH, range.y);
        for (uint k = start; k < stop; ++k) {
            uint i = sorted_prims[k];
            // Fields are read as needed: most samples are rejected after the first 64 bytes.
            vec4 a_o = views[i].a_opacity;
            vec3 b0 = views[i].b0.xyz, b1 = views[i].b1.xyz, b2 = views[i].b2.xyz;
            float q_cut = views[i].misc.w * (1.0 + QMAX_MARGIN) + 1e-7;
            vec4 bbox = views[i].bbox;
            bool in_cols = float(x) >= bbox.x && float(x) <= bbox.z;
            for (uint r = 0u; r < PIX; ++r) {
                if (!open[r] || !in_cols || !(p[r].y >= bbox.y && p[r].y <= bbox.w)) {
                    continue;
                }
                vec3 b = vec3(dot(b0, p[r]), dot(b1, p[r]), dot(b2, p[r]));
                float t = -dot(a_o.xyz, b) / dot(b, b);
                vec3 rr = a_o.xyz + t * b;
                float q = dot(rr, rr);
                if (!(t > near_m && q <= q_cut)) {
                    continue;
                }
                float beta = views[i].cmm_beta.w;
                // beta == 2 (Gaussian): q^1 exactly, no pow.
                float mb = beta == 2.0 ? q : pow(q, 0.5 * beta);
                float alpha = min(a_o.w * exp(-mb), ALPHA_MAX);
                if (!(alpha >= ALPHA_MIN)) {
                    continue;
                }
                float next = trans[r] * (1.0 - alpha);
                if (next < T_MIN) {
                    open[r] = false;
                    continue;
                }
                float omega = views[i].b0.w;
                uint live = uint(views[i].b1.w);
                float pre = omega;
                for (uint j = 0u; j < live; ++j) {
                    BandView bv = bands[m * i + j];
                    pre += bv.amp.x * cos(bv.g_theta0.w + t * dot(bv.g_theta0.xyz, p[r]));
                }
                float w = trans[r] * alpha;
                acc[6u * r] += w * max(pre, 0.0);
                acc[6u * r + 1u] += w * omega;
                acc[6u * r + 2u] += w * views[i].misc.x;
                acc[6u * r + 3u] += w * beta;
                acc[6u * r + 4u] += w * t;
                acc[6u * r + 5u] += w;
                trans[r] = next;
                end[r] = k + 1u;
            }
        }
        any_open = false;
        for (uint r = 0u; r < PIX; ++r) {
            any_open = any_open || open[r];
        }
    }
    uint npix = pc.width * pc.height;
    for (uint r = 0u; r < PIX; ++r) {
        uint y = y0 + r * ROW_STEP;
        if (x < pc.width && y < pc.height) {
            uint pidx = y * pc.width + x;
            for (uint c = 0u; c < 6u; ++c) {
                planes[c * npix + pidx] = acc[6u * r + c];
            }
            planes[END_PLANE * npix + pidx] = uintBitsToFloat(end[r]);
        }
    }
}
