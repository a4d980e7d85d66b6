// Rasteriser step 1 with the RGB colour of each primitive: see raster_project.glsl.
#version 450
#define USE_COLOUR
#include "raster_project.glsl"
