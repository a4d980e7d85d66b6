// Rasteriser step 4 (thermal image and G-buffers): see raster_forward.glsl.
#version 450
#include "raster_forward.glsl"
