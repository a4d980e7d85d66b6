// Backward rasteriser, final step, with the SH colour: see raster_backward_finish.glsl.
#version 450
#define USE_COLOUR
#include "raster_backward_finish.glsl"
