#version 460
// LBVH, passes 3 and 4 in one (CPU twin: lbvh::topology, then refit::refit, and with variant
// `costs` collapse::costs): the binary radix tree of the sorted codes built bottom-up with
// its boxes, after Apetrei's agglomerative LBVH construction (2014). One invocation per
// leaf climbs: a node of range [l, r] is its parent's child `a` when its right neighbour
// shares the longer prefix (δ(r) > δ(l - 1); δ as Karras's, equal codes told apart by their
// positions, so no two are equal), else child `b`; the parent splits at r or at l - 1. The
// two children meet at that split: an atomic exchange of their far ends tells the second
// to arrive the parent's range, and it completes the parent in the next round. Each node
// takes Karras's slot (a child `a` the slot of its last position, a child `b` of its first,
// the root 0), so the tree is Karras's (2012), bit for bit, boxes and collapse decisions
// (accel/bvh/collapse.glsl) included, without his topology pass's binary searches. Rounds
// run in subgroup-uniform control flow with every memory barrier reached by every lane, as
// in accel/bvh/refit.comp (Mesa 22.3's lavapipe), in workgroups of one subgroup; a round
// completes at least one node: never a spin.
// The `64` variants move nodes, boxes and codes as 64-bit pairs (accel/bvh/pairs.glsl).
//! variant boxes
//! variant boxes64 PAIRS64=1
//! variant costs COLLAPSE_COSTS=1
//! variant costs64 COLLAPSE_COSTS=1 PAIRS64=1
layout(local_size_x_id = 0) in;
#extension GL_KHR_shader_subgroup_vote : require
#include "common/grid.glsl"
#include "accel/bvh/pairs.glsl"

layout(std430, binding = 0) coherent buffer Nodes { WORD_PAIR node_pairs[]; };
// The sorted primitive ids (the leaves' references), then a parent link per node from n on.
layout(std430, binding = 1) buffer Refs { uint refs[]; };
// Six floats per primitive, min x, y, z, max x, y, z: three pairs.
layout(std430, binding = 2) readonly buffer Boxes { WORD_PAIR box_pairs[]; };
// The codes in sorted order, (high, low) words.
layout(std430, binding = 3) readonly buffer Codes { WORD_PAIR codes[]; };
// Per split: the far end of the child that arrived first; VKRT_NO_NODE before the dispatch.
layout(std430, binding = 4) coherent buffer Meet { uint meet[]; };
// `SceneInfo` (src/accel/primitives.rs): the root box is written.
layout(std430, binding = 5) buffer VkrtSceneInfoBinding {
    vec4 bounds_min;
    vec4 bounds_max;
    uint n_tris;
    uint n_spheres;
    uint has_motion;
    uint parents_at;
} info;
#ifdef COLLAPSE_COSTS
// Count, SAH cost and decision of every node (accel/bvh/collapse.glsl).
layout(std430, binding = 6) coherent buffer Costs { uint costs[]; };
layout(push_constant) uniform Push {
    uint n;
    uint max_leaf;
    float c_trav;
    float c_isect;
} pc;
#include "accel/bvh/collapse.glsl"
#else
layout(push_constant) uniform Push { uint n; } pc;
#endif

#include "accel/bvh/refit.glsl"

uint clz(uint x) {
    return uint(31 - findMSB(x)); // findMSB(0) = -1: 32
}

// δ(i): the common prefix of sorted codes i and i + 1 (Karras's δ; CPU twin: lbvh::delta).
int delta(uint i) {
    uvec2 ci = pair_uints(codes[i]);
    uvec2 cj = pair_uints(codes[i + 1u]);
    if (ci == cj) {
        return 64 + int(clz(i ^ (i + 1u)));
    }
    uint x = ci.x ^ cj.x;
    return int(x != 0u ? clz(x) : 32u + clz(ci.y ^ cj.y));
}

void main() {
    uint n = pc.n;
    uint i = linear_invocation_id();
    if (n == 1u) {
        // One leaf under the root; child b missing (lbvh::topology's single-primitive tree).
        if (i == 0u) {
            vec3 lo, hi;
            LOAD_PRIM_BOX(box_pairs, refs[0], lo, hi);
            vec3 none_lo = vec3(1.0 / 0.0);
            vec3 none_hi = vec3(-1.0 / 0.0);
            VkrtBvhNode root = VkrtBvhNode(lo, 0u, hi, 1u, none_lo, VKRT_NO_NODE, none_hi, 0u);
            STORE_NODE(node_pairs, 0u, root);
            refs[1] = VKRT_NO_NODE;
            info.bounds_min = vec4(vkrt_vmin(lo, none_lo), 0.0);
            info.bounds_max = vec4(vkrt_vmax(hi, none_hi), 0.0);
        }
        return;
    }
    // The node this lane completes next: range [l, r]; for l < r its split `s` and the box
    // of the child this lane brought (`a` where known_a).
    bool climbing = i < n;
    uint l = i;
    uint r = i;
    uint s = 0u;
    bool known_a = false;
    vec3 known_lo = vec3(0.0);
    vec3 known_hi = vec3(0.0);
    // Where this lane's node meets its sibling, and the end of its range the sibling needs.
    uint meet_at = 0u;
    uint far_end = 0u;
    bool is_a = false;
    for (uint round = 0u; round <= n; round++) {
        if (!subgroupAny(climbing)) {
            break;
        }
        if (climbing) {
            vec3 lo = vec3(0.0);
            vec3 hi = vec3(0.0);
            bool root = l == 0u && r == n - 1u;
            is_a = !root && (l == 0u || (r != n - 1u && delta(r) > delta(l - 1u)));
            if (l == r) {
                child_box(l, 1u, lo, hi); // a leaf: one reference, at its position
            } else {
                // The sibling's box: a leaf's primitive, or the union of its finished node's.
                vec3 other_lo = vec3(0.0);
                vec3 other_hi = vec3(0.0);
                uint other = known_a ? s + 1u : s;
                child_box(other, uint(known_a ? other == r : other == l), other_lo, other_hi);
                VkrtBvhNode node;
                node.a_index = s;
                node.a_count = uint(l == s);
                node.b_index = s + 1u;
                node.b_count = uint(s + 1u == r);
                node.a_min = known_a ? known_lo : other_lo;
                node.a_max = known_a ? known_hi : other_hi;
                node.b_min = known_a ? other_lo : known_lo;
                node.b_max = known_a ? other_hi : known_hi;
                uint slot = root ? 0u : (is_a ? r : l);
                STORE_NODE(node_pairs, slot, node);
                if (node.a_count == 0u) {
                    refs[n + s] = slot;
                }
                if (node.b_count == 0u) {
                    refs[n + s + 1u] = slot;
                }
#ifdef COLLAPSE_COSTS
                decide(CollapseParams(pc.c_trav, pc.c_isect, pc.max_leaf), slot, node);
#endif
                lo = vkrt_vmin(node.a_min, node.b_min);
                hi = vkrt_vmax(node.a_max, node.b_max);
            }
            if (root) {
                refs[n] = VKRT_NO_NODE;
                info.bounds_min = vec4(lo, 0.0);
                info.bounds_max = vec4(hi, 0.0);
                climbing = false;
            } else {
                meet_at = is_a ? r : l - 1u;
                far_end = is_a ? l : r;
                known_lo = lo;
                known_hi = hi;
            }
        }
        memoryBarrierBuffer(); // the node is visible before its arrival is counted
        if (climbing) {
            uint other_end = atomicExchange(meet[meet_at], far_end);
            if (other_end == VKRT_NO_NODE) {
                climbing = false; // the sibling, arriving last, completes the parent
            } else {
                s = meet_at;
                known_a = is_a;
                l = is_a ? l : other_end;
                r = is_a ? other_end : r;
            }
        }
        memoryBarrierBuffer(); // ... and read after it
    }
}
