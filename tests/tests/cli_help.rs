//! Proves every s3tir binary is built by the workspace and explains itself: `--help` exits 0
//! and says what the tool does, and an unknown subcommand is refused (exit 2), never silently
//! accepted. Does NOT test what the subcommands do (each crate's tests do).
#![allow(clippy::unwrap_used)]

use std::process::Command;

use s3tir_tests::bin;

fn help(name: &str) -> String {
    let out = Command::new(bin(name)).arg("--help").output().unwrap();
    assert!(
        out.status.success(),
        "{name} --help exited {:?}",
        out.status
    );
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn every_binary_says_what_it_does() {
    let cases = [
        ("s3tir-capture", "Capture radiometric thermal"),
        ("s3tir-calib", "Calibrate a thermal + RGB camera rig"),
        ("s3tir-train", "S³-TIR thermal splatting"),
        ("s3tir-firmware-sim", "simulated s3tir rig"),
    ];
    for (name, purpose) in cases {
        let text = help(name);
        assert!(
            text.contains(purpose),
            "{name} --help lacks {purpose:?}:\n{text}"
        );
        assert!(text.contains("Usage:"), "{name} --help has no usage line");
    }
}

#[test]
fn unknown_subcommands_are_refused() {
    for name in ["s3tir-capture", "s3tir-train", "s3tir-firmware-sim"] {
        let out = Command::new(bin(name))
            .arg("no-such-subcommand")
            .output()
            .unwrap();
        assert_eq!(
            out.status.code(),
            Some(2),
            "{name} must reject an unknown subcommand"
        );
    }
    // s3tir-calib takes BOARD_DIR as its main argument: an unknown word is a folder that does
    // not exist, refused with an error naming it.
    let out = Command::new(bin("s3tir-calib"))
        .arg("no-such-subcommand")
        .env_remove("RUST_BACKTRACE")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "s3tir-calib must fail on a missing board folder"
    );
    assert!(
        err.contains("no-such-subcommand"),
        "the error must name the folder: {err}"
    );
}
