// Rasteriser step 2, one invocation per primitive: writes a (tile, depth) key and the primitive
// index for every tile of its rectangle, at the offset the exclusive scan of tile counts gave.
// Keys are uvec2(depth bits, tile): camera depth is > near > 0, so its float bits order like
// the floats; the stable radix sort then orders by tile, depth, and primitive index for ties
// (the CPU reference's order). Keys past `capacity` (the key buffers' size) are not written:
// the host sized the buffers from an earlier step and checks the total afterwards.
#version 450
#include "raster_common.glsl"

layout(local_size_x = 128) in;

layout(std430, set = 0, binding = 0) readonly buffer Views { PrimView views[]; };
layout(std430, set = 0, binding = 1) readonly buffer Offsets { uint offsets[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Keys { uvec2 keys[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Values { uint values[]; };

layout(push_constant) uniform Push {
    uint n;
    uint tiles_x;
    uint capacity;
} pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.n || views[i].misc.z == 0.0) {
        return;
    }
    uvec4 r = views[i].rect;
    uint depth_bits = floatBitsToUint(views[i].misc.y);
    uint k = offsets[i];
    for (uint ty = r.y; ty < r.w; ++ty) {
        for (uint tx = r.x; tx < r.z; ++tx) {
            if (k < pc.capacity) {
                keys[k] = uvec2(depth_bits, ty * pc.tiles_x + tx);
                values[k] = i;
            }
            ++k;
        }
    }
}
