#version 460
// LBVH, pass 1: the box of the primitives' centroids (CPU twin: lbvh::centroid_bounds).
// Minima and maxima are exact in any order: each centroid coordinate becomes a key whose
// unsigned order is the IEEE total order, the subgroup takes the minimum, and one lane per
// subgroup folds it into the six words with atomicMin (the maxima as inverted keys, so one
// fill of ~0 starts all six).
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_KHR_shader_subgroup_basic : require
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "accel/bvh/lbvh_common.glsl"

// Six floats per primitive: min x, y, z, max x, y, z.
layout(std430, binding = 0) readonly buffer Boxes { float boxes[]; };
// Keys of min x, y, z, then inverted keys of max x, y, z.
layout(std430, binding = 1) buffer Bounds { uint bounds[]; };
layout(push_constant) uniform Push { uint n; } pc;

void main() {
    uint i = linear_invocation_id();
    uvec3 lo = uvec3(0xffffffffu);
    uvec3 hi_inv = uvec3(0xffffffffu);
    if (i < pc.n) {
        uvec3 k = ordered_key(centroid(boxes, i));
        lo = k;
        hi_inv = ~k;
    }
    // Every lane reaches the reductions (no early return above).
    lo = subgroupMin(lo);
    hi_inv = subgroupMin(hi_inv);
    if (subgroupElect()) {
        for (uint a = 0u; a < 3u; a++) {
            atomicMin(bounds[a], lo[a]);
            atomicMin(bounds[3u + a], hi_inv[a]);
        }
    }
}
