#version 460
// The segmented argmin's plan (src/prims/segmented.rs): reads the segment count the GPU
// left in `count` and the extent of the segments, and writes the plan record and the
// indirect workgroup counts of both paths (common/reduce_segments.glsl). The tiled path
// gets its tiles only if some segment can reach the threshold length (the span of all
// segments does); it then handles exactly the segments of at least `threshold` elements,
// and segmented_segments the others. One invocation: this is O(1) work.
layout(local_size_x = 1) in;

layout(std430, binding = 0) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 1) readonly buffer Count { uint count_in[]; };
layout(std430, binding = 2) writeonly buffer Plan { uint plan[]; };
// Keep in sync with `PlanPush` in src/prims/segmented.rs.
layout(push_constant) uniform Push {
    uint max_segments; // capacity: counts above it are clamped
    uint n_costs;      // elements in the cost buffer
    uint tile;         // elements per tile of the tiled path
    uint threshold;    // segments of at least this many elements take the tiled path (>= 1)
    uint max_groups_x; // maxComputeWorkGroupCount[0]: larger counts fold into y
} pc;

#include "common/reduce_segments.glsl"

void write_groups(uint at, uint groups) {
    uint x = min(groups, pc.max_groups_x);
    plan[at] = x;
    plan[at + 1u] = x == 0u ? 1u : (groups + x - 1u) / x;
    plan[at + 2u] = 1u;
}

void main() {
    uint count = min(count_in[0], pc.max_segments);
    uint first = 0u;
    uint total = 0u;
    if (count > 0u) {
        first = segment_bounds(0u, pc.n_costs).x;
        total = clamp(offsets[count], first, pc.n_costs);
    }
    uint first_tile = first / pc.tile;
    uint tiles = 0u;
    if (count > 0u && total - first >= pc.threshold) {
        tiles = (total + pc.tile - 1u) / pc.tile - first_tile;
    }
    write_groups(PLAN_SEGMENT_GROUPS, count);
    write_groups(PLAN_TILE_GROUPS, tiles);
    plan[PLAN_COUNT] = count;
    plan[PLAN_FIRST] = first;
    plan[PLAN_TOTAL] = total;
    plan[PLAN_FIRST_TILE] = first_tile;
    plan[PLAN_TILES] = tiles;
}
