#version 460
// The SAH leaf collapse's second pass (CPU twin: collapse::collapse): whether each node
// lives (neither it nor an ancestor collapsed) and how many references its leaves will hold
// (a leaf child's, or a collapsed child's subtree's). Both are scanned next: a live node's
// new index and its first reference.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "include/vkrt/bvh_node.glsl"

layout(std430, binding = 0) readonly buffer Nodes { VkrtBvhNode nodes[]; };
layout(std430, binding = 1) readonly buffer Refs { uint refs[]; };
layout(std430, binding = 2) readonly buffer Costs { uint costs[]; };
layout(std430, binding = 3) writeonly buffer Live { uint live[]; };
layout(std430, binding = 4) writeonly buffer LeafRefs { uint leaf_refs[]; };
layout(push_constant) uniform Push {
    uint n_nodes;
    uint parents_at;
    uint max_leaf;
} pc;

#define COLLAPSE_NO_DECIDE
#include "accel/bvh/collapse.glsl"

uint leaf_child_refs(uint index, uint count) {
    if (count > 0u) {
        return count;
    }
    if (index != VKRT_NO_NODE && costs[COST_COLLAPSE(index)] != 0u) {
        return costs[COST_COUNT(index)];
    }
    return 0u;
}

void main() {
    uint i = linear_invocation_id();
    if (i >= pc.n_nodes) {
        return;
    }
    bool alive = node_lives(i, pc.parents_at, pc.max_leaf);
    VkrtBvhNode n = nodes[i];
    live[i] = uint(alive);
    uint refs_below = leaf_child_refs(n.a_index, n.a_count) + leaf_child_refs(n.b_index, n.b_count);
    leaf_refs[i] = alive ? refs_below : 0u;
}
