//! The thermal + RGB rig: the extrinsic between the two cameras, board pose trajectories
//! ("a person waving a board"), and rendering of one board view in both cameras.
//!
//! The rig frame is the thermal camera frame (x right, y down, z forward, metres).

use glam::{DQuat, DVec2, DVec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use s3tir_calib::{CameraModel, Rigid3};

use crate::board::{BoardSpec, BoardThermal};
use crate::error::SimError;
use crate::physics::Radiometry;
use crate::render::{PlaneTexture, RayGrid, gaussian_blur, render_plane};
use crate::sensor::{RgbProfile, ThermalOutput, ThermalProfile, ThermalSensor, expose_rgb};

/// A thermal camera and an RGB camera on one rig.
#[derive(Debug, Clone, Copy)]
pub struct Rig {
    pub thermal: ThermalProfile,
    pub rgb: RgbProfile,
    /// Maps thermal-camera points into the RGB camera frame.
    pub rgb_from_thermal: Rigid3,
}

impl Rig {
    /// The default rig: RGB camera 6.5 cm to the right of the thermal core, 2 mm lower,
    /// 3 mm behind it, mounted with a small misalignment (0.8°, −0.5°, 0.3°).
    pub fn new(thermal: ThermalProfile, rgb: RgbProfile) -> Self {
        let rotation = DQuat::from_euler(
            glam::EulerRot::XYZ,
            0.8f64.to_radians(),
            -0.5f64.to_radians(),
            0.3f64.to_radians(),
        );
        let rgb_centre_in_thermal = DVec3::new(0.065, 0.002, -0.003);
        let rgb_from_thermal = Rigid3::new(rotation, -(rotation * rgb_centre_in_thermal));
        Self {
            thermal,
            rgb,
            rgb_from_thermal,
        }
    }
}

/// One planned board view.
#[derive(Debug, Clone, Copy)]
pub struct BoardView {
    pub thermal_from_board: Rigid3,
    /// Whether the whole board (margin included) is inside each image.
    pub full_in_thermal: bool,
    pub full_in_rgb: bool,
}

/// Number of board outline points (margin included) inside an image, out of `n × 4`.
fn outline_inside(
    cam: &CameraModel,
    cam_from_board: &Rigid3,
    board: &BoardSpec,
    margin_px: f64,
) -> (usize, usize) {
    let (x0, y0, x1, y1) = board.extent_m();
    let n = 8;
    let mut inside = 0;
    let mut total = 0;
    for k in 0..n {
        let f = k as f64 / n as f64;
        for p in [
            DVec3::new(x0 + (x1 - x0) * f, y0, 0.0),
            DVec3::new(x1, y0 + (y1 - y0) * f, 0.0),
            DVec3::new(x1 - (x1 - x0) * f, y1, 0.0),
            DVec3::new(x0, y1 - (y1 - y0) * f, 0.0),
        ] {
            total += 1;
            if let Some(px) = cam.project(cam_from_board.transform_point(p))
                && px.x >= margin_px
                && px.y >= margin_px
                && px.x <= f64::from(cam.width_px) - 1.0 - margin_px
                && px.y <= f64::from(cam.height_px) - 1.0 - margin_px
            {
                inside += 1;
            }
        }
    }
    (inside, total)
}

/// Inner corners of the board inside an image.
pub fn corners_inside(cam: &CameraModel, cam_from_board: &Rigid3, board: &BoardSpec) -> usize {
    board
        .inner_corners_m()
        .iter()
        .filter_map(|p| cam.project(cam_from_board.transform_point(*p)))
        .filter(|px| {
            px.x >= 0.0
                && px.y >= 0.0
                && px.x <= f64::from(cam.width_px) - 1.0
                && px.y <= f64::from(cam.height_px) - 1.0
        })
        .count()
}

/// Plans `n` board poses like a person waving a board in front of the rig: the board centre
/// aimed at points spread over the thermal image (corners included), tilted 5–45° about a
/// random in-plane axis, rolled up to ±20°, 0.6–1.3 m away. Every 7th view (index 3, 10, 17, …) is a partial view
/// (board cut by the thermal image edge, ≥ 30 % of the inner corners visible); all others have
/// the whole board, margin included, inside both images.
pub fn plan_board_views(
    rig: &Rig,
    board: &BoardSpec,
    n: usize,
    seed: u64,
) -> Result<Vec<BoardView>, SimError> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5EED_B0A2D);
    let tcam = rig.thermal.camera;
    let (w, h) = (f64::from(tcam.width_px), f64::from(tcam.height_px));
    let (x0, y0, x1, y1) = board.extent_m();
    let centre_b = DVec3::new((x0 + x1) / 2.0, (y0 + y1) / 2.0, 0.0);
    let n_corners = (board.inner_cols * board.inner_rows) as usize;
    let mut views = Vec::with_capacity(n);
    for view in 0..n {
        let partial = view % 7 == 3;
        // Aim at one of 9 image regions in turn (corners, edges, centre), jittered.
        let region = view % 9;
        let (gx, gy) = ((region % 3) as f64, (region / 3) as f64);
        let mut found = None;
        let attempts = 400;
        for attempt in 0..attempts {
            let aimed = if partial {
                // Near an image edge so part of the board falls outside.
                let side = rng.random_range(0..4);
                let t: f64 = rng.random_range(0.2..0.8);
                match side {
                    0 => DVec2::new(0.02 * w, t * h),
                    1 => DVec2::new(0.98 * w, t * h),
                    2 => DVec2::new(t * w, 0.03 * h),
                    _ => DVec2::new(t * w, 0.97 * h),
                }
            } else {
                DVec2::new(
                    (0.2 + 0.3 * gx + rng.random_range(-0.12..0.12)) * w,
                    (0.2 + 0.3 * gy + rng.random_range(-0.12..0.12)) * h,
                )
            };
            // Aims that cannot fit the whole board drift toward the image centre over the
            // attempts (a near-corner aim is kept whenever a pose there fits).
            let pull = if partial {
                0.0
            } else {
                attempt as f64 / attempts as f64
            };
            let target = aimed * (1.0 - pull) + DVec2::new(w / 2.0, h / 2.0) * pull;
            let Some(ray) = tcam.unproject(target) else {
                continue;
            };
            let dist: f64 = rng.random_range(0.6..1.3);
            // Tilt: about a random axis in the board plane, 5–45° (a hand-held board), then
            // roll about the optical axis up to ±20°.
            let tilt_axis_angle: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let tilt = rng.random_range(5.0f64..45.0).to_radians();
            let roll = rng.random_range(-20.0f64..20.0).to_radians();
            let axis = DVec3::new(tilt_axis_angle.cos(), tilt_axis_angle.sin(), 0.0);
            let rotation = DQuat::from_rotation_z(roll) * DQuat::from_axis_angle(axis, tilt);
            let t = ray * dist - rotation * centre_b;
            let thermal_from_board = Rigid3::new(rotation, t);
            // The board front (−z side) must face the camera.
            let normal = rotation * DVec3::NEG_Z;
            if normal.dot(-t.normalize()) < 0.25 {
                continue;
            }
            let rgb_from_board = rig.rgb_from_thermal.compose(&thermal_from_board);
            let (ti, tn) = outline_inside(&tcam, &thermal_from_board, board, 2.0);
            let (ri, rn) = outline_inside(&rig.rgb.camera, &rgb_from_board, board, 2.0);
            let ok = if partial {
                let c = corners_inside(&tcam, &thermal_from_board, board);
                ti < tn && c * 10 >= n_corners * 3 && c < n_corners
            } else {
                ti == tn && ri == rn
            };
            if ok {
                found = Some(BoardView {
                    thermal_from_board,
                    full_in_thermal: ti == tn,
                    full_in_rgb: ri == rn,
                });
                break;
            }
        }
        views.push(found.ok_or(SimError::NoPose { view, attempts })?);
    }
    Ok(views)
}

/// The board as the thermal camera sees it: apparent in-band radiance.
#[derive(Debug)]
pub struct ThermalBoardTexture<'a> {
    pub thermal: &'a BoardThermal,
    pub radiometry: &'a Radiometry,
}

impl PlaneTexture for ThermalBoardTexture<'_> {
    fn cell_m(&self) -> f64 {
        self.thermal.board.square_m
    }
    fn value(&self, x_m: f64, y_m: f64) -> Option<f64> {
        self.thermal.apparent_radiance_at(self.radiometry, x_m, y_m)
    }
}

/// The board as the RGB camera sees it: visible reflectance.
#[derive(Debug)]
pub struct VisibleBoardTexture<'a> {
    pub board: &'a BoardSpec,
}

impl PlaneTexture for VisibleBoardTexture<'_> {
    fn cell_m(&self) -> f64 {
        self.board.square_m
    }
    fn value(&self, x_m: f64, y_m: f64) -> Option<f64> {
        self.board
            .material_at(x_m, y_m)
            .map(|m| self.board.reflectance(m))
    }
}

/// Supersampling factor per pixel axis (4 × 4 sub-pixels).
pub const SUBPIXELS: u32 = 4;

/// Visible reflectance of the wall behind the board.
pub const BACKGROUND_REFLECTANCE: f64 = 0.30;

/// Renders the thermal view: radiance → PSF → sensor. Returns the sensor's output words
/// (image rows only when the profile has no telemetry).
pub fn render_thermal_board(
    grid: &RayGrid,
    sensor: &mut ThermalSensor,
    thermal: &BoardThermal,
    thermal_from_board: &Rigid3,
) -> Option<Vec<u16>> {
    let radiometry = sensor.radiometry().clone();
    let texture = ThermalBoardTexture {
        thermal,
        radiometry: &radiometry,
    };
    let background = radiometry.radiance(thermal.env_k);
    let img = render_plane(grid, thermal_from_board, SUBPIXELS, &texture, background);
    let p = sensor.profile;
    let img = gaussian_blur(&img, grid.width(), grid.height(), p.psf_sigma_px);
    match sensor.next_frame(&img) {
        ThermalOutput::Frame(f) => Some(f.words),
        ThermalOutput::Dropped { .. } => None,
    }
}

/// Renders the RGB view: reflectance → PSF → exposure and noise → packed 8-bit RGB.
pub fn render_rgb_board(
    grid: &RayGrid,
    profile: &RgbProfile,
    board: &BoardSpec,
    rgb_from_board: &Rigid3,
    rng: &mut ChaCha8Rng,
) -> Vec<u8> {
    let texture = VisibleBoardTexture { board };
    let img = render_plane(
        grid,
        rgb_from_board,
        SUBPIXELS,
        &texture,
        BACKGROUND_REFLECTANCE,
    );
    let img = gaussian_blur(&img, grid.width(), grid.height(), profile.psf_sigma_px);
    expose_rgb(profile, &img, [1.0, 0.97, 0.92], rng)
}
