//! The steps [`super::session_to_dataset`] runs, one function each, in its order: the inputs
//! checked, the keyframes chosen and written, the fiducials found in them, the keyframes
//! registered (by the fiducials or by structure from motion), the scale, the thermal (and
//! RGB) views selected with every frame's decision, the dataset written. Each returns what
//! the later steps read.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::Instant;

use super::agreement::{self, TagAgreement};
use super::fiducials::{self, SeenTags, TagMap, TagPose, TagScale};
use super::frames::{self, FrameInfo, SessionScan, Stream};
use super::select::{self, FrameDecision, RgbView, ThermalView};
use super::{
    PosesError, PosesOptions, RigModels, StageTimes, attached_calibration, dataset, interp,
    rig_models, sfm,
};
use crate::model::calfile::CalibrationFile;
use crate::model::camera::CameraModel;
use crate::model::colmap::ColmapPoint;
use crate::model::geometry::Rigid3;
use crate::progress;

/// The inputs, checked before anything is written.
#[derive(Debug)]
pub(super) struct Inputs {
    pub(super) session: PathBuf,
    pub(super) scan: SessionScan,
    pub(super) rig: RigModels,
    /// `--with-rgb`: the camera of the posed RGB keyframes.
    pub(super) rgb_camera: Option<CameraModel>,
    /// One fiducial map: the tags' (world = the map's) or the board's (world = the board's).
    pub(super) tag_map: Option<TagMap>,
    /// What the fiducials are called in the report, in words and as a pose source.
    pub(super) fiducial: &'static str,
    pub(super) fiducial_source: &'static str,
    /// With a tag layout COLMAP may not be needed: checked when it is.
    pub(super) may_skip_colmap: bool,
}

/// The keyframes structure from motion (or the fiducials) pose, written to `workspace`.
#[derive(Debug)]
pub(super) struct Keyframes {
    pub(super) sfm_stream: Stream,
    pub(super) sfm_camera: CameraModel,
    /// The thermal candidates and the decisions of the frames left out.
    pub(super) candidates: (Vec<FrameInfo>, Vec<FrameDecision>),
    pub(super) keyframes: Vec<FrameInfo>,
    /// COLMAP's workspace (`OUT.partial/colmap`), the keyframes in its `images/`.
    pub(super) workspace: PathBuf,
    /// Registered keyframes needed (`--min-registered`, at least 5).
    pub(super) needed: usize,
}

/// The fiducials in the keyframes and the poses they give.
#[derive(Debug)]
pub(super) struct Seen {
    pub(super) tags: Vec<SeenTags>,
    /// PnP poses of the keyframes (the fast path), jumps dropped.
    pub(super) tag_posed: BTreeMap<u64, TagPose>,
    pub(super) jumps: BTreeSet<u64>,
    /// Enough keyframes are posed by the fiducials: no structure from motion.
    pub(super) fast_path: bool,
}

/// The registered keyframes, `(monotonic_ns, world_from_cam)`.
#[derive(Debug)]
pub(super) struct Registration {
    pub(super) pose_source: &'static str,
    pub(super) registered: Vec<(u64, Rigid3)>,
    pub(super) sfm_points: Vec<ColmapPoint>,
    /// Registered by structure from motion, not used (poses jumping from their neighbours').
    pub(super) sfm_jumps: Vec<u64>,
}

/// The world's scale and what the fiducials say about the model.
#[derive(Debug)]
pub(super) struct Scale {
    /// Scene depth for thinning: the SfM points, or the mapped tags on the fast path.
    pub(super) points: Vec<[f64; 3]>,
    pub(super) tag_agreement: Option<TagAgreement>,
    pub(super) tag_scale: Option<TagScale>,
    pub(super) metres_per_unit: Option<f64>,
    pub(super) scale_source: String,
}

/// The views the dataset holds and every frame's decision.
#[derive(Debug)]
pub(super) struct Views {
    pub(super) thermal: Vec<ThermalView>,
    pub(super) decisions: Vec<FrameDecision>,
    pub(super) skipped: BTreeMap<String, usize>,
    pub(super) rgb: Vec<RgbView>,
}

impl Inputs {
    fn frames(&self, stream: Stream) -> &[FrameInfo] {
        match stream {
            Stream::Rgb => &self.scan.rgb,
            Stream::Thermal => &self.scan.thermal,
        }
    }

    /// What a fiducial is called in a frame's decision: board squares or tags.
    fn units(&self, opts: &PosesOptions) -> &'static str {
        if opts.board.is_some() {
            "squares"
        } else {
            "tags"
        }
    }
}

/// Scans the session and checks everything given (calibration, `--with-rgb`, fiducials,
/// COLMAP when it will run) before anything is written.
pub(super) fn check_inputs(
    session: &Path,
    cal: Option<&CalibrationFile>,
    opts: &PosesOptions,
    times: &mut StageTimes,
) -> Result<Inputs, PosesError> {
    let t = Instant::now();
    let scan = frames::scan_session(session, progress::or_silent(&opts.progress))?;
    times.scan_s = t.elapsed().as_secs_f64();
    if scan.thermal.is_empty() {
        return Err(PosesError::Nothing {
            path: session.to_path_buf(),
            reason: "no readable thermal frame".into(),
        });
    }
    let attached;
    let cal = match cal {
        Some(c) => c,
        None => {
            attached = attached_calibration(&scan)?;
            &attached
        }
    };
    let rig = rig_models(cal, &scan)?;
    // `--with-rgb` needs RGB frames: refused before anything is written (dataset module docs).
    let rgb_camera = match (opts.with_rgb, rig.rgb) {
        (false, _) => None,
        (true, Some((camera, _))) if !scan.rgb.is_empty() => Some(camera),
        (true, _) => {
            return Err(PosesError::Nothing {
                path: session.to_path_buf(),
                reason: "--with-rgb asks for the posed RGB keyframes, but the session records no (readable) RGB frame: a thermal-only session gives a thermal dataset, pose it without --with-rgb".into(),
            });
        }
    };
    let tag_map = fiducial_map(opts)?;
    let (fiducial, fiducial_source) = match &opts.board {
        Some(_) => ("the board", "board"),
        None => ("AprilTags", "apriltags"),
    };
    let may_skip_colmap = tag_map
        .as_ref()
        .is_some_and(|m| m.has_layout() && opts.tag_poses);
    if opts.user_model.is_none() && !may_skip_colmap {
        sfm::check_colmap(&opts.colmap)?;
    }
    Ok(Inputs {
        session: session.to_path_buf(),
        scan,
        rig,
        rgb_camera,
        tag_map,
        fiducial,
        fiducial_source,
        may_skip_colmap,
    })
}

/// The one fiducial map: `--tags` or `--board`, never both (their worlds differ).
fn fiducial_map(opts: &PosesOptions) -> Result<Option<TagMap>, PosesError> {
    match (&opts.tags, &opts.board) {
        (Some(tags), Some(board)) => Err(PosesError::Tags {
            path: tags.clone(),
            reason: format!(
                "give either an AprilTag map or the board ({}), not both: their worlds differ",
                board.path.display()
            ),
        }),
        (Some(tags), None) => Ok(Some(TagMap::read(tags)?)),
        (None, Some(board)) => Ok(Some(board.as_tag_map())),
        (None, None) => Ok(None),
    }
}

/// Picks the stream structure from motion runs on (RGB when there is RGB), the thermal
/// candidates and the keyframes, and writes the keyframes into COLMAP's workspace in `out`.
pub(super) fn choose_keyframes(
    inputs: &Inputs,
    out: &Path,
    opts: &PosesOptions,
    times: &mut StageTimes,
) -> Result<Keyframes, PosesError> {
    let t = Instant::now();
    let sfm_stream = if inputs.rig.rgb.is_some() && !inputs.scan.rgb.is_empty() {
        Stream::Rgb
    } else {
        Stream::Thermal
    };
    let sfm_frames = inputs.frames(sfm_stream);
    let mut candidates = select::thermal_candidates(&inputs.scan.thermal, opts);
    if sfm_stream == Stream::Rgb {
        select::fit_keyframe_budget(&mut candidates, opts.max_keyframes / 2);
    }
    let keyframes = match sfm_stream {
        // The RGB frames around each thermal candidate: its pose is interpolated over one RGB
        // period, not across a hand's jitter.
        Stream::Rgb => select::keyframes_near(sfm_frames, &candidates.0, opts.max_sync_s, opts),
        Stream::Thermal => select::keyframes(sfm_frames, opts),
    };
    times.keyframes_s = t.elapsed().as_secs_f64();
    if keyframes.len() < 5 {
        return Err(PosesError::TooFewRegistered {
            registered: 0,
            keyframes: keyframes.len(),
            needed: 5,
            workspace: out.join("colmap"),
        });
    }
    let sfm_camera = match (sfm_stream, inputs.rig.rgb) {
        (Stream::Rgb, Some((rgb, _))) => rgb,
        _ => inputs.rig.thermal,
    };
    let workspace = out.join("colmap");
    frames::write_keyframes(
        &inputs.session,
        sfm_stream,
        &keyframes,
        &workspace.join("images"),
    )?;
    let needed = ((keyframes.len() as f64 * opts.min_registered).ceil() as usize).max(5);
    Ok(Keyframes {
        sfm_stream,
        sfm_camera,
        candidates,
        keyframes,
        workspace,
        needed,
    })
}

/// AprilTags (or the board) in the keyframes: PnP poses (the fast path) and, for COLMAP's
/// world, the scale.
pub(super) fn find_fiducials(
    inputs: &Inputs,
    keys: &Keyframes,
    opts: &PosesOptions,
    times: &mut StageTimes,
) -> Result<Seen, PosesError> {
    let t = Instant::now();
    let images = keys.workspace.join("images");
    let tags = match (&inputs.tag_map, &opts.board) {
        (Some(_), Some(board)) => {
            board.detect_in_keyframes(&images, keys.sfm_stream, &keys.keyframes)?
        }
        (Some(m), None) => fiducials::detect_in_keyframes(
            &images,
            keys.sfm_stream,
            &keys.keyframes,
            m.has_layout().then(|| m.corners.keys().copied().collect()),
        )?,
        (None, _) => Vec::new(),
    };
    let mut tag_posed: BTreeMap<u64, TagPose> = match &inputs.tag_map {
        Some(m) if inputs.may_skip_colmap && opts.user_model.is_none() => tags
            .iter()
            .filter_map(|s| {
                Some((
                    s.monotonic_ns,
                    fiducials::pnp(m, &keys.sfm_camera, &s.tags)?,
                ))
            })
            .collect(),
        _ => BTreeMap::new(),
    };
    let jumps: BTreeSet<u64> = fiducials::drop_jumps(&mut tag_posed).into_iter().collect();
    times.tags_s = t.elapsed().as_secs_f64();
    let fast_path = !tag_posed.is_empty() && tag_posed.len() >= keys.needed;
    if inputs.may_skip_colmap && opts.user_model.is_none() && !fast_path {
        tracing::info!(
            posed = tag_posed.len(),
            keyframes = keys.keyframes.len(),
            needed = keys.needed,
            "too few keyframes are posed by {}: structure from motion runs",
            inputs.fiducial
        );
    }
    Ok(Seen {
        tags,
        tag_posed,
        jumps,
        fast_path,
    })
}

/// The keyframes' poses: the fiducials' on the fast path, else a COLMAP model (the user's
/// or one COLMAP builds now); fails below `needed` registered keyframes.
pub(super) fn register_keyframes(
    inputs: &Inputs,
    keys: &Keyframes,
    seen: &Seen,
    opts: &PosesOptions,
    times: &mut StageTimes,
) -> Result<Registration, PosesError> {
    let reg = if seen.fast_path {
        Registration {
            pose_source: inputs.fiducial_source,
            registered: seen
                .tag_posed
                .iter()
                .map(|(t, p)| (*t, p.world_from_cam))
                .collect(),
            sfm_points: Vec::new(),
            sfm_jumps: Vec::new(),
        }
    } else {
        structure_from_motion(inputs, keys, opts, times)?
    };
    if reg.registered.len() < keys.needed {
        return Err(PosesError::TooFewRegistered {
            registered: reg.registered.len(),
            keyframes: keys.keyframes.len(),
            needed: keys.needed,
            workspace: keys.workspace.clone(),
        });
    }
    Ok(reg)
}

/// The keyframes registered in a COLMAP model (`--poses DIR`, or COLMAP run on the
/// workspace), poses that jump from their neighbours' dropped.
fn structure_from_motion(
    inputs: &Inputs,
    keys: &Keyframes,
    opts: &PosesOptions,
    times: &mut StageTimes,
) -> Result<Registration, PosesError> {
    let model = match &opts.user_model {
        Some(dir) => crate::model::colmap::read_model(dir).map_err(|source| PosesError::Model {
            path: dir.clone(),
            source,
        })?,
        None => {
            if inputs.may_skip_colmap {
                sfm::check_colmap(&opts.colmap)?;
            }
            let n = keys.keyframes.len();
            sfm::run_colmap(&keys.workspace, &keys.sfm_camera, n, opts, times)?
        }
    };
    let pose_source = if opts.user_model.is_some() {
        "user model"
    } else {
        "colmap"
    };
    let mut registered = sfm::registered_keyframes(&model, inputs.frames(keys.sfm_stream));
    let positions: Vec<[f64; 3]> = model.points.iter().map(|p| p.position_m).collect();
    let sfm_jumps = sfm::drop_jumps(&mut registered, &positions);
    if !sfm_jumps.is_empty() {
        tracing::warn!(
            dropped = sfm_jumps.len(),
            registered = registered.len(),
            "registered keyframes whose poses jump from their neighbours' in time are not used"
        );
    }
    Ok(Registration {
        pose_source,
        registered,
        sfm_points: model.points,
        sfm_jumps,
    })
}

/// The registered poses on the capture clock. With RGB, a thermal frame is interpolated only
/// between its own bracketing keyframes (step 2): across a missing one, a hand's roll makes
/// the slerp wrong by degrees (2.3° on the simulated walk when a bracket keyframe saw too few
/// tags).
pub(super) fn track(keys: &Keyframes, reg: &Registration, opts: &PosesOptions) -> interp::Track {
    let max_gap_s = match keys.sfm_stream {
        Stream::Rgb => opts.max_gap_s.min(2.0 * opts.max_sync_s + 0.02),
        Stream::Thermal => opts.max_gap_s,
    };
    interp::Track::new(&reg.registered, max_gap_s)
}

/// The scene's depth points, the model checked against the tags' own PnP poses (module docs,
/// step 3), and the world's scale with where it comes from.
pub(super) fn scale(
    inputs: &Inputs,
    keys: &Keyframes,
    seen: &Seen,
    reg: &Registration,
    opts: &PosesOptions,
) -> Scale {
    let points: Vec<[f64; 3]> = if seen.fast_path {
        inputs
            .tag_map
            .iter()
            .flat_map(|m| m.corners.values().flatten().map(|p| p.to_array()))
            .collect()
    } else {
        reg.sfm_points.iter().map(|p| p.position_m).collect()
    };
    let tag_agreement = match &inputs.tag_map {
        Some(m) if !seen.fast_path => {
            let pnp: BTreeMap<u64, TagPose> = seen
                .tags
                .iter()
                .filter_map(|s| {
                    Some((
                        s.monotonic_ns,
                        fiducials::pnp(m, &keys.sfm_camera, &s.tags)?,
                    ))
                })
                .collect();
            agreement::rotation_agreement(&reg.registered, &pnp)
        }
        _ => None,
    };
    if let Some(a) = tag_agreement.as_ref().filter(|a| !a.agrees) {
        tracing::warn!(
            median_deg = a.median_deg,
            disagreeing = a.disagreeing,
            keyframes = a.keyframes,
            "the structure-from-motion model disagrees with the poses from {}",
            inputs.fiducial
        );
    }
    let tag_scale = match &inputs.tag_map {
        Some(m) if !seen.fast_path => {
            let by_time: BTreeMap<u64, Rigid3> = reg.registered.iter().copied().collect();
            fiducials::scale_from_tags(m, &keys.sfm_camera, &seen.tags, &by_time)
        }
        _ => None,
    };
    let (metres_per_unit, scale_source) =
        metres_per_unit(inputs, seen.fast_path, tag_scale.as_ref(), opts);
    Scale {
        points,
        tag_agreement,
        tag_scale,
        metres_per_unit,
        scale_source,
    }
}

/// Metres per world unit, and where that figure comes from in words: the fiducials' poses
/// (metric), `--metres-per-unit`, the tags' measured scale, or unknown (and why).
fn metres_per_unit(
    inputs: &Inputs,
    fast_path: bool,
    tag_scale: Option<&TagScale>,
    opts: &PosesOptions,
) -> (Option<f64>, String) {
    let fiducial = inputs.fiducial;
    match (fast_path, opts.metres_per_unit, tag_scale) {
        (true, _, _) => (
            Some(1.0),
            format!(
                "metric: the keyframes were posed by {fiducial} ({}; metres)",
                inputs.tag_map.as_ref().map_or(Path::new(""), |m| &m.path).display()
            ),
        ),
        (false, Some(m), _) => (Some(m), format!("given: {m} m per world unit")),
        (false, None, Some(ts)) => (
            Some(ts.metres_per_unit),
            format!(
                "measured from {fiducial} ({}): {:.5} m per world unit ({} {}, {} lengths, spread {:.2} %)",
                ts.method,
                ts.metres_per_unit,
                ts.tags,
                inputs.units(opts),
                ts.lengths,
                100.0 * ts.spread
            ),
        ),
        (false, None, None) => (
            None,
            match (inputs.rig.rgb, &inputs.tag_map) {
                (None, _) => {
                    "unknown: thermal-only structure from motion, world units are COLMAP's (no lever arm to scale)".to_owned()
                }
                (Some((_, e)), map) => format!(
                    "unknown: COLMAP's world has no metric scale{}, so the {:.3} m thermal-to-RGB lever arm is not applied (thermal centre = RGB centre); pass --metres-per-unit or --tags to apply it",
                    if map.is_some() {
                        " (no tag was seen in three registered keyframes with parallax)"
                    } else {
                        ""
                    },
                    e.translation_m.length()
                ),
            },
        ),
    }
}

/// The thermal views (interpolated, thinned, held out), the keyframes' decisions beside the
/// thermal frames', and with `--with-rgb` the RGB views; fails when no thermal frame is posed.
pub(super) fn select_views(
    inputs: &Inputs,
    keys: &Keyframes,
    seen: &Seen,
    reg: &Registration,
    track: &interp::Track,
    scale: &Scale,
    opts: &PosesOptions,
) -> Result<Views, PosesError> {
    // rgb_from_thermal with its translation in world units: world_from_thermal =
    // world_from_rgb(t) ∘ sfm_from_thermal.
    let units_per_metre = scale.metres_per_unit.map_or(0.0, |m| 1.0 / m);
    let sfm_from_thermal = match inputs.rig.rgb {
        Some((_, rgb_from_thermal)) => Rigid3::new(
            rgb_from_thermal.rotation,
            rgb_from_thermal.translation_m * units_per_metre,
        ),
        None => Rigid3::IDENTITY,
    };
    let (thermal, mut decisions, skipped) = select::thermal_views(
        &keys.candidates,
        track,
        &sfm_from_thermal,
        &scale.points,
        opts,
    );
    let registered_at: BTreeSet<u64> = reg.registered.iter().map(|r| r.0).collect();
    decisions.extend(keys.keyframes.iter().map(|k| FrameDecision {
        stream: keys.sfm_stream.name(),
        sequence: k.sequence,
        monotonic_ns: k.monotonic_ns,
        decision: keyframe_decision(inputs, seen, reg, &registered_at, k.monotonic_ns, opts),
    }));
    decisions.sort_by_key(|d| (d.monotonic_ns, d.stream));
    if thermal.iter().filter(|v| !v.held_out).count() == 0 {
        return Err(PosesError::Nothing {
            path: inputs.session.clone(),
            reason: format!(
                "no thermal frame falls between registered keyframes ({} registered of {})",
                reg.registered.len(),
                keys.keyframes.len()
            ),
        });
    }
    let rgb = rgb_views(inputs, track, &thermal, &mut decisions, opts);
    Ok(Views {
        thermal,
        decisions,
        skipped,
        rgb,
    })
}

/// A keyframe's decision: how it was posed, or why not.
fn keyframe_decision(
    inputs: &Inputs,
    seen: &Seen,
    reg: &Registration,
    registered_at: &BTreeSet<u64>,
    t_ns: u64,
    opts: &PosesOptions,
) -> String {
    let fiducial = inputs.fiducial;
    match (seen.fast_path, seen.tag_posed.get(&t_ns)) {
        (true, Some(p)) => format!(
            "keyframe: posed by {fiducial} ({} {}, corner rms {:.2} px)",
            p.tags,
            inputs.units(opts),
            p.rms_px
        ),
        (true, None) if seen.jumps.contains(&t_ns) => format!(
            "keyframe: not posed (its pose from {fiducial} is more than {}° or {} m off its neighbours' in time)",
            fiducials::OUTLIER_DEG,
            fiducials::OUTLIER_M
        ),
        (true, None) => format!(
            "keyframe: not posed (fewer than {} mapped {} found, or their corners fit no pose within {} px)",
            fiducials::MIN_PNP_TAGS,
            if opts.board.is_some() {
                "board squares"
            } else {
                "AprilTags"
            },
            fiducials::MAX_PNP_RMS_PX
        ),
        (false, _) if registered_at.contains(&t_ns) => {
            "keyframe: registered by structure from motion".into()
        }
        (false, _) if reg.sfm_jumps.contains(&t_ns) => format!(
            "keyframe: registered by structure from motion, not used (its pose is more than {}° or its centre more than the larger of its neighbours' distance apart and {} × the scene depth off their interpolation in time)",
            sfm::OUTLIER_DEG,
            sfm::OUTLIER_DEPTH
        ),
        (false, _) => "keyframe: not registered by structure from motion".into(),
    }
}

/// `--with-rgb`: the track's own keys, the poses the thermal views were interpolated from
/// (one world for both sets; dataset module docs), marked in the RGB keyframes' decisions.
fn rgb_views(
    inputs: &Inputs,
    track: &interp::Track,
    thermal: &[ThermalView],
    decisions: &mut [FrameDecision],
    opts: &PosesOptions,
) -> Vec<RgbView> {
    if inputs.rgb_camera.is_none() {
        return Vec::new();
    }
    let rgb = select::rgb_views(track, &inputs.scan.rgb, thermal, opts.max_sync_s);
    let written: BTreeMap<u64, bool> = rgb.iter().map(|v| (v.monotonic_ns, v.held_out)).collect();
    for d in decisions.iter_mut().filter(|d| d.stream == "rgb") {
        match written.get(&d.monotonic_ns) {
            Some(true) => d.decision.push_str("; held-out RGB view"),
            Some(false) => d.decision.push_str("; RGB view"),
            None => {}
        }
    }
    rgb
}

/// The dataset in `out`: the thermal views (and RGB views), the SfM points, the frames fresh
/// after a flat-field correction marked.
pub(super) fn write_dataset(
    out: &Path,
    inputs: &Inputs,
    views: &Views,
    reg: &Registration,
) -> Result<(), PosesError> {
    let fresh = dataset::fresh_after_ffc(&inputs.scan.thermal, &views.thermal);
    let rgb = inputs.rgb_camera.as_ref().map(|camera| dataset::RgbViews {
        camera,
        views: &views.rgb,
    });
    dataset::write(
        &inputs.session,
        out,
        &inputs.rig.thermal,
        &views.thermal,
        rgb,
        &reg.sfm_points,
        &fresh,
    )
}
