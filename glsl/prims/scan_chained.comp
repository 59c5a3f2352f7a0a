#version 460
// Single-pass chained scan with decoupled fallback (Merrill & Garland 2016's decoupled
// look-back; the fallback of Levien & Smith 2022): every tile publishes its sum, then looks
// back over its predecessors' published sums. A predecessor that has published nothing
// yet is never waited for: the looking-back subgroup reduces that tile's input itself and
// goes on. No workgroup ever waits for another, so this terminates on drivers without
// forward-progress guarantees (lavapipe runs a thread's workgroups one after another), and
// the input is read once instead of twice (reduce-then-scan).
//
// The output must not alias the input: a fallback re-reads a predecessor's input.
//
// Layout: a tile is WG x ROUNDS granules; invocation `rank` owns ROUNDS consecutive
// granules (one subgroup scan per tile). A granule is a u64vec4 (32 bytes; on
// lavapipe every load or store is a loop over lanes and components, so 64-bit components
// halve the loop trips of a uvec4).
// FLAGS=1: the input is 0/1 bytes, a granule of input holds 4x the elements.
//
// Every branch runs on lavapipe with a lane mask whatever its condition (both sides of an
// `if`), so the granule straddling n is handled in loops whose trip count is 0 except in
// the one invocation that owns it, instead of per-granule branches.
//
// State per tile t (zeroed by the host before the dispatch): one 64-bit word, the flag in
// the high half (0 nothing, 1 the tile's sum published, 2 the inclusive prefix through t
// published) and the value in the low half, written and read with relaxed 64-bit atomics.
// Flag and value in one word need no acquire/release ordering between two words — which
// matters on lavapipe (Mesa 22.3), where an acquire or a memory barrier is a coroutine
// switch: inside the look-back's loop it desynchronised the workgroup's barriers and lost
// the tile's results.
//
// Needs shaderInt64 and shaderBufferInt64Atomics; without them src/prims/scan.rs records
// the reduce-then-scan passes instead.
//! variant u32 FLAGS=0
//! variant flags FLAGS=1
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#extension GL_ARB_gpu_shader_int64 : require
#extension GL_EXT_shader_atomic_int64 : require
#extension GL_KHR_shader_subgroup_ballot : require
#define GRANULE u64vec4
#define WORDS 8u
#if FLAGS
#define EPW 4u // elements per input word
#else
#define EPW 1u
#endif
#define EPG (WORDS * EPW) // elements per input granule
layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint ROUNDS = 4;
// Tests only: ignore published sums, reduce every predecessor from the input.
layout(constant_id = 2) const uint FORCE_FALLBACK = 0;
#include "common/grid.glsl"
#include "common/subgroup_scan.glsl"

layout(std430, binding = 0) readonly buffer InG { GRANULE in_g[]; };
layout(std430, binding = 1) readonly buffer In1 { uint in1[]; };
layout(std430, binding = 2) writeonly buffer OutG { GRANULE out_g[]; };
layout(std430, binding = 3) writeonly buffer Out1 { uint out1[]; };
layout(std430, binding = 4) buffer State { uint64_t state[]; };
layout(std430, binding = 5) writeonly buffer Total { uint total[]; };
layout(std430, binding = 6) readonly buffer Counts { uint counts[]; };
layout(push_constant) uniform Push {
    uint capacity;
    uint inclusive; // 1: inclusive scan, 0: exclusive
    uint count_index;
    uint count_mul;
    uint count_div; // 0: n = capacity
} pc;
#include "common/gpu_count.glsl"

const uint FLAG_AGGREGATE = 1;
const uint FLAG_INCLUSIVE = 2;

shared uint subgroup_prefix[gl_WorkGroupSize.x / 4];
shared uint tile_prefix;
shared uint tile_id;

uint word_of(GRANULE g, uint k) {
    uvec2 pair = unpack32(g[k / 2]);
    return pair[k % 2];
}

GRANULE granule_of(uint w[WORDS]) {
    return u64vec4(pack64(uvec2(w[0], w[1])), pack64(uvec2(w[2], w[3])), pack64(uvec2(w[4], w[5])),
        pack64(uvec2(w[6], w[7])));
}

uint word_sum(uint w) {
#if FLAGS
    return (w * 0x01010101u) >> 24; // bytes are 0 or 1: the byte sum lands in the top byte
#else
    return w;
#endif
}

uint granule_sum(GRANULE g) {
    uint s = 0;
    for (uint k = 0; k < WORDS; k++) {
        s += word_sum(word_of(g, k));
    }
    return s;
}

void publish(uint tile, uint flag, uint value) {
    atomicExchange(state[1 + tile], pack64(uvec2(value, flag)));
}

// Run by subgroup 0 alone: the sum of every tile before `tile`. Lanes agree on every
// decision through a broadcast of the first lane's load.
uint look_back(uint tile, uint lanes) {
    uint granules_per_tile = gl_WorkGroupSize.x * ROUNDS;
    uint exclusive = 0;
    uint j = tile;
    uint flag = 0;
    while (flag != FLAG_INCLUSIVE && j > 0) {
        j--;
        uvec2 published = unpack32(atomicAdd(state[1 + j], uint64_t(0)));
        published = uvec2(subgroupBroadcast(published.x, 0), subgroupBroadcast(published.y, 0));
        flag = FORCE_FALLBACK != 0 ? 0 : published.y;
        // Not published yet: reduce its input here (it lies wholly below n). A loop of no
        // trips elsewhere: lavapipe runs both sides of every branch.
        uint fallback_granules = flag == 0 ? granules_per_tile : 0;
        uint s = 0;
        for (uint q = gl_SubgroupInvocationID; q < fallback_granules; q += lanes) {
            s += granule_sum(in_g[j * granules_per_tile + q]);
        }
        uint fallback_sum = subgroupAdd(s);
        exclusive += flag == 0 ? fallback_sum : published.x;
    }
    return exclusive;
}

void main() {
    uint n = gpu_count(pc.capacity, pc.count_div == 0u ? 0u : counts[pc.count_index], pc.count_mul, pc.count_div);
    // Tiles in the order workgroups start (state[0] counts them), not by workgroup id: a
    // driver may hand each thread a contiguous range of workgroup ids (lavapipe does), and
    // the first tile of a later range would then reduce every tile before it itself.
    if (gl_LocalInvocationID.x == 0) {
        tile_id = uint(atomicAdd(state[0], uint64_t(1)));
    }
    barrier();
    uint tile = tile_id;
    uint tile_elements = gl_WorkGroupSize.x * ROUNDS * EPG;
    if (tile * tile_elements >= n) {
        if (n == 0 && tile == 0 && gl_LocalInvocationID.x == 0) {
            total[0] = 0; // an empty scan still reports its total
        }
        return;
    }
    uint lanes = subgroup_lanes();
    uint rank = gl_SubgroupID * lanes + gl_SubgroupInvocationID;
    uint first = (tile * gl_WorkGroupSize.x + rank) * ROUNDS; // this invocation's first granule
    uint full_granules = n / EPG;
    uint straddle = full_granules; // the granule holding n's last elements, if n % EPG != 0
    uint owns_straddle = straddle >= first && straddle < first + ROUNDS && n % EPG != 0 ? 1u : 0u;

    uint tail_words[WORDS];
    for (uint k = 0; k < WORDS; k++) {
        tail_words[k] = 0;
    }
    for (uint once = 0; once < owns_straddle; once++) {
        uint n_words = (n + EPW - 1) / EPW;
        for (uint k = 0; k < WORDS && straddle * WORDS + k < n_words; k++) {
            uint w = in1[straddle * WORDS + k];
#if FLAGS
            uint valid = min(n - (straddle * WORDS + k) * EPW, 4u);
            w &= valid == 4 ? 0xffffffffu : (1u << (8 * valid)) - 1;
#endif
            tail_words[k] = w;
        }
    }
    GRANULE tail = granule_of(tail_words);

    GRANULE granules[ROUNDS];
    uint thread_sum = 0;
    for (uint r = 0; r < ROUNDS; r++) {
        uint g = first + r;
        GRANULE v = g == straddle ? tail : GRANULE(0);
        if (g < full_granules) {
            v = in_g[g];
        }
        granules[r] = v;
        thread_sum += granule_sum(v);
    }

    uint inclusive = subgroup_inclusive_add(thread_sum);
    if (gl_SubgroupInvocationID == lanes - 1) {
        subgroup_prefix[gl_SubgroupID] = inclusive;
    }
    barrier();
    if (gl_SubgroupID == 0) {
        uint carry = 0;
        for (uint base = 0; base < gl_NumSubgroups; base += lanes) {
            uint i = base + gl_SubgroupInvocationID;
            uint s = i < gl_NumSubgroups ? subgroup_prefix[i] : 0;
            uint scanned = subgroup_inclusive_add(s);
            if (i < gl_NumSubgroups) {
                subgroup_prefix[i] = carry + scanned - s;
            }
            carry += subgroupShuffle(scanned, lanes - 1);
        }
        // carry: this tile's sum.
        if (tile > 0 && subgroupElect()) {
            publish(tile, FLAG_AGGREGATE, carry);
        }
        uint exclusive = look_back(tile, lanes);
        if (subgroupElect()) {
            publish(tile, FLAG_INCLUSIVE, exclusive + carry);
            tile_prefix = exclusive;
            if ((n - 1) / tile_elements == tile) {
                total[0] = exclusive + carry;
            }
        }
    }
    barrier();

    uint base = tile_prefix + subgroup_prefix[gl_SubgroupID] + inclusive - thread_sum;
    uint add_self = pc.inclusive != 0 ? 1u : 0u;
    // Output granules of WORDS u32 each: EPW of them per input granule.
    uint full_out = n / WORDS;
    uint tail_out[WORDS];
    for (uint k = 0; k < WORDS; k++) {
        tail_out[k] = 0;
    }
    for (uint r = 0; r < ROUNDS; r++) {
        for (uint q = 0; q < EPW; q++) {
            uint o = (first + r) * EPW + q;
            uint w[WORDS];
            for (uint k = 0; k < WORDS; k++) {
#if FLAGS
                uint x = (word_of(granules[r], (q * WORDS + k) / 4) >> (8 * ((q * WORDS + k) % 4))) & 0xffu;
#else
                uint x = word_of(granules[r], k);
#endif
                w[k] = base + x * add_self;
                base += x;
            }
            if (o < full_out) {
                out_g[o] = granule_of(w);
            }
            if (o == full_out) {
                tail_out = w;
            }
        }
    }
    uint owns_tail_out = full_out >= first * EPW && full_out < (first + ROUNDS) * EPW && n % WORDS != 0 ? 1u : 0u;
    for (uint once = 0; once < owns_tail_out; once++) {
        for (uint k = 0; full_out * WORDS + k < n; k++) {
            out1[full_out * WORDS + k] = tail_out[k];
        }
    }
}
