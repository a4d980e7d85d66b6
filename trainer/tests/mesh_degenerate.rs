//! `s3tir-train mesh` on inputs it cannot mesh, and on a tight memory budget: the synthetic wall
//! scene (`dataset::synth`), its primitives initialised as a run starts and made opaque, meshed
//! through
//! `mesh::run::mesh_views` on the CPU backend.
//!
//! Proves: a model with no opaque surface, a single view, a volume with no surface, and an
//! explicit voxel that does not fit the budget each give their own clear error (no panic);
//! the automatic voxel grows until the volume fits the budget; the wall meshes into a surface
//! at the wall's depth. The command-level guarantee that a failed mesh leaves an existing file
//! untouched is in `tests/tests/mesh_fwsim.rs` (it needs the binary).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use s3tir_trainer::camera::PinholeCamera;
use s3tir_trainer::dataset::synth::{self, SynthConfig};
use s3tir_trainer::dataset::{Dataset, LoadOptions, ThermalRange};
use s3tir_trainer::mesh::MeshError;
use s3tir_trainer::mesh::run::{MeshOptions, mesh_views};
use s3tir_trainer::primitive::Primitives;
use s3tir_trainer::train::{CpuBackend, TrainConfig, Trainer};

struct Scene {
    _tmp: tempfile::TempDir,
    prims: Primitives<f32>,
    cameras: Vec<PinholeCamera>,
    range: ThermalRange,
}

fn scene() -> Scene {
    let tmp = tempfile::tempdir().unwrap();
    let data_dir = tmp.path().join("scene");
    let cfg = SynthConfig {
        views: 6,
        points: 3000,
        ..SynthConfig::default()
    };
    synth::write_scene(&data_dir, &cfg).unwrap();
    let data = Dataset::load(&data_dir, &LoadOptions::default()).unwrap();
    let range = data.range.unwrap();
    let cameras = data.views.iter().map(|v| v.camera).collect();
    let mut c = TrainConfig::new(data_dir);
    c.budget = 3000;
    let t = Trainer::new(c, data, CpuBackend::default(), &tmp.path().join("run")).unwrap();
    // Initialised primitives start at opacity 0.1; a trained wall is opaque.
    let mut prims = t.prims;
    prims.opacity_logits.iter_mut().for_each(|o| *o = 4.0);
    Scene {
        prims,
        cameras,
        range,
        _tmp: tmp,
    }
}

fn mesh(
    s: &Scene,
    prims: &Primitives<f32>,
    cams: &[PinholeCamera],
    o: &MeshOptions,
) -> Result<s3tir_trainer::mesh::Mesh, MeshError> {
    mesh_views(
        prims,
        cams,
        &s.range,
        o,
        &mut CpuBackend::default(),
        &mut |_, _, _| {},
    )
    .map(|(m, _)| m)
}

#[test]
fn degenerate_inputs_give_clear_errors_and_the_wall_meshes() {
    let s = scene();
    let o = MeshOptions::default();

    // The wall itself meshes.
    let (m, stats) = mesh_views(
        &s.prims,
        &s.cameras,
        &s.range,
        &o,
        &mut CpuBackend::default(),
        &mut |_, _, _| {},
    )
    .unwrap();
    assert!(
        m.triangles.len() > 100,
        "the synthetic wall should mesh into a surface, got {} triangles",
        m.triangles.len()
    );
    assert!(
        m.kelvin.iter().all(|k| k.is_finite()),
        "every vertex of the wall should carry a temperature"
    );
    assert!(stats.volume_bytes as u64 <= o.memory_budget_bytes);

    // No opaque surface: every primitive transparent.
    let mut clear = s.prims.clone();
    clear.opacity_logits.iter_mut().for_each(|o| *o = -30.0);
    let e = mesh(&s, &clear, &s.cameras, &o).unwrap_err();
    assert!(
        matches!(e, MeshError::NoOpaqueSurface { views: 6, .. }),
        "a transparent model should fail with NoOpaqueSurface over its 6 views, got {e}"
    );
    assert!(
        e.to_string().contains("alpha 0.5"),
        "the message should name the alpha threshold: {e}"
    );

    // A single view.
    let e = mesh(&s, &s.prims, &s.cameras[..1], &o).unwrap_err();
    assert!(
        matches!(
            e,
            MeshError::TooFewViews {
                views: 1,
                required: 2
            }
        ),
        "one view should fail with TooFewViews, got {e}"
    );

    // A volume with no surface: no voxel is observed enough.
    let strict = MeshOptions {
        min_weight: 1e6,
        ..o.clone()
    };
    let e = mesh(&s, &s.prims, &s.cameras, &strict).unwrap_err();
    assert!(
        matches!(e, MeshError::EmptyVolume { .. }),
        "an unreachable --min-weight should leave an empty volume, got {e}"
    );

    // An explicit voxel that does not fit the budget is refused, not changed.
    let tiny = MeshOptions {
        voxel_m: Some(0.0005),
        memory_budget_bytes: 1 << 20,
        ..o.clone()
    };
    let e = mesh(&s, &s.prims, &s.cameras, &tiny).unwrap_err();
    assert!(
        matches!(e, MeshError::OverBudget { .. }),
        "a 0.5 mm voxel in 1 MiB should be over budget, got {e}"
    );

    // The automatic voxel grows into a small budget.
    let small = MeshOptions {
        memory_budget_bytes: stats.volume_bytes as u64 / 2,
        ..o.clone()
    };
    let (m2, st2) = mesh_views(
        &s.prims,
        &s.cameras,
        &s.range,
        &small,
        &mut CpuBackend::default(),
        &mut |_, _, _| {},
    )
    .unwrap();
    assert!(
        st2.volume_bytes <= stats.volume_bytes / 2 && st2.voxel_m > stats.voxel_m,
        "in half the default volume's {} bytes the voxel should grow from {} m and the volume \
         fit, got {} m and {} bytes",
        stats.volume_bytes,
        stats.voxel_m,
        st2.voxel_m,
        st2.volume_bytes
    );
    assert!(
        !m2.triangles.is_empty(),
        "the coarser volume still holds the wall"
    );
}
