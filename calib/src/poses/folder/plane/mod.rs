//! The planar method: a wall (or the ground) photographed by cameras of known orientation that
//! mostly translate — a facade survey's lawn-mower pattern, a nadir flight. COLMAP finds no
//! initial pair there (a plane seen by translating cameras is two-view geometry's degenerate
//! case; scripts/real-data/README.md, "Why not COLMAP"), so this method uses what the scene is
//! (it began as the Python script `scripts/real-data/thermal_facade_dataset.py`, since removed:
//! git history has it):
//!
//! 1. **Priors** from each file's metadata: position in local east-north-up metres
//!    ([`super::geo`]), gimbal yaw/pitch/roll as the camera's rotation.
//! 2. **One orientation**: every image undistorted and turned by its gimbal rotation into a
//!    reference orientation (the median yaw and pitch, no roll), so that between neighbouring
//!    shots the wall moves by a translation ([`register::warp_homography`]); contrast
//!    equalised per tile for matching.
//! 3. **Pairs**: shots closer than `pair_m` are registered by normalised cross-correlation of
//!    patches, searched around the shift the GPS predicts at the wall's scale (pixels per
//!    metre of camera motion), which tells the repeated windows apart ([`register`]).
//! 4. **In-plane solve** ([`offsets`]): each shot's offset from the pair shifts with GPS as a
//!    weak prior; pairs that disagree (a mismatched window) are dropped. The scale (pixels of
//!    shift per metre of GPS baseline) is measured by what it explains: from a first estimate
//!    (neighbours in a row searched widely), a hill climb in steps of 8 % to the scale at which
//!    the most pairs register and agree. On thermal-facade (2026-11-29): 187 px/m first, then
//!    202 → 218 → 235 → 254 px/m with 172 → 258 agreeing pairs, fewer beyond (290: 237;
//!    330: 132). Regressing the pairs' shifts on their GPS baselines instead gives 166 px/m:
//!    the GPS noise in the baselines dilutes the slope.
//!    The best-correlated matches of each agreeing pair (at most `points_per_pair`, pairs of
//!    at least [`MIN_MATCHES_FOR_POINTS`] matches) become points.
//! 5. **Bundle adjustment** ([`bundle`]) of every camera's centre and rotation and every matched
//!    patch's point, the points held near one fitted plane (robustly: windows and eaves may leave
//!    it), with priors on GPS, barometric altitude and the gimbal angles.
//!
//! Measured on thermal-facade (2026-11-29, `s3tir-calib poses …/thermal-facade/images`): 90 of
//! 93 shots posed (the script: 89; the three others see no matched point, below), 260 of 784
//! candidate pairs agreeing, 1 491 points, reprojection error median 0.37 px, 90th percentile
//! 0.93 px (640×480); 47–100 s on 2 cores (idle or loaded), most of it registering every pair
//! once per scale tried (`s3tir-calib bench --folder`).
//!
//! Shots in no agreeing pair are left out and named, and so are shots that see fewer than
//! [`MIN_POINTS_TO_POSE`] bundle points: nothing but their priors would place them, and a wrong
//! GPS fix (its neighbours then do not register where it predicts) would be trusted
//! (calib/tests/folder_poses.rs moves one facade shot's fix 2 m). The reprojection error is the method's
//! figure of merit; the report also says how far the cameras moved from their GPS positions
//! and names the shots whose GPS disagrees with the images beyond 3 σ (their image-derived
//! position is the one used).

pub mod bundle;
pub mod offsets;
pub mod register;

use std::collections::BTreeMap;

use glam::{DMat3, DQuat, DVec2, DVec3};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use serde::Serialize;

use super::super::PosesError;
use super::super::stats::{median, percentile};
use super::geo::{LocalTangent, world_from_camera};
use super::scan::Folder;
use super::{Posing, Priors};
use crate::model::camera::CameraModel;
use crate::model::geometry::Rigid3;
use crate::progress::Progress;
use register::{Grey, RegisterParams};

/// The first guess of the distance to the wall (metres) when measuring the scale.
const FIRST_GUESS_M: f64 = 3.0;

/// A pair gives points to the bundle adjustment only with at least this many agreeing matches
/// (it still joins the in-plane solve): pairs that barely register are the wide, oblique ones
/// whose patches fit worst.
const MIN_MATCHES_FOR_POINTS: usize = 5;

/// The scale search's step (a factor) and its most steps in one direction.
const SCALE_STEP: f64 = 1.08;
const MAX_SCALE_STEPS: usize = 6;

/// Registered pairs: their agreeing patch matches, by shot indices.
type RegisteredPairs = BTreeMap<(usize, usize), Vec<register::PatchMatch>>;

/// Options of the planar method.
#[derive(Debug, Clone, Serialize)]
pub struct PlaneOptions {
    /// Register shots whose GPS positions are this close (metres).
    pub pair_m: f64,
    /// Search radius around the GPS-predicted shift (pixels).
    pub search_px: f64,
    /// The wall's shift in pixels per metre of camera motion (`None`: measured).
    pub px_per_m: Option<f64>,
    /// σ of the points' distance to the plane (metres).
    pub plane_sigma_m: f64,
    /// σ of the GPS positions (metres), the altitude (metres) and the gimbal angles (degrees).
    pub gps_sigma_m: f64,
    pub altitude_sigma_m: f64,
    pub gimbal_sigma_deg: f64,
    /// Bundle-adjustment iterations.
    pub iterations: usize,
    /// Matches per pair used as points (evenly chosen).
    pub points_per_pair: usize,
}

impl Default for PlaneOptions {
    fn default() -> Self {
        Self {
            pair_m: 3.2,
            search_px: 170.0,
            px_per_m: None,
            plane_sigma_m: 0.05,
            gps_sigma_m: 1.5,
            altitude_sigma_m: 0.15,
            gimbal_sigma_deg: 1.5,
            iterations: 30,
            points_per_pair: 8,
        }
    }
}

/// What the planar method measured (in `poses.json`).
#[derive(Debug, Clone, Default, Serialize)]
pub struct PlaneFigures {
    pub candidate_pairs: usize,
    pub pairs_registered: usize,
    pub pairs_agreeing: usize,
    /// Scale estimates in order (pixels per metre), the last used.
    pub scale_px_per_m: Vec<f64>,
    pub points: usize,
    pub observations: usize,
    pub reprojection_px_median: f64,
    pub reprojection_px_p90: f64,
    pub reprojection_px_max: f64,
    pub plane_distance_m: f64,
    pub plane_tilt_deg: f64,
    pub moved_from_gps_m_median: f64,
    pub turned_from_gimbal_deg_median: f64,
    /// Shots whose GPS position disagrees with the images by more than 3 σ (name, metres).
    pub gps_disagrees: Vec<(String, f64)>,
    pub bundle_iterations: usize,
    /// Seconds undistorting and turning the images into one orientation.
    pub turn_s: f64,
    /// Seconds registering pairs and solving the offsets, every scale tried.
    pub register_s: f64,
    pub bundle_s: f64,
}

fn from_na(m: &Matrix3<f64>) -> DMat3 {
    DMat3::from_cols_slice(m.as_slice())
}

/// Undistorts `grey` (the camera's pixels) into the camera's own pinhole image (same K).
fn undistort(grey: &[f32], cam: &CameraModel) -> Grey {
    let (w, h) = (cam.width_px as usize, cam.height_px as usize);
    let i = cam.intrinsics;
    let src = Grey {
        width: w,
        height: h,
        data: grey.to_vec(),
    };
    let d = cam.distortion;
    if d == Default::default() {
        return src;
    }
    let data = (0..w * h)
        .into_par_iter()
        .map(|k| {
            let (x, y) = ((k % w) as f64, (k / w) as f64);
            let n = DVec2::new((x - i.cx) / i.fx, (y - i.cy) / i.fy);
            let p = d.distort(n);
            src.sample(p.x * i.fx + i.cx, p.y * i.fy + i.cy)
        })
        .collect();
    Grey {
        width: w,
        height: h,
        data,
    }
}

/// The per-shot priors the planar method needs, or why it cannot run.
pub fn priors(folder: &Folder) -> Result<Priors, String> {
    let origin = folder
        .shots
        .iter()
        .find_map(|s| s.meta.position())
        .ok_or("no image carries a GPS position")?;
    let tangent = LocalTangent::at(origin);
    let up0 = folder.shots.iter().find_map(|s| s.meta.relative_altitude_m);
    let mut enu = Vec::new();
    let mut rot = Vec::new();
    for s in &folder.shots {
        let g = s
            .meta
            .gimbal
            .ok_or_else(|| format!("{} has no gimbal angles", s.name))?;
        rot.push(world_from_camera(&g));
        let p = s.meta.position();
        let en = p.map(|p| tangent.east_north(&p));
        let up = match (s.meta.relative_altitude_m, up0) {
            (Some(a), Some(_)) => Some(a),
            _ => p
                .and_then(|p| p.altitude_m)
                .zip(origin.altitude_m)
                .map(|(a, a0)| a - a0),
        };
        enu.push((en, up));
    }
    Ok(Priors {
        tangent,
        east_north: enu.iter().map(|e| e.0).collect(),
        up: enu.iter().map(|e| e.1).collect(),
        world_from_gimbal: rot,
    })
}

/// Poses the folder's shots by the planar method (module docs).
pub fn pose(
    folder: &Folder,
    cam: &CameraModel,
    pri: &Priors,
    opts: &PlaneOptions,
    progress: &dyn Progress,
) -> Result<(Posing, PlaneFigures), PosesError> {
    let n = folder.shots.len();
    let fail = |reason: String| PosesError::Folder {
        path: folder.dir.clone(),
        reason,
    };
    let (w, h) = (cam.width_px as usize, cam.height_px as usize);
    let i = cam.intrinsics;
    let f = 0.5 * (i.fx + i.fy);
    let k = Matrix3::new(i.fx, 0.0, i.cx, 0.0, i.fy, i.cy, 0.0, 0.0, 1.0);
    let k_inv = k
        .try_inverse()
        .ok_or_else(|| fail("the camera matrix is singular".into()))?;
    let mut figures = PlaneFigures::default();
    let t0 = std::time::Instant::now();

    // 2. One orientation.
    let yaw: Vec<f64> = folder
        .shots
        .iter()
        .filter_map(|s| s.meta.gimbal.map(|g| g.yaw_deg))
        .collect();
    let pitch: Vec<f64> = folder
        .shots
        .iter()
        .filter_map(|s| s.meta.gimbal.map(|g| g.pitch_deg))
        .collect();
    let reference = world_from_camera(&s3tir_capture::image_meta::Attitude {
        yaw_deg: circular_median_deg(&yaw),
        pitch_deg: median(&pitch),
        roll_deg: 0.0,
    });
    let (right, down, fwd) = (
        reference.column(0).into_owned(),
        reference.column(1).into_owned(),
        reference.column(2).into_owned(),
    );
    let grey = folder.grey_for_matching();
    progress.start("turning images into one orientation", Some(n as u64));
    let (turned, to_ref): (Vec<Grey>, Vec<Matrix3<f64>>) = grey
        .par_iter()
        .zip(&pri.world_from_gimbal)
        .map(|(g, r)| {
            let u = undistort(g, cam);
            let hmat = k * reference.transpose() * r * k_inv;
            let t = register::clahe(&register::warp_homography(&u, &hmat, w, h), 2.0, [8, 8]);
            progress.advance(1);
            (t, hmat)
        })
        .unzip();
    progress.finish();
    figures.turn_s = t0.elapsed().as_secs_f64();

    // In-plane GPS (metres along the reference's right and down axes).
    let enu: Vec<Option<Vector3<f64>>> = (0..n)
        .map(|c| pri.east_north[c].map(|en| Vector3::new(en[0], en[1], pri.up[c].unwrap_or(0.0))))
        .collect();
    let g: Vec<Option<[f64; 2]>> = enu
        .iter()
        .map(|e| e.map(|e| [e.dot(&right), e.dot(&down)]))
        .collect();
    let params = RegisterParams {
        search_px: opts.search_px,
        ..RegisterParams::default()
    };
    let candidates: Vec<(usize, usize)> = (0..n)
        .flat_map(|a| (a + 1..n).map(move |b| (a, b)))
        .filter(|&(a, b)| match (enu[a], enu[b]) {
            (Some(p), Some(q)) => (q - p).norm() <= opts.pair_m,
            _ => false,
        })
        .collect();
    figures.candidate_pairs = candidates.len();
    if candidates.is_empty() {
        return Err(fail(format!(
            "no two shots within {} m of each other by their GPS positions (--pair-m)",
            opts.pair_m
        )));
    }
    let predicted = |a: usize, b: usize, scale: f64| -> [f64; 2] {
        match (g[a], g[b]) {
            (Some(p), Some(q)) => [-scale * (q[0] - p[0]), -scale * (q[1] - p[1])],
            _ => [0.0, 0.0],
        }
    };

    // 3–4. The scale: given, or from neighbours in a row searched widely, then refined.
    let mut scale = match opts.px_per_m {
        Some(s) => s,
        None => {
            // First guess of the distance: the altitude for a nadir flight, else a facade
            // survey's few metres; the wide search tolerates being wrong by ~2×.
            let guess_m = if median(&pitch) < -60.0 {
                median(&pri.up.iter().flatten().copied().collect::<Vec<_>>()).max(FIRST_GUESS_M)
            } else {
                FIRST_GUESS_M
            };
            let wide = RegisterParams {
                search_px: 2.0 * opts.search_px,
                ..params
            };
            let first: Vec<f64> = (0..n.saturating_sub(1))
                .into_par_iter()
                .filter_map(|a| {
                    let b = a + 1;
                    let (p, q) = (g[a]?, g[b]?);
                    let dz = (pri.up[a]? - pri.up[b]?).abs();
                    let d = (q[0] - p[0]).hypot(q[1] - p[1]);
                    if dz > 0.05 || !(0.5..2.0).contains(&d) {
                        return None;
                    }
                    let m = register::register_pair(
                        &turned[a],
                        &turned[b],
                        predicted(a, b, f / guess_m),
                        &wide,
                    )?;
                    let t = mean_shift(&m);
                    Some(t[0].hypot(t[1]) / d)
                })
                .collect();
            if first.len() < 5 {
                return Err(fail(format!(
                    "only {} neighbouring shots in a row registered: cannot measure the wall's scale (pixels per metre of camera motion); pass --px-per-m (focal length in pixels ÷ the distance to the wall in metres)",
                    first.len()
                )));
            }
            median(&first)
        }
    };
    figures.scale_px_per_m.push(scale);
    let register_all = |scale: f64| -> RegisteredPairs {
        progress.start("registering pairs", Some(candidates.len() as u64));
        let found = candidates
            .par_iter()
            .filter_map(|&(a, b)| {
                let m = register::register_pair(
                    &turned[a],
                    &turned[b],
                    predicted(a, b, scale),
                    &params,
                );
                progress.advance(1);
                Some(((a, b), m?))
            })
            .collect();
        progress.finish();
        found
    };
    let sigma_px = |scale: f64| opts.gps_sigma_m.min(0.5) * scale;
    // Registered pairs at a scale and the in-plane solve over them.
    let attempt = |scale: f64| -> Result<(RegisteredPairs, offsets::Offsets), PosesError> {
        let pairs = register_all(scale);
        let shifts: offsets::PairShifts = pairs.iter().map(|(k, m)| (*k, mean_shift(m))).collect();
        let gps_px: Vec<Option<[f64; 2]>> = g
            .iter()
            .map(|p| p.map(|p| [scale * p[0], scale * p[1]]))
            .collect();
        let solved = offsets::solve(&shifts, &gps_px, sigma_px(scale)).ok_or_else(|| {
            fail("the in-plane solve is singular (shots without a GPS position and without a registered neighbour)".into())
        })?;
        Ok((pairs, solved))
    };
    // The scale is measured by what it explains: the one at which the most pairs register and
    // agree (a hill climb in steps of SCALE_STEP from the first estimate). Regressing the
    // shifts on the GPS baselines instead is diluted by the GPS noise (166 px/m on
    // thermal-facade, where 215 registers the most pairs; see the module docs).
    let mut best = attempt(scale)?;
    if opts.px_per_m.is_none() {
        for dir in [SCALE_STEP, 1.0 / SCALE_STEP] {
            let mut improved_here = false;
            for _ in 0..MAX_SCALE_STEPS {
                let s = scale * dir;
                let next = attempt(s)?;
                figures.scale_px_per_m.push(s);
                tracing::info!(
                    scale = s,
                    agreeing = next.1.agreeing.len(),
                    "planar method: scale tried"
                );
                if next.1.agreeing.len() > best.1.agreeing.len() {
                    best = next;
                    scale = s;
                    improved_here = true;
                } else {
                    break;
                }
            }
            if improved_here {
                break;
            }
        }
        figures.scale_px_per_m.push(scale);
    }
    let (pairs, solved) = best;
    figures.pairs_registered = pairs.len();
    figures.pairs_agreeing = solved.agreeing.len();
    figures.register_s = t0.elapsed().as_secs_f64() - figures.turn_s;

    // Points: matches of agreeing pairs, back in each camera's own (undistorted) pixels, on the
    // plane at the distance the scale says.
    let mut seen = vec![false; n];
    for &(a, b) in &solved.agreeing {
        seen[a] = true;
        seen[b] = true;
    }
    let positioned: Vec<usize> = (0..n).filter(|&c| seen[c]).collect();
    if positioned.len() < 3 {
        return Err(fail(format!(
            "only {} shots registered with a neighbour (at least 3 needed): the images may not overlap, or the wall's scale is off (--px-per-m)",
            positioned.len()
        )));
    }
    let origin = {
        let ps: Vec<Vector3<f64>> = positioned.iter().filter_map(|&c| enu[c]).collect();
        ps.iter().fold(Vector3::zeros(), |a, p| a + p) / ps.len().max(1) as f64
    };
    let mean_off = {
        let s = positioned.iter().fold([0.0, 0.0], |a, &c| {
            [a[0] + solved.offsets[c][0], a[1] + solved.offsets[c][1]]
        });
        [
            s[0] / positioned.len() as f64,
            s[1] / positioned.len() as f64,
        ]
    };
    let centres: Vec<Vector3<f64>> = (0..n)
        .map(|c| {
            origin
                + right * (solved.offsets[c][0] - mean_off[0]) / scale
                + down * (solved.offsets[c][1] - mean_off[1]) / scale
        })
        .collect();
    let d0 = fwd.dot(&origin) + f / scale;
    let to_cam = |c: usize, p: [f64; 2]| -> Option<[f64; 2]> {
        let inv = to_ref[c].try_inverse()?;
        let q = inv * Vector3::new(p[0], p[1], 1.0);
        (q.z.abs() > 1e-12).then(|| [q.x / q.z, q.y / q.z])
    };
    let mut obs = Vec::new();
    let mut points = Vec::new();
    for &(a, b) in &solved.agreeing {
        let m = &pairs[&(a, b)];
        if m.len() < MIN_MATCHES_FOR_POINTS {
            continue;
        }
        let take = opts.points_per_pair.max(1);
        // The best-localised matches: the highest correlation peaks.
        let mut chosen: Vec<&register::PatchMatch> = m.iter().collect();
        chosen.sort_by(|x, y| y.score.total_cmp(&x.score));
        chosen.truncate(take);
        for pm in chosen {
            let (Some(ua), Some(ub)) = (to_cam(a, pm.a), to_cam(b, pm.b)) else {
                continue;
            };
            let ray = pri.world_from_gimbal[a] * k_inv * Vector3::new(ua[0], ua[1], 1.0);
            let denom = fwd.dot(&ray);
            if denom.abs() < 1e-9 {
                continue;
            }
            let x = centres[a] + ray * ((d0 - fwd.dot(&centres[a])) / denom);
            let id = points.len();
            points.push(x);
            obs.push(bundle::Observation {
                camera: a,
                point: id,
                uv: ua,
            });
            obs.push(bundle::Observation {
                camera: b,
                point: id,
                uv: ub,
            });
        }
    }

    // A camera is posed by the images only where it sees matched points: one whose pairs gave
    // none would sit at its GPS position and gimbal angles alone (a wrong GPS fix trusted).
    let mut observed = vec![0usize; n];
    for o in &obs {
        observed[o.camera] += 1;
    }

    // 5. Bundle adjustment.
    progress.start("bundle adjustment", None);
    let t1 = std::time::Instant::now();
    let problem = bundle::BundleProblem {
        focal_px: f,
        cx: i.cx,
        cy: i.cy,
        rotations: pri.world_from_gimbal.clone(),
        centres: centres.clone(),
        gps_en: (0..n)
            .map(|c| pri.east_north[c].filter(|_| seen[c]))
            .collect(),
        altitude: (0..n).map(|c| pri.up[c].filter(|_| seen[c])).collect(),
        points,
        observations: obs,
        plane: bundle::PlaneInit {
            normal: fwd,
            right,
            down,
            distance: d0,
        },
        sigmas: bundle::Sigmas {
            gps_m: opts.gps_sigma_m,
            alt_m: opts.altitude_sigma_m,
            rot_rad: opts.gimbal_sigma_deg.to_radians(),
            plane_m: opts.plane_sigma_m,
        },
        iterations: opts.iterations,
    };
    let sol = bundle::solve(&problem).map_err(|e| PosesError::Folder {
        path: folder.dir.clone(),
        reason: format!("bundle adjustment: {e}"),
    })?;
    progress.finish();
    figures.bundle_s = t1.elapsed().as_secs_f64();
    figures.bundle_iterations = sol.iterations;
    figures.points = problem.points.len();
    figures.observations = problem.observations.len();
    figures.reprojection_px_median = median(&sol.reprojection_px);
    figures.reprojection_px_p90 = percentile(&sol.reprojection_px, 0.9);
    figures.reprojection_px_max = sol.reprojection_px.iter().copied().fold(0.0, f64::max);
    let dist: Vec<f64> = positioned
        .iter()
        .map(|&c| sol.distance - sol.normal.dot(&sol.centres[c]))
        .collect();
    figures.plane_distance_m = median(&dist);
    figures.plane_tilt_deg = sol.normal.dot(&fwd).clamp(-1.0, 1.0).acos().to_degrees();
    let moved: Vec<(usize, f64)> = positioned
        .iter()
        .filter_map(|&c| {
            let en = pri.east_north[c]?;
            Some((
                c,
                (sol.centres[c].x - en[0]).hypot(sol.centres[c].y - en[1]),
            ))
        })
        .collect();
    figures.moved_from_gps_m_median = median(&moved.iter().map(|m| m.1).collect::<Vec<_>>());
    figures.gps_disagrees = moved
        .iter()
        .filter(|m| m.1 > 3.0 * opts.gps_sigma_m)
        .map(|&(c, d)| (folder.shots[c].name.clone(), d))
        .collect();
    let turned_deg: Vec<f64> = positioned
        .iter()
        .map(|&c| {
            let d = pri.world_from_gimbal[c].transpose() * sol.rotations[c];
            ((d.trace() - 1.0) / 2.0)
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees()
        })
        .collect();
    figures.turned_from_gimbal_deg_median = median(&turned_deg);

    // Poses and seed points: the plane seen through each view.
    let mut posed = Vec::new();
    let mut left_out = Vec::new();
    for c in 0..n {
        if !seen[c] {
            left_out.push((c, "no registered neighbour".to_owned()));
            continue;
        }
        if observed[c] < MIN_POINTS_TO_POSE {
            left_out.push((
                c,
                format!(
                    "{} matched point(s), fewer than {MIN_POINTS_TO_POSE}: the images do not pose it (its GPS fix and gimbal angles alone would)",
                    observed[c]
                ),
            ));
            continue;
        }
        let r = from_na(&sol.rotations[c]);
        let centre = DVec3::new(sol.centres[c].x, sol.centres[c].y, sol.centres[c].z);
        posed.push((c, Rigid3::new(DQuat::from_mat3(&r).normalize(), centre)));
    }
    let normal = DVec3::new(sol.normal.x, sol.normal.y, sol.normal.z);
    let points = super::plane_seeds(folder, cam, &posed, normal, sol.distance);
    Ok((Posing::thermal(posed, left_out, points), figures))
}

/// A camera seeing fewer bundle points than this is left out: its pose would be its priors'.
pub const MIN_POINTS_TO_POSE: usize = 4;

/// The mean shift (b − a) of a pair's matches.
fn mean_shift(m: &[register::PatchMatch]) -> [f64; 2] {
    let n = m.len().max(1) as f64;
    let s = m.iter().fold([0.0, 0.0], |a, p| {
        [a[0] + p.b[0] - p.a[0], a[1] + p.b[1] - p.a[1]]
    });
    [s[0] / n, s[1] / n]
}

/// The median of angles (degrees) on the circle: the sample angle minimising the summed
/// angular distance.
fn circular_median_deg(a: &[f64]) -> f64 {
    let dist = |x: f64, y: f64| {
        let d = (x - y).rem_euclid(360.0);
        d.min(360.0 - d)
    };
    a.iter()
        .copied()
        .min_by(|&x, &y| {
            let sx: f64 = a.iter().map(|&z| dist(x, z)).sum();
            let sy: f64 = a.iter().map(|&z| dist(y, z)).sum();
            sx.total_cmp(&sy)
        })
        .unwrap_or(0.0)
}
