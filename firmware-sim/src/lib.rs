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
//! - [`scene`]: trainer datasets of simple thermal scenes with truth (`scene`): their objects,
//!   camera paths, rendering, sensors, per-frame response effects ([`scene::response`]), truth
//!   surface ([`scene::truth`]), dataset writers (COLMAP model through `s3tir_calib::model::colmap`)
//!   and the joint thermal + RGB layout ([`scene::joint`], `scene --rgb-scale K`).
//! - [`serve`]: the live rig (`run`).
//! - [`walk`]: the rig walking through a textured room (`run --walk`), with the truth
//!   trajectory and the AprilTags on its walls ([`walk::fiducials`], `tags.toml`).
//! - [`error`]: the library's error type, [`SimError`].

pub mod board;
pub mod dataset;
pub mod error;
pub mod physics;
pub mod render;
pub mod rig;
pub mod scene;
pub mod sensor;
pub mod serve;
pub mod walk;

pub use error::SimError;
