// Consistency loss with atomicAdd(float) for the source view: see loss_consistency.glsl.
#version 450
#extension GL_EXT_shader_atomic_float : require
#define USE_FLOAT_ATOMICS
#include "loss_consistency.glsl"
