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
//! **Fast path** ([`pnp()`], in `pnp`): with a layout, each keyframe that sees at least [`MIN_PNP_TAGS`]
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
//! **Scale for COLMAP** ([`scale_from_tags`], in `scale`): every tag corner seen in at least three
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
//!
//! This module reads the map file and finds the tags in the keyframes; `pnp` poses keyframes
//! from them and `scale` measures COLMAP's scale.

mod pnp;
mod scale;

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use glam::DVec3;
use rayon::prelude::*;
use serde::Deserialize;

use super::PosesError;
use super::frames::{FrameInfo, Stream};
use crate::tags::{TagConfig, TagDetection, TagDetector, luma_bt601};
pub use pnp::{
    MAX_PNP_RMS_PX, MIN_PNP_TAGS, NEIGHBOUR_S, OUTLIER_DEG, OUTLIER_M, TagPose, drop_jumps, pnp,
};
pub use scale::{MAX_TRIANGULATION_PX, MIN_TRIANGULATION_DEG, TagScale, scale_from_tags};

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
        let read_err = |e: Box<dyn std::error::Error + Send + Sync>| PosesError::TagsRead {
            path: path.to_path_buf(),
            source: e,
        };
        let text = std::fs::read_to_string(path).map_err(|e| read_err(Box::new(e)))?;
        let file: MapFile = toml::from_str(&text).map_err(|e| read_err(Box::new(e)))?;
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
                let err = |e: Box<dyn std::error::Error + Send + Sync>| PosesError::TagsRead {
                    path: path.clone(),
                    source: e,
                };
                let detector = detector.as_mut().map_err(|e| err(Box::new(e.clone())))?;
                let img = image::open(&path).map_err(|e| err(Box::new(e)))?;
                let grey = match img {
                    image::DynamicImage::ImageLuma8(g) => g,
                    other => luma_bt601(&other.to_rgb8()),
                };
                // A thermal fiducial may be seen inverted (hot ink over cold foil, or the other
                // way round: the module docs): the negative is searched too.
                let tags = detect_upscaled(detector, grey, &path, stream == Stream::Thermal)
                    .map_err(|e| err(Box::new(e)))?;
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

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use crate::model::camera::{BrownConrady, CameraModel, Intrinsics};
    use crate::model::geometry::Rigid3;
    use glam::{DMat3, DQuat};

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
