// Consistency loss with compare-and-swap loops for the source view (no float atomics): see
// loss_consistency.glsl.
#version 450
#include "loss_consistency.glsl"
