//! The structure-from-motion method: COLMAP (the session stage's runner, [`crate::poses::sfm`]:
//! CPU SIFT, the camera held fixed, the largest model kept) on a folder's images, for shots
//! without the survey pattern the planar method needs — free-hand views, folders without GPS
//! or gimbal angles.
//!
//! **Which images.** When every thermal shot has an RGB partner and `--calibration` gives the
//! RGB camera and the extrinsic (a dual camera), COLMAP runs on the **RGB partners** (texture
//! and resolution a thermal core lacks) and each thermal pose is its partner's composed with
//! the extrinsic, `world_from_thermal = world_from_rgb ∘ rgb_from_thermal` (the lever arm in
//! world units); the partners' own poses are kept for `--with-rgb`. Otherwise COLMAP runs on
//! the thermal images (as 8-bit grey over the folder's range), with the thermal camera.
//!
//! **The world.** With GPS positions in at least [`MIN_GPS_FOR_ALIGNMENT`] registered shots
//! spread over more than a line, COLMAP's model is carried onto local east-north-up metres
//! ([`super::geo`]) by the similarity that best fits its camera centres to the positions
//! (Umeyama's least squares): metric, and the report gives the residual and names the shots
//! whose fix disagrees with the model beyond 3 σ — refitted without them, their position the
//! model's. With
//! `--metres-per-unit` the model is scaled by it. Otherwise the world is COLMAP's, its scale
//! arbitrary, and the lever arm (centimetres on a dual camera) is left out of the composition:
//! said in the report.
//!
//! Shots COLMAP does not register are left out with that reason; fewer than
//! [`MIN_REGISTERED`] registered is an error naming COLMAP's workspace (`OUT.partial/colmap`,
//! its logs beside it).

use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec3};
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;

use super::super::sfm::run_colmap;
use super::super::stats::median;
use super::super::{Matcher, PosesError, PosesOptions, StageTimes};
use super::Posing;
use super::geo::LocalTangent;
use super::rgb::RgbRig;
use super::scan::Folder;
use crate::model::camera::CameraModel;
use crate::model::colmap::ColmapPoint;
use crate::model::geometry::Rigid3;
use crate::progress::Progress;

/// At least this many registered shots make a posing.
pub const MIN_REGISTERED: usize = 3;
/// At least this many registered shots with GPS positions carry the model onto them.
pub const MIN_GPS_FOR_ALIGNMENT: usize = 3;

/// The method's options.
#[derive(Debug, Clone, Serialize)]
pub struct SfmOptions {
    /// The COLMAP program.
    pub colmap: PathBuf,
    /// Matcher (default: exhaustive up to 30 images, sequential by name beyond).
    #[serde(skip)]
    pub matcher: Option<Matcher>,
    /// Metres per model unit when no GPS gives the scale.
    pub metres_per_unit: Option<f64>,
    /// σ of the GPS positions, metres (a shot whose fix is further than 3 σ from the aligned
    /// model is named).
    pub gps_sigma_m: f64,
}

impl Default for SfmOptions {
    fn default() -> Self {
        Self {
            colmap: PathBuf::from("colmap"),
            matcher: None,
            metres_per_unit: None,
            gps_sigma_m: 1.5,
        }
    }
}

/// What the method measured (in `poses.json`).
#[derive(Debug, Clone, Default, Serialize)]
pub struct SfmFigures {
    /// `thermal` or `rgb_partners`: the images COLMAP ran on.
    pub images_of: String,
    pub images: usize,
    pub registered: usize,
    pub points: usize,
    /// What the world is: `east_north_up` (GPS), `scaled` (`--metres-per-unit`) or `colmap`
    /// (arbitrary scale).
    pub world: String,
    /// Metres per COLMAP unit, when known.
    pub metres_per_unit: Option<f64>,
    /// Distance of the aligned camera centres from their GPS positions, metres (median).
    pub gps_residual_m_median: Option<f64>,
    /// Shots whose GPS fix is more than 3 σ from the aligned model: (file, metres).
    pub gps_disagrees: Vec<(String, f64)>,
    pub colmap_features_s: f64,
    pub colmap_matching_s: f64,
    pub colmap_mapper_s: f64,
}

/// A similarity `x ↦ s·R·x + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity {
    pub scale: f64,
    pub rotation: Matrix3<f64>,
    pub translation: Vector3<f64>,
}

impl Similarity {
    pub fn apply(&self, x: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * x * self.scale + self.translation
    }

    /// `world'_from_cam` of a `world_from_cam`.
    fn apply_pose(&self, p: &Rigid3) -> Rigid3 {
        let r = to_glam(&self.rotation);
        let c = to_na(p.translation_m);
        Rigid3::new(
            (DQuat::from_mat3(&r) * p.rotation).normalize(),
            to_glam_v(&self.apply(&c)),
        )
    }
}

fn to_glam(m: &Matrix3<f64>) -> DMat3 {
    DMat3::from_cols(
        DVec3::new(m[(0, 0)], m[(1, 0)], m[(2, 0)]),
        DVec3::new(m[(0, 1)], m[(1, 1)], m[(2, 1)]),
        DVec3::new(m[(0, 2)], m[(1, 2)], m[(2, 2)]),
    )
}

fn to_na(v: DVec3) -> Vector3<f64> {
    Vector3::new(v.x, v.y, v.z)
}

fn to_glam_v(v: &Vector3<f64>) -> DVec3 {
    DVec3::new(v.x, v.y, v.z)
}

/// The similarity that maps `src` onto `dst` in least squares (Umeyama 1991); `None` with
/// fewer than 3 pairs or points on (nearly) one line.
pub fn fit_similarity(src: &[Vector3<f64>], dst: &[Vector3<f64>]) -> Option<Similarity> {
    let n = src.len();
    if n < 3 || dst.len() != n {
        return None;
    }
    let mean = |v: &[Vector3<f64>]| v.iter().fold(Vector3::zeros(), |a, x| a + x) / n as f64;
    let (ms, md) = (mean(src), mean(dst));
    let mut cov = Matrix3::zeros();
    let mut var_s = 0.0;
    for (s, d) in src.iter().zip(dst) {
        let (a, b) = (s - ms, d - md);
        cov += b * a.transpose();
        var_s += a.norm_squared();
    }
    cov /= n as f64;
    var_s /= n as f64;
    let svd = cov.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let sv = svd.singular_values;
    // Collinear (or coincident) points leave a rotation about their line free.
    let mut sorted = [sv[0], sv[1], sv[2]];
    sorted.sort_by(f64::total_cmp);
    if var_s <= 0.0 || sorted[1] <= 1e-9 * sorted[2].max(1e-300) {
        return None;
    }
    let mut d = Matrix3::identity();
    if (u * vt).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let rotation = u * d * vt;
    let scale = (sv[0] * d[(0, 0)] + sv[1] * d[(1, 1)] + sv[2] * d[(2, 2)]) / var_s;
    let translation = md - rotation * ms * scale;
    Some(Similarity {
        scale,
        rotation,
        translation,
    })
}

/// Each shot's GPS position in local east-north-up metres (up from the relative altitude, else
/// the GPS altitude, else 0 when no shot has either), on the tangent plane at the first fix.
pub fn enu_positions(folder: &Folder) -> Option<Vec<Option<Vector3<f64>>>> {
    let origin = folder.shots.iter().find_map(|s| s.meta.position())?;
    let tangent = LocalTangent::at(origin);
    let relative = folder
        .shots
        .iter()
        .all(|s| s.meta.position().is_none() || s.meta.relative_altitude_m.is_some());
    Some(
        folder
            .shots
            .iter()
            .map(|s| {
                let p = s.meta.position()?;
                let [e, n] = tangent.east_north(&p);
                let up = if relative {
                    s.meta.relative_altitude_m.unwrap_or(0.0)
                } else {
                    p.altitude_m
                        .zip(origin.altitude_m)
                        .map_or(0.0, |(a, a0)| a - a0)
                };
                Some(Vector3::new(e, n, up))
            })
            .collect(),
    )
}

/// What [`world_of`] decided, for the figures.
#[derive(Debug, Clone, Default)]
struct World {
    world: String,
    gps_residual_m_median: Option<f64>,
    gps_disagrees: Vec<(String, f64)>,
}

/// The similarity carrying COLMAP's model (`registered`: shot index, world_from_cam) onto the
/// world (module docs): onto the shots' GPS positions `enu` when at least
/// [`MIN_GPS_FOR_ALIGNMENT`] registered shots have one and they span more than a line — fitted
/// once, then again without the fixes further than 3 σ from it (named: not trusted), as long as
/// [`MIN_GPS_FOR_ALIGNMENT`] remain; else a scale by `--metres-per-unit`; else none.
fn world_of(
    registered: &[(usize, Rigid3)],
    enu: Option<&[Option<Vector3<f64>>]>,
    name: impl Fn(usize) -> String,
    opts: &SfmOptions,
) -> (Option<Similarity>, World) {
    let with_fix: Vec<(usize, Vector3<f64>, Vector3<f64>)> = registered
        .iter()
        .filter_map(|(i, p)| {
            let e = enu?.get(*i).copied().flatten()?;
            Some((*i, to_na(p.translation_m), e))
        })
        .collect();
    let fit = |keep: &dyn Fn(usize) -> bool| {
        let (src, dst): (Vec<_>, Vec<_>) = with_fix
            .iter()
            .filter(|w| keep(w.0))
            .map(|w| (w.1, w.2))
            .unzip();
        (src.len() >= MIN_GPS_FOR_ALIGNMENT)
            .then(|| fit_similarity(&src, &dst))
            .flatten()
    };
    let residuals = |s: &Similarity| -> Vec<(usize, f64)> {
        with_fix
            .iter()
            .map(|(i, c, e)| (*i, (s.apply(c) - e).norm()))
            .collect()
    };
    let bound = 3.0 * opts.gps_sigma_m;
    if let Some(first) = fit(&|_| true) {
        let far: Vec<usize> = residuals(&first)
            .iter()
            .filter(|r| r.1 > bound)
            .map(|r| r.0)
            .collect();
        let s = if far.is_empty() {
            first
        } else {
            fit(&|i| !far.contains(&i)).unwrap_or(first)
        };
        let res = residuals(&s);
        let gps_disagrees = res
            .iter()
            .filter(|r| r.1 > bound)
            .map(|&(i, d)| (name(i), d))
            .collect();
        let distances: Vec<f64> = res.iter().map(|r| r.1).collect();
        return (
            Some(s),
            World {
                world: "east_north_up".to_owned(),
                gps_residual_m_median: Some(median(&distances)),
                gps_disagrees,
            },
        );
    }
    match opts.metres_per_unit {
        Some(m) => (
            Some(Similarity {
                scale: m,
                rotation: Matrix3::identity(),
                translation: Vector3::zeros(),
            }),
            World {
                world: "scaled".to_owned(),
                ..World::default()
            },
        ),
        None => (
            None,
            World {
                world: "colmap".to_owned(),
                ..World::default()
            },
        ),
    }
}

/// Whether COLMAP runs on the RGB partners (module docs).
pub fn uses_partners(folder: &Folder, rgb: Option<&RgbRig>) -> bool {
    rgb.is_some_and(|r| r.rgb_from_thermal.is_some())
        && folder.shots.iter().all(|s| s.rgb.is_some())
}

/// The file name of shot `i` in COLMAP's images folder (`ext` without the dot).
fn colmap_name(i: usize, ext: &str) -> String {
    format!("{i:05}.{ext}")
}

fn write_err(path: &Path, e: impl Into<Box<dyn std::error::Error + Send + Sync>>) -> PosesError {
    PosesError::Write {
        path: path.to_path_buf(),
        source: e.into(),
    }
}

/// Puts the images COLMAP runs on into `workspace/images`.
fn stage_images(folder: &Folder, partners: bool, images: &Path) -> Result<(), PosesError> {
    std::fs::create_dir_all(images).map_err(|e| write_err(images, e))?;
    if partners {
        for (i, s) in folder.shots.iter().enumerate() {
            let Some(src) = &s.rgb else { continue };
            let ext = src
                .extension()
                .map_or("jpg".to_owned(), |e| e.to_string_lossy().to_lowercase());
            let src = std::fs::canonicalize(src).map_err(|e| PosesError::ImageRead {
                path: src.clone(),
                source: Box::new(e),
            })?;
            let dst = images.join(colmap_name(i, &ext));
            std::os::unix::fs::symlink(&src, &dst).map_err(|e| write_err(&dst, e))?;
        }
        return Ok(());
    }
    let grey = folder.grey_for_matching();
    for (i, (s, g)) in folder.shots.iter().zip(grey).enumerate() {
        let dst = images.join(colmap_name(i, "png"));
        let bytes: Vec<u8> = g
            .iter()
            .map(|v| v.round().clamp(0.0, 255.0) as u8)
            .collect();
        image::GrayImage::from_raw(s.width as u32, s.height as u32, bytes)
            .ok_or_else(|| write_err(&dst, "pixel count does not match the size"))?
            .save(&dst)
            .map_err(|e| write_err(&dst, e))?;
    }
    Ok(())
}

/// Poses the folder's shots with COLMAP (module docs); `workspace` is created.
pub fn pose(
    folder: &Folder,
    thermal_cam: &CameraModel,
    rgb: Option<&RgbRig>,
    opts: &SfmOptions,
    workspace: &Path,
    progress: &dyn Progress,
) -> Result<(Posing, SfmFigures), PosesError> {
    let partners = uses_partners(folder, rgb);
    let (camera, images_of) = match rgb {
        Some(r) if partners => (r.camera, "rgb_partners"),
        _ => (*thermal_cam, "thermal"),
    };
    stage_images(folder, partners, &workspace.join("images"))?;
    let n = folder.shots.len();
    progress.start(
        &format!("structure from motion (COLMAP) on {n} {images_of} images"),
        None,
    );
    let run_opts = PosesOptions {
        colmap: opts.colmap.clone(),
        matcher: opts.matcher,
        ..PosesOptions::default()
    };
    let mut times = StageTimes::default();
    let model = run_colmap(workspace, &camera, n, &run_opts, &mut times);
    progress.finish();
    let too_few = |registered: usize| PosesError::Folder {
        path: folder.dir.clone(),
        reason: format!(
            "structure from motion (COLMAP, on the {}) registered {registered} of {n} images (at least {MIN_REGISTERED} needed): the views may overlap too little or the scene be too bland for SIFT (a wall or the ground seen by translating cameras: the planar method, which needs GPS and gimbal angles; a board in view: --board); COLMAP's workspace and logs: {}",
            if partners {
                "RGB partners"
            } else {
                "thermal images"
            },
            workspace.display()
        ),
    };
    let model = match model {
        Err(PosesError::TooFewRegistered { registered, .. }) => return Err(too_few(registered)),
        other => other?,
    };
    // Registered shots: (index, world_from_cam of the images COLMAP ran on).
    let mut registered: Vec<(usize, Rigid3)> = model
        .images
        .iter()
        .filter_map(|im| {
            let i: usize = im.name.split('.').next()?.parse().ok()?;
            (i < n).then(|| (i, im.cam_from_world.inverse()))
        })
        .collect();
    registered.sort_by_key(|r| r.0);
    if registered.len() < MIN_REGISTERED {
        return Err(too_few(registered.len()));
    }
    let mut figures = SfmFigures {
        images_of: images_of.to_owned(),
        images: n,
        registered: registered.len(),
        colmap_features_s: times.colmap_features_s,
        colmap_matching_s: times.colmap_matching_s,
        colmap_mapper_s: times.colmap_mapper_s,
        ..SfmFigures::default()
    };

    // The world: east-north-up by GPS, scaled, or COLMAP's.
    let enu = enu_positions(folder);
    let (similarity, world) = world_of(
        &registered,
        enu.as_deref(),
        |i| folder.shots[i].name.clone(),
        opts,
    );
    figures.world = world.world;
    figures.gps_residual_m_median = world.gps_residual_m_median;
    figures.gps_disagrees = world.gps_disagrees;
    figures.metres_per_unit = similarity.map(|s| s.scale);
    let to_world = |p: &Rigid3| similarity.map_or(*p, |s| s.apply_pose(p));
    let registered: Vec<(usize, Rigid3)> =
        registered.iter().map(|(i, p)| (*i, to_world(p))).collect();

    // Thermal poses: the partners' composed with the extrinsic (the lever arm only in a
    // metric world), or COLMAP's own.
    let (posed, rgb_poses) = match rgb.and_then(|r| r.rgb_from_thermal).filter(|_| partners) {
        Some(e) => {
            let e = if similarity.is_some() {
                e
            } else {
                Rigid3::new(e.rotation, DVec3::ZERO)
            };
            (
                registered
                    .iter()
                    .map(|(i, world_from_rgb)| (*i, world_from_rgb.compose(&e)))
                    .collect(),
                registered.clone(),
            )
        }
        None => (registered.clone(), Vec::new()),
    };
    let registered_set: std::collections::BTreeSet<usize> = posed.iter().map(|p| p.0).collect();
    let left_out = (0..n)
        .filter(|i| !registered_set.contains(i))
        .map(|i| {
            (
                i,
                "structure from motion (COLMAP) did not register it".to_owned(),
            )
        })
        .collect();
    let points: Vec<ColmapPoint> = model
        .points
        .iter()
        .map(|p| {
            let x = Vector3::new(p.position_m[0], p.position_m[1], p.position_m[2]);
            let y = similarity.map_or(x, |s| s.apply(&x));
            ColmapPoint {
                position_m: [y.x, y.y, y.z],
                ..p.clone()
            }
        })
        .collect();
    figures.points = points.len();
    Ok((
        Posing {
            posed,
            left_out,
            points,
            rgb_poses,
        },
        figures,
    ))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn a_similarity_is_recovered_from_its_points() {
        let r = nalgebra::Rotation3::from_euler_angles(0.3, -0.2, 1.1).into_inner();
        let truth = Similarity {
            scale: 2.5,
            rotation: r,
            translation: Vector3::new(4.0, -1.0, 0.5),
        };
        let src = vec![
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.2),
            Vector3::new(0.0, 1.0, -0.1),
            Vector3::new(1.0, 1.0, 0.4),
            Vector3::new(0.5, 0.3, 1.0),
        ];
        let dst: Vec<_> = src.iter().map(|x| truth.apply(x)).collect();
        let got = fit_similarity(&src, &dst).expect("a fit of five points");
        assert!(
            (got.scale - truth.scale).abs() < 1e-9,
            "scale {} (truth {})",
            got.scale,
            truth.scale
        );
        assert!(
            (got.rotation - truth.rotation).norm() < 1e-9,
            "rotation off by {}",
            (got.rotation - truth.rotation).norm()
        );
        assert!((got.translation - truth.translation).norm() < 1e-9);
        // Collinear points leave a rotation free: no fit.
        let line: Vec<_> = (0..5).map(|k| Vector3::new(k as f64, 0.0, 0.0)).collect();
        assert!(
            fit_similarity(&line, &line).is_none(),
            "collinear points give no similarity"
        );
    }

    /// Ten cameras on a curve in COLMAP's units, their GPS fixes the same curve carried by a
    /// known similarity plus 0.2 m of noise, one fix 12 m off: the world is east-north-up, the
    /// wrong fix is named and does not pull the others (the fit is redone without it).
    #[test]
    fn gps_fixes_carry_the_model_and_a_wrong_one_is_named() {
        let truth = Similarity {
            scale: 0.15,
            rotation: nalgebra::Rotation3::from_euler_angles(0.05, -0.1, 2.0).into_inner(),
            translation: Vector3::new(10.0, -3.0, 20.0),
        };
        let registered: Vec<(usize, Rigid3)> = (0..10)
            .map(|k| {
                let t = k as f64;
                (
                    k,
                    Rigid3::new(
                        DQuat::IDENTITY,
                        DVec3::new(10.0 * t, 2.0 * t * t, 5.0 * (t * 0.7).sin()),
                    ),
                )
            })
            .collect();
        let noise = [0.1, -0.2, 0.15, 0.0, -0.1, 0.2, -0.15, 0.05, 0.1, -0.05];
        let mut enu: Vec<Option<Vector3<f64>>> = registered
            .iter()
            .map(|(k, p)| Some(truth.apply(&to_na(p.translation_m)) + Vector3::repeat(noise[*k])))
            .collect();
        enu[6] = enu[6].map(|e| e + Vector3::new(12.0, 0.0, 0.0));
        let opts = SfmOptions::default();
        let (s, w) = world_of(&registered, Some(&enu), |i| format!("shot{i}"), &opts);
        let s = s.expect("ten fixes give a similarity");
        assert_eq!(w.world, "east_north_up");
        assert_eq!(
            w.gps_disagrees
                .iter()
                .map(|d| d.0.as_str())
                .collect::<Vec<_>>(),
            ["shot6"],
            "the 12 m fix is named, no other: {:?}",
            w.gps_disagrees
        );
        assert!(
            (s.scale - truth.scale).abs() < 0.01 * truth.scale,
            "scale {} (truth {}): the wrong fix is left out of the fit",
            s.scale,
            truth.scale
        );
        let median = w.gps_residual_m_median.unwrap();
        assert!(median < 0.5, "median residual {median} m at 0.2 m of noise");
        // Without fixes: COLMAP's world, or scaled when told.
        let (none, w) = world_of(&registered, None, |i| format!("shot{i}"), &opts);
        assert!(none.is_none() && w.world == "colmap");
        let scaled = SfmOptions {
            metres_per_unit: Some(0.5),
            ..SfmOptions::default()
        };
        let (s, w) = world_of(&registered, None, |i| format!("shot{i}"), &scaled);
        assert_eq!(
            (s.map(|s| s.scale), w.world.as_str()),
            (Some(0.5), "scaled")
        );
    }

    #[test]
    fn a_mirror_is_not_a_rotation() {
        // dst is src mirrored: the best proper rotation, never a reflection.
        let src = vec![
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
            Vector3::new(0.0, 0.0, 1.0),
        ];
        let dst: Vec<_> = src.iter().map(|x| Vector3::new(x.x, x.y, -x.z)).collect();
        let got = fit_similarity(&src, &dst).unwrap();
        assert!(
            (got.rotation.determinant() - 1.0).abs() < 1e-9,
            "det {}",
            got.rotation.determinant()
        );
    }
}
