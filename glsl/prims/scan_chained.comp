#version 460
// Single-pass chained scan with decoupled fallback (Merrill & Garland 2016's decoupled
// look-back; the fallback of Levien & Smith 2022): every tile publishes its sum, then looks
// back over its predecessors' published sums. A predecessor that has published nothing
// yet is never waited for: the looking-back subgroup reduces that tile's input itself and
// goes on. No workgroup ever waits for another, so this terminates on drivers without
// forward-progress guarantees (lavapipe runs a thread's workgroups one after another), and
// the input is read from memory once instead of twice (reduce-then-scan; the ROLLED form
// reads a lane's granules again, from its cache).
//
// The output must not alias the input: a fallback re-reads a predecessor's input.
//
// Layout: a tile is one subgroup's lanes x ROUNDS granules (each lane owns ROUNDS
// consecutive granules): subgroups scan, publish and look back on their own, so the
// kernel has no barrier and no shared memory. On lavapipe a barrier is a coroutine switch
// that saves every live register of the subgroup (here its whole tile) and restores it:
// the workgroup-tile version of this kernel (three barriers) measured 1.4-2x slower.
// A granule is a u64vec4 (32 bytes): on lavapipe every load or store is a loop over lanes
// and components, so 64-bit components halve the loop trips of a uvec4. For the same
// reason the look-back reads a tile's word from one lane and broadcasts it.
// FLAGS=1: the input is 0/1 bytes, a granule of input holds 4x the elements.
//
// Every branch runs on lavapipe with a lane mask whatever its condition (both sides of an
// `if`), so the granule straddling n is handled in loops whose trip count is 0 except in
// the one invocation that owns it, instead of per-granule branches.
//
// State per tile t (zeroed by the host before the dispatch): one 64-bit word, the flag in
// the high half (0 nothing, 1 the tile's sum published, 2 the inclusive prefix through t
// published) and the value in the low half, written and read with relaxed 64-bit atomics
// by one lane of the subgroup (reading it in every lane measured 1.3x slower overall).
// Flag and value in one word need no acquire/release ordering between two words — which
// matters on lavapipe (Mesa 22.3), where an acquire or a memory barrier is a coroutine
// switch: inside the look-back's loop it desynchronised the workgroup's barriers and lost
// the tile's results.
//
// Needs shaderInt64 and shaderBufferInt64Atomics; without them src/prims/scan.rs records
// the reduce-then-scan passes instead.
//! variant u32 FLAGS=0
//! variant flags FLAGS=1
//! variant u32_rolled FLAGS=0 ROLLED=1
//! variant flags_rolled FLAGS=1 ROLLED=1
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#extension GL_ARB_gpu_shader_int64 : require
#extension GL_EXT_shader_atomic_int64 : require
#extension GL_KHR_shader_subgroup_ballot : require
#extension GL_EXT_control_flow_attributes : require
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
    [[unroll]] for (uint k = 0; k < WORDS; k++) {
        s += word_sum(word_of(g, k));
    }
    return s;
}

// Granule g of the input: full granules in one load, the one straddling n from `tail`.
GRANULE load_granule(uint g, uint full_granules, uint straddle, GRANULE tail) {
    GRANULE v = g == straddle ? tail : GRANULE(0);
    if (g < full_granules) {
        v = in_g[g];
    }
    return v;
}

void publish(uint tile, uint flag, uint value) {
    atomicExchange(state[1 + tile], pack64(uvec2(value, flag)));
}

// The sum of every tile before `tile`, in every lane of the subgroup. Lanes agree on
// every decision through a broadcast of the first lane's load.
uint look_back(uint tile, uint lanes) {
    uint granules_per_tile = lanes * ROUNDS;
    uint exclusive = 0;
    uint j = tile;
    uint flag = 0;
    while (flag != FLAG_INCLUSIVE && j > 0) {
        j--;
        // One lane reads (an atomic read-modify-write: one 64-bit access whatever the
        // driver does with plain 64-bit loads; a relaxed atomic, so no barrier), all agree.
        uint64_t word = 0;
        if (subgroupElect()) {
            word = atomicAdd(state[1 + j], uint64_t(0));
        }
        uvec2 published = unpack32(word);
        published = uvec2(subgroupBroadcastFirst(published.x), subgroupBroadcastFirst(published.y));
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
    uint lanes = subgroup_lanes();
    // Tiles in the order subgroups start (state[0] counts them), not by workgroup id, so a
    // look-back only ever walks over tiles that are running. Lavapipe hands each thread a
    // contiguous range of workgroup ids, and it silently ends a loop after 65,535 trips:
    // numbered by id, the first tile of a later range walked back over tens of thousands of
    // tiles and lost its prefix (found by the 2^24 + 3 twin test).
    uint tile = 0;
    if (subgroupElect()) {
        tile = uint(atomicAdd(state[0], uint64_t(1)));
    }
    tile = subgroupBroadcastFirst(tile);
    uint tile_elements = lanes * ROUNDS * EPG;
    if (tile * tile_elements >= n) {
        if (n == 0 && tile == 0 && subgroupElect()) {
            total[0] = 0; // an empty scan still reports its total
        }
        return;
    }
    uint first = (tile * lanes + gl_SubgroupInvocationID) * ROUNDS; // this lane's first granule
    uint full_granules = n / EPG;
    uint straddle = full_granules; // the granule holding n's last elements, if n % EPG != 0
    uint owns_straddle = straddle >= first && straddle < first + ROUNDS && n % EPG != 0 ? 1u : 0u;

    uint tail_words[WORDS];
    [[unroll]] for (uint k = 0; k < WORDS; k++) {
        tail_words[k] = 0;
    }
    // Constant trip counts inside, so the arrays stay in registers (an array indexed by a
    // loop variable lives in memory on lavapipe, every access a loop over lanes).
    for (uint once = 0; once < owns_straddle; once++) {
        uint n_words = (n + EPW - 1) / EPW;
        [[unroll]] for (uint k = 0; k < WORDS; k++) {
            if (straddle * WORDS + k < n_words) {
                uint w = in1[straddle * WORDS + k];
#if FLAGS
                uint valid = min(n - (straddle * WORDS + k) * EPW, 4u);
                w &= valid == 4 ? 0xffffffffu : (1u << (8 * valid)) - 1;
#endif
                tail_words[k] = w;
            }
        }
    }
    GRANULE tail = granule_of(tail_words);

    // ROLLED=1: the lane's granules are read twice, summed here and scanned into place
    // after the look-back, in loops kept rolled. Else they are held in registers across the
    // look-back, the loops unrolled: 128 granules per lane (the large u32 tiles) then make
    // a kernel that Mesa 25.0's lavapipe takes 25 s to compile, and that runs slower there
    // than the rolled one; Mesa 26's runs it faster (DeviceInfo::rolled_scan_tiles).
    uint thread_sum = 0;
#if ROLLED
    [[dont_unroll]] for (uint r = 0; r < ROUNDS; r++) {
        thread_sum += granule_sum(load_granule(first + r, full_granules, straddle, tail));
    }
#else
    GRANULE granules[ROUNDS];
    [[unroll]] for (uint r = 0; r < ROUNDS; r++) {
        GRANULE v = load_granule(first + r, full_granules, straddle, tail);
        granules[r] = v;
        thread_sum += granule_sum(v);
    }
#endif
    uint inclusive = subgroup_inclusive_add(thread_sum);
    uint tile_sum = subgroupShuffle(inclusive, lanes - 1);
    if (tile > 0 && subgroupElect()) {
        publish(tile, FLAG_AGGREGATE, tile_sum);
    }
    uint exclusive = look_back(tile, lanes);
    if (subgroupElect()) {
        publish(tile, FLAG_INCLUSIVE, exclusive + tile_sum);
        if ((n - 1) / tile_elements == tile) {
            total[0] = exclusive + tile_sum;
        }
    }

    uint base = exclusive + inclusive - thread_sum;
    uint add_self = pc.inclusive != 0 ? 1u : 0u;
    // Output granules of WORDS u32 each: EPW of them per input granule.
    uint full_out = n / WORDS;
    GRANULE tail_out = GRANULE(0);
#if ROLLED
    [[dont_unroll]] for (uint r = 0; r < ROUNDS; r++) {
        GRANULE v = load_granule(first + r, full_granules, straddle, tail);
#else
    [[unroll]] for (uint r = 0; r < ROUNDS; r++) {
        GRANULE v = granules[r];
#endif
        [[unroll]] for (uint q = 0; q < EPW; q++) {
            uint o = (first + r) * EPW + q;
            uint w[WORDS];
            [[unroll]] for (uint k = 0; k < WORDS; k++) {
#if FLAGS
                uint x = (word_of(v, (q * WORDS + k) / 4) >> (8 * ((q * WORDS + k) % 4))) & 0xffu;
#else
                uint x = word_of(v, k);
#endif
                w[k] = base + x * add_self;
                base += x;
            }
            if (o < full_out) {
                out_g[o] = granule_of(w);
            }
            if (o == full_out) {
                tail_out = granule_of(w);
            }
        }
    }
    uint owns_tail_out = full_out >= first * EPW && full_out < (first + ROUNDS) * EPW && n % WORDS != 0 ? 1u : 0u;
    for (uint once = 0; once < owns_tail_out; once++) {
        [[unroll]] for (uint k = 0; k < WORDS; k++) {
            if (full_out * WORDS + k < n) {
                out1[full_out * WORDS + k] = word_of(tail_out, k);
            }
        }
    }
}
