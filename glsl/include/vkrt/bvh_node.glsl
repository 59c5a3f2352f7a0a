// The BVH node the builders and refits write (`VkrtBvhNode` in src/accel/bvh/layout.rs, 64
// bytes; read by the traversal, common/bvh.glsl), and box unions in the total order on
// ±0 (vkrt_fmin_total, common/kdtree.glsl), so every union is the CPU twins' bit for bit.
#ifndef VKRT_COMMON_BVH_NODE_GLSL
#define VKRT_COMMON_BVH_NODE_GLSL

#include "kdtree.glsl"

#define VKRT_NO_NODE 0xffffffffu
// The parent link of a node slot a leaf collapse freed (collapse::VKRT_DEAD).
#define VKRT_DEAD 0xfffffffeu

struct VkrtBvhNode {
    vec3 a_min;
    uint a_index;
    vec3 a_max;
    uint a_count;
    vec3 b_min;
    uint b_index;
    vec3 b_max;
    uint b_count;
};

// Children of `n` that are nodes (not leaves, not missing): what a climbing pass waits for.
uint vkrt_node_children(VkrtBvhNode n) {
    return uint(n.a_count == 0u && n.a_index != VKRT_NO_NODE) + uint(n.b_count == 0u && n.b_index != VKRT_NO_NODE);
}

vec3 vkrt_vmin(vec3 a, vec3 b) {
    return vec3(vkrt_fmin_total(a.x, b.x), vkrt_fmin_total(a.y, b.y), vkrt_fmin_total(a.z, b.z));
}

vec3 vkrt_vmax(vec3 a, vec3 b) {
    return vec3(vkrt_fmax_total(a.x, b.x), vkrt_fmax_total(a.y, b.y), vkrt_fmax_total(a.z, b.z));
}

#endif
