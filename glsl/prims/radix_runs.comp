#version 460
// Radix sort with lane runs (the `Runs` ranking): every invocation owns one run of TILE
// consecutive elements and walks it in order on its own, like one thread of a CPU radix
// sort. The count table is digit-major over runs, table[digit * blocks + run], so one
// exclusive scan of it gives each (digit, run) its first output position, in key order and
// then run order: the sort is stable and its output a function of the input alone.
//
// histogram: the invocation zeroes its column of the table and counts its run's digits in it.
// scatter:   the column now holds the run's first positions (the scan's output); the
//            invocation hands them out in order, advancing its own counters.
//
// No shared memory, no barrier, no subgroup operation, no atomic: only the invocation that
// owns a column touches it, so plain loads and stores in program order suffice. This suits
// CPU devices: on lavapipe a barrier is a coroutine switch and every lane-varying access a
// loop over lanes, so the tile-wide rankings of radix_scatter.comp spend most of their time
// ranking; here an element costs its counter's load and store and its two stores. Runs are
// read 32 bytes (8 elements) at a time. On a GPU, lanes reading far-apart runs would not
// coalesce: src/prims/radix_sort.rs picks this ranking for CPU devices only.
//! variant histogram SCATTER=0
//! variant scatter SCATTER=1
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#extension GL_ARB_gpu_shader_int64 : require
#extension GL_EXT_control_flow_attributes : require
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "prims/radix_common.glsl"

// Binding numbers of radix_histogram.comp and radix_scatter.comp, so the host binds every
// ranking alike.
layout(std430, binding = 0) readonly buffer KeysG { u64vec4 keys_g[]; };
layout(std430, binding = 1) readonly buffer Keys1 { uint keys1[]; };
#if SCATTER
layout(std430, binding = 2) readonly buffer ValuesG { u64vec4 values_g[]; };
layout(std430, binding = 3) readonly buffer Values1 { uint values1[]; };
// The scanned offsets, advanced as positions are handed out.
layout(std430, binding = 5) buffer Table { uint table[]; };
layout(std430, binding = 6) writeonly buffer KeysOut { uint keys_out[]; };
layout(std430, binding = 7) writeonly buffer ValuesOut { uint values_out[]; };
#else
// The counts.
layout(std430, binding = 2) buffer Table { uint table[]; };
#endif

uint word_of(u64vec4 g, uint k) {
    uvec2 pair = unpack32(g[k / 2]);
    return pair[k % 2];
}

#if SCATTER
void place(uint run, uint raw_key, uint value) {
    uint key = read_key(raw_key);
    uint slot = digit_of(key) * pc.blocks + run;
    uint dst = table[slot];
    table[slot] = dst + 1;
    keys_out[dst] = written_key(key);
    values_out[dst] = value;
}
#else
void count(uint run, uint raw_key) {
    uint slot = digit_of(read_key(raw_key)) * pc.blocks + run;
    table[slot] = table[slot] + 1;
}
#endif

void main() {
    uint run = linear_invocation_id();
    if (run >= pc.blocks) {
        return;
    }
    uint first = run * TILE; // TILE is a multiple of 8: runs start on whole granules
    uint end = min(first + TILE, pc.n);
    uint whole_end = max(first, end & ~7u);
#if !SCATTER
    for (uint d = 0; d < pc.digits; d++) {
        table[d * pc.blocks + run] = 0;
    }
#endif
    for (uint g = first / 8; g < whole_end / 8; g++) {
        u64vec4 k = keys_g[g];
#if SCATTER
        u64vec4 v = values_g[g];
#endif
        [[unroll]] for (uint j = 0; j < 8; j++) {
#if SCATTER
            place(run, word_of(k, j), word_of(v, j));
#else
            count(run, word_of(k, j));
#endif
        }
    }
    // The last run's elements past the last whole granule: a loop of no trips elsewhere.
    for (uint e = whole_end; e < end; e++) {
#if SCATTER
        place(run, keys1[e], values1[e]);
#else
        count(run, keys1[e]);
#endif
    }
}
