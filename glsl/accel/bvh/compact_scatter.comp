#version 460
// Compaction of a collapsed BVH, step 2 (CPU twin: bvh::compact::renumber): every live node
// moves to its rank (the exclusive scan of the live flags) with its interior children and its
// parent renamed to theirs, so the compacted structure is the built one without the freed
// slots, node for node in index order (the root stays node 0). Leaves and missing children
// keep their words; the references move unchanged. Every invocation writes its own slots.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "include/vkrt/bvh_node.glsl"

layout(std430, binding = 0) readonly buffer Nodes { VkrtBvhNode nodes[]; };
// The built structure's references, then its parent links from `n_refs` on.
layout(std430, binding = 1) readonly buffer Refs { uint refs[]; };
layout(std430, binding = 2) readonly buffer Rank { uint rank[]; };
layout(std430, binding = 3) writeonly buffer OutNodes { VkrtBvhNode out_nodes[]; };
// The compacted structure's references, then its parent links from `n_refs` on.
layout(std430, binding = 4) writeonly buffer OutRefs { uint out_refs[]; };
layout(push_constant) uniform Push {
    uint n_nodes;
    uint n_refs;
} pc;

// An interior child's new index; a leaf's first reference and a missing child as they are.
uint renamed(uint index, uint count) {
    return count == 0u && index != VKRT_NO_NODE ? rank[index] : index;
}

void main() {
    uint i = linear_invocation_id();
    if (i < pc.n_refs) {
        out_refs[i] = refs[i];
    }
    if (i >= pc.n_nodes) {
        return;
    }
    uint parent = refs[pc.n_refs + i];
    if (parent == VKRT_DEAD) {
        return;
    }
    uint j = rank[i];
    VkrtBvhNode n = nodes[i];
    n.a_index = renamed(n.a_index, n.a_count);
    n.b_index = renamed(n.b_index, n.b_count);
    out_nodes[j] = n;
    out_refs[pc.n_refs + j] = parent == VKRT_NO_NODE ? VKRT_NO_NODE : rank[parent];
}
