// The child boxes a refit computes (CPU twin: src/accel/bvh/refit.rs), shared by the climbing
// refit and the per-depth refit. Include after declaring `nodes` (BvhNode), `refs` (the
// references) and `boxes` (six floats per primitive).
#ifndef VKRT_ACCEL_BVH_REFIT_GLSL
#define VKRT_ACCEL_BVH_REFIT_GLSL

// The box of a child (index, count); `lo`/`hi` hold its old box (kept for a missing child).
void child_box(uint index, uint count, inout vec3 lo, inout vec3 hi) {
    if (count > 0u) {
        lo = vec3(1.0 / 0.0);
        hi = vec3(-1.0 / 0.0);
        for (uint k = 0u; k < count; k++) {
            uint p = refs[index + k];
            lo = vmin(lo, vec3(boxes[6u * p], boxes[6u * p + 1u], boxes[6u * p + 2u]));
            hi = vmax(hi, vec3(boxes[6u * p + 3u], boxes[6u * p + 4u], boxes[6u * p + 5u]));
        }
    } else if (index != NO_NODE) {
        BvhNode c = nodes[index];
        lo = vmin(c.a_min, c.b_min);
        hi = vmax(c.a_max, c.b_max);
    }
}

#endif
