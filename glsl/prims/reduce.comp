#version 460
// One pass of a device-wide reduction (src/prims/reduce.rs): workgroup g reduces tile g of
// `src` (TILE = workgroup size × ITEMS elements) and writes one partial, dst[dst_offset + g].
// The host repeats passes over the partials until one value is left.
//
// Layout, run-striped: runs of RUN = min(REDUCE_RUN, WG) consecutive reduce_lane()s own
// contiguous chunks of RUN·ITEMS/4 16-byte blocks, starting at block g·TILE/4 +
// (lane / RUN)·RUN·ITEMS/4, and lane r of a run reads blocks chunk + RUN·k + r, k < ITEMS/4.
// A run reads 128 contiguous bytes per step (coalesced on GPUs), each llvmpipe SIMD batch
// streams through its own chunk, and the assignment depends on the workgroup size only,
// never on the subgroup size. Elements past `n` read as the identity.
//
// sum_f32 fixes its order, so its CPU twin (`sum_f32_pass_cpu`) gives the same bits: each
// invocation keeps four running sums (one per vec4 component, in k order), folds them as
// (x + y) + (z + w), then the workgroup adds the invocation partials as a perfect binary tree
// in reduce_lane() order: xor butterflies in each subgroup, then the subgroup totals in
// shared memory, where lane l of subgroup 0 folds an aligned block of them as a perfect tree
// and butterflies combine the blocks. All counts are powers of two, so the whole is the same
// perfect tree whatever the subgroup size. Padding is -0.0, the exact identity of IEEE
// addition; `precise` keeps the compiler from reassociating or contracting. Sums of n = 0 are
// +0.0 (the kernel special-cases it).
//
// u32 sums wrap and use subgroupAdd (integer order does not matter). f32 min/max reduce the
// bits mapped to an order-preserving u32 key (-0.0 < +0.0, so they are order-independent
// too); empty inputs give +inf / -inf.
//! variant sum_u32 OP_SUM_U32
//! variant min_u32 OP_MIN_U32
//! variant max_u32 OP_MAX_U32
//! variant sum_f32 OP_SUM_F32
//! variant min_f32 OP_MIN_F32
//! variant max_f32 OP_MAX_F32
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_KHR_shader_subgroup_shuffle : require
layout(local_size_x_id = 0) in;
// Elements per invocation per tile: a multiple of 4, at most MAX_ITEMS_PER_INVOCATION
// (src/prims/reduce.rs; llvmpipe's loop budget, common/reduce_lanes.glsl).
layout(constant_id = 1) const uint ITEMS = 4;
#include "common/grid.glsl"
#include "common/reduce_lanes.glsl"

layout(std430, binding = 0) readonly buffer Src { uvec4 src[]; };
layout(std430, binding = 1) writeonly buffer Dst { uint dst[]; };
// Keep in sync with `PassPush` in src/prims/reduce.rs.
layout(push_constant) uniform Push {
    uint n;           // elements of src to reduce
    uint src_offset4; // where they start in src, in vec4 units
    uint dst_offset;  // where the partials go in dst, in elements
} pc;

// Order-preserving key of f32 bits: negative values flip all bits, others set the sign bit.
uint f32_key(uint bits) {
    return (bits & 0x80000000u) != 0u ? ~bits : bits | 0x80000000u;
}

uint f32_unkey(uint key) {
    return (key & 0x80000000u) != 0u ? key & 0x7fffffffu : ~key;
}

#if defined(OP_SUM_F32)
#define VALUE float
#define PAD_BITS 0x80000000u
#define IDENTITY uintBitsToFloat(0x80000000u)
#else
#define VALUE uint
#if defined(OP_SUM_U32) || defined(OP_MAX_U32)
#define PAD_BITS 0u
#elif defined(OP_MIN_U32)
#define PAD_BITS 0xffffffffu
#elif defined(OP_MIN_F32)
#define PAD_BITS 0x7f800000u // +inf
#elif defined(OP_MAX_F32)
#define PAD_BITS 0xff800000u // -inf
#endif
#if defined(OP_MIN_F32) || defined(OP_MAX_F32)
#define IDENTITY f32_key(PAD_BITS)
#else
#define IDENTITY PAD_BITS
#endif
#endif

#if defined(OP_SUM_F32)
float combine(float a, float b) {
    precise float r = a + b;
    return r;
}
// Perfect binary tree over the subgroup's lanes; every lane ends with the same bits
// (IEEE addition is commutative).
float subgroup_reduce(float v) {
    precise float acc = v;
    for (uint k = 1; k < reduce_subgroup_lanes(); k <<= 1) {
        acc = acc + subgroupShuffleXor(acc, k);
    }
    return acc;
}
#elif defined(OP_SUM_U32)
uint combine(uint a, uint b) { return a + b; }
uint subgroup_reduce(uint v) { return subgroupAdd(v); }
#elif defined(OP_MIN_U32) || defined(OP_MIN_F32)
uint combine(uint a, uint b) { return min(a, b); }
uint subgroup_reduce(uint v) { return subgroupMin(v); }
#else
uint combine(uint a, uint b) { return max(a, b); }
uint subgroup_reduce(uint v) { return subgroupMax(v); }
#endif

shared VALUE slots[gl_WorkGroupSize.x / 4];

// The workgroup's total, valid in subgroup 0, with one barrier (each one suspends and
// resumes every SIMD batch of the workgroup on llvmpipe, the dominant cost of a pass there):
// subgroup totals go to shared memory; then lane l of subgroup 0 reduces the aligned block
// of slots [l·m, (l + 1)·m), m = slots / lanes, alone (a perfect tree for the f32 sum,
// level by level in place), and a subgroup reduction combines the blocks. Slot and lane
// counts are powers of two, so for the f32 sum the whole is the perfect binary tree over the
// subgroup totals, which is the perfect tree over the invocations.
VALUE workgroup_reduce(VALUE v) {
    v = subgroup_reduce(v);
    uint count = gl_NumSubgroups;
    if (count == 1) {
        return v;
    }
    uint lanes = reduce_subgroup_lanes();
    if (gl_SubgroupInvocationID == 0) {
        slots[gl_SubgroupID] = v;
    }
    barrier();
    if (gl_SubgroupID == 0) {
        uint lane = gl_SubgroupInvocationID;
        if (count <= lanes) {
            v = lane < count ? slots[lane] : IDENTITY;
        } else {
            uint m = count / lanes;
            uint base = lane * m;
#if defined(OP_SUM_F32)
            for (uint width = m; width > 1u; width >>= 1) {
                for (uint q = 0; q < width / 2u; q++) {
                    slots[base + q] = combine(slots[base + 2u * q], slots[base + 2u * q + 1u]);
                }
            }
            v = slots[base];
#else
            v = slots[base];
            for (uint q = 1; q < m; q++) {
                v = combine(v, slots[base + q]);
            }
#endif
        }
        v = subgroup_reduce(v);
    }
    return v;
}

#if !defined(OP_SUM_F32) && !defined(OP_SUM_U32)
uvec4 fold4(uvec4 acc, uvec4 v) {
#if defined(OP_MIN_F32) || defined(OP_MAX_F32)
    v = uvec4(f32_key(v.x), f32_key(v.y), f32_key(v.z), f32_key(v.w));
#endif
    return uvec4(combine(acc.x, v.x), combine(acc.y, v.y), combine(acc.z, v.z),
                 combine(acc.w, v.w));
}
#endif

// The vec4 that holds the last elements when n is not a multiple of 4, padded.
uvec4 load_partial4(uint j) {
    uvec4 r = uvec4(PAD_BITS);
    for (uint c = 0; 4u * j + c < pc.n; c++) {
        r[c] = src[pc.src_offset4 + j][c];
    }
    return r;
}

void main() {
    const uint items4 = ITEMS / 4u;
    uint tile4 = gl_WorkGroupSize.x * items4;
    uint groups = max(1u, (pc.n + 4u * tile4 - 1u) / (4u * tile4));
    uint group = linear_group_id();
    if (group >= groups) {
        return;
    }
    uint lane = reduce_lane();
    // This invocation's blocks: j = begin + RUN·k, k < ITEMS / 4. The loop runs over the
    // whole ones (llvmpipe runs both sides of a branch that is not uniform, so no per-load
    // tail test); the partial one (if any) is the tile's last, added after them, and padding
    // after it would add identities: the order is the twin's.
    const uint run = min(REDUCE_RUN, gl_WorkGroupSize.x);
    uint chunk = group * tile4 + (lane / run) * (run * items4);
    uint begin = chunk + lane % run;
    uint whole = pc.n / 4u;
    uint end = min(chunk + run * items4, whole);
    bool partial = (pc.n & 3u) != 0u && whole >= begin && whole < chunk + run * items4
        && (whole - begin) % run == 0u;

#if defined(OP_SUM_F32)
    precise vec4 acc = uintBitsToFloat(uvec4(PAD_BITS));
    for (uint j = begin; j < end; j += run) {
        acc = acc + uintBitsToFloat(src[pc.src_offset4 + j]);
    }
    if (partial) {
        acc = acc + uintBitsToFloat(load_partial4(whole));
    }
    precise float part = (acc.x + acc.y) + (acc.z + acc.w);
#elif defined(OP_SUM_U32)
    uvec4 acc = uvec4(0u);
    for (uint j = begin; j < end; j += run) {
        acc += src[pc.src_offset4 + j];
    }
    if (partial) {
        acc += load_partial4(whole);
    }
    uint part = (acc.x + acc.y) + (acc.z + acc.w);
#else
    uvec4 acc = uvec4(IDENTITY);
    for (uint j = begin; j < end; j += run) {
        acc = fold4(acc, src[pc.src_offset4 + j]);
    }
    if (partial) {
        acc = fold4(acc, load_partial4(whole));
    }
    uint part = combine(combine(acc.x, acc.y), combine(acc.z, acc.w));
#endif

    VALUE total = workgroup_reduce(part);
    if (lane == 0) {
#if defined(OP_SUM_F32)
        dst[pc.dst_offset + group] = pc.n == 0 ? 0u : floatBitsToUint(total);
#elif defined(OP_MIN_F32) || defined(OP_MAX_F32)
        dst[pc.dst_offset + group] = f32_unkey(total);
#else
        dst[pc.dst_offset + group] = total;
#endif
    }
}
