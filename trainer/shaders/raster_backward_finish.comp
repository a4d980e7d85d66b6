// Backward rasteriser, final step: see raster_backward_finish.glsl.
#version 450
#include "raster_backward_finish.glsl"
