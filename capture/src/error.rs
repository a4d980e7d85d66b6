//! Errors of the capture layer. Every variant names the device or file it is about.

use std::path::PathBuf;

/// The cause of an error whose type varies with the device or codec (I/O, image, nokhwa, wire
/// codec errors).
pub type BoxedCause = Box<dyn std::error::Error + Send + Sync>;

/// Errors raised by the capture library.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    /// A device node could not be opened or queried.
    #[error("device {path}: {what}: {source}")]
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
    #[error("{device}: frame {sequence} is corrupt: {what}: {source}")]
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
    #[error("session {path}: {what}: {source}")]
    SessionIo {
        path: PathBuf,
        what: &'static str,
        #[source]
        source: std::io::Error,
    },
    /// The MCAP layer refused a record.
    #[cfg(feature = "session")]
    #[error("session {path}: {what}: {source}")]
    Mcap {
        path: PathBuf,
        what: &'static str,
        #[source]
        source: mcap::McapError,
    },
    /// A JSON message in a session does not parse.
    #[error("session {path}: message on {topic} (sequence {sequence}): {source}")]
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
    #[error("device {device}: {what}: {source}")]
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
    #[error("serial {port}: {command}: {what}: {source}")]
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
    #[error("export {path}: {what}: {source}")]
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

/// An error and its causes as one line for a person, each fact once. The workspace's errors
/// show their cause's text in their own message (`"session {path}: {source}"`) and return the
/// cause from `source()` as well, so walking the chain would repeat it: a cause whose text the
/// line already holds is left out; any other is appended after `": "`.
pub fn report(err: &(dyn std::error::Error + 'static)) -> String {
    let mut line = err.to_string();
    let mut cause = err.source();
    while let Some(c) = cause {
        let text = c.to_string();
        if !line.contains(&text) {
            line.push_str(": ");
            line.push_str(&text);
        }
        cause = c.source();
    }
    line
}

/// How the binaries end: `Ok` exits 0; an error is printed once on stderr as `error: …`
/// ([`report`]) and exits 1.
pub fn exit_with<E>(result: Result<(), E>) -> std::process::ExitCode
where
    E: AsRef<dyn std::error::Error + Send + Sync + 'static>,
{
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", report(e.as_ref()));
            std::process::ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod report_tests {
    use super::report;

    #[derive(Debug, thiserror::Error)]
    #[error("session {path}: {source}")]
    struct Outer {
        path: String,
        #[source]
        source: std::io::Error,
    }

    #[derive(Debug, thiserror::Error)]
    #[error("poses from {path}")]
    struct Context {
        path: String,
        #[source]
        source: Outer,
    }

    /// A cause whose text its error already shows is not repeated; a context that does not
    /// show its cause gets it appended once.
    #[test]
    fn each_fact_is_printed_once() {
        let io = std::io::Error::other("Is a directory");
        let err = Context {
            path: "d".into(),
            source: Outer {
                path: "d".into(),
                source: io,
            },
        };
        let line = report(&err);
        assert_eq!(
            line, "poses from d: session d: Is a directory",
            "got {line:?}"
        );
        assert_eq!(
            line.matches("Is a directory").count(),
            1,
            "the OS cause once: {line:?}"
        );
    }
}
