//! Errors of the capture layer, and how the workspace prints any error.
//!
//! Every variant names the device or file it is about.
//!
//! The workspace's rule for every error type (rerun's): an error's `Display` says only its
//! own level — what was being done, to which file or device — and a wrapped error is returned
//! from `source()` (`#[source]`), never also interpolated into the message. Each fact is then
//! held by exactly one level of the chain. Text for a person (a log line, a `reason` string, a
//! report or JSON warning, a binary's last line) is the whole chain, built with [`Chain`]:
//! `format!("{}", Chain(&err))` gives `"session a.mcap: read: Is a directory (os error 21)"`.
//! `err.to_string()` alone drops the cause. A variant that only forwards another error is
//! `#[error(transparent)]`.

use std::path::PathBuf;

/// The cause of an error whose type varies with the device or codec (I/O, image, nokhwa, wire
/// codec errors).
pub type BoxedCause = Box<dyn std::error::Error + Send + Sync>;

/// Errors raised by the capture library.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    /// A device node could not be opened or queried.
    #[error("device {path}: {what}")]
    Device {
        path: PathBuf,
        what: &'static str,
        #[source]
        source: std::io::Error,
    },
    /// A buffer does not have the size its format says it must have.
    #[error(
        "{device}: frame buffer of {actual_bytes} bytes, expected {expected_bytes} for {width}x{height} {fourcc}"
    )]
    BufferSize {
        device: String,
        fourcc: String,
        width: u32,
        height: u32,
        expected_bytes: usize,
        actual_bytes: usize,
    },
    /// A fourcc that is not four ASCII bytes.
    #[error("invalid fourcc {text:?}: must be exactly four ASCII characters")]
    InvalidFourcc { text: String },
    /// A buffer whose contents are not a valid frame (truncated MJPEG, bad telemetry, wrong
    /// format): counted and never recorded as a good frame.
    #[error("{device}: frame {sequence} is corrupt: {reason}")]
    CorruptBuffer {
        device: String,
        sequence: u32,
        reason: String,
    },
    /// A buffer that failed to decode or encode (MJPEG, telemetry rows): like
    /// [`CaptureError::CorruptBuffer`], with the codec's error as the cause.
    #[error("{device}: frame {sequence} is corrupt: {what}")]
    UndecodableBuffer {
        device: String,
        sequence: u32,
        what: &'static str,
        #[source]
        source: BoxedCause,
    },
    /// A session would be written over an existing file.
    #[error(
        "session {path} already exists: refusing to overwrite it (it may be a recording); \
         choose another --out or remove it first"
    )]
    SessionExists { path: PathBuf },
    /// Reading or writing a session file failed.
    #[error("session {path}: {what}")]
    SessionIo {
        path: PathBuf,
        what: &'static str,
        #[source]
        source: std::io::Error,
    },
    /// The MCAP layer refused a record.
    #[cfg(feature = "session")]
    #[error("session {path}: {what}")]
    Mcap {
        path: PathBuf,
        what: &'static str,
        #[source]
        source: mcap::McapError,
    },
    /// A JSON message in a session does not parse.
    #[error("session {path}: message on {topic} (sequence {sequence})")]
    SessionJson {
        path: PathBuf,
        topic: String,
        sequence: u32,
        #[source]
        source: serde_json::Error,
    },
    /// A message in a session does not decode as its channel says.
    #[error("session {path}: message on {topic} (sequence {sequence}): {reason}")]
    SessionMessage {
        path: PathBuf,
        topic: String,
        sequence: u32,
        reason: String,
    },
    /// A device (V4L2 node, simulated rig socket) stopped delivering or cannot be used.
    #[error("device {device}: {reason}")]
    DeviceUnavailable { device: String, reason: String },
    /// A device (simulated rig socket, nokhwa camera, simulator process) failed with an error of
    /// its own: like [`CaptureError::DeviceUnavailable`], with that error as the cause.
    #[error("device {device}: {what}")]
    DeviceFailed {
        device: String,
        what: String,
        #[source]
        source: BoxedCause,
    },
    /// The device cannot deliver any format the role needs.
    #[error("device {device}: no usable format for {role}: offers [{offered}], wants [{wanted}]")]
    NoUsableFormat {
        device: String,
        role: String,
        offered: String,
        wanted: String,
    },
    /// A serial exchange failed (timeout, CRC, status, sequence mismatch).
    #[error("serial {port}: {command}: {reason}")]
    Serial {
        port: String,
        command: String,
        reason: String,
    },
    /// A serial port failed (open, write, read) or a request did not encode.
    #[error("serial {port}: {command}: {what}")]
    SerialIo {
        port: String,
        command: String,
        what: &'static str,
        #[source]
        source: BoxedCause,
    },
    /// An exported image does not fit its recorded size.
    #[error("export {path}: {reason}")]
    Export { path: PathBuf, reason: String },
    /// Writing an exported image or its folder failed.
    #[error("export {path}: {what}")]
    ExportWrite {
        path: PathBuf,
        what: &'static str,
        #[source]
        source: BoxedCause,
    },
    /// The rig controller's clock could not be mapped to the camera clock.
    #[error("rig controller clock → camera clock fit: {reason}")]
    ClockFit { reason: String },
}

/// An error and its causes as one line for a person: the error's text, then each cause's
/// after `": "`. The workspace's errors say only their own level and return the cause from
/// `source()` (module docs), so this is how a log line, a `reason` or a binary's last line
/// gets the whole story. A cause the level above already printed — its text equal to that
/// level's, or ending it after `": "`, as some other crates' errors do (`image`'s decoding
/// errors) — is skipped.
#[derive(Clone, Copy)]
pub struct Chain<'a>(pub &'a (dyn std::error::Error + 'static));

impl std::fmt::Display for Chain<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut previous = self.0.to_string();
        f.write_str(&previous)?;
        let mut cause = self.0.source();
        while let Some(c) = cause {
            let text = c.to_string();
            if text != previous && !previous.ends_with(&format!(": {text}")) {
                write!(f, ": {text}")?;
            }
            previous = text;
            cause = c.source();
        }
        Ok(())
    }
}

impl std::fmt::Debug for Chain<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        std::fmt::Display::fmt(self, f)
    }
}

/// How the binaries end: `Ok` exits 0; an error is printed once on stderr as one
/// `error: …` line (the whole [`Chain`]) and exits 1.
pub fn exit_with<E>(result: Result<(), E>) -> std::process::ExitCode
where
    E: AsRef<dyn std::error::Error + Send + Sync + 'static>,
{
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", Chain(e.as_ref()));
            std::process::ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod chain_tests {
    use super::Chain;

    #[derive(Debug, thiserror::Error)]
    #[error("session {path}: read")]
    struct Outer {
        path: String,
        #[source]
        source: std::io::Error,
    }

    #[derive(Debug, thiserror::Error)]
    #[error("poses")]
    struct Context {
        #[source]
        source: Outer,
    }

    #[derive(Debug, thiserror::Error)]
    #[error("same")]
    struct Leaf;

    #[derive(Debug, thiserror::Error)]
    #[error("same")]
    struct Same(#[source] Leaf);

    /// Another crate's habit: the cause in the message and from `source()`.
    #[derive(Debug, thiserror::Error)]
    #[error("decoding: {0}")]
    struct Prints(#[source] Leaf);

    /// Each level's text once, joined by ": "; a cause whose text equals the one before it
    /// (a wrapper that forwards its cause's message) is skipped.
    #[test]
    fn each_level_is_printed_once() {
        let io = std::io::Error::other("Is a directory");
        let err = Context {
            source: Outer {
                path: "d".into(),
                source: io,
            },
        };
        let line = Chain(&err).to_string();
        assert_eq!(
            line, "poses: session d: read: Is a directory",
            "got {line:?}"
        );
        assert_eq!(err.to_string(), "poses", "Display is this level only");

        let doubled = Same(Leaf);
        assert_eq!(
            Chain(&doubled).to_string(),
            "same",
            "a cause equal to its parent's text is skipped"
        );
        let printed = Prints(Leaf);
        assert_eq!(
            Chain(&printed).to_string(),
            "decoding: same",
            "a cause its parent already printed at its end is skipped"
        );
    }
}
