#version 460
// Scan pass 3 of 3 (or the only pass when n fits one tile): rescan each tile starting from
// its carry-in (the exclusive scan of the tile sums) and write the prefix sums.
// Output is always u32 elements; the last tile also writes the grand total to total[0].
//
// All ROUNDS granules of an invocation are loaded first and scanned together: one subgroup
// scan per round without barriers, then a single shared-memory pass over the
// ROUNDS x subgroups totals — two barriers per tile instead of three per round (barriers
// are coroutine switches on lavapipe, and stalls everywhere).
//
// CONTIGUOUS=1: each invocation owns ROUNDS consecutive granules instead (one subgroup scan
// per tile instead of one per round; strided loads) — `vkrt bench prims` compares them.
//! variant u32 FLAGS=0
//! variant u32_shuffle FLAGS=0 SCAN_SHUFFLE=1
//! variant u32_contiguous FLAGS=0 CONTIGUOUS=1
//! variant flags FLAGS=1
//! variant flags_contiguous FLAGS=1 CONTIGUOUS=1
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "common/subgroup_scan.glsl"

layout(std430, binding = 0) readonly buffer In4 { uvec4 in4[]; };
layout(std430, binding = 1) readonly buffer In1 { uint in1[]; };
layout(std430, binding = 2) writeonly buffer Out4 { uvec4 out4[]; };
layout(std430, binding = 3) writeonly buffer Out1 { uint out1[]; };
layout(std430, binding = 4) readonly buffer Carries { uint carries[]; };
layout(std430, binding = 5) writeonly buffer Total { uint total[]; };
layout(std430, binding = 6) readonly buffer Counts { uint counts[]; };
layout(push_constant) uniform Push {
    uint capacity;
    uint has_carry; // 0: single tile, carry-in 0
    uint inclusive; // 1: inclusive scan, 0: exclusive
    uint count_index;
    uint count_mul;
    uint count_div; // 0: n = capacity
} pc;
#include "common/gpu_count.glsl"

#include "prims/scan_tile.glsl"

// Subgroup totals per round, round-major: [round * gl_NumSubgroups + subgroup].
shared uint round_sums[ROUNDS * (gl_WorkGroupSize.x / 4)];
shared uint tile_total;

void main() {
    uint n = gpu_count(pc.capacity, pc.count_div == 0u ? 0u : counts[pc.count_index], pc.count_mul, pc.count_div);
    uint group = linear_group_id();
    uint tile = tile_elements();
    uint tile_start = group * tile;
    if (tile_start >= n) {
        if (n == 0 && group == 0 && gl_LocalInvocationID.x == 0) {
            total[0] = 0; // an empty scan still reports its total
        }
        return;
    }
    uint lanes = subgroup_lanes();
    uint rank = gl_SubgroupID * lanes + gl_SubgroupInvocationID; // order of the scan
    uint first_granule = tile_start / EPG;

#ifndef CONTIGUOUS
#define CONTIGUOUS 0
#endif
#if CONTIGUOUS
#define GRANULE(r) (first_granule + rank * ROUNDS + (r))
    uvec4 words[ROUNDS];
    uint inclusive_sums[ROUNDS];
    uint thread_sum = 0;
    for (uint r = 0; r < ROUNDS; r++) {
        words[r] = load_granule_words(GRANULE(r), n);
        inclusive_sums[r] = thread_sum;
        thread_sum += granule_sum(words[r]);
    }
    uint thread_excl = subgroup_inclusive_add(thread_sum) - thread_sum;
    if (gl_SubgroupInvocationID == lanes - 1) {
        round_sums[gl_SubgroupID] = thread_excl + thread_sum;
    }
    for (uint r = 0; r < ROUNDS; r++) {
        inclusive_sums[r] += thread_excl;
    }
    const uint SLOTS_PER_ROUND = 0; // one slot per subgroup, not per round
#else
#define GRANULE(r) (first_granule + (r) * gl_WorkGroupSize.x + rank)
    uvec4 words[ROUNDS];
    uint inclusive_sums[ROUNDS];
    for (uint r = 0; r < ROUNDS; r++) {
        uint g = GRANULE(r);
        words[r] = load_granule_words(g, n);
        uint s = granule_sum(words[r]);
        inclusive_sums[r] = subgroup_inclusive_add(s);
        if (gl_SubgroupInvocationID == lanes - 1) {
            round_sums[r * gl_NumSubgroups + gl_SubgroupID] = inclusive_sums[r];
        }
        inclusive_sums[r] -= s; // now exclusive within the subgroup
    }
    const uint SLOTS_PER_ROUND = 1;
#endif
    barrier();
    if (gl_SubgroupID == 0) {
        uint carry = 0;
        uint count = (SLOTS_PER_ROUND == 0 ? 1 : ROUNDS) * gl_NumSubgroups;
        for (uint base = 0; base < count; base += lanes) {
            uint i = base + gl_SubgroupInvocationID;
            uint s = i < count ? round_sums[i] : 0;
            uint scanned = subgroup_inclusive_add(s);
            if (i < count) {
                round_sums[i] = carry + scanned - s;
            }
            carry += subgroupShuffle(scanned, lanes - 1);
        }
        if (gl_SubgroupInvocationID == 0) {
            tile_total = carry;
        }
    }
    barrier();

    uint carry_in = pc.has_carry != 0 ? carries[group] : 0;
    for (uint r = 0; r < ROUNDS; r++) {
        uint first = GRANULE(r) * EPG;
        if (first >= n) {
            break;
        }
        uint base = carry_in + round_sums[SLOTS_PER_ROUND * r * gl_NumSubgroups + gl_SubgroupID]
            + inclusive_sums[r];
        uvec4 w = words[r];
        if (first + EPG <= n) {
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
            for (uint i = 0; i < EPG && first + i < n; i++) {
                uint x = granule_element(w, i);
                out1[first + i] = pc.inclusive != 0 ? base + x : base;
                base += x;
            }
        }
    }
    if (rank == 0 && (n - 1) / tile == group) {
        total[0] = carry_in + tile_total;
    }
}
