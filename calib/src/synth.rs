//! Synthetic board sets with known truth, for tests and the benchmark (not a physical
//! simulation: that is `s3tir-firmware-sim board`). A chessboard is projected through
//! [`CameraModel`] (distortion included) and rendered anti-aliased by 12×12 supersampling of edge pixels of
//! the board coordinates interpolated from exact ray–plane intersections at the pixel corners;
//! seeded Gaussian noise is added. Thermal images are 16-bit counts (either polarity) or 8-bit
//! pseudo-colour, RGB images 8-bit RGB.

use std::path::Path;

use glam::{DQuat, DVec2, DVec3, EulerRot};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;

use crate::detect::board::{BoardSpec, ThermalPolarity};
use crate::detect::scalar::{Palette, palette_lut};
use crate::error::CalibError;
use crate::model::camera::{BrownConrady, CameraModel, Intrinsics};
use crate::model::geometry::Rigid3;

/// A synthetic rig: two cameras and the extrinsic between them.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct SynthRig {
    pub thermal: CameraModel,
    pub rgb: CameraModel,
    pub rgb_from_thermal: Rigid3,
}

/// A 1280×720 RGB camera (≈ 70° horizontal field of view) with mild distortion.
pub fn rgb_720p() -> CameraModel {
    CameraModel {
        width_px: 1280,
        height_px: 720,
        intrinsics: Intrinsics {
            fx: 910.0,
            fy: 908.0,
            cx: 641.3,
            cy: 358.2,
        },
        distortion: BrownConrady {
            k1: -0.12,
            k2: 0.08,
            p1: 0.0007,
            p2: -0.0004,
            k3: -0.02,
        },
    }
}

/// A 640×360 RGB camera (same field of view as [`rgb_720p`], a quarter of the pixels): for
/// tests where the RGB side is not what is measured.
pub fn rgb_360p() -> CameraModel {
    CameraModel {
        width_px: 640,
        height_px: 360,
        intrinsics: Intrinsics {
            fx: 455.0,
            fy: 454.0,
            cx: 320.4,
            cy: 179.3,
        },
        distortion: BrownConrady {
            k1: -0.12,
            k2: 0.08,
            p1: 0.0007,
            p2: -0.0004,
            k3: -0.02,
        },
    }
}

/// A FLIR-Lepton-like 160×120 thermal core (≈ 57° HFOV, strong barrel distortion).
pub fn lepton() -> CameraModel {
    CameraModel {
        width_px: 160,
        height_px: 120,
        intrinsics: Intrinsics {
            fx: 146.0,
            fy: 146.8,
            cx: 80.6,
            cy: 59.1,
        },
        distortion: BrownConrady {
            k1: -0.30,
            k2: 0.11,
            p1: 0.001,
            p2: -0.0012,
            k3: -0.02,
        },
    }
}

/// A FLIR-Boson-like 640×512 thermal core (≈ 50° HFOV).
pub fn boson() -> CameraModel {
    CameraModel {
        width_px: 640,
        height_px: 512,
        intrinsics: Intrinsics {
            fx: 690.0,
            fy: 689.2,
            cx: 322.4,
            cy: 254.7,
        },
        distortion: BrownConrady {
            k1: -0.21,
            k2: 0.09,
            p1: -0.0006,
            p2: 0.0009,
            k3: -0.01,
        },
    }
}

/// Thermal beside RGB: 60 mm baseline, ~1.5° relative rotation.
pub fn rig(thermal: CameraModel, rgb: CameraModel) -> SynthRig {
    SynthRig {
        thermal,
        rgb,
        rgb_from_thermal: Rigid3::new(
            DQuat::from_euler(EulerRot::XYZ, 0.012, -0.02, 0.008),
            DVec3::new(-0.060, 0.004, 0.002),
        ),
    }
}

/// How thermal images are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ThermalFormat {
    Grey16,
    PseudoColour(Palette),
}

/// What to generate.
#[derive(Debug, Clone)]
pub struct SynthOptions {
    pub board: BoardSpec,
    pub views: usize,
    pub seed: u64,
    /// Largest tilt about the board's x and y axes, degrees.
    pub max_tilt_deg: f64,
    /// Coated squares bright (warmer-looking) in thermal instead of dark.
    pub coated_bright: bool,
    pub thermal_format: ThermalFormat,
    /// Thermal noise (counts) and RGB noise (grey levels).
    pub thermal_noise: f64,
    pub rgb_noise: f64,
    /// Only the first N views show the board to the RGB camera (the others are empty scenes).
    pub rgb_board_views: Option<usize>,
    /// The last N views put the board partly outside the thermal image.
    pub thermal_partly_out: usize,
    /// The first N views move the board sideways (the pose itself, so the truth keeps it) until
    /// its centre sits on the nearer left/right edge of the RGB image: about half of the board
    /// leaves the RGB image (and usually the thermal one). With tags, RGB still gives the
    /// corners around the visible tags.
    pub rgb_partly_out: usize,
    /// Write thermal images (false: RGB-only folder).
    pub write_thermal: bool,
    /// Write RGB images (false: thermal-only folder).
    pub write_rgb: bool,
}

impl SynthOptions {
    pub fn new(board: BoardSpec, views: usize, seed: u64) -> Self {
        Self {
            board,
            views,
            seed,
            max_tilt_deg: 45.0,
            coated_bright: false,
            thermal_format: ThermalFormat::Grey16,
            thermal_noise: 4.0,
            rgb_noise: 2.0,
            rgb_board_views: None,
            thermal_partly_out: 0,
            rgb_partly_out: 0,
            write_thermal: true,
            write_rgb: true,
        }
    }
}

/// Ground truth of a generated set.
#[derive(Debug, Clone, Serialize)]
pub struct SynthTruth {
    pub rig: SynthRig,
    /// `thermal_from_board` per view.
    pub thermal_from_board: Vec<Rigid3>,
}

/// A board spec for synthetic sets: 9×6 inner corners, 30 mm squares.
pub fn default_board() -> BoardSpec {
    BoardSpec {
        inner_corners: [9, 6],
        square_mm: 30.0,
        thermal_polarity: ThermalPolarity::Auto,
        thermal_palette: Palette::Auto,
        apriltag_ids: Vec::new(),
        apriltag_ratio: crate::detect::board::DEFAULT_APRILTAG_RATIO,
    }
}

fn board_outline_m(board: &BoardSpec) -> Vec<DVec3> {
    // The outer edge of the squares plus the white margin: what must be in view for detection.
    let s = board.square_m();
    let (c, r) = (f64::from(board.cols()), f64::from(board.rows()));
    let m = 1.4;
    let mut pts = Vec::new();
    for i in 0..=8 {
        let f = f64::from(i) / 8.0;
        let x = -m + f * (c - 1.0 + 2.0 * m);
        let y = -m + f * (r - 1.0 + 2.0 * m);
        pts.push(DVec3::new(x * s, -m * s, 0.0));
        pts.push(DVec3::new(x * s, (r - 1.0 + m) * s, 0.0));
        pts.push(DVec3::new(-m * s, y * s, 0.0));
        pts.push(DVec3::new((c - 1.0 + m) * s, y * s, 0.0));
    }
    pts
}

fn all_inside(cam: &CameraModel, cam_from_board: &Rigid3, pts: &[DVec3], margin_px: f64) -> bool {
    pts.iter().all(|p| {
        cam.project(cam_from_board.transform_point(*p))
            .is_some_and(|q| {
                q.x >= margin_px
                    && q.y >= margin_px
                    && q.x <= f64::from(cam.width_px) - 1.0 - margin_px
                    && q.y <= f64::from(cam.height_px) - 1.0 - margin_px
            })
    })
}

/// Smallest projected distance between neighbouring inner corners (px).
fn min_square_px(cam: &CameraModel, cam_from_board: &Rigid3, board: &BoardSpec) -> f64 {
    let pts: Vec<Option<DVec2>> = board
        .object_points_m()
        .iter()
        .map(|p| cam.project(cam_from_board.transform_point(*p)))
        .collect();
    let cols = board.cols() as usize;
    let mut min = f64::INFINITY;
    for (i, p) in pts.iter().enumerate() {
        for j in [i + 1, i + cols] {
            if (j == i + 1 && (i + 1) % cols == 0) || j >= pts.len() {
                continue;
            }
            match (p, pts[j]) {
                (Some(a), Some(b)) => min = min.min((*a - b).length()),
                _ => return 0.0,
            }
        }
    }
    min
}

/// Random board poses `thermal_from_board` that both cameras see whole, with thermal squares
/// at least 5 px across (smaller ones are beyond what the detectors find at 160×120).
pub fn random_poses(rig: &SynthRig, opts: &SynthOptions, rng: &mut ChaCha8Rng) -> Vec<Rigid3> {
    let board = &opts.board;
    let s = board.square_m();
    let centre = DVec3::new(
        f64::from(board.cols() - 1) * s * 0.5,
        f64::from(board.rows() - 1) * s * 0.5,
        0.0,
    );
    let width_m = f64::from(board.cols() + 1) * s;
    let outline = board_outline_m(board);
    let tan_half = f64::from(rig.thermal.width_px) * 0.5 / rig.thermal.intrinsics.fx;
    let tilt = opts.max_tilt_deg.to_radians();
    let mut poses = Vec::with_capacity(opts.views);
    let mut attempts = 0usize;
    while poses.len() < opts.views && attempts < 200_000 {
        attempts += 1;
        // Distance so the board spans 45–85 % of the thermal image width.
        let fill = rng.random_range(0.45..0.85);
        let d = width_m / (2.0 * tan_half * fill);
        let ax = rng.random_range(-tilt..=tilt);
        let ay = rng.random_range(-tilt..=tilt);
        let az = rng.random_range(-0.3..=0.3);
        let rot = DQuat::from_euler(EulerRot::ZYX, az, ay, ax);
        let lateral = d * tan_half * 0.9;
        let target = DVec3::new(
            rng.random_range(-lateral..=lateral),
            rng.random_range(-lateral * 0.75..=lateral * 0.75),
            d,
        );
        let pose = Rigid3::new(rot, target - rot * centre);
        let rgb_pose = rig.rgb_from_thermal.compose(&pose);
        if all_inside(&rig.thermal, &pose, &outline, 1.0)
            && all_inside(&rig.rgb, &rgb_pose, &outline, 2.0)
            && min_square_px(&rig.thermal, &pose, board) >= 5.0
        {
            poses.push(pose);
        }
    }
    poses
}

/// Scene radiometry for one camera.
#[derive(Debug, Clone, Copy)]
pub struct Shades {
    pub coated: f64,
    pub uncoated: f64,
    pub background: f64,
    /// Background gradient across the image (value per image width).
    pub gradient: f64,
    /// Draw the board's AprilTags (black cells in the coated shade, white in the uncoated);
    /// false for thermal, where printed tags do not show.
    pub tags: bool,
}

/// Renders the board seen by `cam` at `cam_from_board` (`None`: empty scene).
pub fn render(
    cam: &CameraModel,
    cam_from_board: Option<&Rigid3>,
    board: &BoardSpec,
    shades: Shades,
    noise_sigma: f64,
    rng: &mut ChaCha8Rng,
) -> Vec<f64> {
    let (w, h) = (cam.width_px as usize, cam.height_px as usize);
    let s = board.square_m();
    let (cols, rows) = (f64::from(board.cols()), f64::from(board.rows()));
    // Board coordinates (in squares) at pixel corners; NaN when the ray misses the board plane.
    let board_from_cam = cam_from_board.map(Rigid3::inverse);
    let mut grid = vec![DVec2::NAN; (w + 1) * (h + 1)];
    if let Some(b) = board_from_cam {
        for j in 0..=h {
            for i in 0..=w {
                let pixel = DVec2::new(i as f64 - 0.5, j as f64 - 0.5);
                if let Some(ray) = cam.unproject(pixel) {
                    let o = b.translation_m;
                    let d = b.transform_vector(ray);
                    if d.z.abs() > 1e-12 {
                        let l = -o.z / d.z;
                        if l > 0.0 {
                            let p = o + d * l;
                            grid[j * (w + 1) + i] = DVec2::new(p.x / s, p.y / s);
                        }
                    }
                }
            }
        }
    }
    // Tag cells per square (i, j), indexed j·(cols + 1) + i (`board` module docs: square
    // (i, j) spans [i − 1, i] × [j − 1, j] in square units); looked up per sub-sample.
    let squares_x = board.cols() as usize + 1;
    let mut tag_cells: Vec<Option<[[bool; 8]; 8]>> =
        vec![None; squares_x * (board.rows() as usize + 1)];
    if shades.tags {
        for ((i, j), &id) in board.tag_squares().into_iter().zip(&board.apriltag_ids) {
            tag_cells[j as usize * squares_x + i as usize] = crate::tags::tag36h11_cells(id);
        }
    }
    let half_tag = 0.5 * board.apriltag_ratio;
    let value_at = |u: f64, v: f64| -> Option<f64> {
        if !(u.is_finite() && v.is_finite()) {
            return None;
        }
        if u >= -1.0 && u <= cols && v >= -1.0 && v <= rows {
            let parity = (u.floor() + v.floor()).rem_euclid(2.0);
            // Inside the squares, u and v lie in [-1, cols] × [-1, rows]: i, j ≥ 0.
            let (i, j) = ((u.floor() + 1.0) as usize, (v.floor() + 1.0) as usize);
            if parity >= 0.5
                && let Some(Some(cells)) = tag_cells.get(j * squares_x + i.min(squares_x - 1))
            {
                let fx = (u - u.floor() - 0.5 + half_tag) / (2.0 * half_tag);
                let fy = (v - v.floor() - 0.5 + half_tag) / (2.0 * half_tag);
                if (0.0..1.0).contains(&fx) && (0.0..1.0).contains(&fy) {
                    let white = cells[(fy * 8.0) as usize][(fx * 8.0) as usize];
                    return Some(if white {
                        shades.uncoated
                    } else {
                        shades.coated
                    });
                }
            }
            Some(if parity < 0.5 {
                shades.coated
            } else {
                shades.uncoated
            })
        } else if u >= -1.6 && u <= cols + 0.6 && v >= -1.6 && v <= rows + 0.6 {
            Some(shades.uncoated)
        } else {
            None
        }
    };
    let noise = Normal::new(0.0, noise_sigma.max(1e-12)).ok();
    let mut out = vec![0.0; w * h];
    // Pixels whose four corners see the same shade are uniform (squares are wider than a
    // pixel); the others, on an edge, are supersampled 12×12 (144 coverage levels).
    const N: usize = 12;
    for y in 0..h {
        for x in 0..w {
            let bg = shades.background
                + shades.gradient * (x as f64 / w as f64 - 0.5 + 0.3 * y as f64 / h as f64);
            let g00 = grid[y * (w + 1) + x];
            let g10 = grid[y * (w + 1) + x + 1];
            let g01 = grid[(y + 1) * (w + 1) + x];
            let g11 = grid[(y + 1) * (w + 1) + x + 1];
            let corners = [g00, g10, g01, g11].map(|g| value_at(g.x, g.y));
            let acc = if corners.iter().all(|c| *c == corners[0]) {
                corners[0].unwrap_or(bg)
            } else {
                let mut acc = 0.0;
                for sy in 0..N {
                    for sx in 0..N {
                        let fx = (sx as f64 + 0.5) / N as f64;
                        let fy = (sy as f64 + 0.5) / N as f64;
                        let p = (g00 * (1.0 - fx) + g10 * fx) * (1.0 - fy)
                            + (g01 * (1.0 - fx) + g11 * fx) * fy;
                        acc += value_at(p.x, p.y).unwrap_or(bg);
                    }
                }
                acc / (N * N) as f64
            };
            let n = noise.map_or(0.0, |n| n.sample(rng));
            out[y * w + x] = acc + n;
        }
    }
    out
}

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> CalibError + '_ {
    move |e| CalibError::Write {
        path: path.to_path_buf(),
        source: Box::new(e),
    }
}

fn img_err(path: &Path) -> impl Fn(image::ImageError) -> CalibError + '_ {
    move |source| CalibError::ImageFile {
        path: path.to_path_buf(),
        source,
    }
}

/// Writes `board.toml`, `thermal/thermal_NNNN.png`, `rgb/rgb_NNNN.png` and `truth.json` and
/// returns the truth.
pub fn write_board_folder(
    dir: &Path,
    rig: &SynthRig,
    opts: &SynthOptions,
) -> Result<SynthTruth, CalibError> {
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    let mut poses = random_poses(rig, opts, &mut rng);
    for pose in poses.iter_mut().take(opts.rgb_partly_out) {
        move_half_out_of_rgb(pose, rig, &opts.board);
    }
    std::fs::create_dir_all(dir.join("thermal")).map_err(io_err(dir))?;
    std::fs::create_dir_all(dir.join("rgb")).map_err(io_err(dir))?;
    write_board_toml(dir, opts)?;
    let b = &opts.board;
    let thermal_shades = thermal_shades(opts.coated_bright);
    let n_views = poses.len();
    for (k, pose) in poses.iter().enumerate() {
        let thermal_pose = if k + opts.thermal_partly_out >= n_views {
            half_out_of_thermal(pose, rig, b)
        } else {
            *pose
        };
        if opts.write_thermal {
            let values = render(
                &rig.thermal,
                Some(&thermal_pose),
                b,
                thermal_shades,
                opts.thermal_noise,
                &mut rng,
            );
            let path = dir.join(format!("thermal/thermal_{k:04}.png"));
            write_thermal_png(&path, &values, &rig.thermal, opts.thermal_format)?;
        }
        if opts.write_rgb {
            let rgb_pose = rig.rgb_from_thermal.compose(pose);
            let show = opts.rgb_board_views.is_none_or(|n| k < n);
            let values = render(
                &rig.rgb,
                show.then_some(&rgb_pose),
                b,
                RGB_SHADES,
                opts.rgb_noise,
                &mut rng,
            );
            let path = dir.join(format!("rgb/rgb_{k:04}.png"));
            write_rgb_png(&path, &values, &rig.rgb)?;
        }
    }
    let truth = SynthTruth {
        rig: *rig,
        thermal_from_board: poses,
    };
    let truth_path = dir.join("truth.json");
    let json = serde_json::to_string_pretty(&truth).unwrap_or_default();
    std::fs::write(&truth_path, json).map_err(io_err(&truth_path))?;
    Ok(truth)
}

/// The centre of the board's inner corners, board frame (m).
fn board_centre(board: &BoardSpec) -> DVec3 {
    let s = board.square_m();
    DVec3::new(
        f64::from(board.cols() - 1) * s * 0.5,
        f64::from(board.rows() - 1) * s * 0.5,
        0.0,
    )
}

/// Moves the board sideways (the pose itself, thermal frame) until its centre sits on the
/// nearer left/right edge of the RGB image ([`SynthOptions::rgb_partly_out`]).
fn move_half_out_of_rgb(pose: &mut Rigid3, rig: &SynthRig, board: &BoardSpec) {
    let centre = rig
        .rgb_from_thermal
        .compose(pose)
        .transform_point(board_centre(board));
    let i = rig.rgb.intrinsics;
    let edge_px = if centre.x >= 0.0 {
        f64::from(rig.rgb.width_px) - 1.0
    } else {
        0.0
    };
    let shift_rgb = DVec3::new((edge_px - i.cx) / i.fx * centre.z - centre.x, 0.0, 0.0);
    pose.translation_m += rig.rgb_from_thermal.inverse().transform_vector(shift_rgb);
}

/// The pose moved sideways so the board's centre sits on the nearer left/right thermal image
/// edge: about half of it leaves the thermal image ([`SynthOptions::thermal_partly_out`]).
fn half_out_of_thermal(pose: &Rigid3, rig: &SynthRig, board: &BoardSpec) -> Rigid3 {
    let mut thermal_pose = *pose;
    let centre = pose.transform_point(board_centre(board));
    let i = rig.thermal.intrinsics;
    let edge_px = if centre.x >= 0.0 {
        f64::from(rig.thermal.width_px) - 1.0
    } else {
        0.0
    };
    let target_x = (edge_px - i.cx) / i.fx * centre.z;
    thermal_pose.translation_m.x += target_x - centre.x;
    thermal_pose
}

/// Writes the folder's `board.toml` (the seed in a comment; tags when the board has them).
fn write_board_toml(dir: &Path, opts: &SynthOptions) -> Result<(), CalibError> {
    let b = &opts.board;
    let mut toml = format!(
        "# synthetic board set (s3tir_calib::synth), seed {}\n[board]\ninner_corners = [{}, {}]\nsquare_mm = {}\n",
        opts.seed,
        b.cols(),
        b.rows(),
        b.square_mm
    );
    if b.has_tags() {
        toml.push_str(&format!(
            "apriltag_ids = {:?}\napriltag_ratio = {}\n",
            b.apriltag_ids, b.apriltag_ratio
        ));
    }
    let toml_path = dir.join("board.toml");
    std::fs::write(&toml_path, toml).map_err(io_err(&toml_path))
}

/// The thermal scene: coated squares 400 counts darker than the uncoated (or brighter).
fn thermal_shades(coated_bright: bool) -> Shades {
    let (dark, bright) = (7300.0, 7700.0);
    if coated_bright {
        Shades {
            coated: bright,
            uncoated: dark,
            background: 7450.0,
            gradient: 120.0,
            tags: false,
        }
    } else {
        Shades {
            coated: dark,
            uncoated: bright,
            background: 7550.0,
            gradient: 120.0,
            tags: false,
        }
    }
}

/// The RGB scene: dark coated squares, white paper, the tags drawn.
const RGB_SHADES: Shades = Shades {
    coated: 35.0,
    uncoated: 215.0,
    background: 110.0,
    gradient: 60.0,
    tags: true,
};

/// The "buffer size" error of an image whose data does not fit its size.
fn buffer_size(path: &Path) -> CalibError {
    CalibError::Image {
        path: path.to_path_buf(),
        reason: "buffer size".into(),
    }
}

/// Writes a rendered thermal image as 16-bit grey counts or as pseudo-colour.
fn write_thermal_png(
    path: &Path,
    values: &[f64],
    cam: &CameraModel,
    format: ThermalFormat,
) -> Result<(), CalibError> {
    let (w, h) = (cam.width_px, cam.height_px);
    match format {
        ThermalFormat::Grey16 => {
            let data: Vec<u16> = values
                .iter()
                .map(|v| v.round().clamp(0.0, 65535.0) as u16)
                .collect();
            let img = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, data)
                .ok_or_else(|| buffer_size(path))?;
            img.save(path).map_err(img_err(path))
        }
        ThermalFormat::PseudoColour(p) => {
            let lut = palette_lut(p).or_else(|| palette_lut(Palette::Ironbow));
            let mut data = Vec::with_capacity(values.len() * 3);
            for v in values {
                let t = ((v - 7200.0) / 600.0).clamp(0.0, 1.0);
                let c = lut.map_or([0.0; 3], |l| l[(t * 255.0).round() as usize]);
                data.extend(c.iter().map(|x| x.round().clamp(0.0, 255.0) as u8));
            }
            let img = image::RgbImage::from_raw(w, h, data).ok_or_else(|| buffer_size(path))?;
            img.save(path).map_err(img_err(path))
        }
    }
}

/// Writes a rendered RGB image (grey levels with a slight warm tint).
fn write_rgb_png(path: &Path, values: &[f64], cam: &CameraModel) -> Result<(), CalibError> {
    let mut data = Vec::with_capacity(values.len() * 3);
    for v in values {
        let g = v.round().clamp(0.0, 255.0) as u8;
        // A slightly warm tint so the image is colour, not grey.
        data.extend([g, g.saturating_sub(3), g.saturating_sub(6)]);
    }
    let img = image::RgbImage::from_raw(cam.width_px, cam.height_px, data)
        .ok_or_else(|| buffer_size(path))?;
    img.save(path).map_err(img_err(path))
}
