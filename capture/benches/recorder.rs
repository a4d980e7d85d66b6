//! Criterion benchmark of the recorder's hot path on the Boson 640×512 Y16 frame and a 1080p
//! MJPEG frame: parse + drop detection + pairing + MCAP write (LZ4 chunks) per frame. The
//! sustained whole-run figure as a ratio to real time is `s3tir-capture bench`.
#![allow(clippy::unwrap_used, missing_docs)]

use criterion::{Criterion, criterion_group, criterion_main};
use s3tir_capture::backend::synth::{Script, SynthRig, ThermalSynth};
use s3tir_capture::frame::StreamKind;
use s3tir_capture::session::pairing::{DEFAULT_TOLERANCE_NS, PairingMode};
use s3tir_capture::session::pipeline::Pipeline;
use s3tir_capture::session::{SessionInfo, SessionWriter};

fn recorder(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let mut rig = SynthRig::new(
        ThermalSynth::boson640(),
        Some((1920, 1080, 30.0)),
        Script::default(),
        0,
    )
    .unwrap();
    let mut thermal = None;
    let mut rgb = None;
    while thermal.is_none() || rgb.is_none() {
        let b = rig.next_buffer().unwrap();
        match b.stream {
            StreamKind::Thermal => thermal = Some(b),
            StreamKind::Rgb => rgb = Some(b),
        }
    }
    let mut w = SessionWriter::create(&dir.path().join("b.mcap"), &SessionInfo::default()).unwrap();
    let mut pipe = Pipeline::new(PairingMode::Nearest {
        tolerance_ns: DEFAULT_TOLERANCE_NS,
    });
    let mut seq = 0u32;
    for (name, frame) in [
        ("boson640_y16", thermal.unwrap()),
        ("rgb1080p_mjpeg", rgb.unwrap()),
    ] {
        c.bench_function(&format!("record_{name}"), |b| {
            b.iter(|| {
                let mut raw = frame.clone();
                seq += 1;
                raw.sequence = seq;
                raw.monotonic_ns = u64::from(seq) * 16_666_667;
                for r in pipe.push("bench", &raw, 0).unwrap() {
                    w.write(&r).unwrap();
                }
            })
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = recorder
}
criterion_main!(benches);
