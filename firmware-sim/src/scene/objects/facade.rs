//! The `Facade` layout: a brick facade with thermal texture finer than a splatting model's
//! primitives, for the claim that spectral bands pay where a scene needs them (the S³-TIR
//! issue). It is meant to be seen at a real core's resolution (`scene --layout facade --width
//! 640 --height 512`, a Boson's): at the wall arc's 1.6 m a pixel covers about 2.7 mm of wall.
//!
//! The wall plane, its extent and the cameras are the `Wall` layout's (y = [`WALL_Y`], facing
//! −y; [`crate::scene::wall_arc`]); every pixel of every view sees facade. On it, back to front:
//! - **Brick in running bond**: bricks [`BRICK_W`] × [`BRICK_H`] (215 × 65 mm, a metric brick
//!   face) in [`JOINT`] = 10 mm mortar joints, every second course shifted by half a brick.
//!   Bricks at [`FACADE_BASE_K`] = 278 K, each warmer or colder by up to ±0.4 K (a
//!   deterministic hash of its course and column, the simulator's `lattice_hash`: bricks differ in density and moisture), ε
//!   [`BRICK_EMISSIVITY`] = 0.93; joints are thermal bridges, [`MORTAR_BRIDGE_K`] = 1.2 K
//!   warmer, ε [`MORTAR_EMISSIVITY`] = 0.90. A joint is ~3.7 px wide at 640 px: texture that
//!   a Gaussian of a few pixels averages away and a banded primitive can represent.
//! - **An in-wall heating pipe's warm band**: the `Wall` layout's smooth band ([`wall_temp_k`]
//!   minus its base), the low-frequency part of the scene.
//! - **A surface-mounted heating pipe** (painted, ε 0.94, [`PIPE_K`] = 333 K) along the wall
//!   at z ∈ [`SURFACE_PIPE_Z`]: two sharp horizontal edges across every view.
//! - **A warm cabinet** (painted steel, ε 0.92, [`CABINET_K`] = 308 K) at x ∈ [`CABINET_X`],
//!   z ∈ [`CABINET_Z`], flush with the wall, carrying **printed foil labels**: three lines of
//!   8 × 14 mm "characters" on a 12 mm pitch (about 3 px of foil per character at 640 px),
//!   present where a hash says so; foil (ε [`FOIL_EMISSIVITY`] = 0.15) mostly mirrors the
//!   290 K room, so each character is ~15 K apparent below the paint around it: the classic
//!   label that a thermal camera reads as a pattern of cold marks.
//!
//! RGB: red-brown bricks varying per brick, light grey mortar, white pipe, grey cabinet,
//! silver labels. The truth (depth, temperature, `truth/surface.ply`) comes from the same
//! tracer as for every layout.

use glam::DVec3;

use super::{
    SceneObject, SurfaceHit, WALL_BASE_K, WALL_X, WALL_Y, WALL_Z, axis_plane, face, lattice_hash,
    wall_temp_k,
};

/// Brick face width and height, metres (a metric brick's 215 × 65 mm face).
pub const BRICK_W: f64 = 0.215;
pub const BRICK_H: f64 = 0.065;
/// Mortar joint width, metres.
pub const JOINT: f64 = 0.010;
/// Brick surface temperature before its own variation and the in-wall pipe's band, kelvin.
pub const FACADE_BASE_K: f64 = 278.0;
/// Largest per-brick temperature deviation, kelvin.
pub const BRICK_SPREAD_K: f64 = 0.4;
/// How much warmer the mortar joints are (thermal bridges), kelvin.
pub const MORTAR_BRIDGE_K: f64 = 1.2;
pub const BRICK_EMISSIVITY: f64 = 0.93;
pub const MORTAR_EMISSIVITY: f64 = 0.90;
/// Surface-mounted pipe: its band on the wall (z from, to), metres, and its temperature.
pub const SURFACE_PIPE_Z: (f64, f64) = (0.40, 0.44);
pub const PIPE_K: f64 = 333.0;
/// The cabinet's front (x from, to; z from, to), metres, and its temperature.
pub const CABINET_X: (f64, f64) = (0.25, 0.85);
pub const CABINET_Z: (f64, f64) = (0.80, 1.50);
pub const CABINET_K: f64 = 308.0;
/// The labels' foil emissivity.
pub const FOIL_EMISSIVITY: f64 = 0.15;
/// Label text block: left edge and top of the first line, metres.
const LABEL_X0: f64 = 0.35;
const LABEL_Z_TOP: f64 = 1.40;
/// Character cell pitch, character size, line pitch, and the block's size.
const CHAR_PITCH: f64 = 0.012;
const CHAR_W: f64 = 0.008;
const CHAR_H: f64 = 0.014;
const LINE_PITCH: f64 = 0.025;
const LINES: i64 = 3;
const CHARS_PER_LINE: i64 = 30;

/// What the facade is at `(x, z)`: temperature, emissivity, RGB albedo and the object.
pub fn facade_material(x: f64, z: f64) -> (f64, f64, [f64; 3], SceneObject) {
    let band = wall_temp_k(x, z) - WALL_BASE_K;
    if (SURFACE_PIPE_Z.0..=SURFACE_PIPE_Z.1).contains(&z) {
        return (PIPE_K, 0.94, [0.85, 0.85, 0.82], SceneObject::SurfacePipe);
    }
    if (CABINET_X.0..=CABINET_X.1).contains(&x) && (CABINET_Z.0..=CABINET_Z.1).contains(&z) {
        return if on_label_character(x, z) {
            (
                CABINET_K,
                FOIL_EMISSIVITY,
                [0.78, 0.78, 0.80],
                SceneObject::Label,
            )
        } else {
            (CABINET_K, 0.92, [0.42, 0.44, 0.46], SceneObject::Cabinet)
        };
    }
    let course_h = BRICK_H + JOINT;
    let pitch = BRICK_W + JOINT;
    let course = (z / course_h).floor();
    let shift = if (course as i64).rem_euclid(2) == 1 {
        0.5 * pitch
    } else {
        0.0
    };
    let column = ((x + shift) / pitch).floor();
    let in_course = z - course * course_h;
    let in_row = x + shift - column * pitch;
    if in_course < JOINT || in_row < JOINT {
        return (
            FACADE_BASE_K + MORTAR_BRIDGE_K + band,
            MORTAR_EMISSIVITY,
            [0.62, 0.60, 0.56],
            SceneObject::Mortar,
        );
    }
    let h = lattice_hash(course as i64, column as i64, 0, 0);
    let shade = 0.85 + 0.3 * h;
    (
        FACADE_BASE_K + BRICK_SPREAD_K * (2.0 * h - 1.0) + band,
        BRICK_EMISSIVITY,
        [0.55 * shade, 0.27 * shade, 0.20 * shade],
        SceneObject::Brick,
    )
}

/// Whether `(x, z)` (inside the cabinet) is on a printed foil character.
fn on_label_character(x: f64, z: f64) -> bool {
    let line = ((LABEL_Z_TOP - z) / LINE_PITCH).floor();
    let cell = ((x - LABEL_X0) / CHAR_PITCH).floor();
    if !(0.0..LINES as f64).contains(&line) || !(0.0..CHARS_PER_LINE as f64).contains(&cell) {
        return false;
    }
    let in_line = LABEL_Z_TOP - z - line * LINE_PITCH;
    let in_cell = x - LABEL_X0 - cell * CHAR_PITCH;
    // About two characters in three are printed (the rest are spaces).
    in_line < CHAR_H && in_cell < CHAR_W && lattice_hash(line as i64, cell as i64, 1, 0) < 0.65
}

/// The facade along the ray `o + t d`, if it meets it inside the wall's extent.
pub fn trace_facade(o: DVec3, d: DVec3) -> Option<SurfaceHit> {
    let (t, p) = axis_plane(o, d, 1, WALL_Y)?;
    let inside = p.x >= WALL_X.0 && p.x <= WALL_X.1 && p.z >= WALL_Z.0 && p.z <= WALL_Z.1;
    (t > 1e-9 && inside).then(|| {
        let (temp_k, emissivity, albedo, object) = facade_material(p.x, p.z);
        SurfaceHit {
            t,
            temp_k,
            emissivity,
            albedo,
            normal: face(DVec3::Y, d),
            object,
        }
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use crate::physics::Radiometry;
    use crate::scene::{ENV_K, SceneLayout, pixel_hits, poses, scene_camera};

    /// Apparent temperature of a grey body at `t` with emissivity `e` reflecting [`ENV_K`].
    fn apparent(t: f64, e: f64) -> f64 {
        let r = Radiometry::new();
        r.temperature_k(r.apparent_radiance(e, t, ENV_K))
    }

    /// Proves what the layout is for: at 640×512 every view of the arc is all facade, each
    /// sees hundreds of bricks, the mortar joints are 2–6 px wide and differ from the bricks
    /// by more than the bricks differ among themselves, and the labels are cold marks of a few
    /// pixels on the warm cabinet.
    #[test]
    fn a_boson_view_sees_fine_thermal_texture() {
        let (w, h) = (640usize, 512usize);
        let cam = scene_camera(w as u32, h as u32);
        let views = poses(SceneLayout::Facade, 16);
        for (k, pose) in views.iter().enumerate().step_by(5) {
            let hits = pixel_hits(SceneLayout::Facade, &cam, pose);
            assert!(
                hits.iter().all(Option::is_some),
                "view {k}: every pixel sees the facade"
            );
            let count = |o: SceneObject| hits.iter().flatten().filter(|(h, _)| *h == o).count();
            let (mortar, brick) = (count(SceneObject::Mortar), count(SceneObject::Brick));
            assert!(
                mortar > w * h / 20 && brick > w * h / 3,
                "view {k}: mortar {mortar} px, brick {brick} px"
            );
            // Bed-joint width along three columns: runs of mortar pixels (a column that runs
            // down a head joint adds a few long runs; the median is the bed joints').
            let mut runs = Vec::new();
            for x in [w / 4 + 3, w / 2 + 7, 3 * w / 4 + 11] {
                let mut run = 0;
                for y in 0..h {
                    if matches!(hits[y * w + x], Some((SceneObject::Mortar, _))) {
                        run += 1;
                    } else if run > 0 {
                        runs.push(run);
                        run = 0;
                    }
                }
            }
            runs.sort_unstable();
            let median = runs[runs.len() / 2];
            assert!(
                (2..=6).contains(&median) && runs.len() >= 30,
                "view {k}: bed joints {median} px wide (median of {})",
                runs.len()
            );
        }
        // Joints against bricks, in apparent temperature (the in-wall band left out).
        let brick_lo = apparent(FACADE_BASE_K - BRICK_SPREAD_K, BRICK_EMISSIVITY);
        let brick_hi = apparent(FACADE_BASE_K + BRICK_SPREAD_K, BRICK_EMISSIVITY);
        let mortar = apparent(FACADE_BASE_K + MORTAR_BRIDGE_K, MORTAR_EMISSIVITY);
        assert!(
            mortar - brick_hi > 0.3 && brick_hi - brick_lo > 0.3,
            "joints {mortar:.2} K apparent, bricks {brick_lo:.2}–{brick_hi:.2} K"
        );
        let paint = apparent(CABINET_K, 0.92);
        let foil = apparent(CABINET_K, FOIL_EMISSIVITY);
        assert!(paint - foil > 10.0, "label contrast {:.1} K", paint - foil);
        // The labels exist and are printed only partly (characters and spaces).
        let (mut on, mut cells) = (0, 0);
        for line in 0..LINES {
            for cell in 0..CHARS_PER_LINE {
                let x = LABEL_X0 + (cell as f64 + 0.5 * CHAR_W / CHAR_PITCH) * CHAR_PITCH;
                let z = LABEL_Z_TOP - line as f64 * LINE_PITCH - 0.5 * CHAR_H;
                cells += 1;
                on += usize::from(facade_material(x, z).3 == SceneObject::Label);
            }
        }
        assert!(
            on > cells / 2 && on < cells,
            "{on} of {cells} character cells printed"
        );
    }

    /// The hash is deterministic and spreads the bricks over the whole ±0.4 K.
    #[test]
    fn bricks_vary_over_the_whole_spread() {
        let temps: Vec<f64> = (0..20)
            .flat_map(|c| (0..20).map(move |r| (c, r)))
            .map(|(c, r)| {
                let x = 0.5 * JOINT + JOINT + (c as f64) * (BRICK_W + JOINT) + 0.05;
                let z = JOINT + 0.02 + 2.0 * (r as f64) * (BRICK_H + JOINT);
                facade_material(x, z).0
            })
            .collect();
        let lo = temps.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = temps.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        assert!(hi - lo > 0.6, "bricks span {lo:.2}–{hi:.2} K");
        assert_eq!(facade_material(0.1, 2.0), facade_material(0.1, 2.0));
    }
}
