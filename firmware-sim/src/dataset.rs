//! The `board` calibration set: `board.toml`, `thermal/NNNN.png`, `rgb/NNNN.png`, `truth.json`
//! (layout documented in firmware-sim/README.md).

use std::fs;
use std::path::{Path, PathBuf};

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use s3tir_calib::{CameraModel, Rigid3};
use serde::Serialize;

use crate::board::{BoardSpec, BoardThermal};
use crate::error::SimError;
use crate::render::RayGrid;
use crate::rig::{Rig, plan_board_views, render_rgb_board, render_thermal_board};
use crate::sensor::ThermalSensor;

/// Which thermal-gradient induction the board went through.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Polarity {
    /// 25 °C board moved into −20 °C surroundings: coated squares look colder.
    Cooled,
    /// 25 °C board moved into 70 °C surroundings: coated squares look warmer.
    Heated,
}

/// Parameters of a board set.
#[derive(Debug, Clone)]
pub struct BoardSetConfig {
    pub out_dir: PathBuf,
    pub views: usize,
    pub rig: Rig,
    pub board: BoardSpec,
    pub polarity: Polarity,
    pub seed: u64,
    /// Time after the temperature step at which view 0 is taken, seconds.
    pub first_view_s: f64,
    /// Time between views, seconds.
    pub view_interval_s: f64,
}

/// A 3×3 rotation (row-major) and translation in metres.
#[derive(Debug, Clone, Serialize)]
pub struct PoseJson {
    pub rotation: [[f64; 3]; 3],
    pub translation_m: [f64; 3],
}

impl From<&Rigid3> for PoseJson {
    fn from(r: &Rigid3) -> Self {
        let m = r.rotation_matrix();
        let row = |i: usize| [m.row(i).x, m.row(i).y, m.row(i).z];
        Self {
            rotation: [row(0), row(1), row(2)],
            translation_m: r.translation_m.to_array(),
        }
    }
}

#[derive(Debug, Serialize)]
struct ViewJson {
    index: usize,
    thermal: String,
    rgb: String,
    time_after_step_s: f64,
    thermal_from_board: PoseJson,
    board_fully_in_thermal: bool,
    board_fully_in_rgb: bool,
    physical_contrast_k: f64,
    apparent_contrast_k: f64,
}

#[derive(Debug, Serialize)]
struct TruthJson<'a> {
    thermal: &'a CameraModel,
    rgb: &'a CameraModel,
    thermal_profile: &'a str,
    rgb_from_thermal: PoseJson,
    board: &'a BoardSpec,
    polarity: Polarity,
    seed: u64,
    views: Vec<ViewJson>,
}

fn io(path: &Path, what: &'static str) -> impl FnOnce(std::io::Error) -> SimError {
    let path = path.to_path_buf();
    move |source| SimError::Io { path, what, source }
}

/// Writes a board calibration set; `progress(done, total)` is called after each view.
pub fn write_board_set(
    cfg: &BoardSetConfig,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<(), SimError> {
    let out = &cfg.out_dir;
    for d in [out.clone(), out.join("thermal"), out.join("rgb")] {
        fs::create_dir_all(&d).map_err(io(&d, "create directory"))?;
    }
    let views = plan_board_views(&cfg.rig, &cfg.board, cfg.views, cfg.seed)?;
    let mut thermal = match cfg.polarity {
        Polarity::Cooled => BoardThermal::cooled(cfg.board),
        Polarity::Heated => BoardThermal::heated(cfg.board),
    };
    let mut tprofile = cfg.rig.thermal;
    tprofile.telemetry_rows = 0;
    tprofile.drop_probability = 0.0;
    tprofile.auto_ffc_period_s = 0.0;
    let mut sensor = ThermalSensor::new(tprofile, cfg.seed);
    let mut rgb_rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x0052_4742);
    let tgrid = RayGrid::new(&tprofile.camera);
    let rgrid = RayGrid::new(&cfg.rig.rgb.camera);
    let mut views_json = Vec::with_capacity(views.len());
    for (k, view) in views.iter().enumerate() {
        let t = cfg.first_view_s + cfg.view_interval_s * k as f64;
        thermal.advance(t - thermal.time_s);
        let words = loop {
            // The sensor never drops frames here (drop probability 0); loop for safety.
            if let Some(w) =
                render_thermal_board(&tgrid, &mut sensor, &thermal, &view.thermal_from_board)
            {
                break w;
            }
        };
        let name = format!("{k:04}.png");
        let tpath = out.join("thermal").join(&name);
        let img = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(
            tprofile.camera.width_px,
            tprofile.camera.height_px,
            words,
        )
        .ok_or(SimError::InvalidParameter {
            parameter: "thermal frame",
            value: format!("{k}"),
            why: "buffer does not match the image size",
        })?;
        img.save(&tpath).map_err(|source| SimError::Image {
            path: tpath.clone(),
            what: "thermal PNG",
            source: Box::new(source),
        })?;
        let rgb_from_board = cfg.rig.rgb_from_thermal.compose(&view.thermal_from_board);
        let rgb = render_rgb_board(
            &rgrid,
            &cfg.rig.rgb,
            &cfg.board,
            &rgb_from_board,
            &mut rgb_rng,
        );
        let rpath = out.join("rgb").join(&name);
        let img = image::RgbImage::from_raw(
            cfg.rig.rgb.camera.width_px,
            cfg.rig.rgb.camera.height_px,
            rgb,
        )
        .ok_or(SimError::InvalidParameter {
            parameter: "rgb frame",
            value: format!("{k}"),
            why: "buffer does not match the image size",
        })?;
        img.save(&rpath).map_err(|source| SimError::Image {
            path: rpath.clone(),
            what: "RGB PNG",
            source: Box::new(source),
        })?;
        views_json.push(ViewJson {
            index: k,
            thermal: format!("thermal/{name}"),
            rgb: format!("rgb/{name}"),
            time_after_step_s: thermal.time_s,
            thermal_from_board: PoseJson::from(&view.thermal_from_board),
            board_fully_in_thermal: view.full_in_thermal,
            board_fully_in_rgb: view.full_in_rgb,
            physical_contrast_k: thermal.physical_contrast_k(),
            apparent_contrast_k: thermal.apparent_contrast_k(sensor.radiometry()),
        });
        progress(k + 1, views.len());
    }
    let truth = TruthJson {
        thermal: &tprofile.camera,
        rgb: &cfg.rig.rgb.camera,
        thermal_profile: tprofile.name,
        rgb_from_thermal: PoseJson::from(&cfg.rig.rgb_from_thermal),
        board: &cfg.board,
        polarity: cfg.polarity,
        seed: cfg.seed,
        views: views_json,
    };
    let path = out.join("truth.json");
    let text = serde_json::to_string_pretty(&truth).map_err(|source| SimError::Json {
        what: "truth.json",
        source,
    })?;
    fs::write(&path, text + "\n").map_err(io(&path, "write"))?;
    let path = out.join("board.toml");
    fs::write(&path, board_toml(&cfg.board, cfg.polarity)).map_err(io(&path, "write"))?;
    Ok(())
}

/// The `board.toml` text.
pub fn board_toml(b: &BoardSpec, polarity: Polarity) -> String {
    let pol = match polarity {
        Polarity::Cooled => "cooled",
        Polarity::Heated => "heated",
    };
    let thermal_polarity = match polarity {
        Polarity::Cooled => "coated_dark",
        Polarity::Heated => "coated_bright",
    };
    format!(
        "# Emissivity-coated checkerboard written by s3tir-firmware-sim (see its README).\n\
         [board]\n\
         # Inner corners as [cols, rows]: corners along a row, corners along a column.\n\
         inner_corners = [{}, {}]\n\
         square_mm = {:?}\n\
         # Uncoated white margin around the pattern, in squares.\n\
         margin_squares = {}\n\
         # Which squares carry the low-emissivity coating: the black ones; the top-left\n\
         # pattern square (touching inner corner (0, 0) diagonally) is black.\n\
         coated = \"black\"\n\
         top_left_square = \"black\"\n\
         emissivity_coated = {:?}\n\
         emissivity_uncoated = {:?}\n\
         # Thermal-gradient induction and how coated squares look in the thermal images.\n\
         induction = \"{pol}\"\n\
         thermal_polarity = \"{thermal_polarity}\"\n",
        b.inner_cols,
        b.inner_rows,
        b.square_m * 1000.0,
        b.margin_squares,
        b.emissivity_coated,
        b.emissivity_uncoated,
    )
}
