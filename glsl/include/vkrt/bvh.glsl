// BVH traversal, included by traverse.glsl (which declares the geometry buffers,
// vkrt_hit_primitive and vkrt_test_leaf). Nodes hold both children's boxes (Aila & Laine 2009); a child is an
// interior node (count 0), a leaf (count > 0 references from index on) or missing (count 0,
// index VKRT_NO_NODE). Two walks, the same decisions in the same order as src/trace/bvh_cpu.rs:
// a while-while stack walk (vkrt_trace_bvh_stack: interior nodes until a leaf is in hand, then the
// leaf; far children and leaves on the stack with their entry distance), or Novák's (2019)
// stackless bitstack (vkrt_trace_bvh_bitstack: parent links and one bit per level, "the other
// child still waits"). Trees are at most 128 levels deep (MAX_TRAVERSAL_DEPTH in
// src/accel/bvh/layout.rs: the SAH builder stops at 64, the LBVH's codes and indices give at
// most 95, PLOC one level per round), which sizes the stack (one entry per level at most)
// and the trail.
#ifndef VKRT_COMMON_BVH_GLSL
#define VKRT_COMMON_BVH_GLSL

#include "bvh_node.glsl"
#include "bvh_wide_node.glsl"

#define VKRT_BVH_MAX_DEPTH 128u
// The wide walk's stack: a wide level spans two binary ones (at most 64 levels), and each
// pushes at most three children.
#define VKRT_WIDE_STACK_SIZE 192u


// The nodes: in the nodes binding, as 16-byte units (VKRT_NODE_UNIT, traverse.glsl: texels,
// or one storage block whatever the structure), four per node, binary or wide; or at the
// structure's device address.
#ifndef VKRT_DEVICE_ADDRESS
VkrtBvhNode vkrt_load_bvh_node(uint i) {
    uint t = 4u * i;
    uvec4 a = VKRT_NODE_UNIT(t);
    uvec4 b = VKRT_NODE_UNIT(t + 1u);
    uvec4 c = VKRT_NODE_UNIT(t + 2u);
    uvec4 d = VKRT_NODE_UNIT(t + 3u);
    return VkrtBvhNode(uintBitsToFloat(a.xyz), a.w, uintBitsToFloat(b.xyz), b.w,
                   uintBitsToFloat(c.xyz), c.w, uintBitsToFloat(d.xyz), d.w);
}

VkrtWideNode vkrt_load_wide_node(uint i) {
    uint t = 4u * i;
    return VkrtWideNode(VKRT_NODE_UNIT(t), VKRT_NODE_UNIT(t + 1u), VKRT_NODE_UNIT(t + 2u),
                    VKRT_NODE_UNIT(t + 3u));
}
#elif VKRT_FP64_FALLBACK
// The same nodes as two 64-bit vectors each: on lavapipe every load is a loop over lanes and
// components, so eight 64-bit components cost half the trips of sixteen 32-bit ones.
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer VkrtBvhNodes { VkrtBvhNode v[]; };
VkrtBvhNodes vkrt_bvh_nodes_ref;
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer VkrtBvhNodes64 { u64vec4 v[]; };
VkrtBvhNodes64 vkrt_bvh_nodes64_ref;
#define vkrt_bvh_nodes64 vkrt_bvh_nodes64_ref.v

vec2 vkrt_two_floats(uint64_t w) {
    return uintBitsToFloat(unpack32(w));
}

uvec2 vkrt_two_uints(uint64_t w) {
    return unpack32(w);
}

VkrtBvhNode vkrt_load_bvh_node(uint i) {
    u64vec4 p = vkrt_bvh_nodes64[2u * i];
    u64vec4 q = vkrt_bvh_nodes64[2u * i + 1u];
    vec2 a0 = vkrt_two_floats(p.x);
    uvec2 a1 = vkrt_two_uints(p.y);
    vec2 a2 = vkrt_two_floats(p.z);
    uvec2 a3 = vkrt_two_uints(p.w);
    vec2 b0 = vkrt_two_floats(q.x);
    uvec2 b1 = vkrt_two_uints(q.y);
    vec2 b2 = vkrt_two_floats(q.z);
    uvec2 b3 = vkrt_two_uints(q.w);
    return VkrtBvhNode(vec3(a0, uintBitsToFloat(a1.x)), a1.y, vec3(a2, uintBitsToFloat(a3.x)), a3.y,
                   vec3(b0, uintBitsToFloat(b1.x)), b1.y, vec3(b2, uintBitsToFloat(b3.x)), b3.y);
}

VkrtWideNode vkrt_load_wide_node(uint i) {
    u64vec4 p = vkrt_bvh_nodes64[2u * i];
    u64vec4 q = vkrt_bvh_nodes64[2u * i + 1u];
    return VkrtWideNode(uvec4(unpack32(p.x), unpack32(p.y)), uvec4(unpack32(p.z), unpack32(p.w)),
                    uvec4(unpack32(q.x), unpack32(q.y)), uvec4(unpack32(q.z), unpack32(q.w)));
}
#else
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer VkrtBvhNodes { VkrtBvhNode v[]; };
VkrtBvhNodes vkrt_bvh_nodes_ref;
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer VkrtWideNodes { VkrtWideNode v[]; };
VkrtWideNodes vkrt_wide_nodes_ref;

VkrtBvhNode vkrt_load_bvh_node(uint i) {
    return vkrt_bvh_nodes_ref.v[i];
}

VkrtWideNode vkrt_load_wide_node(uint i) {
    return vkrt_wide_nodes_ref.v[i];
}
#endif

// A stack entry: the child (index, count) and the distance at which the ray enters it, in
// two words: the index, and the distance's bits with the leaf size (< 256) in the low eight.
// Clearing those bits rounds a distance >= 0 down, so an entry is dropped at a pop only when
// it lies beyond the closest hit (the CPU twins round the same way). One array of two
// components, not three: on lavapipe every component of a private array is zeroed at entry
// and read and written by its own gather and scatter.
uvec2 vkrt_stack_entry(uvec2 child, float t) {
    return uvec2(child.x, (floatBitsToUint(t) & ~0xffu) | child.y);
}

// The stack walks' pop: the nearest entry the ray still reaches before its closest hit
// (`have` false when none is left). A statement over the walk's own `top`, `cur`, `have` and
// `best_t`, and its stack's entries AT(i) (an accessor macro: GLSL passes arrays by copy; the
// walks' own array, or a ray query's, vkrt/ext_ray_query.glsl).
#define VKRT_BVH_POP_ON(AT)                                       \
    have = false;                                                 \
    while (top > 0u && !have) {                                   \
        VKRT_BVH_POP_ONE_ON(AT)                                   \
    }

// One pop of VKRT_BVH_POP_ON, with no loop (`top` > 0): `have` false when the entry lies
// beyond the closest hit and is dropped.
#define VKRT_BVH_POP_ONE_ON(AT)                                   \
    {                                                             \
        top--;                                                    \
        uvec2 e_ = AT(top);                                       \
        cur = uvec2(e_.x, e_.y & 0xffu);                          \
        have = uintBitsToFloat(e_.y & ~0xffu) <= best_t;          \
    }

// One step of the descent at the interior node `cur`: the nearer child hit becomes `cur`
// (ties: child a) and the other one goes on the stack; where neither is hit, NO_HIT runs.
#define VKRT_BVH_NODE_STEP_ON(AT, NO_HIT)                                              \
    {                                                                                  \
        steps++;                                                                       \
        VkrtBvhNode nd = vkrt_load_bvh_node(cur.x);                                    \
        float ta;                                                                      \
        float tb;                                                                      \
        bool hit_a = (nd.a_count > 0u || nd.a_index != VKRT_NO_NODE)                   \
            && vkrt_bvh_enter(nd.a_min, nd.a_max, r, inv_d, tmin, best_t, ta);         \
        bool hit_b = (nd.b_count > 0u || nd.b_index != VKRT_NO_NODE)                   \
            && vkrt_bvh_enter(nd.b_min, nd.b_max, r, inv_d, tmin, best_t, tb);         \
        uvec2 ca = uvec2(nd.a_index, nd.a_count);                                      \
        uvec2 cb = uvec2(nd.b_index, nd.b_count);                                      \
        if (hit_a && hit_b) {                                                          \
            bool b_first = tb < ta;                                                    \
            AT(top) = vkrt_stack_entry(b_first ? ca : cb, b_first ? ta : tb);          \
            top++;                                                                     \
            cur = b_first ? cb : ca;                                                   \
        } else if (hit_a || hit_b) {                                                   \
            cur = hit_a ? ca : cb;                                                     \
        } else {                                                                       \
            NO_HIT;                                                                    \
        }                                                                              \
    }

// The stack walks' descent: interior nodes, the nearer child first (ties: child a) and the
// other one on the stack, until a leaf is in hand (`cur.y` > 0), the stack is empty (`have`
// false) or the step cap is reached. A statement over the walk's `r`, `inv_d`, `tmin`,
// `steps` and VKRT_BVH_POP_ON's variables (the binary stack walk, the top-level walk of
// vkrt/instances.glsl and the ray query's walk of vkrt/ext_ray_query.glsl).
#define VKRT_BVH_DESCEND_ON(AT)                                                        \
    while (have && cur.y == 0u && steps <= VKRT_STEP_LIMIT) {                          \
        VKRT_BVH_NODE_STEP_ON(AT, VKRT_BVH_POP_ON(AT))                                 \
    }

// The walks' own stack: `stack` (VKRT_STACK_WALK_STATE).
#define VKRT_STACK_AT(i) stack[i]
#define VKRT_BVH_POP() VKRT_BVH_POP_ON(VKRT_STACK_AT)
#define VKRT_BVH_DESCEND() VKRT_BVH_DESCEND_ON(VKRT_STACK_AT)

// Where the ray enters the box within [t0, t1] (traverse.glsl's vkrt_clip_to_box).
bool vkrt_bvh_enter(vec3 bmin, vec3 bmax, VkrtRay r, vec3 inv_d, float t0, float t1, out float t_in) {
    float hi = t1;
    t_in = t0;
    return vkrt_clip_to_box(bmin, bmax, r, inv_d, t_in, hi);
}

uint vkrt_bvh_parent(uint node) {
    return VKRT_KD_REF(vkrt_scene_info.parents_at + node);
}

// The stack walk, "while-while" (Aila & Laine 2009): descend through interior nodes until a
// leaf is in hand, then test it, so that the lanes of a SIMD group test their leaves
// together instead of every node step carrying the leaf test under a mask. Entries keep the
// distance at which the ray enters them, and one that lies beyond the closest hit so far is
// dropped when popped.
VkrtWalkHit vkrt_trace_bvh_stack(VkrtRay r, float time, bool any_hit) {
    VKRT_WALK_START(r);
    VKRT_STACK_WALK_STATE(VKRT_BVH_MAX_DEPTH);
    // Every natural end returns inside the loop; the code after it runs when the step cap
    // ends the walk, or when a driver ends a loop on its own (Mesa 22.3's lavapipe stops
    // every loop of an invocation after 65,535 iterations in all): both report exhaustion,
    // never a silent miss.
    while (true) {
        VKRT_BVH_DESCEND();
        if (!have) {
            return best; // the stack is empty: the walk is complete
        }
        if (cur.y == 0u) {
            break; // an interior node still to visit: the step cap (or the driver) ended it
        }
        steps += cur.y;
        if (vkrt_test_leaf(cur.x, cur.y, r, sh, time, tmin, any_hit, best, best_t)) {
            return best;
        }
        VKRT_BVH_POP();
    }
    vkrt_trace_steps_exhausted = true;
    return best;
}

// The bitstack walk (Áfra & Szirmay-Kalos 2014; Novák 2019, Algorithm 3).
VkrtWalkHit vkrt_trace_bvh_bitstack(VkrtRay r, float time, bool any_hit) {
    VKRT_WALK_START(r);
    uvec4 trail = uvec4(0u); // one bit per level, 128 in all; .x the lowest word
    uint node = 0u;
    uint steps = 0u;
    // Every natural end returns inside the loop: after it, the step cap or the driver
    // (Mesa 22.3's loop budget, as in the stack walk) ended the walk.
    while (steps <= VKRT_STEP_LIMIT) {
        steps++;
        VkrtBvhNode nd = vkrt_load_bvh_node(node);
        uint inner[2] = uint[2](VKRT_NO_NODE, VKRT_NO_NODE);
        float t_in[2] = float[2](0.0, 0.0);
        for (uint which = 0u; which < 2u; which++) {
            vec3 bmin = which == 0u ? nd.a_min : nd.b_min;
            vec3 bmax = which == 0u ? nd.a_max : nd.b_max;
            uint index = which == 0u ? nd.a_index : nd.b_index;
            uint count = which == 0u ? nd.a_count : nd.b_count;
            float te;
            if (!vkrt_bvh_enter(bmin, bmax, r, inv_d, tmin, best_t, te)) {
                continue;
            }
            if (count > 0u) {
                steps += count;
                if (vkrt_test_leaf(index, count, r, sh, time, tmin, any_hit, best, best_t)) {
                    return best;
                }
            } else if (index != VKRT_NO_NODE) {
                inner[which] = index;
                t_in[which] = te;
            }
        }
        uint near = inner[0];
        uint far = inner[1];
        if (near == VKRT_NO_NODE) {
            near = far;
            far = VKRT_NO_NODE;
        } else if (far != VKRT_NO_NODE && t_in[1] < t_in[0]) {
            near = inner[1];
            far = inner[0];
        }
        if (near != VKRT_NO_NODE) {
            trail = (trail << 1u) | (uvec4(0u, trail.xyz) >> 31u);
            trail.x |= far != VKRT_NO_NODE ? 1u : 0u;
            node = near;
            continue;
        }
        // Dead end: climb to the deepest level whose other child waits, and take it if the
        // ray still enters its box.
        bool found = false;
        while (!found) {
            if (all(equal(trail, uvec4(0u)))) {
                return best;
            }
            while ((trail.x & 1u) == 0u) {
                steps++;
                node = vkrt_bvh_parent(node);
                trail = (trail >> 1u) | (uvec4(trail.yzw, 0u) << 31u);
            }
            trail.x ^= 1u;
            VkrtBvhNode pn = vkrt_load_bvh_node(vkrt_bvh_parent(node));
            bool node_is_a = pn.a_count == 0u && pn.a_index == node;
            uint sibling = node_is_a ? pn.b_index : pn.a_index;
            vec3 smin = node_is_a ? pn.b_min : pn.a_min;
            vec3 smax = node_is_a ? pn.b_max : pn.a_max;
            steps++;
            float te;
            found = vkrt_bvh_enter(smin, smax, r, inv_d, tmin, best_t, te);
            node = sibling;
        }
    }
    vkrt_trace_steps_exhausted = true;
    return best;
}

// Child k of a wide node: where the ray enters it (+inf and NO_CHILD where it does not).
void vkrt_wide_child(VkrtWideNode w, uint k, vec3 p, vec3 s, VkrtRay r, vec3 inv_d, float tmin, float best_t,
                out float t, out uvec2 c) {
    uint count = vkrt_wide_count(w, k);
    uint index = w.index[k];
    t = 1.0 / 0.0;
    c = uvec2(VKRT_NO_NODE, 0u);
    if (count == 0u && index == VKRT_NO_NODE) {
        return;
    }
    vec3 bmin;
    vec3 bmax;
    vkrt_wide_box(w, k, p, s, bmin, bmax);
    float te;
    if (vkrt_bvh_enter(bmin, bmax, r, inv_d, tmin, best_t, te)) {
        t = te;
        c = uvec2(index, count);
    }
}

// Compare-exchange of two children by entry distance (a sorting network: no loop).
#define VKRT_WIDE_ORDER(ta, ca, tb, cb) \
    if (tb < ta) {                 \
        float t_ = ta;             \
        ta = tb;                   \
        tb = t_;                   \
        uvec2 c_ = ca;             \
        ca = cb;                   \
        cb = c_;                   \
    }

#define VKRT_WIDE_PUSH_ON(AT, t, c)                     \
    if (c.x != VKRT_NO_NODE || c.y != 0u) {             \
        AT(top) = vkrt_stack_entry(c, t);               \
        top++;                                          \
    }

// The 4-wide walk's descent: at a node, its four children's boxes are tested, sorted by entry
// distance, pushed farthest first, and the nearest taken, until a leaf is in hand, the stack
// is empty or the step cap is reached. A statement over the same variables as
// VKRT_BVH_DESCEND_ON (the wide stack walk, and the ray query's walk of a wide bottom level).
#define VKRT_WIDE_DESCEND_ON(AT)                                            \
    while (have && cur.y == 0u && steps <= VKRT_STEP_LIMIT) {               \
        VKRT_WIDE_NODE_STEP_ON(AT, VKRT_BVH_POP_ON(AT))                     \
    }

// One step of VKRT_WIDE_DESCEND_ON at the interior node `cur`; where no child is hit, NO_HIT
// runs.
#define VKRT_WIDE_NODE_STEP_ON(AT, NO_HIT)                                  \
    {                                                                       \
        steps++;                                                            \
        VkrtWideNode w_ = vkrt_load_wide_node(cur.x);                       \
        vec3 p_ = uintBitsToFloat(w_.frame.xyz);                            \
        vec3 s_ = vkrt_wide_scales(w_.frame.w);                             \
        float t0, t1, t2, t3;                                               \
        uvec2 c0, c1, c2, c3;                                               \
        vkrt_wide_child(w_, 0u, p_, s_, r, inv_d, tmin, best_t, t0, c0);    \
        vkrt_wide_child(w_, 1u, p_, s_, r, inv_d, tmin, best_t, t1, c1);    \
        vkrt_wide_child(w_, 2u, p_, s_, r, inv_d, tmin, best_t, t2, c2);    \
        vkrt_wide_child(w_, 3u, p_, s_, r, inv_d, tmin, best_t, t3, c3);    \
        VKRT_WIDE_ORDER(t0, c0, t1, c1)                                     \
        VKRT_WIDE_ORDER(t2, c2, t3, c3)                                     \
        VKRT_WIDE_ORDER(t0, c0, t2, c2)                                     \
        VKRT_WIDE_ORDER(t1, c1, t3, c3)                                     \
        VKRT_WIDE_ORDER(t1, c1, t2, c2)                                     \
        VKRT_WIDE_PUSH_ON(AT, t3, c3)                                       \
        VKRT_WIDE_PUSH_ON(AT, t2, c2)                                       \
        VKRT_WIDE_PUSH_ON(AT, t1, c1)                                       \
        if (c0.x != VKRT_NO_NODE || c0.y != 0u) {                           \
            cur = c0;                                                       \
        } else {                                                            \
            NO_HIT;                                                         \
        }                                                                   \
    }

// The stack walk over the 4-wide nodes (Ylitie et al. 2017's layout, Aila & Laine's
// while-while order): VKRT_WIDE_DESCEND_ON to a leaf; leaves are tested when in hand.
// Wide node 0 is the root. Twin: `wide_stack` in src/trace/bvh_cpu.rs.
VkrtWalkHit vkrt_trace_bvh_wide(VkrtRay r, float time, bool any_hit) {
    VKRT_WALK_START(r);
    VKRT_STACK_WALK_STATE(VKRT_WIDE_STACK_SIZE);
    // As in the binary stack walk: every natural end returns inside the loop.
    while (true) {
        VKRT_WIDE_DESCEND_ON(VKRT_STACK_AT);
        if (!have) {
            return best;
        }
        if (cur.y == 0u) {
            break; // the step cap (or the driver) ended the walk
        }
        steps += cur.y;
        if (vkrt_test_leaf(cur.x, cur.y, r, sh, time, tmin, any_hit, best, best_t)) {
            return best;
        }
        VKRT_BVH_POP();
    }
    vkrt_trace_steps_exhausted = true;
    return best;
}

#endif
