// Argmin of (f32 cost, u32 index) pairs: the order, the subgroup butterfly and the workgroup
// reduction. Keep in sync with `CostIndex` and `argmin_cpu` in src/prims/reduce.rs.
//
// Order: lower cost first, then lower index; -0.0 and +0.0 compare equal, so the lower index
// wins between them. Costs are NaN-free. Indices are unique, so this is a total order and the
// winner is unique: the result does not depend on the order in which pairs are combined, and
// every kernel may combine them however is fastest.
//
// The subgroup step is Kolodzey's SAH shuffle reduction (Listing 6.7): the 64-bit pair
// moves as two 32-bit shuffles, here an xor butterfly (subgroupShuffleXor), so every lane
// ends with the subgroup's winner.
//
// Include after the `layout(local_size_x_id = 0) in;` line (the shared slots are sized by
// the workgroup). Define ARGMIN_COSTS4 as the name of a `vec4` cost array before including
// to get argmin_range().
#ifndef VKRT_COMMON_ARGMIN_GLSL
#define VKRT_COMMON_ARGMIN_GLSL

#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_shuffle : require

#include "common/reduce_lanes.glsl"

// The result of an empty argmin: (+inf, u32::MAX) (`CostIndex::NONE`).
#define ARGMIN_NONE_COST uintBitsToFloat(0x7f800000u)
#define ARGMIN_NONE_INDEX 0xffffffffu

bool argmin_better(float c, uint i, float best_c, uint best_i) {
    return c < best_c || (c == best_c && i < best_i);
}

void argmin_consider(float c, uint i, inout float best_c, inout uint best_i) {
    if (argmin_better(c, i, best_c, best_i)) {
        best_c = c;
        best_i = i;
    }
}

// Elements e .. e + 3 with costs v, in index order.
void argmin_consider4(vec4 v, uint e, inout float best_c, inout uint best_i) {
    argmin_consider(v.x, e, best_c, best_i);
    argmin_consider(v.y, e + 1u, best_c, best_i);
    argmin_consider(v.z, e + 2u, best_c, best_i);
    argmin_consider(v.w, e + 3u, best_c, best_i);
}

// Every lane ends with the subgroup's winner.
void subgroup_argmin(inout float c, inout uint i) {
    for (uint k = 1; k < reduce_subgroup_lanes(); k <<= 1) {
        float other_c = subgroupShuffleXor(c, k);
        uint other_i = subgroupShuffleXor(i, k);
        argmin_consider(other_c, other_i, c, i);
    }
}

#ifdef ARGMIN_SHARED
// The shared-memory workgroup reduction that Kolodzey's shuffle reduction replaced (Fig. 6.12;
// the ablation benchmark's baseline): every invocation stores its pair, then a tree over
// shared memory halves the live invocations with one barrier per step. No shuffles. The
// winner ends in invocation 0 (reduce_lane() == 0 in subgroup 0); the closing barrier makes
// a second call safe.
shared float argmin_tree_cost[gl_WorkGroupSize.x];
shared uint argmin_tree_index[gl_WorkGroupSize.x];

void workgroup_argmin(inout float c, inout uint i) {
    uint t = reduce_lane();
    argmin_tree_cost[t] = c;
    argmin_tree_index[t] = i;
    barrier();
    uint live = gl_WorkGroupSize.x;
    while (live > 1u) {
        uint half_live = (live + 1u) >> 1;
        if (t < live - half_live) {
            argmin_consider(argmin_tree_cost[t + half_live], argmin_tree_index[t + half_live], c, i);
            argmin_tree_cost[t] = c;
            argmin_tree_index[t] = i;
        }
        barrier();
        live = half_live;
    }
    c = argmin_tree_cost[0];
    i = argmin_tree_index[0];
    barrier();
}
#else
// One slot per subgroup (subgroups have at least 4 lanes).
shared float argmin_slot_cost[gl_WorkGroupSize.x / 4];
shared uint argmin_slot_index[gl_WorkGroupSize.x / 4];

// The workgroup's winner, valid in subgroup 0 (reduce_lane() == 0 writes it), with one
// barrier (each one suspends and resumes every SIMD batch of the workgroup on llvmpipe):
// subgroup winners go to shared slots, then subgroup 0 alone reduces the slots. Call from
// uniform control flow, and put a barrier() between two calls (the second would overwrite
// slots the first may still be reading).
void workgroup_argmin(inout float c, inout uint i) {
    subgroup_argmin(c, i);
    uint count = gl_NumSubgroups;
    if (count == 1) {
        return;
    }
    if (gl_SubgroupInvocationID == 0) {
        argmin_slot_cost[gl_SubgroupID] = c;
        argmin_slot_index[gl_SubgroupID] = i;
    }
    barrier();
    if (gl_SubgroupID == 0) {
        c = ARGMIN_NONE_COST;
        i = ARGMIN_NONE_INDEX;
        for (uint slot = gl_SubgroupInvocationID; slot < count; slot += reduce_subgroup_lanes()) {
            argmin_consider(argmin_slot_cost[slot], argmin_slot_index[slot], c, i);
        }
        subgroup_argmin(c, i);
    }
}

#endif

#ifdef ARGMIN_COSTS4
// Folds the costs of elements [begin, end) of ARGMIN_COSTS4 into this invocation's (c, i).
// The aligned body is cut into one contiguous chunk of 16-byte blocks per subgroup, its
// lanes taking consecutive blocks (coalesced on GPUs; on llvmpipe each SIMD batch runs to
// completion on its own, so it must stream through one chunk rather than stride over the
// whole range). The unaligned head and tail (< 4 elements each) take one element per
// invocation; a workgroup has at least 4.
void argmin_range(uint begin, uint end, inout float c, inout uint i) {
    if (begin >= end) {
        return;
    }
    uint lane = reduce_lane();
    uint body_begin = (begin + 3u) >> 2;
    uint body_end = end >> 2;
    if (body_begin >= body_end) {
        for (uint e = begin + lane; e < end; e += gl_WorkGroupSize.x) {
            argmin_consider(ARGMIN_COSTS4[e >> 2][e & 3u], e, c, i);
        }
        return;
    }
    uint head = begin + lane;
    if (head < 4u * body_begin) {
        argmin_consider(ARGMIN_COSTS4[head >> 2][head & 3u], head, c, i);
    }
    uint lanes = reduce_subgroup_lanes();
    uint chunk = (body_end - body_begin + gl_NumSubgroups - 1u) / gl_NumSubgroups;
    chunk = (chunk + lanes - 1u) / lanes * lanes;
    uint chunk_begin = body_begin + gl_SubgroupID * chunk;
    uint chunk_end = min(chunk_begin + chunk, body_end);
    // REDUCE_UNROLL blocks per iteration (llvmpipe's loop budget, common/reduce_lanes.glsl),
    // then the rest one at a time (fewer than REDUCE_UNROLL iterations).
    uint j = chunk_begin + gl_SubgroupInvocationID;
    for (; j + 3u * lanes < chunk_end; j += 4u * lanes) {
        vec4 v0 = ARGMIN_COSTS4[j];
        vec4 v1 = ARGMIN_COSTS4[j + lanes];
        vec4 v2 = ARGMIN_COSTS4[j + 2u * lanes];
        vec4 v3 = ARGMIN_COSTS4[j + 3u * lanes];
        argmin_consider4(v0, 4u * j, c, i);
        argmin_consider4(v1, 4u * (j + lanes), c, i);
        argmin_consider4(v2, 4u * (j + 2u * lanes), c, i);
        argmin_consider4(v3, 4u * (j + 3u * lanes), c, i);
    }
    for (; j < chunk_end; j += lanes) {
        argmin_consider4(ARGMIN_COSTS4[j], 4u * j, c, i);
    }
    uint tail = 4u * body_end + lane;
    if (tail < end) {
        argmin_consider(ARGMIN_COSTS4[tail >> 2][tail & 3u], tail, c, i);
    }
}
#endif

#endif
