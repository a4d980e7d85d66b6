//! Tests that cannot run on this machine skip visibly, and a machine that promises a capability
//! fails instead of skipping.
//!
//! A test that needs something a machine may lack (a camera, `spirv-val`, `/dev/full`,
//! `systemd-analyze`) calls [`skip`] and returns: the harness has no "skipped" state, so the
//! line `SKIPPED: …` goes straight to the process's stderr (past the harness's output capture)
//! and shows in `cargo test`'s output. `S3TIR_REQUIRE` lists the capabilities a machine has
//! (comma-separated, or `all`); `make test` sets the CI machine's, so a skip there that should
//! not happen (a package that failed to install) fails the run.

use std::io::Write as _;

/// The environment variable naming the capabilities that must not be skipped.
pub const REQUIRE_ENV: &str = "S3TIR_REQUIRE";

/// `capability` is in the `S3TIR_REQUIRE`-style list `required` (comma-separated names, or `all`).
pub fn is_required(capability: &str, required: Option<&str>) -> bool {
    required.is_some_and(|list| {
        list.split(',')
            .map(str::trim)
            .any(|c| c == capability || c == "all")
    })
}

/// A test cannot run because `capability` is missing (`why`): prints `SKIPPED: …` on stderr and
/// returns, or panics when `S3TIR_REQUIRE` says this machine has the capability.
///
/// # Panics
/// When the capability is required on this machine: that is a failed test, not a skip.
pub fn skip(capability: &str, why: &str) {
    skip_with(capability, why, std::env::var(REQUIRE_ENV).ok().as_deref());
}

/// [`skip`] against an explicit requirement list (`S3TIR_REQUIRE`'s value).
pub fn skip_with(capability: &str, why: &str, required: Option<&str>) {
    if is_required(capability, required) {
        panic!(
            "{capability} is required on this machine ({REQUIRE_ENV}={}) but the test cannot \
             run: {why}",
            required.unwrap_or_default()
        );
    }
    let _ = std::io::stderr().write_all(format!("SKIPPED ({capability}): {why}\n").as_bytes());
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_listed_capability_is_required_and_others_are_not() {
        assert!(is_required("spirv-val", Some("dev-full, spirv-val")));
        assert!(is_required("camera", Some("all")));
        assert!(!is_required("camera", Some("dev-full,spirv-val")));
        assert!(!is_required("spirv-val", None));
        assert!(
            !is_required("spirv", Some("spirv-val")),
            "names match whole, not by prefix"
        );
    }

    #[test]
    fn an_unlisted_capability_skips() {
        for required in [Some("dev-full"), None] {
            let skipped = std::panic::catch_unwind(|| {
                skip_with(
                    "example",
                    "this line is the skip test's own output",
                    required,
                );
            });
            assert!(
                skipped.is_ok(),
                "a capability not in S3TIR_REQUIRE={required:?} must skip, not fail"
            );
        }
    }

    #[test]
    #[should_panic(expected = "camera is required on this machine")]
    fn skipping_a_required_capability_fails() {
        skip_with("camera", "no /dev/video* device", Some("dev-full,camera"));
    }
}
