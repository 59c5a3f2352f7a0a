// Shared by the leaf-collapse kernels (CPU twin: src/accel/bvh/collapse.rs): a node's
// primitive count, SAH cost and decision, three words per node in `costs`.
#ifndef VKRT_ACCEL_BVH_COLLAPSE_GLSL
#define VKRT_ACCEL_BVH_COLLAPSE_GLSL

#include "common/bvh_node.glsl"

#define COST_COUNT(i) (3u * (i))
#define COST_SAH(i) (3u * (i) + 1u)
#define COST_COLLAPSE(i) (3u * (i) + 2u)

// Half the surface area of a box, 0 for an empty one (layout::half_area, `(x*y + y*z) + z*x`).
float half_area(vec3 lo, vec3 hi) {
    if (any(greaterThan(lo, hi))) {
        return 0.0;
    }
    precise vec3 d = hi - lo;
    precise float s = d.x * d.y + d.y * d.z + d.z * d.x;
    return s;
}

#endif
