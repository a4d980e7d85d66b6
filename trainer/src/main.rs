//! `s3tir-train`: S³-TIR thermal splatting trainer.
fn main() {}
