//! The camera model and the files cameras travel in: what every stage shares, built without
//! OpenCV (the trainer and the simulated rig link this and nothing else of calib). Imports
//! only [`crate::error`].
//!
//! - [`camera`]: pinhole + Brown–Conrady camera model.
//! - [`geometry`]: rigid transforms (`b_from_a`).
//! - [`calfile`]: `calibration.yaml` reader and model-only writer.
//! - [`colmap`]: the workspace's COLMAP sparse-model codec (text and binary).
//! - [`ply`]: binary PLY, the one codec of the trainer's primitives and meshes and the
//!   simulator's truth surface (header, types, body cursor, atomic write).
//! - [`palette`]: the thermal colour palettes (ironbow, inferno), one table each: drawing
//!   temperatures for people and mapping pseudo-colour frames back to scalars.

pub mod calfile;
pub mod camera;
pub mod colmap;
pub mod geometry;
pub mod palette;
pub mod ply;
