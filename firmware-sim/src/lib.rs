//! s3tir-firmware-sim: the simulated rig (thermal core, RGB camera, rig controller firmware).
//!
//! It plays the devices a real rig has, so that every command runs without hardware and every
//! test has ground truth. It depends on `s3tir-capture` (frame types, wire protocols) and on the
//! camera model of `s3tir-calib`; nothing depends on it except the end-to-end tests.
//!
//! - [`physics`]: in-band (8–14 µm) radiance, grey-body apparent radiance, TLinear inverse.
//! - [`board`]: the emissivity-coated checkerboard and its heat model.
//! - [`render`]: area-integrated rendering through the Brown–Conrady camera, PSF blur.
//! - [`sensor`]: thermal core and RGB camera sensor models and profiles.
//! - [`rig`]: the thermal + RGB rig geometry and board trajectories.
//! - [`dataset`]: the `board` calibration set writer.
//! - [`scene`]: trainer datasets of simple thermal scenes with truth; [`response`]: their
//!   per-frame automatic gain control (8-bit) and drift between flat-field corrections;
//!   [`scene_joint`]: the same scenes seen by a thermal + RGB rig (RGB at K× the thermal
//!   resolution), with high-resolution truth (`scene --rgb-scale K`); [`scene_truth`]: the
//!   truth surface both write (`truth/surface.ply`: visible points with their apparent
//!   temperature, for scoring meshes).
//! - [`serve`]: the live rig (`run`); [`walk`]: the rig walking through a textured scene
//!   (`run --walk`), with the truth trajectory; [`fiducials`]: the AprilTags on its walls and
//!   their map (`tags.toml`).

pub mod board;
pub mod dataset;
pub mod error;
pub mod fiducials;
pub mod physics;
pub mod render;
pub mod response;
pub mod rig;
pub mod scene;
pub mod scene_joint;
pub mod scene_truth;
pub mod sensor;
pub mod serve;
pub mod walk;

pub use error::SimError;
