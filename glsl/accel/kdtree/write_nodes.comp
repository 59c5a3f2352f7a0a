#version 460
// kd-tree Phase II: the level's node records in BFS order, and the leaves' reference ranges.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "accel/kdtree/level.glsl"

layout(std430, binding = 0) readonly buffer State { uint state[]; };
layout(std430, binding = 1) readonly buffer NodeRange { uint node_range[]; };
layout(std430, binding = 2) readonly buffer NodeSplit { uint node_split[]; };
layout(std430, binding = 3) readonly buffer InnerBefore { uint inner_before[]; };
layout(std430, binding = 4) readonly buffer LeafBefore { uint leaf_before[]; };
// The output nodes in two buffers (each within maxStorageBufferRange): node g is
// nodes0[g] below `split`, nodes1[g − split] from there on.
layout(std430, binding = 5) writeonly buffer Nodes0 { VkrtKdNode nodes0[]; };
layout(std430, binding = 6) writeonly buffer Nodes1 { VkrtKdNode nodes1[]; };
layout(push_constant) uniform Push { uint node_capacity; uint split; } pc;

void put(uint g, VkrtKdNode n) {
    if (g < pc.split) {
        nodes0[g] = n;
    } else {
        nodes1[g - pc.split] = n;
    }
}

void main() {
    uint i = linear_invocation_id();
    uint m = state[ST_NODES];
    uint g = state[ST_NODE_BASE] + i;
    if (i >= m || g >= pc.node_capacity) {
        return; // past capacity: kdtree_advance raises the overflow flag
    }
    uint kind = node_split[2u * i];
    if (kind == VKRT_KD_LEAF) {
        put(g, VkrtKdNode(0.0, VKRT_KD_LEAF, state[ST_REF_BASE] + leaf_before[i], node_range[2u * i + 1u]));
    } else {
        uint first_child = state[ST_NODE_BASE] + m + 2u * inner_before[i];
        put(g, VkrtKdNode(uintBitsToFloat(node_split[2u * i + 1u]), kind, first_child, 0u));
    }
}
