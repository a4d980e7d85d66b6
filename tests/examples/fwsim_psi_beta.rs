//! Study tool for the capacity stage's Ψ_β criterion: reads the exact Ψ_β / alpha G-buffers
//! (`gbuffers/<view>_{psi_beta,alpha}.npy`) a `s3tir-train` run wrote for the held-out views of a
//! `s3tir-firmware-sim scene` dataset and prints the mean Ψ_β over the same ground-truth masks
//! as `tests/tests/train_fwsim.rs` (box emissivity edge, pipe interior, floor stripe), plus the
//! rest of the box, both raw (what the test checks) and divided by alpha; then, from the run's
//! `checkpoint.json`, the median β and ω_low of the primitives by where their centre lies (box
//! painted half, within 3 cm of the emissivity edge, bare half; pipe hot, middle and cool
//! thirds; floor stripe; rest of the floor; radiator).
//!
//! With `wall` as fifth argument (a `scene --layout wall` dataset), the masks are the wall
//! layout's instead: emissivity edge (wall within 3 cm of the line x = `WALL_EDGE_X`), pipe
//! band (wall within σ/2 of the in-wall pipe's axis, on the paint, > 0.3 m from the line) and
//! the rest of the wall; the per-primitive table then groups by distance from the line and the band.
//!
//! `cargo run -p s3tir-tests --example fwsim_psi_beta -- RUN_DIR WIDTH HEIGHT VIEWS [wall]`
//! (`VIEWS`: the `--views` the scene was written with; the views are read from the G-buffer
//! names in `RUN_DIR/gbuffers`).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use s3tir_firmware_sim::scene::{
    self, BOX_C, BOX_H, FLOOR_PIPE_X, PIPE_R, PIPE_X, PIPE_YZ, SceneLayout, SceneObject,
    WALL_EDGE_X, WALL_PIPE_SIGMA, WALL_PIPE_Z,
};
use s3tir_trainer::checkpoint;
use s3tir_trainer::primitive::Primitives;
use s3tir_trainer::report::read_npy_f32;

/// Same mask parameters as `tests/tests/train_fwsim.rs`.
const EDGE_HALF_WIDTH_M: f64 = 0.03;
const STRIPE_HALF_WIDTH_M: f64 = 0.06;
const ERODE_PX: i64 = 2;
/// Same wall-layout mask parameters as `tests/tests/train_fwsim.rs`.
const WALL_PIPE_AWAY_FROM_EDGE_M: f64 = 0.3;

#[derive(Default)]
struct Acc {
    raw: f64,
    norm: f64,
    n: usize,
}

impl Acc {
    fn add(&mut self, beta: f32, alpha: f32) {
        self.raw += f64::from(beta);
        self.norm += f64::from(beta / alpha);
        self.n += 1;
    }
    fn show(&self) -> String {
        let n = self.n.max(1) as f64;
        format!(
            "{:.3} (/alpha {:.3}, {} px)",
            self.raw / n,
            self.norm / n,
            self.n
        )
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    assert!(
        args.len() == 4 || (args.len() == 5 && args[4] == "wall"),
        "usage: fwsim_psi_beta RUN_DIR WIDTH HEIGHT VIEWS [wall] (got {args:?})"
    );
    let layout = if args.len() == 5 {
        SceneLayout::Wall
    } else {
        SceneLayout::Objects
    };
    let run = PathBuf::from(&args[0]);
    let (width, height, views): (u32, u32, usize) = (
        args[1].parse().unwrap(),
        args[2].parse().unwrap(),
        args[3].parse().unwrap(),
    );
    let cam = scene::scene_camera(width, height);
    let poses = scene::poses(layout, views);
    let (w, h) = (width as usize, height as usize);
    let gb = run.join("gbuffers");
    let mut stems: Vec<String> = std::fs::read_dir(&gb)
        .unwrap()
        .filter_map(|e| {
            let name = e.ok()?.file_name().to_string_lossy().into_owned();
            name.strip_suffix("_psi_beta.npy").map(str::to_owned)
        })
        .collect();
    stems.sort();
    let names = match layout {
        SceneLayout::Objects => ["box edge", "pipe interior", "floor stripe", "box off-edge"],
        // Facade is never chosen here (the arguments give objects or wall).
        SceneLayout::Wall | SceneLayout::Facade => {
            ["wall edge", "pipe band", "(unused)", "rest of the wall"]
        }
    };
    let mut total: [Acc; 4] = Default::default();
    for stem in &stems {
        let k: usize = stem.parse().unwrap();
        let hits = scene::pixel_hits(layout, &cam, &poses[k]);
        let interior = |x: usize, y: usize, obj: SceneObject| {
            scene::is_interior(&hits, w, x, y, obj, ERODE_PX)
        };
        let (_, _, beta) = read_npy_f32(&gb.join(format!("{stem}_psi_beta.npy"))).unwrap();
        let (_, _, alpha) = read_npy_f32(&gb.join(format!("{stem}_alpha.npy"))).unwrap();
        let mut acc: [Acc; 4] = Default::default();
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                if alpha[i] <= 0.5 {
                    continue;
                }
                let slot = match hits[i] {
                    Some((SceneObject::Wall, pt)) => {
                        let from_edge = (pt.x - WALL_EDGE_X).abs();
                        if from_edge < EDGE_HALF_WIDTH_M {
                            0
                        } else if (pt.z - WALL_PIPE_Z).abs() < 0.5 * WALL_PIPE_SIGMA
                            && pt.x < WALL_EDGE_X - WALL_PIPE_AWAY_FROM_EDGE_M
                        {
                            1
                        } else {
                            3
                        }
                    }
                    Some((SceneObject::Box, pt)) if (pt.x - BOX_C.x).abs() < EDGE_HALF_WIDTH_M => 0,
                    Some((SceneObject::Box, _)) => 3,
                    Some((SceneObject::PipeSide, _)) if interior(x, y, SceneObject::PipeSide) => 1,
                    Some((SceneObject::Ground, pt))
                        if (pt.x - FLOOR_PIPE_X).abs() < STRIPE_HALF_WIDTH_M
                            && interior(x, y, SceneObject::Ground) =>
                    {
                        2
                    }
                    _ => continue,
                };
                acc[slot].add(beta[i], alpha[i]);
                total[slot].add(beta[i], alpha[i]);
            }
        }
        let line: Vec<String> = names
            .iter()
            .zip(&acc)
            .map(|(n, a)| format!("{n} {}", a.show()))
            .collect();
        println!("view {stem}: {}", line.join(", "));
    }
    let line: Vec<String> = names
        .iter()
        .zip(&total)
        .map(|(n, a)| format!("{n} {}", a.show()))
        .collect();
    println!("all held-out views: {}", line.join(", "));
    primitives_by_place(&run, layout);
}

/// Where a primitive's centre lies on the wall layout (world metres).
fn place_on_wall(p: [f64; 3]) -> &'static str {
    let [x, _, z] = p;
    let from_edge = (x - WALL_EDGE_X).abs();
    let on_band = (z - WALL_PIPE_Z).abs() < 0.5 * WALL_PIPE_SIGMA;
    match (from_edge, on_band) {
        (d, _) if d < 0.1 => "wall, within 10 cm of the emissivity edge",
        (d, true) if d > WALL_PIPE_AWAY_FROM_EDGE_M && x < WALL_EDGE_X => {
            "wall, pipe band on the paint > 0.3 m from the edge"
        }
        (d, false) if d > 0.4 => "wall, off the band, > 0.4 m from the edge",
        _ => "wall, elsewhere",
    }
}

/// Where a primitive's centre lies (world metres), for the per-primitive table.
fn place(p: [f64; 3]) -> &'static str {
    let [x, y, z] = p;
    let slack = 0.02;
    if (x - BOX_C.x).abs() <= BOX_H + slack
        && (y - BOX_C.y).abs() <= BOX_H + slack
        && (z - BOX_C.z).abs() <= BOX_H + slack
    {
        return match x - BOX_C.x {
            d if d.abs() < EDGE_HALF_WIDTH_M => "box, within 3 cm of the emissivity edge",
            d if d < 0.0 => "box, painted half",
            _ => "box, bare half",
        };
    }
    let r = (y - PIPE_YZ.0).hypot(z - PIPE_YZ.1);
    if x >= PIPE_X.0 - slack && x <= PIPE_X.1 + slack && r < PIPE_R + 0.05 {
        let third = (PIPE_X.1 - PIPE_X.0) / 3.0;
        return if x < PIPE_X.0 + third {
            "pipe, hot third"
        } else if x < PIPE_X.1 - third {
            "pipe, middle third"
        } else {
            "pipe, cool third"
        };
    }
    if z.abs() < 0.05 {
        return if (x - FLOOR_PIPE_X).abs() < 2.0 * STRIPE_HALF_WIDTH_M {
            "floor stripe"
        } else {
            "rest of the floor"
        };
    }
    if (x + 0.9).abs() < 0.05 {
        return "radiator";
    }
    "elsewhere"
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// Median β and ω_low of the run's primitives by [`place`].
fn primitives_by_place(run: &std::path::Path, layout: SceneLayout) {
    let place = match layout {
        SceneLayout::Objects => place,
        SceneLayout::Wall | SceneLayout::Facade => place_on_wall,
    };
    let ck = checkpoint::load(&run.join("checkpoint.json")).unwrap();
    let prims: Primitives<f32> = ck.primitives;
    let mut by: std::collections::BTreeMap<&str, (Vec<f64>, Vec<f64>)> = Default::default();
    for i in 0..prims.len() {
        let e = by.entry(place(prims.mean(i).map(f64::from))).or_default();
        e.0.push(f64::from(prims.beta(i).0));
        e.1.push(f64::from(prims.omega_low[i]));
    }
    println!(
        "primitives by centre (checkpoint of iteration {}):",
        ck.iteration
    );
    for (name, (beta, omega)) in by {
        println!(
            "  {name}: {} primitives, median β {:.2}, median ω_low {:.2}",
            beta.len(),
            median(beta),
            median(omega)
        );
    }
}
