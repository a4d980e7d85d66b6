//! The rig's serial ports: pseudo-terminals ([`open_pty`]) served by a loop that hands the
//! bytes a client writes to the firmware and writes back its replies ([`pty_loop`]).

use std::io::{Read, Write};
use std::os::fd::{AsFd, OwnedFd};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread;
use std::time::Duration;

use crate::error::SimError;

/// A pseudo-terminal: the master we serve and the slave a client opens by path.
pub(super) struct Pty {
    master: OwnedFd,
    /// Kept open so the master does not see EIO while no client has the slave open.
    _slave: OwnedFd,
    pub(super) path: PathBuf,
}

pub(super) fn open_pty(what: &'static str) -> Result<Pty, SimError> {
    let err = |e: nix::Error| SimError::Io {
        path: PathBuf::from("/dev/ptmx"),
        what,
        source: std::io::Error::from(e),
    };
    let pair = nix::pty::openpty(None, None).map_err(err)?;
    // Raw mode: bytes pass unchanged (no echo, no CR/LF translation).
    let mut tio = nix::sys::termios::tcgetattr(pair.slave.as_fd()).map_err(err)?;
    nix::sys::termios::cfmakeraw(&mut tio);
    nix::sys::termios::tcsetattr(pair.slave.as_fd(), nix::sys::termios::SetArg::TCSANOW, &tio)
        .map_err(err)?;
    let path = nix::unistd::ttyname(pair.slave.as_fd()).map_err(err)?;
    Ok(Pty {
        master: pair.master,
        _slave: pair.slave,
        path,
    })
}

/// Serves one pty until `stop`: reads bytes, hands them to `on_bytes`, writes its output.
pub(super) fn pty_loop(
    pty: Pty,
    stop: Arc<AtomicBool>,
    mut on_bytes: impl FnMut(&[u8]) -> Vec<u8>,
) {
    let mut file = std::fs::File::from(pty.master);
    let mut buf = [0u8; 512];
    while !stop.load(Ordering::Relaxed) {
        let ready = {
            let mut fds = [nix::poll::PollFd::new(
                file.as_fd(),
                nix::poll::PollFlags::POLLIN,
            )];
            nix::poll::poll(&mut fds, nix::poll::PollTimeout::from(50u16)).unwrap_or(0)
        };
        if ready <= 0 {
            continue;
        }
        match file.read(&mut buf) {
            Ok(0) => thread::sleep(Duration::from_millis(20)),
            Ok(n) => {
                let out = on_bytes(&buf[..n]);
                if !out.is_empty()
                    && let Err(e) = file.write_all(&out)
                {
                    tracing::warn!(pty = %pty.path.display(), "write failed: {e}");
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(_) => thread::sleep(Duration::from_millis(20)),
        }
    }
}
