//! Buffer layouts shared with the shaders (raster_common.glsl): the camera and parameter
//! blocks, the sizes of the per-primitive and per-pixel buffers, what a run of a given budget
//! allocates at most ([`run_buffers`], [`run_texel_buffers`]) and how key lists are sized
//! ([`KeySizing`]).

use crate::camera::PinholeCamera;
use crate::primitive::Primitives;
use crate::render::RenderSettings;

/// Bytes of one `PrimView` (raster_common.glsl).
pub(super) const PRIM_VIEW_BYTES: u64 = 112;
pub(super) const PROJECT_WG: usize = 128;
pub(super) const RANGES_WG: usize = 256;
/// Output planes of `raster_forward`, in order.
pub const PLANES: [&str; 6] = [
    "thermal", "psi_low", "psi_high", "psi_beta", "depth", "alpha",
];

/// Bytes of one `BandView` (raster_common.glsl).
pub(super) const BAND_VIEW_BYTES: u64 = 32;
/// Bytes of one primitive's colour in a view (vec4: r, g, b, 0; raster_common.glsl).
pub(super) const COLOUR_BYTES: u64 = 16;
/// The first of the R, G, B planes of `raster_forward_rgb`'s output (after the end plane).
pub(super) const RGB_PLANE: usize = 7;
/// Upstream planes of the backward pass: the six of [`PLANES`], then with colour R, G, B.
pub(super) const UP_PLANES: usize = 6;
pub(super) const UP_PLANES_RGB: usize = 9;

/// Planes of `raster_forward`'s output: the six of [`PLANES`] and the end plane; with colour
/// (`raster_forward_rgb`) then R, G, B.
pub(super) fn forward_planes(colour: bool) -> usize {
    if colour { 10 } else { 7 }
}

/// Upstream planes the backward pass of a view with or without colour reads.
pub(super) fn upstream_planes(colour: bool) -> usize {
    if colour { UP_PLANES_RGB } else { UP_PLANES }
}

/// Capacity to allocate for `need` items: 25 % headroom so slowly growing views do not
/// reallocate every step.
pub(super) fn grown(need: usize) -> usize {
    need + need / 4 + 64
}

/// Floats of per-primitive view-space gradient sums for `bands` bands, with or without the
/// colour's 3 (`acc_fields` in raster_common.glsl).
pub(super) fn acc_fields(bands: usize, colour: bool) -> usize {
    16 + if colour { 3 } else { 0 } + 5 * bands
}

/// Floats of the parameter block of `prims`: every group, the SH colour last (none without
/// colour; a resident block never holds it).
pub fn parameter_count(prims: &Primitives<f32>) -> usize {
    thermal_parameter_count(prims) + prims.len() * 3 * prims.sh_k()
}

/// Floats of the parameter block before the SH colour (all of it without colour).
pub(super) fn thermal_parameter_count(prims: &Primitives<f32>) -> usize {
    prims.len() * (13 + 5 * prims.bands)
}

/// The largest per-primitive and per-pixel buffers a run with `budget` primitives of `bands`
/// bands, `sh_k` SH coefficients per colour channel (0: no colour) and views of `npix` pixels
/// allocates, as (name, bytes): the parameter block (the optimiser's moments and gradients
/// have its size), the view data, the colours, the backward pass's scratch, the tile counts
/// and the forward planes. The key lists depend on the scene's coverage and are checked when
/// created.
pub fn run_buffers(
    budget: usize,
    bands: usize,
    sh_k: usize,
    npix: usize,
) -> [(&'static str, u64); 7] {
    let n = budget as u64;
    let colour = sh_k > 0;
    [
        (
            "parameters",
            n * (13 + 5 * bands as u64 + 3 * sh_k as u64) * 4,
        ),
        ("raster.views", n * PRIM_VIEW_BYTES),
        ("raster.bands", n * bands as u64 * BAND_VIEW_BYTES),
        ("raster.colours", if colour { n * COLOUR_BYTES } else { 0 }),
        ("raster.grad_acc", n * acc_fields(bands, colour) as u64 * 4),
        ("raster.tile_counts", (n + 1) * 4),
        ("raster.planes", (forward_planes(colour) * npix * 4) as u64),
    ]
}

/// The per-primitive buffers the rasterisers read as texel buffers (see raster_common.glsl), as
/// (name, texels) for a run with `budget` primitives of `bands` bands: checked against the
/// device's `maxTexelBufferElements` before training (the sorted lists are checked when bound).
pub fn run_texel_buffers(budget: usize, bands: usize) -> [(&'static str, u64); 2] {
    let n = budget as u64;
    [
        ("raster.views", n * PRIM_VIEW_BYTES / 16),
        ("raster.bands", n * bands as u64 * BAND_VIEW_BYTES / 16),
    ]
}

/// How [`super::GpuRasterizer::render_kept`] sizes a view's key list (one key per primitive and tile
/// it covers), whose length only the GPU knows after binning.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KeySizing {
    /// The host reads the key totals of all views after binning (one small read) and sizes
    /// every list exactly.
    Exact,
    /// Every list has room for this many keys and the host reads nothing: the sort and the
    /// tile ranges read the total on the GPU. A view with more keys is cut to its first
    /// `capacity` (an incomplete render); the caller finds out from the view's
    /// [`super::KeptView::key_total`] and repeats the work with more room.
    Capacity(usize),
}

/// The camera block of `raster_common.glsl`.
pub fn camera_block(cam: &PinholeCamera, settings: &RenderSettings) -> [f32; 32] {
    let mut out = [0f32; 32];
    let c = cam.centre_world();
    let w = cam.pixel_to_world_dir();
    let r = cam.rotation_cam_from_world();
    let t = cam.cam_from_world.translation_m;
    let tail = [
        t.x,
        t.y,
        t.z,
        cam.fx_px,
        cam.fy_px,
        cam.cx_px,
        cam.cy_px,
        settings.near_m,
        cam.width as f64,
        cam.height as f64,
        if settings.cull { 1.0 } else { 0.0 },
    ];
    let fields = c.iter().chain(w.iter()).chain(r.iter()).chain(tail.iter());
    for (o, v) in out.iter_mut().zip(fields) {
        *o = *v as f32;
    }
    out
}

/// The parameter block of `raster_common.glsl` (sections in its order; the SH colour last,
/// empty without colour).
pub fn parameter_block(prims: &Primitives<f32>) -> Vec<f32> {
    let mut out = Vec::new();
    for section in [
        &prims.means,
        &prims.log_scales,
        &prims.quats,
        &prims.opacity_logits,
        &prims.beta_raw,
        &prims.omega_low,
        &prims.band_amp,
        &prims.band_freq,
        &prims.band_phase,
        &prims.sh,
    ] {
        out.extend_from_slice(section);
    }
    out
}
