#version 460
// Scan pass 3 of 3 (or the only pass when n fits one tile): rescan each tile starting from
// its carry-in (the exclusive scan of the tile sums) and write the prefix sums.
// Output is always u32 elements; the last tile also writes the grand total to total[0].
//! variant u32 FLAGS=0
//! variant u32_shuffle FLAGS=0 SCAN_SHUFFLE=1
//! variant flags FLAGS=1
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "common/subgroup_scan.glsl"

layout(std430, binding = 0) readonly buffer In4 { uvec4 in4[]; };
layout(std430, binding = 1) readonly buffer In1 { uint in1[]; };
layout(std430, binding = 2) writeonly buffer Out4 { uvec4 out4[]; };
layout(std430, binding = 3) writeonly buffer Out1 { uint out1[]; };
layout(std430, binding = 4) readonly buffer Carries { uint carries[]; };
layout(std430, binding = 5) writeonly buffer Total { uint total[]; };
layout(push_constant) uniform Push {
    uint n;
    uint has_carry; // 0: single tile, carry-in 0
    uint inclusive; // 1: inclusive scan, 0: exclusive
} pc;

#include "prims/scan_tile.glsl"

void main() {
    uint group = linear_group_id();
    uint tile = tile_elements();
    uint tile_start = group * tile;
    if (tile_start >= pc.n) {
        if (pc.n == 0 && group == 0 && gl_LocalInvocationID.x == 0) {
            total[0] = 0; // an empty scan still reports its total
        }
        return;
    }
    uint carry = pc.has_carry != 0 ? carries[group] : 0;
    uint first_granule = tile_start / EPG;
    for (uint r = 0; r < ROUNDS; r++) {
        if (tile_start + r * gl_WorkGroupSize.x * EPG >= pc.n) {
            break; // uniform: depends on the workgroup and the round only
        }
        uint g = first_granule + r * gl_WorkGroupSize.x + gl_LocalInvocationID.x;
        uvec4 w = load_granule_words(g, pc.n);
        uint local_sum = granule_sum(w);
        uint round_total;
        uint base = carry + workgroup_exclusive_add(local_sum, round_total);
        uint first = g * EPG;
        if (first + EPG <= pc.n) {
            for (uint q = 0; q < EPG / 4; q++) {
                uvec4 o;
                for (uint k = 0; k < 4; k++) {
                    uint x = granule_element(w, 4 * q + k);
                    o[k] = pc.inclusive != 0 ? base + x : base;
                    base += x;
                }
                out4[first / 4 + q] = o;
            }
        } else {
            for (uint i = 0; i < EPG && first + i < pc.n; i++) {
                uint x = granule_element(w, i);
                out1[first + i] = pc.inclusive != 0 ? base + x : base;
                base += x;
            }
        }
        carry += round_total;
    }
    if (gl_LocalInvocationID.x == 0 && (pc.n - 1) / tile == group) {
        total[0] = carry;
    }
}
