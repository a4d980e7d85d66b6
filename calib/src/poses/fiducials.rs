//! AprilTags in view (`--tags FILE`): poses without structure from motion, and metric scale
//! for COLMAP's world.
//!
//! **The map file** (TOML, what `s3tir-firmware-sim` writes as `tags.toml` beside a walk's
//! truth):
//! ```toml
//! family = "tag36h11"
//! size_m = 0.4            # the black border's outer side, every tag
//! [[tag]]                 # optional: where each tag is (a surveyed or taped-up layout)
//! id = 0
//! corners_m = [[x, y, z], …]   # 4 corners, world metres: bottom-left, bottom-right,
//!                              # top-right, top-left of the tag as printed
//! ```
//! The size alone gives metric scale; the corners also give poses.
//!
//! **Thermal fiducials.** Printed tags are paper at the wall's temperature and emissivity: a
//! thermal camera does not see them. Tags a thermal camera sees are made like the emissivity
//! board: polished aluminium (low emissivity, reflecting the room) cut over a heated matte black
//! panel, which appear inverted in thermal (the black cells are the warm ones). In a session
//! without RGB the keyframes are thermal and the detector searches each one and its negative,
//! so either make works with the same map (`s3tir-firmware-sim run --walk-tags heated`
//! simulates them).
//!
//! **Fast path** ([`pnp`]): with a layout, each keyframe that sees at least [`MIN_PNP_TAGS`]
//! mapped tags gets its pose by perspective-n-point on their corners (a planar homography of
//! one tag as the start, Gauss–Newton on every corner, the calibrated distortion removed
//! first), accepted below [`MAX_PNP_RMS_PX`]. When enough keyframes are posed this way
//! (`min_registered`, as for COLMAP) the stage skips COLMAP entirely, and the world is the
//! map's, in metres. Two tags are required because a single small tag's pose flips between two
//! mirror solutions under a fraction of a pixel of noise. Tags in more than one plane matter:
//! with one row of tags on one wall, 4.7 m away, the pitch trades against the height and the
//! pose moves about 2° per pixel of corner noise; add tags on the floor in the same view and
//! it moves about 0.005° (the unit tests measure both, at ±0.3 px).
//!
//! **Scale for COLMAP** ([`scale_from_tags`]): every tag corner seen in at least three
//! registered keyframes is triangulated in COLMAP's world (the point closest to all its rays,
//! kept when the rays span at least [`MIN_TRIANGULATION_DEG`] and it reprojects within
//! [`MAX_TRIANGULATION_PX`]). With a layout, every distance between corners of two different
//! mapped tags (at least two tag sides long) gives one metres-per-unit ratio; with the size
//! only, each tag's four sides and two diagonals do. The scale is their median; the report
//! gives the count and the spread (median absolute deviation over the median). Tag sides are
//! short: a corner bias of a fifth of a pixel (blur seen through the camera's gamma shrinks a
//! dark square) moves a 40 px side by 1 %. On the simulated 16 s walk, against the scale the
//! truth alignment measures: sides and diagonals +0.50 %, distances between tags −0.28 %
//! (spread 0.16 % over 1 702 lengths).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec2, DVec3};
use nalgebra::{Matrix3, Matrix6, SMatrix, SVector, Vector6};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::PosesError;
use super::frames::{FrameInfo, Stream};
use crate::camera::CameraModel;
use crate::geometry::Rigid3;
use crate::tags::{TagConfig, TagDetection, TagDetector, luma_bt601};

/// A keyframe is posed by PnP only with at least this many mapped tags in view (module docs).
pub const MIN_PNP_TAGS: usize = 2;
/// A PnP pose is kept when its corners reproject within this RMS, pixels.
pub const MAX_PNP_RMS_PX: f64 = 2.0;
/// A triangulated tag corner needs rays spanning at least this angle, degrees.
pub const MIN_TRIANGULATION_DEG: f64 = 2.0;
/// … and must reproject within this many pixels in every view it was seen in.
pub const MAX_TRIANGULATION_PX: f64 = 3.0;

/// The tag map of `--tags FILE` (module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct TagMap {
    pub path: PathBuf,
    /// Black-border side of every tag, metres.
    pub size_m: f64,
    /// World corners of the mapped tags (may be empty: size only).
    pub corners: BTreeMap<u32, [DVec3; 4]>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MapFile {
    family: String,
    size_m: f64,
    #[serde(default)]
    tag: Vec<MapTag>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MapTag {
    id: u32,
    corners_m: [[f64; 3]; 4],
}

impl TagMap {
    /// Reads and checks a map file: the family must be tag36h11, the size positive, ids unique
    /// and each tag's corners a square of the stated size (within 2 %).
    pub fn read(path: &Path) -> Result<Self, PosesError> {
        let err = |reason: String| PosesError::Tags {
            path: path.to_path_buf(),
            reason,
        };
        let text = std::fs::read_to_string(path).map_err(|e| err(e.to_string()))?;
        let file: MapFile = toml::from_str(&text).map_err(|e| err(e.to_string()))?;
        if file.family != "tag36h11" {
            return Err(err(format!(
                "family \"{}\" is not supported (only tag36h11 is detected)",
                file.family
            )));
        }
        if !(file.size_m.is_finite() && file.size_m > 0.0) {
            return Err(err(format!(
                "size_m = {} must be the tags' black-border side in metres (> 0)",
                file.size_m
            )));
        }
        let mut corners = BTreeMap::new();
        for t in &file.tag {
            let c = t.corners_m.map(DVec3::from_array);
            if !c.iter().all(|p| p.is_finite()) {
                return Err(err(format!("tag {}: corners must be finite", t.id)));
            }
            let sides = [0, 1, 2, 3].map(|i| (c[(i + 1) % 4] - c[i]).length());
            let diagonals = [(c[2] - c[0]).length(), (c[3] - c[1]).length()];
            let off = sides
                .iter()
                .map(|s| s / file.size_m)
                .chain(diagonals.iter().map(|d| d / (file.size_m * 2f64.sqrt())))
                .map(|r| (r - 1.0).abs())
                .fold(0.0, f64::max);
            if off > 0.02 {
                return Err(err(format!(
                    "tag {}: its corners are not a {} m square (sides {:.3?} m, diagonals {:.3?} m): check size_m and the corner order (bottom-left, bottom-right, top-right, top-left as printed)",
                    t.id, file.size_m, sides, diagonals
                )));
            }
            if corners.insert(t.id, c).is_some() {
                return Err(err(format!("tag {} is listed twice", t.id)));
            }
        }
        Ok(Self {
            path: path.to_path_buf(),
            size_m: file.size_m,
            corners,
        })
    }

    /// Whether the map places tags in the world (the PnP fast path).
    pub fn has_layout(&self) -> bool {
        !self.corners.is_empty()
    }
}

/// The tags decoded in one keyframe.
#[derive(Debug, Clone, PartialEq)]
pub struct SeenTags {
    pub sequence: u32,
    pub monotonic_ns: u64,
    pub tags: Vec<TagDetection>,
}

/// Detects tag36h11 in every keyframe image the stage wrote (`dir`, [`Stream::file_name`]),
/// in parallel; keeps `ids` only when given. A keyframe image that does not read is an error
/// naming it.
pub fn detect_in_keyframes(
    dir: &Path,
    stream: Stream,
    keyframes: &[FrameInfo],
    ids: Option<BTreeSet<u32>>,
) -> Result<Vec<SeenTags>, PosesError> {
    let config = TagConfig {
        allowed_ids: ids,
        // Hamming ≤ 1: far, small tags among texture; two corrected bits admit false decodes.
        max_bits_corrected: 1,
        // Edges snapped to the image gradient: on the simulated walk's blurred JPEG keyframes
        // the worst PnP pose went from 2.6° to 0.9° off (median 0.18° → 0.13°).
        refine_edges: true,
        ..TagConfig::default()
    };
    keyframes
        .par_iter()
        .map_init(
            || TagDetector::new(config.clone()),
            |detector, k| {
                let path = dir.join(stream.file_name(k.sequence));
                let err = |reason: String| PosesError::Tags {
                    path: path.clone(),
                    reason,
                };
                let detector = detector.as_mut().map_err(|e| err(e.to_string()))?;
                let img = image::open(&path).map_err(|e| err(e.to_string()))?;
                let grey = match img {
                    image::DynamicImage::ImageLuma8(g) => g,
                    other => luma_bt601(&other.to_rgb8()),
                };
                // A thermal fiducial may be seen inverted (hot ink over cold foil, or the other
                // way round: the module docs): the negative is searched too.
                let tags = detect_upscaled(detector, grey, &path, stream == Stream::Thermal)
                    .map_err(|e| err(e.to_string()))?;
                Ok(SeenTags {
                    sequence: k.sequence,
                    monotonic_ns: k.monotonic_ns,
                    tags,
                })
            },
        )
        .collect()
}

/// Factor a keyframe is enlarged by before tag detection: small images (a 160×120 thermal
/// core's) are enlarged to a long side of about 640 px (Lanczos), larger ones not at all (an
/// RGB keyframe of 640 px keeps its size). The C detector fits each quad's edges to a few
/// pixels at least: a tag 12–30 px wide in a Lepton's frame is often missed at its own size,
/// and its corners are coarse. On the simulated thermal-only walk with heated tags (16 s, 27
/// thermal keyframes; posed / median rotation error against the truth): 13 posed (too few) at
/// 1×; 18 / 0.47° at 3× Catmull–Rom; 19 / 0.26° at 4× Catmull–Rom; 24 / 0.21° at 4× Lanczos.
pub fn tag_upscale(width: u32, height: u32) -> u32 {
    let long = width.max(height).max(1);
    ((640 + long / 2) / long).clamp(1, 4)
}

/// Tags in `grey` enlarged by [`tag_upscale`] (Lanczos, once), and with `negative_too` in
/// its negative as well (a tag found in both kept once, as found first), their coordinates
/// mapped back to the image's own pixels (pixel-centre origin: enlarged pixel `x` is
/// `(x + 0.5) / scale − 0.5`).
pub fn detect_upscaled(
    detector: &mut TagDetector,
    grey: image::GrayImage,
    path: &Path,
    negative_too: bool,
) -> Result<Vec<TagDetection>, crate::tags::TagError> {
    let scale = tag_upscale(grey.width(), grey.height());
    let mut big = if scale <= 1 {
        grey
    } else {
        image::imageops::resize(
            &grey,
            grey.width() * scale,
            grey.height() * scale,
            image::imageops::FilterType::Lanczos3,
        )
    };
    let mut tags = detector.detect(&big, path)?;
    if negative_too {
        image::imageops::invert(&mut big);
        for t in detector.detect(&big, path)? {
            if tags.iter().all(|d| d.id != t.id) {
                tags.push(t);
            }
        }
    }
    if scale > 1 {
        let s = f64::from(scale);
        let back = |p: [f64; 2]| [(p[0] + 0.5) / s - 0.5, (p[1] + 0.5) / s - 0.5];
        for t in &mut tags {
            t.centre_px = back(t.centre_px);
            t.corners_px = t.corners_px.map(back);
        }
    }
    Ok(tags)
}

/// A keyframe posed from the tags in view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TagPose {
    pub world_from_cam: Rigid3,
    /// Corner reprojection RMS, pixels.
    pub rms_px: f64,
    /// Mapped tags used.
    pub tags: usize,
}

/// A world point and its undistorted normalised image point.
type Correspondence = (DVec3, DVec2);

/// Undistorted normalised coordinates of a detected corner.
fn normalised(camera: &CameraModel, px: [f64; 2]) -> Option<DVec2> {
    camera
        .unproject(DVec2::new(px[0], px[1]))
        .map(|r| DVec2::new(r.x, r.y))
}

/// Pose of a keyframe from the mapped tags it sees (module docs); `None` with fewer than
/// [`MIN_PNP_TAGS`] mapped tags or a reprojection RMS above [`MAX_PNP_RMS_PX`].
pub fn pnp(map: &TagMap, camera: &CameraModel, seen: &[TagDetection]) -> Option<TagPose> {
    let mut tags: Vec<(u32, [Correspondence; 4])> = Vec::new();
    for d in seen {
        let Some(world) = map.corners.get(&d.id) else {
            continue;
        };
        let mut pairs = [(DVec3::ZERO, DVec2::ZERO); 4];
        let mut ok = true;
        for (k, pair) in pairs.iter_mut().enumerate() {
            match normalised(camera, d.corners_px[k]) {
                Some(x) => *pair = (world[k], x),
                None => ok = false,
            }
        }
        if ok && !tags.iter().any(|t| t.0 == d.id) {
            tags.push((d.id, pairs));
        }
    }
    if tags.len() < MIN_PNP_TAGS {
        return None;
    }
    let all: Vec<Correspondence> = tags.iter().flat_map(|t| t.1).collect();
    let focal = 0.5 * (camera.intrinsics.fx + camera.intrinsics.fy);
    // Start from each tag's own planar pose; keep the refinement that fits every corner best.
    let best = tags
        .iter()
        .filter_map(|(_, corners)| planar_pose(corners))
        .map(|start| refine(start, &all))
        .map(|pose| (rms(&pose, &all) * focal, pose))
        .filter(|(r, _)| r.is_finite())
        .min_by(|a, b| a.0.total_cmp(&b.0))?;
    (best.0 <= MAX_PNP_RMS_PX).then(|| TagPose {
        world_from_cam: best.1.inverse(),
        rms_px: best.0,
        tags: tags.len(),
    })
}

/// A PnP pose is dropped when it is this far (degrees or metres) from the interpolation of its
/// posed neighbours in time (each within [`NEIGHBOUR_S`]).
pub const OUTLIER_DEG: f64 = 1.0;
pub const OUTLIER_M: f64 = 0.05;
pub const NEIGHBOUR_S: f64 = 0.7;

/// Drops PnP poses that disagree with their neighbours in time (a hand does not jump a degree
/// in a fraction of a second; a tag decoded at a wrong corner does), worst first
/// ([`super::interp::drop_worst_jumps`]). Returns the capture times dropped.
pub fn drop_jumps(posed: &mut BTreeMap<u64, TagPose>) -> Vec<u64> {
    let mut keys: Vec<(u64, Rigid3)> = posed.iter().map(|(t, p)| (*t, p.world_from_cam)).collect();
    let dropped = super::interp::drop_worst_jumps(&mut keys, NEIGHBOUR_S, |j| {
        (j.turn_deg / OUTLIER_DEG).max(j.moved / OUTLIER_M)
    });
    for t in &dropped {
        posed.remove(t);
    }
    dropped
}

/// Reprojection RMS of `cam_from_world` over `pairs`, normalised units (∞ behind the camera).
fn rms(cam_from_world: &Rigid3, pairs: &[Correspondence]) -> f64 {
    let mut sum = 0.0;
    for (x, obs) in pairs {
        let c = cam_from_world.transform_point(*x);
        if c.z <= 1e-9 {
            return f64::INFINITY;
        }
        sum += (DVec2::new(c.x / c.z, c.y / c.z) - *obs).length_squared();
    }
    (sum / pairs.len() as f64).sqrt()
}

/// `cam_from_world` of one square tag from its four corners by the plane-to-image homography.
fn planar_pose(corners: &[Correspondence; 4]) -> Option<Rigid3> {
    let [bl, br, _, tl] = corners.map(|c| c.0);
    let e1 = (br - bl).normalize();
    let e2 = (tl - bl - e1 * (tl - bl).dot(e1)).normalize();
    let n = e1.cross(e2);
    if !(e1.is_finite() && e2.is_finite()) {
        return None;
    }
    let world_from_plane = Rigid3::new(DQuat::from_mat3(&DMat3::from_cols(e1, e2, n)), bl);
    let plane_from_world = world_from_plane.inverse();
    // DLT with h33 = 1: 8 equations in 8 unknowns from the 4 corners.
    let mut a = SMatrix::<f64, 8, 8>::zeros();
    let mut b = SVector::<f64, 8>::zeros();
    for (k, (x, obs)) in corners.iter().enumerate() {
        let p = plane_from_world.transform_point(*x);
        let (u, v) = (obs.x, obs.y);
        let r = 2 * k;
        a.row_mut(r)
            .copy_from_slice(&[p.x, p.y, 1.0, 0.0, 0.0, 0.0, -u * p.x, -u * p.y]);
        a.row_mut(r + 1)
            .copy_from_slice(&[0.0, 0.0, 0.0, p.x, p.y, 1.0, -v * p.x, -v * p.y]);
        b[r] = u;
        b[r + 1] = v;
    }
    let h = a.lu().solve(&b)?;
    let hm = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], 1.0);
    let (h1, h2, h3) = (hm.column(0), hm.column(1), hm.column(2));
    let mut lambda = 2.0 / (h1.norm() + h2.norm());
    // The tag is in front of the camera: its origin's depth is positive.
    if h3[2] * lambda < 0.0 {
        lambda = -lambda;
    }
    let r1 = h1 * lambda;
    let r2 = h2 * lambda;
    let r3 = r1.cross(&r2);
    let approx = Matrix3::from_columns(&[r1, r2, r3]);
    let svd = approx.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut r = u * vt;
    if r.determinant() < 0.0 {
        let mut u = u;
        u.column_mut(2).neg_mut();
        r = u * vt;
    }
    let rot = DMat3::from_cols(
        DVec3::new(r[(0, 0)], r[(1, 0)], r[(2, 0)]),
        DVec3::new(r[(0, 1)], r[(1, 1)], r[(2, 1)]),
        DVec3::new(r[(0, 2)], r[(1, 2)], r[(2, 2)]),
    );
    let t = DVec3::new(h3[0], h3[1], h3[2]) * lambda;
    let cam_from_plane = Rigid3::new(DQuat::from_mat3(&rot), t);
    Some(cam_from_plane.compose(&plane_from_world))
}

/// Gauss–Newton (lightly damped) on the normalised reprojection error of every corner.
fn refine(start: Rigid3, pairs: &[Correspondence]) -> Rigid3 {
    let mut pose = start;
    let mut cost = rms(&pose, pairs);
    for _ in 0..20 {
        let mut jtj = Matrix6::<f64>::zeros();
        let mut jtr = Vector6::<f64>::zeros();
        for (x, obs) in pairs {
            let rx = pose.rotation * *x;
            let c = rx + pose.translation_m;
            if c.z <= 1e-9 {
                return pose;
            }
            let iz = 1.0 / c.z;
            let res = DVec2::new(c.x * iz, c.y * iz) - *obs;
            // d(proj)/dc, then dc/dω = −[Rx]×, dc/dt = I (left perturbation of the rotation).
            let du = DVec3::new(iz, 0.0, -c.x * iz * iz);
            let dv = DVec3::new(0.0, iz, -c.y * iz * iz);
            for (row, r) in [(du, res.x), (dv, res.y)] {
                let dw = rx.cross(row); // row · (−[rx]× ω) = (rx × row) · ω
                let j = Vector6::new(dw.x, dw.y, dw.z, row.x, row.y, row.z);
                jtj += j * j.transpose();
                jtr += j * r;
            }
        }
        for i in 0..6 {
            jtj[(i, i)] *= 1.0 + 1e-6;
        }
        let Some(chol) = jtj.cholesky() else {
            return pose;
        };
        let step = chol.solve(&(-jtr));
        let w = DVec3::new(step[0], step[1], step[2]);
        let next = Rigid3::new(
            DQuat::from_scaled_axis(w) * pose.rotation,
            pose.translation_m + DVec3::new(step[3], step[4], step[5]),
        );
        let next_cost = rms(&next, pairs);
        if !next_cost.is_finite() || next_cost >= cost {
            break;
        }
        let converged = cost - next_cost < 1e-12;
        pose = next;
        cost = next_cost;
        if converged {
            break;
        }
    }
    pose
}

/// Metric scale of an SfM world from the tags seen in its registered keyframes (module docs).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct TagScale {
    pub metres_per_unit: f64,
    /// "distances between mapped tags" (with a layout) or "tag sides and diagonals".
    pub method: &'static str,
    /// Tags with a triangulated corner, and the lengths measured.
    pub tags: usize,
    pub lengths: usize,
    /// Median absolute deviation of the per-length ratios over their median.
    pub spread: f64,
}

/// Metres per world unit from the map's tags seen in registered keyframes (`world_from_cam`
/// by capture time); `None` when nothing could be measured (module docs).
pub fn scale_from_tags(
    map: &TagMap,
    camera: &CameraModel,
    seen: &[SeenTags],
    registered: &BTreeMap<u64, Rigid3>,
) -> Option<TagScale> {
    // Rays per tag id and corner: (camera centre, unit direction, cam_from_world, observation).
    type Ray = (DVec3, DVec3, Rigid3, DVec2);
    let mut rays: BTreeMap<u32, [Vec<Ray>; 4]> = BTreeMap::new();
    for s in seen {
        let Some(world_from_cam) = registered.get(&s.monotonic_ns) else {
            continue;
        };
        let cam_from_world = world_from_cam.inverse();
        for d in &s.tags {
            let entry = rays.entry(d.id).or_default();
            for (k, px) in d.corners_px.iter().enumerate() {
                if let Some(x) = normalised(camera, *px) {
                    let dir = world_from_cam.transform_vector(DVec3::new(x.x, x.y, 1.0));
                    entry[k].push((
                        world_from_cam.translation_m,
                        dir.normalize(),
                        cam_from_world,
                        x,
                    ));
                }
            }
        }
    }
    let focal = 0.5 * (camera.intrinsics.fx + camera.intrinsics.fy);
    let min_sin = MIN_TRIANGULATION_DEG.to_radians().sin();
    // Triangulated corners: (tag id, corner index, world point).
    let mut corners: Vec<(u32, usize, DVec3)> = Vec::new();
    for (id, corner_rays) in &rays {
        let points: Vec<Option<DVec3>> = corner_rays
            .iter()
            .map(|rs| {
                if rs.len() < 3 {
                    return None;
                }
                // Widest angle between any ray and the first: is there parallax?
                let spread = rs
                    .iter()
                    .map(|r| r.1.cross(rs[0].1).length())
                    .fold(0.0, f64::max);
                if spread < min_sin {
                    return None;
                }
                let p = closest_to_rays(rs.iter().map(|r| (r.0, r.1)))?;
                let worst = rs
                    .iter()
                    .map(|(_, _, cam_from_world, obs)| {
                        let c = cam_from_world.transform_point(p);
                        if c.z <= 0.0 {
                            f64::INFINITY
                        } else {
                            (DVec2::new(c.x / c.z, c.y / c.z) - *obs).length() * focal
                        }
                    })
                    .fold(0.0, f64::max);
                (worst <= MAX_TRIANGULATION_PX).then_some(p)
            })
            .collect();
        corners.extend(
            points
                .iter()
                .enumerate()
                .filter_map(|(k, p)| p.map(|p| (*id, k, p))),
        );
    }
    // With a layout: distances between corners of different mapped tags, at least two tag
    // sides apart (metres of baseline, so a corner bias of a fraction of a pixel — gamma
    // and blur shrink a dark square — does not reach the scale).
    let mapped: Vec<(u32, DVec3, DVec3)> = corners
        .iter()
        .filter_map(|(id, k, p)| Some((*id, *p, map.corners.get(id)?[*k])))
        .collect();
    let mut ratios = Vec::new();
    for (i, a) in mapped.iter().enumerate() {
        for b in &mapped[i + 1..] {
            let metres = (a.2 - b.2).length();
            let units = (a.1 - b.1).length();
            if a.0 != b.0 && metres >= 2.0 * map.size_m && units > 1e-12 {
                ratios.push(metres / units);
            }
        }
    }
    let method = if ratios.is_empty() {
        // Size only (or one mapped tag): each tag's sides and diagonals.
        for (id, k, a) in &corners {
            for (id2, k2, b) in &corners {
                let diagonal = (k2 + 4 - k) % 4 == 2;
                if id == id2 && k < k2 {
                    let metres = map.size_m * if diagonal { 2f64.sqrt() } else { 1.0 };
                    let units = (*a - *b).length();
                    if units > 1e-12 {
                        ratios.push(metres / units);
                    }
                }
            }
        }
        "tag sides and diagonals"
    } else {
        "distances between mapped tags"
    };
    if ratios.is_empty() {
        return None;
    }
    let tags = corners.iter().map(|c| c.0).collect::<BTreeSet<u32>>().len();
    let median = super::select::median(ratios.clone());
    let mad = super::select::median(ratios.iter().map(|r| (r - median).abs()).collect());
    Some(TagScale {
        metres_per_unit: median,
        method,
        tags,
        lengths: ratios.len(),
        spread: mad / median,
    })
}

/// The point closest (least squares) to lines `origin + s · dir` (unit directions).
fn closest_to_rays(rays: impl Iterator<Item = (DVec3, DVec3)>) -> Option<DVec3> {
    let mut a = Matrix3::<f64>::zeros();
    let mut b = nalgebra::Vector3::<f64>::zeros();
    for (o, d) in rays {
        let d = nalgebra::Vector3::new(d.x, d.y, d.z);
        let o = nalgebra::Vector3::new(o.x, o.y, o.z);
        let m = Matrix3::identity() - d * d.transpose();
        a += m;
        b += m * o;
    }
    let p = a.lu().solve(&b)?;
    Some(DVec3::new(p[0], p[1], p[2]))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use crate::camera::{BrownConrady, Intrinsics};

    fn camera() -> CameraModel {
        CameraModel {
            width_px: 640,
            height_px: 360,
            intrinsics: Intrinsics {
                fx: 457.0,
                fy: 457.0,
                cx: 319.5,
                cy: 179.5,
            },
            distortion: BrownConrady {
                k1: -0.08,
                k2: 0.02,
                ..BrownConrady::default()
            },
        }
    }

    /// The simulated walk room's layout (s3tir-firmware-sim `fiducials`) in part: tags of
    /// side 0.4 m on the wall y = −3 (facing +y) and on the floor in a ring of radius 1.25 m,
    /// seen from around (0, 1.7, 1).
    fn map() -> TagMap {
        let mut corners = BTreeMap::new();
        let mut add = |id: u32, c: DVec3, right: DVec3, up: DVec3| {
            let (r, u) = (right * 0.2, up * 0.2);
            corners.insert(id, [c - r - u, c + r - u, c + r + u, c - r + u]);
        };
        for (id, x) in [(0u32, -2.2), (1, -1.1), (2, 1.1), (3, 2.2)] {
            add(id, DVec3::new(x, -3.0, 0.3), DVec3::NEG_X, DVec3::Z);
        }
        for k in 0..12u32 {
            let a = std::f64::consts::TAU * (f64::from(k) + 0.5) / 12.0;
            let out = DVec3::new(a.cos(), a.sin(), 0.0);
            add(16 + k, out * 1.25, out.cross(DVec3::Z), out);
        }
        TagMap {
            path: PathBuf::from("tags.toml"),
            size_m: 0.4,
            corners,
        }
    }

    fn looking_at(eye: DVec3, target: DVec3) -> Rigid3 {
        let fwd = (target - eye).normalize();
        let right = fwd.cross(DVec3::Z).normalize();
        let down = fwd.cross(right);
        Rigid3::new(DQuat::from_mat3(&DMat3::from_cols(right, down, fwd)), eye)
    }

    /// Detections of the map's tags as `world_from_cam` sees them, with corner noise.
    fn observe(
        map: &TagMap,
        world_from_cam: &Rigid3,
        noise_px: f64,
        seed: u64,
    ) -> Vec<TagDetection> {
        let cam = camera();
        let cam_from_world = world_from_cam.inverse();
        let mut state = seed;
        let mut noise = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 2.0 * noise_px
        };
        map.corners
            .iter()
            .filter_map(|(id, c)| {
                let px = c.map(|p| cam.project(cam_from_world.transform_point(p)));
                let inside = px.iter().all(|p| {
                    p.is_some_and(|p| p.x > 0.0 && p.y > 0.0 && p.x < 639.0 && p.y < 359.0)
                });
                inside.then(|| TagDetection {
                    id: *id,
                    hamming: 0,
                    decision_margin: 100.0,
                    centre_px: [0.0; 2],
                    corners_px: px.map(|p| {
                        let p = p.unwrap();
                        [p.x + noise(), p.y + noise()]
                    }),
                })
            })
            .collect()
    }

    #[test]
    fn pnp_recovers_a_pose_from_wall_and_floor_tags_with_corner_noise() {
        let map = map();
        let truth = looking_at(DVec3::new(0.3, 1.7, 1.0), DVec3::new(0.0, 0.0, 0.2));
        let seen = observe(&map, &truth, 0.3, 7);
        assert!(seen.len() >= 2, "the test camera sees at least two tags");
        let pose = pnp(&map, &camera(), &seen).expect("two tags pose a camera");
        let rot_err = pose
            .world_from_cam
            .rotation
            .angle_between(truth.rotation)
            .to_degrees();
        let centre_err = (pose.world_from_cam.translation_m - truth.translation_m).length();
        // Wall and floor tags together (not coplanar): about 0.005° and 0.2 mm here. Wall tags
        // alone, one row, give about 0.6° and 5 cm at this noise (module docs).
        assert!(
            rot_err < 0.05,
            "rotation error {rot_err}° (expected < 0.05° at 0.3 px noise)"
        );
        assert!(
            centre_err < 0.005,
            "centre error {centre_err} m (expected < 5 mm)"
        );
        assert!(
            pose.rms_px < 0.5,
            "rms {} px for 0.3 px uniform noise",
            pose.rms_px
        );
    }

    #[test]
    fn pnp_on_one_row_of_wall_tags_is_poorly_conditioned() {
        // The module docs' figure: why the simulated room also has floor tags.
        let mut wall = map();
        wall.corners.retain(|id, _| *id < 16);
        let truth = looking_at(DVec3::new(0.3, 1.7, 1.0), DVec3::new(0.0, 0.0, 0.2));
        let pose = pnp(&wall, &camera(), &observe(&wall, &truth, 0.3, 7)).expect("4 wall tags");
        let rot_err = pose
            .world_from_cam
            .rotation
            .angle_between(truth.rotation)
            .to_degrees();
        assert!(
            (0.2..2.0).contains(&rot_err),
            "one row of wall tags: rotation error {rot_err}° at 0.3 px (about 0.6° expected)"
        );
    }

    #[test]
    fn pnp_refuses_one_tag_and_a_wrong_map() {
        let map = map();
        let truth = looking_at(DVec3::new(0.3, 1.7, 1.0), DVec3::new(0.0, 0.0, 0.2));
        let seen = observe(&map, &truth, 0.0, 1);
        assert!(
            pnp(&map, &camera(), &seen[..1]).is_none(),
            "one tag is not enough"
        );
        // Swap two tags' places in the map: no pose fits both.
        let mut wrong = map.clone();
        let a = wrong.corners[&seen[0].id];
        let b = wrong.corners[&seen[1].id];
        wrong.corners.insert(seen[0].id, b);
        wrong.corners.insert(seen[1].id, a);
        if let Some(p) = pnp(&wrong, &camera(), &seen[..2]) {
            panic!(
                "a map with two tags swapped posed the camera at rms {} px",
                p.rms_px
            );
        }
    }

    #[test]
    fn scale_from_tags_measures_an_unknown_world_scale() {
        let map = map();
        let cam = camera();
        // A similarity unknown to the stage: world units = metres × 0.37, shifted and turned.
        let s = 0.37;
        let turn = Rigid3::new(DQuat::from_rotation_z(0.8), DVec3::new(1.0, -2.0, 0.5));
        let mut seen = Vec::new();
        let mut registered = BTreeMap::new();
        for k in 0..12u64 {
            let a = -0.4 + 0.07 * k as f64;
            let eye = DVec3::new(1.7 * a.sin(), 1.7 * a.cos(), 1.0);
            let truth = looking_at(eye, DVec3::new(0.0, 0.0, 0.2));
            let tags = observe(&map, &truth, 0.3, k);
            // The same camera in the scaled world.
            let sfm = turn.compose(&Rigid3::new(truth.rotation, truth.translation_m * s));
            registered.insert(k * 1000, sfm);
            seen.push(SeenTags {
                sequence: k as u32,
                monotonic_ns: k * 1000,
                tags,
            });
        }
        let scale =
            scale_from_tags(&map, &cam, &seen, &registered).expect("tags were triangulated");
        assert_eq!(scale.method, "distances between mapped tags");
        let sides = TagMap {
            corners: BTreeMap::new(),
            ..map.clone()
        };
        let by_sides = scale_from_tags(&sides, &cam, &seen, &registered).expect("size only");
        assert_eq!(by_sides.method, "tag sides and diagonals");
        let err_sides = (by_sides.metres_per_unit * s - 1.0).abs();
        assert!(
            err_sides < 0.01,
            "size only: error {:.2} %",
            100.0 * err_sides
        );
        let err = (scale.metres_per_unit * s - 1.0).abs();
        assert!(
            err < 0.01,
            "metres per unit {} against {} (error {:.2} %, expected < 1 %)",
            scale.metres_per_unit,
            1.0 / s,
            100.0 * err
        );
        assert!(scale.tags >= 2 && scale.lengths >= 12, "{scale:?}");
    }

    #[test]
    fn map_file_is_checked() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("tags.toml");
        std::fs::write(
            &p,
            "family = \"tag36h11\"\nsize_m = 0.4\n[[tag]]\nid = 3\ncorners_m = [[0,0,0],[0.4,0,0],[0.4,0,0.4],[0,0,0.4]]\n",
        )
        .unwrap();
        let m = TagMap::read(&p).unwrap();
        assert!(m.has_layout() && m.corners.contains_key(&3));
        std::fs::write(
            &p,
            "family = \"tag36h11\"\nsize_m = 0.5\n[[tag]]\nid = 3\ncorners_m = [[0,0,0],[0.4,0,0],[0.4,0,0.4],[0,0,0.4]]\n",
        )
        .unwrap();
        let e = TagMap::read(&p).unwrap_err().to_string();
        assert!(
            e.contains("not a 0.5 m square") && e.contains("tags.toml"),
            "{e}"
        );
        std::fs::write(&p, "family = \"tag25h9\"\nsize_m = 0.4\n").unwrap();
        let e = TagMap::read(&p).unwrap_err().to_string();
        assert!(e.contains("tag25h9"), "{e}");
        std::fs::write(&p, "family = \"tag36h11\"\nsize_m = 0.4\n").unwrap();
        assert!(
            !TagMap::read(&p).unwrap().has_layout(),
            "size only: scale, no layout"
        );
    }
}
