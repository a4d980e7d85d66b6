//! Metric scale for COLMAP's world from tags: tag corners triangulated in the world of the
//! registered keyframes, their distances against the map's layout or the tags' printed size.

use std::collections::{BTreeMap, BTreeSet};

use glam::{DVec2, DVec3};
use nalgebra::Matrix3;
use serde::Serialize;

use super::pnp::normalised;
use super::{SeenTags, TagMap};
use crate::model::camera::CameraModel;
use crate::model::geometry::Rigid3;

/// A triangulated tag corner needs rays spanning at least this angle, degrees.
pub const MIN_TRIANGULATION_DEG: f64 = 2.0;
/// … and must reproject within this many pixels in every view it was seen in.
pub const MAX_TRIANGULATION_PX: f64 = 3.0;

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
    let median = crate::poses::stats::median(&ratios);
    let mad = crate::poses::stats::median(
        &ratios
            .iter()
            .map(|r| (r - median).abs())
            .collect::<Vec<_>>(),
    );
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
