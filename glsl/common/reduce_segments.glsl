// The segmented argmin's plan record and segment bounds (src/prims/segmented.rs; keep the
// PLAN_* word offsets in sync with the constants there).
//
// The plan lives in the first PLAN_WORDS words of the scratch buffer, written by
// prims/segmented_plan.comp and read by the other two kernels and by the indirect
// dispatches. The (tile, segment) partial winners follow it: the pair for tile t and segment
// s lives at word PLAN_WORDS + 2 (t + s). Walking the pairs in element order steps t or s
// up by at least one each time, so t + s never repeats.
//
// Requires, before inclusion: a `uint offsets[]` buffer (segment s = [offsets[s],
// offsets[s + 1]) of the flat cost array).
#ifndef VKRT_COMMON_REDUCE_SEGMENTS_GLSL
#define VKRT_COMMON_REDUCE_SEGMENTS_GLSL

#define PLAN_SEGMENT_GROUPS 0u // uvec3: indirect workgroup counts of segmented_segments
#define PLAN_TILE_GROUPS 3u    // uvec3: indirect workgroup counts of segmented_tiles
#define PLAN_COUNT 6u          // segments (the count buffer clamped to max_segments)
#define PLAN_FIRST 7u          // first element of segment 0
#define PLAN_TOTAL 8u          // end of the last segment
#define PLAN_FIRST_TILE 9u     // tile of PLAN_FIRST
#define PLAN_TILES 10u         // tiles the tiled path runs (0: it does not run)
#define PLAN_WORDS 16u

// Segment s clamped into [0, n_costs] and to a non-negative length, so malformed offsets
// give unspecified results but never an out-of-bounds access.
uvec2 segment_bounds(uint s, uint n_costs) {
    uint begin = min(offsets[s], n_costs);
    uint end = clamp(offsets[s + 1u], begin, n_costs);
    return uvec2(begin, end);
}

// The last segment s < count with offsets[s] <= x: for x in [offsets[0], offsets[count]),
// the non-empty segment that holds element x.
uint segment_containing(uint x, uint count) {
    uint lo = 0u;
    uint hi = count;
    while (hi - lo > 1u) {
        uint mid = (lo + hi) >> 1;
        if (offsets[mid] <= x) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    return lo;
}

#endif
