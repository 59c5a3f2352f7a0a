#version 460
// The segmented argmin's plan (src/prims/segmented.rs), one workgroup: reads the segment
// count the GPU left in `count`, decides which segments are long, lists them in segment
// order with the prefix sum of the tiles each touches, and writes the plan record:
// the indirect workgroup counts of segmented_tiles (one workgroup per (long segment, tile)
// pair; none when no segment is long) and of the per-segment path: segmented_segments (one
// workgroup per segment) or, on a level of at least `pack_min` segments, segmented_packed
// (one invocation per segment, `pack_width` per workgroup; its segments of at least
// `pack_cut` elements are long).
// Invocation L scans the contiguous range of segments [L·chunk, (L + 1)·chunk) twice
// (count, then write); one invocation turns the per-invocation counts into offsets.
layout(local_size_x = 128) in;

layout(std430, binding = 0) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 1) readonly buffer Count { uint count_in[]; };
layout(std430, binding = 2) writeonly buffer Plan { uint plan[]; };
// Keep in sync with `PlanPush` in src/prims/segmented.rs.
layout(push_constant) uniform Push {
    uint max_segments; // capacity: counts above it are clamped
    uint n_costs;      // elements in the cost buffer
    uint tile;         // elements per tile of the tiled path
    uint share;        // long: more than 1/share of all elements (0: never, by that rule)
    uint capacity;     // long: more than a segment workgroup may loop over (>= tile)
    uint max_groups_x; // maxComputeWorkGroupCount[0]: larger counts fold into y
    uint pack_min;     // segments from which the level takes segmented_packed (0: never)
    uint pack_width;   // segmented_packed's workgroup size
    uint pack_cut;     // segmented_packed: long from this many elements (its loop budget)
} pc;

#include "common/reduce_segments.glsl"

shared uint long_before[gl_WorkGroupSize.x];
shared uint pairs_before[gl_WorkGroupSize.x];
shared uint totals[2];

void write_groups(uint at, uint groups) {
    uint x = min(groups, pc.max_groups_x);
    plan[at] = x;
    plan[at + 1u] = x == 0u ? 1u : (groups + x - 1u) / x;
    plan[at + 2u] = 1u;
}

void main() {
    uint lane = gl_LocalInvocationIndex;
    uint lanes = gl_WorkGroupSize.x;
    uint count = min(count_in[0], pc.max_segments);
    // Long: at least a tile, and more than 1/share of the span of all segments (Kolodzey's
    // node-count switch, per segment), or more than a workgroup may loop over.
    uint total = 0u;
    if (count > 0u) {
        uint first = segment_bounds(0u, pc.n_costs).x;
        total = clamp(offsets[count], first, pc.n_costs) - first;
    }
    uint cut = pc.share == 0u ? pc.capacity : clamp(total / pc.share + 1u, pc.tile, pc.capacity);
    bool packed = pc.pack_min != 0u && count >= pc.pack_min;
    if (packed) {
        cut = min(cut, pc.pack_cut);
    }
    uint chunk = (count + lanes - 1u) / lanes;
    uint begin = min(lane * chunk, count);
    uint end = min(begin + chunk, count);
    uint n_long = 0u;
    uint n_pairs = 0u;
    for (uint s = begin; s < end; s++) {
        uvec2 seg = segment_bounds(s, pc.n_costs);
        if (seg.y - seg.x >= cut) {
            n_long++;
            n_pairs += segment_tiles(seg, pc.tile);
        }
    }
    long_before[lane] = n_long;
    pairs_before[lane] = n_pairs;
    barrier();
    if (lane == 0u) {
        uint l = 0u;
        uint p = 0u;
        for (uint k = 0u; k < lanes; k++) {
            uint nl = long_before[k];
            uint np = pairs_before[k];
            long_before[k] = l;
            pairs_before[k] = p;
            l += nl;
            p += np;
        }
        totals[0] = l;
        totals[1] = p;
    }
    barrier();
    if (totals[0] > 0u && n_long > 0u) {
        uint l = long_before[lane];
        uint p = pairs_before[lane];
        for (uint s = begin; s < end; s++) {
            uvec2 seg = segment_bounds(s, pc.n_costs);
            if (seg.y - seg.x >= cut) {
                plan[PLAN_WORDS + 2u * l] = s;
                plan[PLAN_WORDS + 2u * l + 1u] = p;
                l++;
                p += segment_tiles(seg, pc.tile);
            }
        }
    }
    if (lane == 0u) {
        write_groups(PLAN_SEGMENT_GROUPS, packed ? 0u : count);
        uint packed_groups = (count + pc.pack_width - 1u) / pc.pack_width;
        write_groups(PLAN_PACKED_GROUPS, packed ? packed_groups : 0u);
        write_groups(PLAN_TILE_GROUPS, totals[1]);
        plan[PLAN_COUNT] = count;
        plan[PLAN_LONG] = totals[0];
        plan[PLAN_PAIRS] = totals[1];
        plan[PLAN_CUT] = cut;
    }
}
