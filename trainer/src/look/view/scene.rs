//! What the viewer's page is told about a run (`/api/scene.json`): the run's meshes (each with
//! its vertex and triangle counts and the 1st–99th percentile of its temperatures), the unit, the
//! palettes, and the camera to start from.

use std::path::{Path, PathBuf};

use s3tir_calib::model::palette::Colormap;
use serde::Serialize;

use super::ViewError;
use crate::camera::PinholeCamera;
use crate::dataset::Dataset;
use crate::look::image::{DisplayUnits, quantile};
use crate::mesh::plyio::read_mesh_ply;
use crate::train::load_config;

/// Served under `/api/scene.json`.
#[derive(Debug, Clone, Serialize)]
pub struct SceneInfo {
    /// The run folder's name.
    pub run: String,
    /// `Some(true)`: the meshes' `kelvin` values are kelvin; `Some(false)`: the run's data is
    /// not radiometric and they are its normalised unit; `None`: the run's dataset did not load
    /// (`units_note` says why) and the values are shown as stored.
    pub radiometric: Option<bool>,
    /// The unit of the meshes' values as the page labels them: `K`, `normalised`, or `kelvin
    /// property` when unknown.
    pub unit: String,
    /// Why the unit is what it is, for the page.
    pub units_note: String,
    pub meshes: Vec<MeshInfo>,
    /// Each palette's name and 256 sRGB entries, from calib (the report's palettes).
    pub palettes: Vec<PaletteInfo>,
    pub default_palette: &'static str,
    /// The first held-out view's camera (else the first training view's), when the dataset
    /// loads.
    pub camera: Option<StartCamera>,
}

/// A mesh of the run folder (`s3tir-train mesh` output).
#[derive(Debug, Clone, Serialize)]
pub struct MeshInfo {
    /// The file's name in the run folder.
    pub name: String,
    /// Where the page fetches it.
    pub url: String,
    pub vertices: usize,
    pub triangles: usize,
    /// Vertices without a temperature (no view observed them).
    pub unobserved: usize,
    /// 1st and 99th percentile of the vertices' values: the default range of the palette
    /// (`None` when no vertex has a value).
    pub lo: Option<f64>,
    pub hi: Option<f64>,
    /// Extreme values.
    pub min: Option<f64>,
    pub max: Option<f64>,
}

#[derive(Debug, Clone, Serialize)]
pub struct PaletteInfo {
    pub name: &'static str,
    pub lut: Vec<[u8; 3]>,
}

/// A recorded view's pose, for the page's first camera.
#[derive(Debug, Clone, Serialize)]
pub struct StartCamera {
    /// The view's name in the dataset.
    pub view: String,
    /// Camera centre, world metres.
    pub eye: [f64; 3],
    /// Viewing direction (camera +z) and up (camera −y), world.
    pub forward: [f64; 3],
    pub up: [f64; 3],
    /// Vertical field of view, degrees; width / height.
    pub fov_deg: f64,
    pub aspect: f64,
}

/// Mesh files of a run folder: its top-level `.ply` files with triangles (the meshing stage's
/// `*_thermal.ply` colour copies, the same surface, left out; the primitives' `point_cloud.ply`
/// has none), sorted by name.
fn mesh_files(run_dir: &Path) -> Result<Vec<PathBuf>, ViewError> {
    let io = |source| ViewError::Io {
        path: run_dir.to_path_buf(),
        source,
    };
    let mut out = Vec::new();
    for entry in std::fs::read_dir(run_dir).map_err(io)? {
        let path = entry.map_err(io)?.path();
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if path.is_file()
            && name.ends_with(".ply")
            && !name.ends_with("_thermal.ply")
            && name != crate::train::files::PLY
        {
            out.push(path);
        }
    }
    out.sort();
    Ok(out)
}

/// Reads the run folder's configuration, dataset (for the unit and the first camera) and
/// meshes. A dataset that does not load leaves the unit unknown and the camera out (said in
/// `units_note`); a mesh that does not read is an error naming it.
pub fn scene_info(run_dir: &Path) -> Result<SceneInfo, ViewError> {
    let run = run_dir
        .canonicalize()
        .unwrap_or_else(|_| run_dir.to_path_buf())
        .file_name()
        .map_or_else(|| "run".to_string(), |n| n.to_string_lossy().into_owned());
    let data = load_config(run_dir)
        .map_err(|e| e.to_string())
        .and_then(|cfg| {
            Dataset::load(&cfg.data, &cfg.load)
                .map_err(|e| format!("the dataset {} does not load: {e}", cfg.data.display()))
        });
    let (radiometric, unit, units_note, camera) = match &data {
        Ok(d) => {
            let units = DisplayUnits { range: d.range };
            let note = if units.radiometric() {
                "kelvin: the run's rendered apparent temperature (emissivity 1)".to_string()
            } else {
                "the run's data is not radiometric: values are its normalised unit, not a \
                 temperature"
                    .to_string()
            };
            (
                Some(units.radiometric()),
                units.unit().to_string(),
                note,
                start_camera(d),
            )
        }
        Err(why) => (
            None,
            "kelvin property".to_string(),
            format!("unit unknown ({why}): values shown as stored in the mesh"),
            None,
        ),
    };
    let mut meshes = Vec::new();
    for path in mesh_files(run_dir)? {
        let mesh = read_mesh_ply(&path).map_err(|e| ViewError::Run {
            path: path.clone(),
            reason: e.to_string(),
        })?;
        if mesh.triangles.is_empty() {
            continue;
        }
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let finite: Vec<f32> = mesh
            .kelvin
            .iter()
            .copied()
            .filter(|k| k.is_finite())
            .collect();
        let q = |p| quantile(&finite, p);
        meshes.push(MeshInfo {
            url: format!(
                "/run/{}",
                percent_encoding::utf8_percent_encode(&name, percent_encoding::NON_ALPHANUMERIC)
            ),
            name,
            vertices: mesh.positions.len(),
            triangles: mesh.triangles.len(),
            unobserved: mesh.kelvin.len() - finite.len(),
            lo: q(0.01),
            hi: q(0.99),
            min: q(0.0),
            max: q(1.0),
        });
    }
    Ok(SceneInfo {
        run,
        radiometric,
        unit,
        units_note,
        meshes,
        palettes: Colormap::ALL
            .iter()
            .map(|&p| PaletteInfo {
                name: p.name(),
                lut: p.lut_u8().to_vec(),
            })
            .collect(),
        default_palette: Colormap::Ironbow.name(),
        camera,
    })
}

fn start_camera(d: &Dataset) -> Option<StartCamera> {
    let &i = d.test.first().or_else(|| d.train.first())?;
    let view = &d.views[i];
    let (forward, up, fov_deg) = axes_and_fov(&view.camera);
    Some(StartCamera {
        view: view.name.clone(),
        eye: view.camera.centre_world(),
        forward,
        up,
        fov_deg,
        aspect: view.camera.width as f64 / view.camera.height as f64,
    })
}

/// A camera's viewing direction (+z) and up (−y) in the world, and its vertical field of view
/// in degrees.
fn axes_and_fov(c: &PinholeCamera) -> ([f64; 3], [f64; 3], f64) {
    let r = c.rotation_cam_from_world();
    (
        [r[6], r[7], r[8]],
        [-r[3], -r[4], -r[5]],
        2.0 * (c.height as f64 / (2.0 * c.fy_px)).atan().to_degrees(),
    )
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    /// The page's first camera is the recorded view's: its forward and up are the camera's
    /// +z and −y axes in the world, and the field of view is the intrinsics'.
    #[test]
    fn the_start_camera_is_the_recorded_views_pose() {
        // Looking along +x with +z up, 120 px high at fy = 100 px.
        let cam = PinholeCamera::look_at(
            [1.0, 2.0, 3.0],
            [4.0, 2.0, 3.0],
            [0.0, 0.0, 1.0],
            100.0,
            160,
            120,
        );
        let (fwd, up, fov) = axes_and_fov(&cam);
        for (a, b) in fwd.iter().zip([1.0, 0.0, 0.0]) {
            assert!((a - b).abs() < 1e-9, "forward {fwd:?}, expected +x");
        }
        for (a, b) in up.iter().zip([0.0, 0.0, 1.0]) {
            assert!((a - b).abs() < 1e-9, "up {up:?}, expected +z");
        }
        assert!(
            (fov - 61.93).abs() < 0.01,
            "vertical field of view {fov}, expected 2·atan(60/100) = 61.93°"
        );
    }
}
