// Shared by the rasteriser kernels: buffer layouts and constants. They mirror the CPU
// reference (trainer/src/render, trainer/src/primitive.rs); change both together.

#define TILE_SIZE 16u
#define ALPHA_MAX 0.99
#define ALPHA_MIN (1.0 / 255.0)
#define T_MIN 1e-4
#define BETA_MAX 64.0
#define QUAT_NORM_MIN 1e-12
#define CULL_PAD_PX 1.0

// Camera buffer (floats): centre c (0..3), W = R_world_from_cam K^-1 row-major (3..12),
// R_cam_from_world row-major (12..21), t_cam_from_world (21..24), fx fy cx cy (24..28),
// near_m (28), width (29), height (30), cull flag (31).
#define CAM_C 0
#define CAM_W 3
#define CAM_R 12
#define CAM_T 21
#define CAM_FX 24
#define CAM_FY 25
#define CAM_CX 26
#define CAM_CY 27
#define CAM_NEAR 28
#define CAM_WIDTH 29
#define CAM_HEIGHT 30
#define CAM_CULL 31

// Parameter buffer (floats), sections for n primitives with m bands, in this order:
// means 3n, log_scales 3n, quats 4n (w x y z), opacity_logits n, beta_raw n, omega_low n,
// band_amp m n, band_freq 3 m n, band_phase m n; then, in a run with colour only, sh 3 K n
// (K = (degree + 1)^2 coefficients per channel: channel c of coefficient k of primitive i at
// 3 (K i + k) + c, primitive.rs).
uint off_means(uint n, uint m) { return 0u; }
uint off_log_scales(uint n, uint m) { return 3u * n; }
uint off_quats(uint n, uint m) { return 6u * n; }
uint off_opacity(uint n, uint m) { return 10u * n; }
uint off_beta(uint n, uint m) { return 11u * n; }
uint off_omega_low(uint n, uint m) { return 12u * n; }
uint off_band_amp(uint n, uint m) { return 13u * n; }
uint off_band_freq(uint n, uint m) { return 13u * n + m * n; }
uint off_band_phase(uint n, uint m) { return 13u * n + 4u * m * n; }
uint off_sh(uint n, uint m) { return 13u * n + 5u * m * n; }

// Samples with q* > q_max (1 + QMAX_MARGIN) cannot reach alpha >= 1/255: q_max = L^(2/beta),
// L = ln(255 o), is where o exp(-q^(beta/2)) = 1/255. The margin keeps every sample whose exact
// test could pass (f32 rounding of pow/log is ~1e-6 relative), so the early reject never changes
// a decision; it only skips pow/exp for the many samples far outside the support.
#define QMAX_MARGIN 1e-3

// The samples' cut on q* for a primitive's q_max (see QMAX_MARGIN).
float q_cut_of(float q_max) {
    return q_max * (1.0 + QMAX_MARGIN) + 1e-7;
}

// The point of pixel p's ray where a primitive's support peaks (see PrimView): whitened ray
// direction b = B p (rows b0, b1, b2), depth t* = -a.b / b.b and whitened offset r = a + t* b;
// returns q* = r.r. The rasterisers' screen and full evaluations share it, so both make the
// same decisions.
float ray_point(vec3 p, vec3 a, vec3 b0, vec3 b1, vec3 b2, out vec3 b, out float t, out vec3 r) {
    b = vec3(dot(b0, p), dot(b1, p), dot(b2, p));
    t = -dot(a, b) / dot(b, b);
    r = a + t * b;
    return dot(r, r);
}

// One primitive as seen from the current view (112 bytes).
struct PrimView {
    vec4 b0;        // rows of B = N W: whitened ray direction of pixel p is B p; b0.w = omega_low,
    vec4 b1;        // b1.w = live bands (the band loops run over j < live),
    vec4 b2;        // b2.w = 1 for a beta frozen on the Gaussian path (no beta gradient), else 0
    vec4 a_opacity; // a = N (c - mu), opacity
    vec4 cmm_beta;  // c - mu, beta
    vec4 misc;      // psi_high, camera depth of mu, visible (0/1), q_max (see QMAX_MARGIN)
    uvec4 rect;     // tiles [tx0, ty0, tx1, ty1): the tiles of the padded silhouette of the
                    // culling ellipsoid (every tile without culling)
};

// The rasterisers read PrimView and BandView through texel buffers (RGBA32F, one vec4 texel
// per field, in struct order) and the sorted primitive list through an R32UI texel buffer:
// the samples are fetched at scattered, per-invocation positions, which software Vulkan
// (lavapipe's gallivm) does with vector gathers for texels but one invocation at a time, with a
// branch per invocation and component, for storage buffers (measured: the forward pass spent
// about a quarter of its time on the extra loads of one more PrimView per sample).
#define PV_B0 0
#define PV_B1 1
#define PV_B2 2
#define PV_A_OPACITY 3
#define PV_CMM_BETA 4
#define PV_MISC 5
#define PV_TEXELS 7
#define BV_G_THETA0 0
#define BV_AMP 1
#define BV_TEXELS 2
// Declares the texel-buffer bindings and their accessors (views, bands, sorted list).
#define RASTER_TEXELS(VIEWS, BANDS, SORTED)                                                  \
    layout(set = 0, binding = VIEWS) uniform samplerBuffer view_texels;                      \
    layout(set = 0, binding = BANDS) uniform samplerBuffer band_texels;                      \
    layout(set = 0, binding = SORTED) uniform usamplerBuffer sorted_texels;                  \
    vec4 view_field(uint i, int field) {                                                     \
        return texelFetch(view_texels, PV_TEXELS * int(i) + field);                          \
    }                                                                                        \
    vec4 band_field(uint band, int field) {                                                  \
        return texelFetch(band_texels, BV_TEXELS * int(band) + field);                       \
    }                                                                                        \
    uint sorted_prim(uint k) {                                                               \
        return texelFetch(sorted_texels, int(k)).x;                                          \
    }

// Band j of primitive i as seen from the current view (32 bytes, at index m i + j), written by
// raster_project. The phase of the band at the sample (t, pixel p) of the ray c + t W p is
//   theta = 2 pi f . (c - mu + t W p) + phase = theta0 + t (g . p),
// g = 2 pi W^T f, theta0 = 2 pi f . (c - mu) + phase, so the rasterisers need one dot product
// and one cosine per band and sample, and no parameter reads.
struct BandView {
    vec4 g_theta0;  // g, theta0
    vec4 amp;       // amplitude, 0, 0, 0
};

// Planes written by raster_forward (each width*height floats): thermal, psi_low, psi_high,
// psi_beta, depth, alpha, then the end plane: per pixel, one past the position in the tile's
// list of the last sample blended (uint bits), which bounds the backward pass; with colour
// (the *_rgb kernels, USE_COLOUR) then the R, G and B planes.
// The backward pass's upstream planes: dL/d(thermal, psi_low, psi_high, psi_beta, depth,
// alpha) and with colour dL/d(R, G, B).
#define END_PLANE 6u
#ifdef USE_COLOUR
#define FORWARD_PLANES 10u
#define RGB_PLANE 7u
#define UP_PLANES 9u
#define UP_RGB 6u
#else
#define FORWARD_PLANES 7u
#define UP_PLANES 6u
#endif

// A primitive's colour in the current view (vec4: r, g, b, 0 per primitive, written by
// raster_project_rgb), read by the rasterisers through a texel buffer as the views are.
#define COLOUR_TEXELS(BINDING)                                                               \
    layout(set = 0, binding = BINDING) uniform samplerBuffer colour_texels;                  \
    vec3 prim_colour(uint i) {                                                               \
        return texelFetch(colour_texels, int(i)).xyz;                                        \
    }

// View-space gradient sums per primitive, written by raster_backward_* and chained to the
// parameters by raster_backward_finish: dL/da (3), dL/dB p^T (9, row-major: row = component of
// b), dL/dopacity, dL/dbeta, dL/domega_low, dL/dpsi_high (the primitive's own psi_high = sum_j
// |amp_j|; finish gives band j sign(amp_j) of it), then per band: dL/damp through the thermal
// image, dL/dtheta0 (= dL/dphase), sum dL/dtheta t p (3). With colour (USE_COLOUR) the
// geometry fields end with dL/dc (3, the colour's sums, before its ReLU) at ACC_COLOUR.
#ifdef USE_COLOUR
#define ACC_COLOUR 16u
#define ACC_GEOM 19u
#else
#define ACC_GEOM 16u
#endif
#define ACC_BAND 5u
uint acc_fields(uint m) { return ACC_GEOM + ACC_BAND * m; }

#define LN_2 0.69314718055994531

// q^(beta/2) from q and log2(q), as pow() computes it (exp2 of the product of the logarithm), so
// the backward pass reuses log2(q) for dL/dbeta; beta == 2 (Gaussian) gives q exactly.
float support_power(float q, float log2_q, float beta) {
    return beta == 2.0 ? q : exp2(0.5 * beta * log2_q);
}

// (sin x, cos x) from one argument reduction: x = y + j pi/2 with |y| <= pi/4 (pi/2 split in
// three parts, Cody & Waite, so y is exact to f32 for |x| < 2^16), then the minimax polynomials
// of Cephes' sinf and cosf on y (about 1 ulp) and the quadrant j mod 4. On SIMD implementations
// sin() and cos() each repeat the reduction and both polynomials, so this costs about one of them.
vec2 sin_cos(float x) {
    float j = floor(x * 0.63661977236758134 + 0.5);
    float y = ((x - j * 1.5703125) - j * 4.837512969970703125e-4) - j * 7.54978995489188216e-8;
    float z = y * y;
    float s = ((-1.9515295891e-4 * z + 8.3321608736e-3) * z - 1.6666654611e-1) * z * y + y;
    float c = ((2.443315711809948e-5 * z - 1.388731625493765e-3) * z + 4.166664568298827e-2) * z * z -
              0.5 * z + 1.0;
    uint quadrant = uint(int(j)) & 3u;
    vec2 sc = (quadrant & 1u) == 0u ? vec2(s, c) : vec2(c, -s);
    return quadrant >= 2u ? -sc : sc;
}
