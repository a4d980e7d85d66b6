// Backward rasteriser with the RGB planes and atomicAdd(float): see raster_backward.glsl.
#version 450
#extension GL_EXT_shader_atomic_float : require
#define USE_FLOAT_ATOMICS
#define USE_COLOUR
#include "raster_backward.glsl"
