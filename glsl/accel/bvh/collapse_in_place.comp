#version 460
// The SAH leaf collapse's last pass for trees whose references lie in depth-first order,
// every subtree a contiguous run (the LBVH's Morton order; CPU twin:
// collapse::collapse_in_place): no reference moves, so this one pass replaces the flags,
// the scan and the write of accel/bvh/collapse_write.comp. Every invocation copies one
// reference; every node learns whether it lives, and a live node points each collapsed
// child at its run — the first reference of its leftmost leaf — as a leaf of the count the
// cost pass found. Nodes keep their slots: a removed node's parent link becomes VKRT_DEAD,
// and the live nodes are counted into the word after the parent links (zero before), where
// compaction reads how many there are.
// Only live nodes are written, and the walks below read only removed nodes, costs and
// parent links: no invocation reads what another writes.
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_KHR_shader_subgroup_basic : require
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "include/vkrt/bvh_node.glsl"

layout(std430, binding = 0) buffer Nodes { VkrtBvhNode nodes[]; };
// The builder's references, then its parent links from `parents_at` on.
layout(std430, binding = 1) readonly buffer Refs { uint refs[]; };
layout(std430, binding = 2) readonly buffer Costs { uint costs[]; };
// The structure's references, parent links and live-node count.
layout(std430, binding = 3) buffer OutRefs { uint out_refs[]; };
layout(push_constant) uniform Push {
    uint n_nodes;
    uint parents_at;
    uint max_leaf;
} pc;

#define COLLAPSE_NO_DECIDE
#define COLLAPSE_COUNT_LIVE
#include "accel/bvh/collapse.glsl"

// The first reference below `node` in depth-first order (collapse::first_ref): a collapsed
// subtree holds at most MAX_COLLAPSE_LEAF (32) primitives, so the walk down is short.
uint first_ref(uint node) {
    for (uint step = 0u; step < 32u; step++) {
        VkrtBvhNode n = nodes[node];
        bool a = n.a_count > 0u || n.a_index != VKRT_NO_NODE;
        uint index = a ? n.a_index : n.b_index;
        uint count = a ? n.a_count : n.b_count;
        if (count > 0u) {
            return index;
        }
        if (index == VKRT_NO_NODE) {
            break;
        }
        node = index;
    }
    return 0u;
}

// A collapsed child becomes a leaf over its run; true where the child changed.
bool relay(inout uint index, inout uint count) {
    if (count > 0u || index == VKRT_NO_NODE || costs[COST_COLLAPSE(index)] == 0u) {
        return false;
    }
    count = costs[COST_COUNT(index)];
    index = first_ref(index);
    return true;
}

void main() {
    uint i = linear_invocation_id();
    if (i < pc.parents_at) {
        out_refs[i] = refs[i];
    }
    bool alive = i < pc.n_nodes && node_lives(i, pc.parents_at, pc.max_leaf);
    count_live(alive, pc.parents_at + pc.n_nodes);
    if (i >= pc.n_nodes) {
        return;
    }
    if (!alive) {
        out_refs[pc.parents_at + i] = VKRT_DEAD;
        return;
    }
    out_refs[pc.parents_at + i] = refs[pc.parents_at + i];
    VkrtBvhNode n = nodes[i];
    if (relay(n.a_index, n.a_count)) {
        nodes[i].a_index = n.a_index;
        nodes[i].a_count = n.a_count;
    }
    if (relay(n.b_index, n.b_count)) {
        nodes[i].b_index = n.b_index;
        nodes[i].b_count = n.b_count;
    }
}
