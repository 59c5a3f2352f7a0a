#version 460
// Radix sort, pass 3 of 3 per digit: every element of the tile moves to
// offsets[digit * blocks + tile] + its stable rank among the tile's elements of that digit.
// Two ways to rank, both deterministic on any subgroup size and schedule:
//
// counters: each invocation owns a contiguous run of TILE / workgroup elements and counts
//   its digits in its own column of shared counters ctr[digit][invocation]. One exclusive
//   scan of the counters in digit-major order gives every (digit, invocation) the tile
//   position of its first element; a second walk over the run hands out positions in
//   order. Stable because runs follow invocation order and each run is walked in order.
//   No subgroup operations (one workgroup scan per tile); memory and lane work per element
//   are few fixed shared-memory accesses, but the counters take 2^BITS x workgroup words.
//
// match: each subgroup owns a contiguous chunk of the tile and walks it in rounds of one
//   element per lane. In a round, lanes holding the same digit find each other with BITS
//   ballots (the warp-level "match" of Onesweep and multisplit); a lane's rank is the number
//   of its peers on lower lanes plus the subgroup's running count of that digit, which the
//   round's last peer then advances. With several subgroups, a first walk counts each
//   chunk's digits and the counts are scanned per digit in subgroup order. Shared memory:
//   (workgroup / 4) x 2^BITS words, so it suits wide digits on wide workgroups.
//
// Both: a tile whose keys all have the same digit (sorted input, the zero top bits of small
// keys) skips the ranking and moves as one contiguous run. The host picks workgroup sizes
// whose shared memory fits (src/prims/radix_sort.rs).
//! variant counters RANKING_COUNTERS=1
//! variant match RANKING_COUNTERS=0
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_ballot : require
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "common/subgroup_scan.glsl"
#include "prims/radix_common.glsl"

layout(std430, binding = 0) readonly buffer KeysIn { uint keys_in[]; };
layout(std430, binding = 1) readonly buffer KeysIn4 { uvec4 keys_in4[]; };
layout(std430, binding = 2) readonly buffer ValuesIn { uint values_in[]; };
layout(std430, binding = 3) readonly buffer ValuesIn4 { uvec4 values_in4[]; };
layout(std430, binding = 4) readonly buffer Counts { uint counts[]; };
layout(std430, binding = 5) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 6) writeonly buffer KeysOut { uint keys_out[]; };
layout(std430, binding = 7) writeonly buffer ValuesOut { uint values_out[]; };

shared uint tile_digit;

#if RANKING_COUNTERS

shared uint ctr[RADIX * gl_WorkGroupSize.x]; // ctr[digit * workgroup + invocation]
shared uint tile_delta[RADIX]; // offsets[digit][tile] - the digit's first tile position

// Keys (or values) e .. e+3, those at or past `last` zero. Whole granules load 16 bytes.
uvec4 load_keys(uint e, uint last) {
    if (e + 4 <= last) {
        return keys_in4[e / 4];
    }
    uvec4 k = uvec4(0);
    for (uint c = 0; e + c < last; c++) {
        k[c] = keys_in[e + c];
    }
    return k;
}

uvec4 load_values(uint e, uint last) {
    if (e + 4 <= last) {
        return values_in4[e / 4];
    }
    uvec4 v = uvec4(0);
    for (uint c = 0; e + c < last; c++) {
        v[c] = values_in[e + c];
    }
    return v;
}

void scatter_tile(uint block, uint start, uint end) {
    uint wg = gl_WorkGroupSize.x;
    uint t = gl_LocalInvocationID.x;
    uint first = start + t * (TILE / wg); // TILE / wg is a multiple of 4
    uint last = min(first + TILE / wg, end); // below `first` past the end: an empty run
    for (uint d = 0; d < pc.digits; d++) {
        ctr[d * wg + t] = 0;
    }
    for (uint e = first; e < last; e += 4) {
        uvec4 k = load_keys(e, last);
        for (uint c = 0; c < 4 && e + c < last; c++) {
            atomicAdd(ctr[digit_of(read_key(k[c])) * wg + t], 1u);
        }
    }
    barrier();
    // Exclusive scan of ctr[0 .. digits * wg) in memory (digit-major) order: invocation t
    // scans the words [t * digits, (t + 1) * digits) around one workgroup scan.
    uint segment = t * pc.digits;
    uint sum = 0;
    for (uint j = 0; j < pc.digits; j++) {
        sum += ctr[segment + j];
    }
    uint total;
    uint position = workgroup_exclusive_add(sum, total);
    for (uint j = 0; j < pc.digits; j++) {
        uint c = ctr[segment + j];
        ctr[segment + j] = position;
        position += c;
    }
    barrier();
    for (uint d = t; d < pc.digits; d += wg) {
        tile_delta[d] = offsets[d * pc.blocks + block] - ctr[d * wg];
    }
    barrier();
    for (uint e = first; e < last; e += 4) {
        uvec4 k = load_keys(e, last);
        uvec4 v = load_values(e, last);
        for (uint c = 0; c < 4 && e + c < last; c++) {
            uint key = read_key(k[c]);
            uint d = digit_of(key);
            uint dst = atomicAdd(ctr[d * wg + t], 1u) + tile_delta[d];
            keys_out[dst] = written_key(key);
            values_out[dst] = v[c];
        }
    }
}

#else

shared uint run[(gl_WorkGroupSize.x / 4u) * RADIX]; // run[subgroup * RADIX + digit]

// The lanes (of those with `valid`) whose digit equals this lane's.
uvec4 match_digit(uint d, bool valid) {
    uvec4 peers = subgroupBallot(valid);
    for (uint b = 0; b < BITS; b++) {
        bool bit = ((d >> b) & 1u) != 0;
        uvec4 ballot = subgroupBallot(bit);
        peers &= bit ? ballot : ~ballot;
    }
    return peers;
}

// Every subgroup runs the same number of rounds, `live_rounds` (those of the first chunk,
// the longest), its lanes past the tile's end idle. The spec asks only subgroup-uniform
// control flow of subgroupBarrier(), but Mesa 25.0 lavapipe takes it for a workgroup barrier:
// with per-subgroup trip counts the workgroup's barrier count went out of step there and
// subgroups were released early or never (every Match case wrong; probe:
// glsl/gpu/subgroup_barrier_probe.comp). Equal counts are right under both readings, and
// cost idle rounds in a tile's last chunks only.
void scatter_tile(uint block, uint start, uint end) {
    uint lanes = subgroup_lanes();
    uint lane = gl_SubgroupInvocationID;
    uint row = gl_SubgroupID * RADIX;
    uint rounds = TILE / gl_WorkGroupSize.x;
    uint first = start + gl_SubgroupID * rounds * lanes;
    uint live_rounds = min(rounds, (end - start + lanes - 1) / lanes);

    // Phase 1 (several subgroups): the digit counts of this subgroup's chunk.
    if (gl_NumSubgroups > 1) {
        for (uint d = lane; d < pc.digits; d += lanes) {
            run[row + d] = 0;
        }
        subgroupBarrier(); // also orders shared memory within the subgroup
        for (uint r = 0; r < live_rounds; r++) {
            uint e = first + r * lanes + lane;
            bool valid = e < end;
            uint d = valid ? digit_of(read_key(keys_in[e])) : 0;
            uvec4 peers = match_digit(d, valid);
            uint count = subgroupBallotBitCount(peers);
            if (valid && subgroupBallotExclusiveBitCount(peers) == count - 1) {
                run[row + d] += count; // the round's last peer of each digit
            }
            subgroupBarrier();
        }
    }
    barrier();

    // Phase 2: each chunk's first position per digit: the tile's offset plus the counts of
    // the earlier chunks.
    for (uint d = gl_LocalInvocationID.x; d < pc.digits; d += gl_WorkGroupSize.x) {
        uint sum = offsets[d * pc.blocks + block];
        if (gl_NumSubgroups == 1) {
            run[d] = sum;
        } else {
            for (uint s = 0; s < gl_NumSubgroups; s++) {
                uint c = run[s * RADIX + d];
                run[s * RADIX + d] = sum;
                sum += c;
            }
        }
    }
    barrier();

    // Phase 3: rank and move, round by round.
    for (uint r = 0; r < live_rounds; r++) {
        uint e = first + r * lanes + lane;
        bool valid = e < end;
        uint key = valid ? read_key(keys_in[e]) : 0;
        uint d = digit_of(key);
        uvec4 peers = match_digit(d, valid);
        uint count = subgroupBallotBitCount(peers);
        uint rank = subgroupBallotExclusiveBitCount(peers);
        uint before = valid ? run[row + d] : 0;
        subgroupBarrier(); // every peer has read before the last one advances the count
        if (valid && rank == count - 1) {
            run[row + d] = before + count;
        }
        subgroupBarrier();
        if (valid) {
            keys_out[before + rank] = written_key(key);
            values_out[before + rank] = values_in[e];
        }
    }
}

#endif

void main() {
    uint block = linear_group_id();
    if (block >= pc.blocks) {
        return; // a whole workgroup of the folded grid's overshoot
    }
    uint start = block * TILE;
    uint end = min(start + TILE, pc.n);

    // All keys of the tile share one digit iff that digit's count is the tile's length.
    if (gl_LocalInvocationID.x == 0) {
        uint d0 = digit_of(read_key(keys_in[start]));
        tile_digit = counts[d0 * pc.blocks + block] == end - start ? d0 : RADIX;
    }
    barrier();
    uint d0 = tile_digit;
    if (d0 < RADIX) {
        uint dst = offsets[d0 * pc.blocks + block];
        for (uint i = gl_LocalInvocationID.x; start + i < end; i += gl_WorkGroupSize.x) {
            keys_out[dst + i] = written_key(read_key(keys_in[start + i]));
            values_out[dst + i] = values_in[start + i];
        }
        return;
    }
    scatter_tile(block, start, end);
}
