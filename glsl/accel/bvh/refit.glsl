// The child boxes a refit computes (CPU twin: src/accel/bvh/refit.rs), shared by the climbing
// refit and the per-depth refit. Include after declaring `node_pairs` (VkrtBvhNode as word pairs,
// accel/bvh/pairs.glsl), `refs` (the references) and `box_pairs` (three pairs per primitive).
#ifndef VKRT_ACCEL_BVH_REFIT_GLSL
#define VKRT_ACCEL_BVH_REFIT_GLSL

#include "accel/bvh/pairs.glsl"

// The box of a child (index, count); `lo`/`hi` hold its old box (kept for a missing child).
void child_box(uint index, uint count, inout vec3 lo, inout vec3 hi) {
    if (count > 0u) {
        lo = vec3(1.0 / 0.0);
        hi = vec3(-1.0 / 0.0);
        for (uint k = 0u; k < count; k++) {
            vec3 plo, phi;
            LOAD_PRIM_BOX(box_pairs, refs[index + k], plo, phi);
            lo = vkrt_vmin(lo, plo);
            hi = vkrt_vmax(hi, phi);
        }
    } else if (index != VKRT_NO_NODE) {
        VkrtBvhNode c = LOAD_NODE(node_pairs, index);
        lo = vkrt_vmin(c.a_min, c.b_min);
        hi = vkrt_vmax(c.a_max, c.b_max);
    }
}

// Node `i` with its child boxes refit, stored whole.
VkrtBvhNode refit_node(uint i) {
    VkrtBvhNode n = LOAD_NODE(node_pairs, i);
    child_box(n.a_index, n.a_count, n.a_min, n.a_max);
    child_box(n.b_index, n.b_count, n.b_min, n.b_max);
    STORE_NODE(node_pairs, i, n);
    return n;
}

#endif
