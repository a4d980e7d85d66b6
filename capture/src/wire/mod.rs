//! Wire codecs and serial clients: how the rig's devices talk to the host.
//!
//! The codecs are pure and always built (the simulated rig in `s3tir-firmware-sim` speaks
//! them too, so they live at the bottom layer and neither side depends on the other):
//! - [`fslp`]: the FLIR Boson command protocol (FSLP),
//! - [`rig_protocol`]: the rig controller's serial protocol,
//! - [`simwire`]: V4L2-shaped frames over a local socket (simulated rig → capture).
//!
//! [`serial`] (feature `rig`) holds the clients that run them over a serial port; the private
//! `crc16` holds the CRC-16 (polynomial 0x1021) both serial codecs check their frames with.

mod crc16;
pub mod fslp;
pub mod rig_protocol;
#[cfg(feature = "rig")]
pub mod serial;
pub mod simwire;
