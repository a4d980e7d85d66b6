//! AprilTags on the walk room's walls: the fiducials a real rig's user tapes up so that poses
//! come without structure from motion and COLMAP's world gets its metric scale (the poses
//! stage's `--tags FILE`, `s3tir_calib::poses::fiducials`).
//!
//! **Layout** ([`room_tags`]), every tag tag36h11, [`TAG_SIZE_M`] wide (the black border's
//! outer side), with a white quiet zone of one cell:
//! - ids 0–15: [`TAGS_PER_WALL`] on each of the four walls of the walk room, wall by wall,
//!   printed upright, their centres [`TAG_CENTRE_Z_M`] above the floor. The walk cameras look
//!   down at the scene from about 1 m, so only the lower band of the far wall is in view: that
//!   is where the tags are.
//! - ids 16–27: [`FLOOR_TAGS`] flat on the floor in a ring of radius [`FLOOR_RING_M`] around the
//!   scene, between the objects and the walk, their tops pointing outwards.
//!
//! Why both: tags in one row on one wall are nearly coplanar and only 0.4 m tall, so a
//! camera's pitch trades against its height (the PnP pose moved 2° per pixel of corner noise
//! in the unit test of `s3tir_calib::poses::fiducials`); tags on the floor in the same view
//! fix it. The thermal camera does not see printed tags (paper at the surface's temperature
//! and emissivity); the RGB camera does. For a rig without RGB the tags can be made thermal
//! fiducials ([`TagInk::Heated`], `run --walk-tags heated`): aluminium foil cut over a heated
//! black panel, the emissivity board's principle; the thermal camera sees them inverted.
//!
//! **Map** ([`tags_toml`], `tags.toml` beside the walk's truth): family, size, and each tag's
//! four corners in the world (metres), in the AprilTag library's corner order (the tag's
//! bottom-left, bottom-right, top-right, top-left as printed) — the format the poses stage
//! reads.

use glam::DVec3;

use super::{ROOM_HALF_M, ROOM_HEIGHT_M};

/// Side of each tag's black border, metres.
pub const TAG_SIZE_M: f64 = 0.4;
/// Height of each tag's centre above the floor, metres.
pub const TAG_CENTRE_Z_M: f64 = 0.3;
/// Tags on each wall.
pub const TAGS_PER_WALL: usize = 4;
/// Positions of the tags along a wall (from the wall's left as seen from inside), metres.
const ALONG_M: [f64; TAGS_PER_WALL] = [-2.2, -1.1, 1.1, 2.2];
/// Tags on the floor.
pub const FLOOR_TAGS: usize = 12;
/// Radius of the floor tags' ring around the scene's centre, metres.
pub const FLOOR_RING_M: f64 = 1.25;

/// One printed tag.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PrintedTag {
    pub id: u32,
    pub centre: DVec3,
    /// Unit vectors to the tag's right and top as printed; `right × up` is the surface normal
    /// on the side the tag faces.
    pub right: DVec3,
    pub up: DVec3,
    /// The tag's 8×8 cells (`cells[y][x]`, y down as printed, true = white).
    pub cells: [[bool; 8]; 8],
}

impl PrintedTag {
    /// The four corners in the AprilTag library's order: bottom-left, bottom-right, top-right,
    /// top-left (as printed).
    pub fn corners(&self) -> [DVec3; 4] {
        let h = TAG_SIZE_M / 2.0;
        let (r, u) = (self.right * h, self.up * h);
        [
            self.centre - r - u,
            self.centre + r - u,
            self.centre + r + u,
            self.centre - r + u,
        ]
    }

    /// The albedo at wall point `p`: `Some(white or black)` inside the tag or its one-cell
    /// quiet zone, `None` elsewhere.
    fn albedo_at(&self, p: DVec3) -> Option<f64> {
        let d = p - self.centre;
        let cell = TAG_SIZE_M / 8.0;
        let x = (d.dot(self.right) + TAG_SIZE_M / 2.0) / cell;
        let y = (TAG_SIZE_M / 2.0 - d.dot(self.up)) / cell;
        if !(-1.0..9.0).contains(&x) || !(-1.0..9.0).contains(&y) {
            return None;
        }
        let white = if (0.0..8.0).contains(&x) && (0.0..8.0).contains(&y) {
            self.cells[y as usize][x as usize]
        } else {
            true
        };
        Some(if white { WHITE } else { BLACK })
    }
}

/// Albedo of the tags' white paper and black ink.
const WHITE: f64 = 0.85;
const BLACK: f64 = 0.06;

/// How the room's tags are made, which decides whether the thermal camera sees them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TagInk {
    /// Printed paper at the surface's temperature and emissivity: RGB only.
    #[default]
    Printed,
    /// Thermal fiducials for a rig without RGB: each tag is cut in polished aluminium (the
    /// white cells and quiet zone, emissivity [`FOIL_EMISSIVITY`]) over a matte black heated
    /// panel at [`HEATED_TAG_K`] (the black cells, [`PANEL_EMISSIVITY`]). RGB sees the same
    /// black-on-light tag; the thermal camera sees it inverted: the black cells emit as the warm
    /// panel, the foil reflects the room.
    Heated,
}

impl TagInk {
    pub fn name(self) -> &'static str {
        match self {
            TagInk::Printed => "printed",
            TagInk::Heated => "heated",
        }
    }

    /// The tag's surface where `albedo` (from [`tag_albedo`]) says ink or paper: temperature
    /// and emissivity in thermal, `None` for printed tags (the surface's own).
    pub fn thermal(self, albedo: f64) -> Option<(f64, f64)> {
        match self {
            TagInk::Printed => None,
            TagInk::Heated if albedo < 0.5 => Some((HEATED_TAG_K, PANEL_EMISSIVITY)),
            TagInk::Heated => Some((HEATED_TAG_K, FOIL_EMISSIVITY)),
        }
    }
}

/// Temperature of a heated tag's panel, kelvin (a low-voltage heating foil behind it).
pub const HEATED_TAG_K: f64 = 310.0;
/// Emissivity of the heated tag's matte black panel (its black cells) …
pub const PANEL_EMISSIVITY: f64 = 0.95;
/// … and of the polished aluminium cut over it (its white cells and quiet zone).
pub const FOIL_EMISSIVITY: f64 = 0.08;

/// Every tag of the walk room (module docs), in id order.
pub fn room_tags() -> Vec<PrintedTag> {
    let mut placed: Vec<(DVec3, DVec3, DVec3)> = Vec::new();
    // Walls by inward normal: the viewer looks along −normal, right = (−normal) × Z.
    for n in [DVec3::Y, DVec3::NEG_X, DVec3::NEG_Y, DVec3::X] {
        let right = (-n).cross(DVec3::Z);
        for along in ALONG_M {
            let centre = -n * ROOM_HALF_M + right * along + DVec3::Z * TAG_CENTRE_Z_M;
            placed.push((centre, right, DVec3::Z));
        }
    }
    // Floor: top outwards, so right = outwards × Z (right × up = +Z, facing up).
    for k in 0..FLOOR_TAGS {
        let a = std::f64::consts::TAU * (k as f64 + 0.5) / FLOOR_TAGS as f64;
        let out = DVec3::new(a.cos(), a.sin(), 0.0);
        placed.push((out * FLOOR_RING_M, out.cross(DVec3::Z), out));
    }
    placed
        .into_iter()
        .enumerate()
        .filter_map(|(id, (centre, right, up))| {
            // ids 0..28 are all inside tag36h11 (587 codes).
            let cells = s3tir_calib::tags::tag36h11_cells(id as u32)?;
            Some(PrintedTag {
                id: id as u32,
                centre,
                right,
                up,
                cells,
            })
        })
        .collect()
}

/// The albedo of a tag at the surface point `p` (on a wall or the floor), if one is printed
/// there.
pub fn tag_albedo(tags: &[PrintedTag], p: DVec3) -> Option<f64> {
    if p.z > TAG_CENTRE_Z_M + TAG_SIZE_M || p.z > ROOM_HEIGHT_M {
        return None;
    }
    tags.iter()
        // On the tag's plane (the hit point is exact to rounding).
        .filter(|t| (p - t.centre).dot(t.right.cross(t.up)).abs() < 1e-6)
        .find_map(|t| t.albedo_at(p))
}

/// `tags.toml`: the map the poses stage reads (`--tags FILE`; module docs).
pub fn tags_toml(tags: &[PrintedTag]) -> String {
    let mut s = String::from(
        "# AprilTag map of the simulated walk room (s3tir-firmware-sim): for the poses stage's\n\
         # --tags FILE. Corners: bottom-left, bottom-right, top-right, top-left as printed, world\n\
         # metres (the frame of truth.json).\n",
    );
    s.push_str("family = \"tag36h11\"\n");
    s.push_str(&format!("size_m = {TAG_SIZE_M}\n"));
    for t in tags {
        s.push_str(&format!("\n[[tag]]\nid = {}\ncorners_m = [", t.id));
        let corners: Vec<String> = t
            .corners()
            .iter()
            .map(|c| format!("[{:?}, {:?}, {:?}]", c.x, c.y, c.z))
            .collect();
        s.push_str(&corners.join(", "));
        s.push_str("]\n");
    }
    s
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn tags_lie_on_the_walls_and_floor_facing_the_room() {
        let tags = room_tags();
        assert_eq!(
            tags.len(),
            4 * TAGS_PER_WALL + FLOOR_TAGS,
            "every tag of every wall and the floor"
        );
        for t in &tags[16..] {
            let [bl, br, _, tl] = t.corners();
            assert!(
                t.centre.z.abs() < 1e-12,
                "floor tag {} lies on the floor",
                t.id
            );
            assert!(
                (br - bl).cross(tl - bl).z > 0.0,
                "floor tag {} faces up",
                t.id
            );
            let r = t.centre.truncate().length();
            assert!((r - FLOOR_RING_M).abs() < 1e-12);
            // Clear of the objects (|x| ≤ 0.9, |y| ≤ 0.5) and under no walk (radius ≥ 1.5).
            for c in t.corners() {
                assert!(
                    c.truncate().length() < 1.5,
                    "floor tag {} under the walk",
                    t.id
                );
                assert!(
                    c.x.abs() > 0.9 || c.y.abs() > 0.5,
                    "floor tag {} on an object",
                    t.id
                );
            }
        }
        for t in &tags[..16] {
            let [bl, br, tr, tl] = t.corners();
            assert!(
                (t.centre.x.abs() - ROOM_HALF_M).abs() < 1e-12
                    || (t.centre.y.abs() - ROOM_HALF_M).abs() < 1e-12,
                "tag {} centre {:?} is on a wall",
                t.id,
                t.centre
            );
            assert!((br - bl).length() - TAG_SIZE_M < 1e-12 && tl.z > bl.z && tr.z > br.z);
            // Seen from the room's centre, bottom-left → bottom-right runs to the right:
            // (br − bl) × (tl − bl) points into the room (towards the viewer).
            let towards_viewer = (br - bl).cross(tl - bl);
            assert!(
                towards_viewer.dot(DVec3::new(0.0, 0.0, t.centre.z) - t.centre) > 0.0,
                "tag {} faces the room, not the wall",
                t.id
            );
        }
    }

    #[test]
    fn albedo_draws_the_tag_cells_and_the_quiet_zone() {
        let tags = room_tags();
        let t = tags[5];
        let cell = TAG_SIZE_M / 8.0;
        let at = |x: f64, y: f64| {
            t.centre
                + t.right * (x * cell - TAG_SIZE_M / 2.0)
                + DVec3::Z * (TAG_SIZE_M / 2.0 - y * cell)
        };
        assert_eq!(
            tag_albedo(&tags, at(0.5, 0.5)),
            Some(BLACK),
            "the border is black"
        );
        assert_eq!(tag_albedo(&tags, at(-0.5, 3.5)), Some(WHITE), "quiet zone");
        assert_eq!(
            tag_albedo(&tags, at(-1.5, 3.5)),
            None,
            "beyond the quiet zone"
        );
        for y in 1..7 {
            for x in 1..7 {
                let expect = if t.cells[y][x] { WHITE } else { BLACK };
                assert_eq!(
                    tag_albedo(&tags, at(x as f64 + 0.5, y as f64 + 0.5)),
                    Some(expect)
                );
            }
        }
    }

    #[test]
    fn map_lists_every_tag_with_four_corners() {
        let text = tags_toml(&room_tags());
        let doc: toml::Table = toml::from_str(&text).unwrap();
        assert_eq!(doc["family"].as_str(), Some("tag36h11"));
        let list = doc["tag"].as_array().unwrap();
        assert_eq!(list.len(), 28);
        assert_eq!(list[3]["corners_m"].as_array().unwrap().len(), 4);
    }
}
