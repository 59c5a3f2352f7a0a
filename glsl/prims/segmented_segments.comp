#version 460
//! variant shuffle
//! variant shared ARGMIN_SHARED=1
// The segmented argmin's workgroup-per-segment path (src/prims/segmented.rs): workgroup s
// writes out[s] for segment s < PLAN_COUNT. A long segment (at least PLAN_CUT elements) was
// cut into tiles by segmented_tiles, so the workgroup combines its (tile, segment) winners;
// any other segment the workgroup reduces itself, looping over its elements. Empty segments
// give (+inf, u32::MAX).
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_shuffle : require
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

layout(std430, binding = 0) readonly buffer Costs { vec4 costs4[]; };
layout(std430, binding = 1) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 2) readonly buffer Scratch { uint scratch[]; };
layout(std430, binding = 3) writeonly buffer Out { uvec2 out_winners[]; };
// Keep in sync with `PathPush` in src/prims/segmented.rs.
layout(push_constant) uniform Push {
    uint n_costs;
    uint tile;      // elements per tile of segmented_tiles (its workgroup size may differ)
    uint slot_base; // scratch word of the first (tile, segment) slot
} pc;

#define ARGMIN_COSTS4 costs4
#include "common/argmin.glsl"
#include "common/reduce_segments.glsl"

void main() {
    uint s = linear_group_id();
    if (s >= scratch[PLAN_COUNT]) {
        return;
    }
    uvec2 seg = segment_bounds(s, pc.n_costs);
    float c = ARGMIN_NONE_COST;
    uint i = ARGMIN_NONE_INDEX;
    uint lane = reduce_lane();
    if (seg.y - seg.x >= scratch[PLAN_CUT]) {
        argmin_segment_slots(seg, s, lane, gl_WorkGroupSize.x, pc.tile, pc.slot_base, c, i);
    } else {
        argmin_range(seg.x, seg.y, c, i);
    }
    workgroup_argmin(c, i);
    if (lane == 0u) {
        out_winners[s] = uvec2(floatBitsToUint(c), i);
    }
}
