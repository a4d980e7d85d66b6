// Backward rasteriser with the RGB planes, without float atomics (CAS loops): see
// raster_backward.glsl.
#version 450
#define USE_COLOUR
#include "raster_backward.glsl"
