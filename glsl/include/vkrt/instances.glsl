// The walk of a top level (vkrt/ray_query.glsl with VKRT_DEVICE_ADDRESS): a BVH over the
// instances' world boxes, whose leaves name instances; at each the ray moves into the
// instance's object space by its world-to-object rows (the direction not renormalised, so t
// keeps its meaning and the closest hit so far bounds the bottom level's walk) and the
// bottom level is walked with its own walk. A moving instance's object-to-world is its two
// steps around the ray's time interpolated, and inverted, per ray (as Embree's
// motion-blurred instances; vkrt/affine.glsl). CPU twin: `vkrt_trace_instances` in
// src/accel/instances.rs. Two levels only: a top level named by an instance reports the
// query exhausted, as any structure a walk does not serve.
#ifndef VKRT_INSTANCES_GLSL
#define VKRT_INSTANCES_GLSL
#include "affine.glsl"

// rows · (p, 1), summed left to right and rounded term by term, as the CPU twin.
vec3 vkrt_to_object(vec4 rows[3], vec3 p, float w) {
    precise vec3 q = vec3(rows[0].x * p.x + rows[0].y * p.y + rows[0].z * p.z,
                          rows[1].x * p.x + rows[1].y * p.y + rows[1].z * p.z,
                          rows[2].x * p.x + rows[2].y * p.y + rows[2].z * p.z);
    precise vec3 t = q + vec3(rows[0].w, rows[1].w, rows[2].w);
    return w != 0.0 ? t : q;
}

// The instance's world-to-object rows at `time`; false where its transform there is not
// invertible (the ray then misses it).
bool vkrt_world_to_object(VkrtInstanceRecord rec, float time, out vec4 rows[3]) {
    rows = rec.rows;
    uint steps = rec.motion.x;
    if (steps < 2u) {
        return true;
    }
    float f;
    uint k = vkrt_motion_segment(time, uintBitsToFloat(rec.motion.z),
                                 uintBitsToFloat(rec.motion.w), steps, f);
    uint first = rec.motion.y + k;
    return vkrt_invert_rows(vkrt_lerp_rows(vkrt_steps.v[first].rows,
                                           vkrt_steps.v[first + 1u].rows, f), rows);
}

// The closest hit (or any, with any_hit) over the instances whose mask shares a bit with
// `cull_mask`: its bottom-level hit, `geom` (geometry and primitive index in the bottom
// level, found while that level is in use) and `instance` (index, custom index). Ties in t
// go to the lowest instance index. Called with the top level in use; returns with it in use.
VkrtWalkHit vkrt_trace_instances(VkrtRay r, float time, bool any_hit, uint cull_mask, out uvec2 geom,
                    out uvec2 instance) {
    geom = uvec2(0xffffffffu);
    instance = uvec2(0xffffffffu, 0u);
    VKRT_WALK_START(r);
    VkrtInstances records = vkrt_instances;
    VKRT_STACK_WALK_STATE(VKRT_BVH_MAX_DEPTH);
    // The stack walk of vkrt_trace_bvh_stack (bvh.glsl), with instances at its leaves.
    while (true) {
        VKRT_BVH_DESCEND();
        if (!have) {
            return best;
        }
        if (cur.y == 0u) {
            break; // the step cap (or the driver) ended the walk
        }
        for (uint k = cur.x; k < cur.x + cur.y; k++) {
            uint i = VKRT_KD_REF(k);
            VkrtInstanceRecord rec = records.v[i];
            if (all(equal(rec.meta.xy, uvec2(0u))) || ((rec.meta.z >> 24u) & cull_mask) == 0u) {
                continue;
            }
            vec4 rows[3];
            if (!vkrt_world_to_object(rec, time, rows)) {
                continue;
            }
            VkrtRay ro = VkrtRay(vkrt_to_object(rows, r.o, 1.0), r.tmin, vkrt_to_object(rows, r.d, 0.0),
                         best_t);
            vkrt_use(packUint2x32(rec.meta.xy));
            VkrtWalkHit h = vkrt_walk(ro, time, any_hit);
            bool better = h.prim != VKRT_NO_HIT && !vkrt_trace_steps_exhausted
                && (instance.x == 0xffffffffu || h.t < best_t || (h.t == best_t && i < instance.x));
            if (better) {
                geom = vkrt_geometry_of(h.prim);
            }
            vkrt_use(vkrt_top);
            if (vkrt_trace_steps_exhausted) {
                return vkrt_miss_hit();
            }
            if (better) {
                best = h;
                best_t = h.t;
                instance = uvec2(i, rec.meta.z & 0xffffffu);
                if (any_hit) {
                    return best;
                }
            }
        }
        VKRT_BVH_POP();
    }
    vkrt_trace_steps_exhausted = true;
    return best;
}

#endif
