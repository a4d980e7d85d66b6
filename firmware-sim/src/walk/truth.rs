//! The walk's truth (`--truth-dir DIR`): `truth.json` with both cameras and every frame's pose
//! ([`TruthFrame`], [`write_truth`]), and the maps beside it (`tags.toml`, `board.toml`).

use std::path::Path;

use glam::DVec3;
use s3tir_calib::{CameraModel, Rigid3};
use s3tir_capture::wire::simwire::StreamId;
use serde::Serialize;

use super::room::{scene_extent, walk_board_pose, walk_tags};
use super::{WalkKind, WalkRig, WalkSpec};
use crate::dataset::PoseJson;
use crate::error::SimError;
use crate::rig::Rig;
use crate::sensor::RgbProfile;

/// One frame in `truth.json`.
#[derive(Debug, Clone, Serialize)]
pub struct TruthFrame {
    pub stream: &'static str,
    pub sequence: u32,
    pub monotonic_ns: u64,
    pub ffc_frozen: bool,
    pub world_from_cam: PoseJson,
}

impl TruthFrame {
    /// A frame as sent; `monotonic_ns` is set from the wire stamp once the walk has run.
    pub(super) fn sent(
        stream: StreamId,
        sequence: u32,
        ffc_frozen: bool,
        world_from_cam: &Rigid3,
    ) -> Self {
        Self {
            stream: match stream {
                StreamId::Thermal => "thermal",
                StreamId::Rgb => "rgb",
            },
            sequence,
            monotonic_ns: 0,
            ffc_frozen,
            world_from_cam: PoseJson::from(world_from_cam),
        }
    }
}

#[derive(Debug, Serialize)]
struct SceneJson {
    layout: &'static str,
    centre_m: [f64; 3],
    extent_m: f64,
}

#[derive(Debug, Serialize)]
struct TruthJson<'a> {
    format: &'static str,
    trajectory: &'static str,
    /// How the room's tags are made (`printed`: RGB only; `heated`: thermal too).
    tags: &'static str,
    /// `world_from_board` of the board standing in the room (`--walk-board`; its
    /// `board.toml` beside the truth), or null.
    board: Option<PoseJson>,
    seed: u64,
    duration_s: f64,
    thermal_profile: &'static str,
    thermal: CameraModel,
    rgb: Option<CameraModel>,
    rgb_from_thermal: PoseJson,
    scene: SceneJson,
    frames: &'a [TruthFrame],
}

/// Writes `dir/truth.json` atomically (module docs).
pub fn write_truth(
    dir: &Path,
    rig: &WalkRig,
    spec: &WalkSpec,
    frames: &[TruthFrame],
) -> Result<(), SimError> {
    let io = |what: &'static str| {
        let path = dir.to_path_buf();
        move |source| SimError::Io { path, what, source }
    };
    std::fs::create_dir_all(dir).map_err(io("create truth folder"))?;
    let rgb_from_thermal =
        Rig::new(rig.thermal, rig.rgb.unwrap_or_else(RgbProfile::hd720)).rgb_from_thermal;
    let (centre, extent) = if spec.kind == WalkKind::Board {
        // The board wave: the scene is the board (its own frame); board.toml beside the truth.
        let b = crate::board::BoardSpec::default();
        let toml = crate::dataset::board_toml(&b, crate::dataset::Polarity::Cooled);
        std::fs::write(dir.join("board.toml"), toml).map_err(io("write board.toml"))?;
        let (x0, y0, x1, y1) = b.extent_m();
        (
            DVec3::new((x0 + x1) / 2.0, (y0 + y1) / 2.0, 0.0),
            ((x1 - x0).powi(2) + (y1 - y0).powi(2)).sqrt(),
        )
    } else {
        if spec.room.board {
            // The board in the room: the poses stage's --board file.
            let toml = crate::dataset::board_toml(
                &crate::board::BoardSpec::default(),
                // Warmer than its surroundings: coated squares look colder (`Cooled`'s look).
                crate::dataset::Polarity::Cooled,
            );
            std::fs::write(dir.join("board.toml"), toml).map_err(io("write board.toml"))?;
        }
        // The room's AprilTags: the poses stage's --tags map.
        std::fs::write(
            dir.join("tags.toml"),
            super::fiducials::tags_toml(walk_tags()),
        )
        .map_err(io("write tags.toml"))?;
        scene_extent()
    };
    let doc = TruthJson {
        format: "s3tir-walk-truth/1",
        trajectory: spec.kind.name(),
        tags: spec.room.tags.name(),
        board: spec.room.board.then(|| PoseJson::from(&walk_board_pose())),
        seed: rig.seed,
        duration_s: spec.duration_s,
        thermal_profile: rig.thermal.name,
        thermal: rig.thermal.camera,
        rgb: rig.rgb.map(|p| p.camera),
        rgb_from_thermal: PoseJson::from(&rgb_from_thermal),
        scene: SceneJson {
            layout: if spec.kind == WalkKind::Board {
                "board"
            } else {
                "walk"
            },
            centre_m: centre.to_array(),
            extent_m: extent,
        },
        frames,
    };
    let text = serde_json::to_string_pretty(&doc).map_err(|source| SimError::Json {
        what: "truth.json",
        source,
    })?;
    let tmp = dir.join("truth.json.tmp");
    std::fs::write(&tmp, text).map_err(io("write truth.json"))?;
    std::fs::rename(&tmp, dir.join("truth.json")).map_err(io("rename truth.json"))
}
