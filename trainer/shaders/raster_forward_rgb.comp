// Rasteriser step 4 with the RGB planes: see raster_forward.glsl.
#version 450
#define USE_COLOUR
#include "raster_forward.glsl"
