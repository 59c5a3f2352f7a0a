#version 460
// The segmented argmin's packed path (src/prims/segmented.rs), for levels of many short
// segments, where launching a workgroup per segment costs more than reducing it: invocation
// k of workgroup g owns segment g·W + k (numbered by reduce_lane()). A segment of at most
// `short_len` elements its invocation reduces alone, in a plain loop. Each longer one the
// whole subgroup then takes in turn: lanes stride over its elements, or, for a long
// segment (at least PLAN_CUT elements, cut into tiles by segmented_tiles), over its
// (tile, segment) winners. The size classes of CUB's segmented reduction: a thread, a warp
// or the whole device per segment.
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_shuffle : require
#extension GL_KHR_shader_subgroup_vote : require
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

layout(std430, binding = 0) readonly buffer Costs { float costs[]; };
layout(std430, binding = 1) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 2) readonly buffer Scratch { uint scratch[]; };
layout(std430, binding = 3) writeonly buffer Out { uvec2 out_winners[]; };
// Keep in sync with `PackedPush` in src/prims/segmented.rs.
layout(push_constant) uniform Push {
    uint n_costs;
    uint tile;      // elements per tile of segmented_tiles
    uint slot_base; // scratch word of the first (tile, segment) slot
    uint short_len; // segments of at most this many elements: one invocation each
} pc;

#include "common/argmin.glsl"
#include "common/reduce_segments.glsl"

// Segment s's winner, reduced by the whole subgroup (uniform s); every lane ends with it.
// Loop iterations per lane: under len / (REDUCE_UNROLL · lanes) + REDUCE_UNROLL, as in
// segmented_segments (the plan keeps the sum over a subgroup's segments in the budget).
void subgroup_segment(uint s, uint lane, uint lanes, out float c, out uint i) {
    c = ARGMIN_NONE_COST;
    i = ARGMIN_NONE_INDEX;
    uvec2 seg = segment_bounds(s, pc.n_costs);
    if (seg.y - seg.x >= scratch[PLAN_CUT]) {
        argmin_segment_slots(seg, s, lane, lanes, pc.tile, pc.slot_base, c, i);
    } else {
        uint e = seg.x + lane;
        for (; e + 3u * lanes < seg.y; e += 4u * lanes) {
            argmin_consider(costs[e], e, c, i);
            argmin_consider(costs[e + lanes], e + lanes, c, i);
            argmin_consider(costs[e + 2u * lanes], e + 2u * lanes, c, i);
            argmin_consider(costs[e + 3u * lanes], e + 3u * lanes, c, i);
        }
        for (; e < seg.y; e += lanes) {
            argmin_consider(costs[e], e, c, i);
        }
    }
    subgroup_argmin(c, i);
}

void main() {
    uint s = linear_group_id() * gl_WorkGroupSize.x + reduce_lane();
    uint lane = gl_SubgroupInvocationID;
    uint lanes = reduce_subgroup_lanes();
    // Every lane stays to the end: the subgroup's shuffles below need all of them.
    uint needs_subgroup = 0u;
    if (s < scratch[PLAN_COUNT]) {
        uvec2 seg = segment_bounds(s, pc.n_costs);
        if (seg.y - seg.x <= pc.short_len) {
            float c = ARGMIN_NONE_COST;
            uint i = ARGMIN_NONE_INDEX;
            for (uint e = seg.x; e < seg.y; e++) {
                argmin_consider(costs[e], e, c, i);
            }
            out_winners[s] = uvec2(floatBitsToUint(c), i);
        } else {
            needs_subgroup = 1u;
        }
    }
    if (subgroupAny(needs_subgroup != 0u)) {
        for (uint k = 0u; k < lanes; k++) {
            uint owner_s = subgroupShuffle(s, k);
            if (subgroupShuffle(needs_subgroup, k) != 0u) {
                float c;
                uint i;
                subgroup_segment(owner_s, lane, lanes, c, i);
                if (lane == k) {
                    out_winners[s] = uvec2(floatBitsToUint(c), i);
                }
            }
        }
    }
}
