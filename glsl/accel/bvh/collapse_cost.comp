#version 460
// The SAH leaf collapse's bottom-up pass (CPU twin: collapse::costs): every node's primitive
// count and SAH cost, and whether it becomes a leaf of its parent — at most `max_leaf`
// primitives and `C_isect·A·n <= C_trav·A + cost(a) + cost(b)`; the root never does. It climbs
// like the refit (accel/bvh/refit.comp): invocations whose node has only leaf children start,
// and the last child to arrive at a parent (an atomic visit counter) decides it, so nothing
// waits on another invocation. A child's words are visible before its arrival is counted.
layout(local_size_x_id = 0) in;
#extension GL_KHR_shader_subgroup_vote : require
#include "common/grid.glsl"
#include "include/vkrt/bvh_node.glsl"

layout(std430, binding = 0) readonly buffer Nodes { VkrtBvhNode nodes[]; };
// References, then one parent link per node from `parents_at` on.
layout(std430, binding = 1) readonly buffer Refs { uint refs[]; };
// One counter per node, zero before the dispatch.
layout(std430, binding = 2) coherent buffer Visits { uint visits[]; };
layout(std430, binding = 3) coherent buffer Costs { uint costs[]; };
layout(push_constant) uniform Push {
    uint n_nodes;
    uint parents_at;
    uint max_leaf;
    float c_trav;
    float c_isect;
} pc;

#include "accel/bvh/collapse.glsl"

void main() {
    uint i = linear_invocation_id();
    bool climbing = i < pc.n_nodes && vkrt_node_children(nodes[i]) == 0u;
    uint cur = i;
    for (uint round = 0u; round <= pc.n_nodes; round++) {
        if (!subgroupAny(climbing)) {
            break;
        }
        if (climbing) {
            decide(CollapseParams(pc.c_trav, pc.c_isect, pc.max_leaf), cur, nodes[cur]);
        }
        memoryBarrierBuffer(); // the words are visible before the arrival is counted
        if (climbing) {
            uint parent = refs[pc.parents_at + cur];
            if (parent == VKRT_NO_NODE) {
                climbing = false;
            } else {
                uint arrived = atomicAdd(visits[parent], 1u) + 1u;
                climbing = arrived >= vkrt_node_children(nodes[parent]);
                cur = parent;
            }
        }
        memoryBarrierBuffer(); // ... and read after it
    }
}
