#version 460
//! variant shuffle
//! variant shared ARGMIN_SHARED=1
// The segmented argmin's tiled path (src/prims/segmented.rs): fixed tiles of `tile`
// (= workgroup size × items per invocation) elements over the flat cost array. The plan
// listed the long segments with the prefix sum of the tiles each touches; workgroup g finds
// its (segment s, tile t) pair by binary search in that list, reduces the part of s inside
// tile t, and writes the winner to the (t, s) slot (common/reduce_segments.glsl), which
// segmented_segments then combines per segment. Every workgroup reduces at most one tile,
// so its loop iterations stay bounded (llvmpipe's loop budget, common/reduce_lanes.glsl).
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_shuffle : require
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

layout(std430, binding = 0) readonly buffer Costs { vec4 costs4[]; };
layout(std430, binding = 1) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 2) buffer Scratch { uint scratch[]; };
// Keep in sync with `PathPush` in src/prims/segmented.rs.
layout(push_constant) uniform Push {
    uint n_costs;
    uint tile;      // elements per tile: workgroup size × items per invocation
    uint slot_base; // scratch word of the first (tile, segment) slot
} pc;

#define ARGMIN_COSTS4 costs4
#include "common/argmin.glsl"
#include "common/reduce_segments.glsl"

void main() {
    uint g = linear_group_id();
    if (g >= scratch[PLAN_PAIRS]) {
        return;
    }
    // The last listed segment whose first pair is at most g.
    uint lo = 0u;
    uint hi = scratch[PLAN_LONG];
    while (hi - lo > 1u) {
        uint mid = (lo + hi) >> 1;
        if (scratch[PLAN_WORDS + 2u * mid + 1u] <= g) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    uint s = scratch[PLAN_WORDS + 2u * lo];
    uvec2 seg = segment_bounds(s, pc.n_costs);
    uint t = seg.x / pc.tile + (g - scratch[PLAN_WORDS + 2u * lo + 1u]);
    float c = ARGMIN_NONE_COST;
    uint i = ARGMIN_NONE_INDEX;
    argmin_range(max(seg.x, t * pc.tile), min(seg.y, t * pc.tile + pc.tile), c, i);
    workgroup_argmin(c, i);
    if (reduce_lane() == 0u) {
        uint w = pc.slot_base + 2u * (t + s);
        scratch[w] = floatBitsToUint(c);
        scratch[w + 1u] = i;
    }
}
