#version 460
// Compaction of a collapsed BVH, step 1 (CPU twin: bvh::compact::ranks): a 1 for every node
// slot that lives (its parent link is not VKRT_DEAD), a 0 for a slot the leaf collapse freed.
// The exclusive scan of these flags (prims::scan) is each live node's index in the compacted
// structure.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "include/vkrt/bvh_node.glsl"

// The built structure's references, then its parent links from `parents_at` on.
layout(std430, binding = 0) readonly buffer Refs { uint refs[]; };
layout(std430, binding = 1) writeonly buffer Rank { uint rank[]; };
layout(push_constant) uniform Push {
    uint n_nodes;
    uint parents_at;
} pc;

void main() {
    uint i = linear_invocation_id();
    if (i < pc.n_nodes) {
        rank[i] = uint(refs[pc.parents_at + i] != VKRT_DEAD);
    }
}
