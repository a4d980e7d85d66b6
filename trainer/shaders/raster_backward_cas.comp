// Backward rasteriser without float atomics (CAS loops): see raster_backward.glsl.
#version 450
#include "raster_backward.glsl"
