// The segmented argmin's plan record and segment bounds (src/prims/segmented.rs; keep the
// PLAN_* word offsets in sync with the constants there).
//
// Scratch layout (words): the plan record [0, PLAN_WORDS), written by
// prims/segmented_plan.comp and read by the other two kernels and the indirect dispatches;
// the list of long segments (at least PLAN_CUT elements) from PLAN_WORDS, one (segment, first pair) uvec2 each, in
// segment order; and from `slot_base` the (tile, segment) winners: the pair for tile t and
// segment s at word slot_base + 2 (t + s). Walking the pairs in element order steps t or s
// up by at least one each time, so t + s never repeats.
//
// Requires, before inclusion: a `uint offsets[]` buffer (segment s = [offsets[s],
// offsets[s + 1]) of the flat cost array).
#ifndef VKRT_COMMON_REDUCE_SEGMENTS_GLSL
#define VKRT_COMMON_REDUCE_SEGMENTS_GLSL

#define PLAN_SEGMENT_GROUPS 0u // uvec3: indirect workgroup counts of segmented_segments
#define PLAN_TILE_GROUPS 3u    // uvec3: indirect workgroup counts of segmented_tiles
#define PLAN_COUNT 6u          // segments (the count buffer clamped to max_segments)
#define PLAN_LONG 7u           // long segments (at least PLAN_CUT elements), listed
#define PLAN_PAIRS 8u          // (long segment, tile) pairs: workgroups of segmented_tiles
#define PLAN_CUT 9u            // segments of at least this many elements are long
#define PLAN_PACKED_GROUPS 10u // uvec3: indirect workgroup counts of segmented_packed
#define PLAN_WORDS 16u

// Segment s clamped into [0, n_costs] and to a non-negative length, so malformed offsets
// give unspecified results but never an out-of-bounds access.
uvec2 segment_bounds(uint s, uint n_costs) {
    uint begin = min(offsets[s], n_costs);
    uint end = clamp(offsets[s + 1u], begin, n_costs);
    return uvec2(begin, end);
}

// Tiles of `tile` elements that segment [begin, end) (non-empty) touches.
uint segment_tiles(uvec2 seg, uint tile) {
    return (seg.y - 1u) / tile - seg.x / tile + 1u;
}

#ifdef VKRT_COMMON_ARGMIN_GLSL
// Slot p's winner (the (tile, segment) pairs from word slot_base on) folded into (c, i).
// Needs a `uint scratch[]` buffer; include after common/argmin.glsl.
void argmin_consider_slot(uint slot_base, uint p, inout float c, inout uint i) {
    uint w = slot_base + 2u * p;
    argmin_consider(uintBitsToFloat(scratch[w]), scratch[w + 1u], c, i);
}

// Folds long segment s's tile winners into this lane's (c, i): the slots of tiles [first,
// end) are the consecutive pairs first + s .. end + s, and the lane takes every lanes-th
// from its own, REDUCE_UNROLL per iteration (llvmpipe's loop budget,
// common/reduce_lanes.glsl).
void argmin_segment_slots(uvec2 seg, uint s, uint lane, uint lanes, uint tile, uint slot_base,
                          inout float c, inout uint i) {
    uint p = seg.x / tile + s + lane;
    uint p_end = (seg.y - 1u) / tile + 1u + s;
    for (; p + 3u * lanes < p_end; p += 4u * lanes) {
        argmin_consider_slot(slot_base, p, c, i);
        argmin_consider_slot(slot_base, p + lanes, c, i);
        argmin_consider_slot(slot_base, p + 2u * lanes, c, i);
        argmin_consider_slot(slot_base, p + 3u * lanes, c, i);
    }
    for (; p < p_end; p += lanes) {
        argmin_consider_slot(slot_base, p, c, i);
    }
}
#endif

#endif
