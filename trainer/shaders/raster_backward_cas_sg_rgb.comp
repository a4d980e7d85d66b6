// Backward rasteriser with the RGB planes and compare-and-swap loops after a subgroup sum: see
// raster_backward.glsl.
#version 450
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#define USE_SUBGROUP_REDUCE
#define USE_COLOUR
#include "raster_backward.glsl"
