#version 460
// The segmented argmin's tiled path (src/prims/segmented.rs): fixed tiles of TILE = workgroup
// size × ITEMS elements over the flat cost array, whatever the segments. Workgroup g takes
// tile t = PLAN_FIRST_TILE + g, finds the segments holding its first and last element (two
// binary searches over `offsets`), and for each segment in between of at least `threshold`
// elements reduces the part inside the tile and writes the winner to the (t, s) slot
// (common/reduce_segments.glsl). segmented_segments then combines each such segment's slots.
//
// With threshold >= TILE only the first and the last segment of a tile can qualify (one
// strictly inside is shorter than the tile), so the workgroup skips the ones in between
// without reading them: at most two workgroup reductions per tile. The tile size comes as a
// push constant (= workgroup size × ITEMS) because segmented_segments needs it too.
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
    uint threshold;
    uint tile; // elements per tile: workgroup size × items per invocation
} pc;

#define ARGMIN_COSTS4 costs4
#include "common/argmin.glsl"
#include "common/reduce_segments.glsl"

void write_slot(uint t, uint s, float c, uint i) {
    if (reduce_lane() == 0u) {
        uint w = PLAN_WORDS + 2u * (t + s);
        scratch[w] = floatBitsToUint(c);
        scratch[w + 1u] = i;
    }
}

void main() {
    uint g = linear_group_id();
    if (g >= scratch[PLAN_TILES]) {
        return;
    }
    uint tile = pc.tile;
    uint t = scratch[PLAN_FIRST_TILE] + g;
    uint count = scratch[PLAN_COUNT];
    uint tile_begin = max(t * tile, scratch[PLAN_FIRST]);
    uint tile_end = min(t * tile + tile, scratch[PLAN_TOTAL]);
    // Every invocation searches (uniform loads; sharing the result would cost a barrier).
    uint first = segment_containing(tile_begin, count);
    uint last = segment_containing(tile_end - 1u, count);

    // The tile's first and last segment, in straight-line code before any barrier: llvmpipe
    // turns a loop that contains a barrier() into a coroutine state machine, and an element
    // loop inside one ran about 4x slower (measured, Mesa 22.3).
    uvec2 a = segment_bounds(first, pc.n_costs);
    uvec2 b = segment_bounds(last, pc.n_costs);
    bool do_a = a.y - a.x >= pc.threshold;
    bool do_b = last != first && b.y - b.x >= pc.threshold;
    float ca = ARGMIN_NONE_COST;
    uint ia = ARGMIN_NONE_INDEX;
    float cb = ARGMIN_NONE_COST;
    uint ib = ARGMIN_NONE_INDEX;
    if (do_a) {
        argmin_range(tile_begin, min(a.y, tile_end), ca, ia);
    }
    if (do_b) {
        argmin_range(max(b.x, tile_begin), tile_end, cb, ib);
    }
    if (do_a) {
        workgroup_argmin(ca, ia);
        write_slot(t, first, ca, ia);
    }
    if (do_b) {
        // The second workgroup_argmin reuses the shared slots of the first.
        barrier();
        workgroup_argmin(cb, ib);
        write_slot(t, last, cb, ib);
    }

    // Segments strictly inside the tile are shorter than it: with threshold >= tile none
    // qualifies. Below that (DeviceWide and small hybrid thresholds), one workgroup
    // reduction per qualifying segment.
    if (pc.threshold < tile) {
        for (uint s = first + 1u; s < last; s++) {
            uvec2 seg = segment_bounds(s, pc.n_costs);
            if (seg.y - seg.x >= pc.threshold) {
                float c = ARGMIN_NONE_COST;
                uint i = ARGMIN_NONE_INDEX;
                argmin_range(seg.x, seg.y, c, i);
                barrier();
                workgroup_argmin(c, i);
                write_slot(t, s, c, i);
            }
        }
    }
}
