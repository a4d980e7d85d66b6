//! s3tir-firmware-sim: the simulated rig (thermal core, RGB camera, rig controller firmware).
//!
//! It plays the devices a real rig has, so that every command runs without hardware and every
//! test has ground truth. It depends on `s3tir-capture` (frame types, wire protocols) and on the
//! camera model of `s3tir-calib`; nothing depends on it except the end-to-end tests.
