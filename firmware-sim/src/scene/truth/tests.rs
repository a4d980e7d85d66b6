//! Proves: the tracing camera is the thermal camera at 2× (as the joint layout builds its
//! K× camera); both scene writers write `truth/surface.ply` with the documented header and
//! N records of 7 f32, equal to [`surface_points`]; every point lies on a surface of its
//! layout, with a unit normal facing a camera; kelvin is the apparent temperature of the
//! surface hit (wall: ≈ 280.5 K paint, ≈ 289 K metal); one point per 4 mm cube, the first
//! in view order; the same bytes twice and the same points on 1 and 3 threads.
//! Does not prove the surface is complete (a point per visible cube): the grid's spacing
//! exceeds 4 mm at small image sizes, by design.
#![allow(clippy::unwrap_used, clippy::expect_used)]
use super::*;
use crate::scene::joint::{JointOptions, thermal_cam_from_world, write_joint_scene_set};
use crate::scene::objects::{RAD_X, RAD_Y, RAD_Z};
use crate::scene::response::ResponseEffects;
use crate::scene::{
    BOX_C, BOX_H, PIPE_R, PIPE_X, PIPE_YZ, SceneConfig, WALL_EDGE_X, WALL_METAL_EMISSIVITY,
    WALL_PAINT_EMISSIVITY, WALL_PIPE_Z, WALL_X, WALL_Y, WALL_Z, floor_temp_k, poses, scene_camera,
    wall_temp_k, write_scene_set_with,
};
use std::collections::HashSet;
use std::fs;
use std::path::PathBuf;

const W: u32 = 16;
const H: u32 = 12;
const VIEWS: usize = 4;
/// Distance from a surface a written (f32) point may have, metres.
const ON_SURFACE_M: f64 = 1e-4;

/// A `truth/surface.ply` read back: the header's vertex count and the records.
fn read_surface_ply(path: &Path) -> Vec<SurfacePoint> {
    let bytes = fs::read(path).unwrap_or_else(|e| panic!("{} should exist: {e}", path.display()));
    let end = b"end_header\n";
    let body_at = bytes
        .windows(end.len())
        .position(|w| w == end)
        .map(|i| i + end.len())
        .unwrap_or_else(|| panic!("{}: no end_header line", path.display()));
    let header = std::str::from_utf8(&bytes[..body_at]).expect("ASCII header");
    let n: usize = header
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .expect("an `element vertex N` line")
        .parse()
        .expect("a vertex count");
    assert!(
        [SceneLayout::Objects, SceneLayout::Wall, SceneLayout::Facade]
            .iter()
            .any(|&l| header == surface_ply_header(n, l)),
        "{}: expected exactly the documented header of a layout",
        path.display()
    );
    let region_line = header
        .lines()
        .find(|l| l.starts_with("comment region_m "))
        .expect("a region_m comment");
    let expected = [
        "ply",
        "format binary_little_endian 1.0",
        "comment s3tir truth surface: visible points of the simulated scene, world metres; \
         kelvin = apparent temperature (emissivity 1)",
        region_line,
        &format!("element vertex {n}"),
        "property float x",
        "property float y",
        "property float z",
        "property float nx",
        "property float ny",
        "property float nz",
        "property float kelvin",
        "end_header",
    ];
    assert_eq!(
        header.lines().collect::<Vec<_>>(),
        expected,
        "the header, line by line"
    );
    let body = &bytes[body_at..];
    assert_eq!(
        body.len(),
        28 * n,
        "{}: expected {n} records of 7 f32 (28 bytes) after the header",
        path.display()
    );
    body.chunks_exact(28)
        .map(|r| {
            let f = |i: usize| f32::from_le_bytes(r[4 * i..4 * i + 4].try_into().unwrap());
            SurfacePoint {
                position_m: [f(0), f(1), f(2)],
                normal: [f(3), f(4), f(5)],
                kelvin: f(6),
            }
        })
        .collect()
}

fn cfg(dir: PathBuf) -> SceneConfig {
    SceneConfig {
        out_dir: dir,
        views: VIEWS,
        width_px: W,
        height_px: H,
        seed: 7,
    }
}

fn v(p: [f32; 3]) -> DVec3 {
    DVec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
}

/// The apparent temperature (emissivity 1) of a grey body at `temp_k`, ε `emissivity`.
fn apparent_k(emissivity: f64, temp_k: f64) -> f64 {
    static RADIOMETRY: std::sync::OnceLock<Radiometry> = std::sync::OnceLock::new();
    let r = RADIOMETRY.get_or_init(Radiometry::new);
    r.temperature_k(r.apparent_radiance(emissivity, temp_k, ENV_K))
}

/// Which Objects surface `p` lies on (within [`ON_SURFACE_M`]), if any.
fn objects_surface(p: DVec3) -> Option<&'static str> {
    let tol = ON_SURFACE_M;
    let radial = ((p.y - PIPE_YZ.0).powi(2) + (p.z - PIPE_YZ.1).powi(2)).sqrt();
    let lo = BOX_C - DVec3::splat(BOX_H);
    let hi = BOX_C + DVec3::splat(BOX_H);
    let in_box = (0..3).all(|k| p[k] >= lo[k] - tol && p[k] <= hi[k] + tol);
    let on_box_face = (0..3).any(|k| (p[k] - lo[k]).abs() < tol || (p[k] - hi[k]).abs() < tol);
    if p.z.abs() < tol && p.x.abs() <= 2.0 + tol && p.y.abs() <= 2.0 + tol {
        Some("ground")
    } else if (radial - PIPE_R).abs() < tol && p.x >= PIPE_X.0 - tol && p.x <= PIPE_X.1 + tol {
        Some("pipe side")
    } else if ((p.x - PIPE_X.0).abs() < tol || (p.x - PIPE_X.1).abs() < tol)
        && radial <= PIPE_R + tol
    {
        Some("pipe cap")
    } else if in_box && on_box_face {
        Some("box")
    } else if (p.x - RAD_X).abs() < tol
        && p.y >= RAD_Y.0 - tol
        && p.y <= RAD_Y.1 + tol
        && p.z >= RAD_Z.0 - tol
        && p.z <= RAD_Z.1 + tol
    {
        Some("radiator")
    } else {
        None
    }
}

/// Checks shared by both layouts: count, normals facing a camera, kelvin range, one point
/// per cube, and the file equals [`surface_points`].
fn check_common(
    what: &str,
    points: &[SurfacePoint],
    layout: SceneLayout,
    cam: &CameraModel,
    poses: &[Rigid3],
) {
    assert!(
        !points.is_empty(),
        "{what}: expected surface points, got none"
    );
    let expected = surface_points(layout, cam, poses).unwrap();
    assert!(
        points == expected.as_slice(),
        "{what}: the file should hold exactly surface_points() ({} points), has {}",
        expected.len(),
        points.len()
    );
    let eyes: Vec<DVec3> = poses.iter().map(|p| p.inverse().translation_m).collect();
    let mut cells = HashSet::new();
    for (i, q) in points.iter().enumerate() {
        let (p, n) = (v(q.position_m), v(q.normal));
        assert!(
            (n.length() - 1.0).abs() < 1e-5,
            "{what}: point {i} normal {n} should be a unit vector"
        );
        assert!(
            eyes.iter().any(|&e| (e - p).dot(n) > 0.0),
            "{what}: point {i} at {p}: normal {n} should face one of the cameras"
        );
        assert!(
            (270.0..=340.0).contains(&q.kelvin),
            "{what}: point {i} at {p}: expected 270..340 K, got {} K",
            q.kelvin
        );
        assert!(
            cells.insert(surface_cell(q.position_m)),
            "{what}: point {i} at {p} shares its 4 mm cube {:?} with an earlier point",
            surface_cell(q.position_m)
        );
    }
}

#[test]
fn surface_camera_is_the_thermal_camera_at_twice_the_resolution() {
    let cam = scene_camera(W, H);
    let s = surface_camera(&cam).unwrap();
    let joint = JointOptions {
        rgb_scale: 2,
        low_light: false,
    }
    .rgb_camera(W, H)
    .unwrap();
    for (other, name) in [
        (scene_camera(2 * W, 2 * H), "scene_camera(2W, 2H)"),
        (joint, "the joint layout's 2x RGB camera"),
    ] {
        assert_eq!(
            (s.width_px, s.height_px),
            (other.width_px, other.height_px),
            "size vs {name}"
        );
        let (a, b) = (s.intrinsics, other.intrinsics);
        for (x, y, p) in [
            (a.fx, b.fx, "fx"),
            (a.fy, b.fy, "fy"),
            (a.cx, b.cx, "cx"),
            (a.cy, b.cy, "cy"),
        ] {
            assert!((x - y).abs() < 1e-12, "{p}: {x} should equal {name}'s {y}");
        }
    }
    assert_eq!(
        (s.intrinsics.cx, s.intrinsics.cy),
        (2.0 * cam.intrinsics.cx + 0.5, 2.0 * cam.intrinsics.cy + 0.5),
        "c' = 2c + 1/2"
    );
}

/// The facade's truth is its fine texture: points on joints, bricks, the pipe, the cabinet
/// and its labels, each at its own apparent temperature.
#[test]
fn facade_scene_writes_its_texture_as_truth() {
    let tmp = tempfile::tempdir().unwrap();
    let c = cfg(tmp.path().join("facade"));
    write_scene_set_with(
        &c,
        SceneLayout::Facade,
        ResponseEffects::default(),
        &mut |_, _| {},
    )
    .unwrap();
    let points = read_surface_ply(&c.out_dir.join(SURFACE_TRUTH_FILE));
    let cam = scene_camera(W, H);
    let poses = poses(SceneLayout::Facade, VIEWS);
    check_common("facade", &points, SceneLayout::Facade, &cam, &poses);
    let mut seen = std::collections::BTreeSet::new();
    for q in &points {
        let p = v(q.position_m);
        seen.insert(format!(
            "{:?}",
            crate::scene::facade::facade_material(p.x, p.z).3
        ));
    }
    for object in ["Brick", "Mortar", "SurfacePipe", "Cabinet"] {
        assert!(
            seen.contains(object),
            "the facade's truth holds {object} points (seen: {seen:?})"
        );
    }
}

#[test]
fn wall_scene_writes_the_wall_with_its_apparent_temperatures() {
    let tmp = tempfile::tempdir().unwrap();
    let c = cfg(tmp.path().join("wall"));
    write_scene_set_with(
        &c,
        SceneLayout::Wall,
        ResponseEffects::default(),
        &mut |_, _| {},
    )
    .unwrap();
    let points = read_surface_ply(&c.out_dir.join(SURFACE_TRUTH_FILE));
    let cam = scene_camera(W, H);
    let poses = poses(SceneLayout::Wall, VIEWS);
    check_common("wall", &points, SceneLayout::Wall, &cam, &poses);
    let (mut paint, mut metal) = (Vec::new(), Vec::new());
    for (i, q) in points.iter().enumerate() {
        let p = v(q.position_m);
        assert!(
            (p.y - WALL_Y).abs() < ON_SURFACE_M
                && p.x >= WALL_X.0 - ON_SURFACE_M
                && p.x <= WALL_X.1 + ON_SURFACE_M
                && p.z >= WALL_Z.0 - ON_SURFACE_M
                && p.z <= WALL_Z.1 + ON_SURFACE_M,
            "wall: point {i} at {p} should lie on the wall y = {WALL_Y}"
        );
        assert!(
            v(q.normal).distance(DVec3::NEG_Y) < 1e-6,
            "wall: point {i}: normal {:?} should be -y (toward the cameras)",
            q.normal
        );
        let eps = if p.x < WALL_EDGE_X {
            WALL_PAINT_EMISSIVITY
        } else {
            WALL_METAL_EMISSIVITY
        };
        let want = apparent_k(eps, wall_temp_k(p.x, p.z));
        assert!(
            (f64::from(q.kelvin) - want).abs() < 2e-3,
            "wall: point {i} at {p}: expected apparent {want:.3} K, got {} K",
            q.kelvin
        );
        if (p.z - WALL_PIPE_Z).abs() > 0.5 && (p.x - WALL_EDGE_X).abs() > 0.05 {
            if p.x < WALL_EDGE_X {
                &mut paint
            } else {
                &mut metal
            }
            .push(f64::from(q.kelvin));
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    assert!(
        paint.len() > 20 && metal.len() > 20,
        "wall: expected > 20 points each on paint and metal away from the pipe, got {} and {}",
        paint.len(),
        metal.len()
    );
    let (pk, mk) = (mean(&paint), mean(&metal));
    assert!(
        (pk - 280.5).abs() < 0.3 && (mk - 289.0).abs() < 0.3,
        "wall: expected ≈ 280.5 K on the paint and ≈ 289 K on the metal, got {pk:.3} and \
         {mk:.3} K"
    );
    let meta: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(c.out_dir.join("scene.json")).unwrap()).unwrap();
    assert_eq!(
        meta["truth_surface"]["path"], SURFACE_TRUTH_FILE,
        "scene.json truth_surface.path"
    );
    assert_eq!(
        meta["truth_surface"]["points"],
        points.len(),
        "scene.json truth_surface.points should be the file's count"
    );
}

#[test]
fn objects_scene_writes_points_on_its_surfaces() {
    let tmp = tempfile::tempdir().unwrap();
    let c = cfg(tmp.path().join("objects"));
    write_scene_set_with(
        &c,
        SceneLayout::Objects,
        ResponseEffects::default(),
        &mut |_, _| {},
    )
    .unwrap();
    let points = read_surface_ply(&c.out_dir.join(SURFACE_TRUTH_FILE));
    let cam = scene_camera(W, H);
    let poses = poses(SceneLayout::Objects, VIEWS);
    check_common("objects", &points, SceneLayout::Objects, &cam, &poses);
    let mut counts: std::collections::BTreeMap<&str, usize> = Default::default();
    for (i, q) in points.iter().enumerate() {
        let p = v(q.position_m);
        let surface = objects_surface(p)
            .unwrap_or_else(|| panic!("objects: point {i} at {p} lies on no scene surface"));
        *counts.entry(surface).or_default() += 1;
        let want = match surface {
            "ground" => Some(apparent_k(0.95, floor_temp_k(p.x))),
            "box" => Some(apparent_k(if p.x < BOX_C.x { 0.95 } else { 0.12 }, 313.0)),
            _ => None,
        };
        if let Some(want) = want {
            assert!(
                (f64::from(q.kelvin) - want).abs() < 2e-3,
                "objects: {surface} point {i} at {p}: expected apparent {want:.3} K, got {} K",
                q.kelvin
            );
        }
    }
    for s in ["ground", "pipe side", "box", "radiator"] {
        assert!(
            counts.get(s).copied().unwrap_or(0) > 0,
            "objects: expected points on the {s}; per surface: {counts:?}"
        );
    }
}

#[test]
fn joint_scene_writes_the_surface_at_the_thermal_poses() {
    let tmp = tempfile::tempdir().unwrap();
    let c = cfg(tmp.path().join("joint"));
    let joint = JointOptions {
        rgb_scale: 2,
        low_light: false,
    };
    write_joint_scene_set(
        &c,
        SceneLayout::Wall,
        ResponseEffects::default(),
        &joint,
        &mut |_, _| {},
    )
    .unwrap();
    let points = read_surface_ply(&c.out_dir.join(SURFACE_TRUTH_FILE));
    let thermal: Vec<Rigid3> = poses(SceneLayout::Wall, VIEWS)
        .iter()
        .map(thermal_cam_from_world)
        .collect();
    check_common(
        "joint",
        &points,
        SceneLayout::Wall,
        &scene_camera(W, H),
        &thermal,
    );
    let meta: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(c.out_dir.join("scene.json")).unwrap()).unwrap();
    assert_eq!(
        meta["truth_surface"]["points"],
        points.len(),
        "joint scene.json truth_surface.points should be the file's count"
    );
    assert!(
        !c.out_dir.join("truth/surface.ply.tmp").exists(),
        "the temporary file should be renamed away"
    );
}

#[test]
fn deduplication_keeps_the_first_hit_in_view_order() {
    let cam = scene_camera(W, H);
    let p = poses(SceneLayout::Objects, VIEWS);
    let one = surface_points(SceneLayout::Objects, &cam, &p[..1]).unwrap();
    let twice = surface_points(SceneLayout::Objects, &cam, &[p[0], p[0]]).unwrap();
    assert!(
        one == twice,
        "a view seen twice should add no point: {} vs {}",
        one.len(),
        twice.len()
    );
    let two = surface_points(SceneLayout::Objects, &cam, &p[..2]).unwrap();
    assert!(
        two.len() > one.len() && two[..one.len()] == one[..],
        "view 1's points should follow view 0's unchanged ({} then {})",
        one.len(),
        two.len()
    );
    // Finer than 4 mm on the wall (320×240 → 640×480 rays, ≈ 2.7 mm apart at 1.6 m): cubes
    // merge rays within a view, and still hold one point each.
    let fine = surface_points(
        SceneLayout::Wall,
        &scene_camera(320, 240),
        &poses(SceneLayout::Wall, 1),
    )
    .unwrap();
    let cells: HashSet<_> = fine.iter().map(|q| surface_cell(q.position_m)).collect();
    assert!(
        fine.len() < 640 * 480 && cells.len() == fine.len(),
        "fine grid: expected fewer points than the 307200 rays, one per cube; got {} points \
         in {} cubes",
        fine.len(),
        cells.len()
    );
}

#[test]
fn output_is_the_same_twice_and_on_any_thread_count() {
    let tmp = tempfile::tempdir().unwrap();
    let cam = scene_camera(W, H);
    let p = poses(SceneLayout::Objects, VIEWS);
    let (a, b) = (tmp.path().join("a.ply"), tmp.path().join("b.ply"));
    let na = write_surface_truth(&a, SceneLayout::Objects, &cam, &p).unwrap();
    let nb = write_surface_truth(&b, SceneLayout::Objects, &cam, &p).unwrap();
    assert_eq!(na, nb, "point counts of two runs");
    assert!(
        fs::read(&a).unwrap() == fs::read(&b).unwrap(),
        "two runs should write identical bytes"
    );
    let on = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| surface_points(SceneLayout::Objects, &cam, &p).unwrap())
    };
    assert!(
        on(1) == on(3),
        "1 and 3 threads should give the same points"
    );
}
