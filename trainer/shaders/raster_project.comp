// Rasteriser step 1 (thermal and G-buffers): see raster_project.glsl.
#version 450
#include "raster_project.glsl"
