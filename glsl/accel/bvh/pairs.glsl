// A VkrtBvhNode as eight word pairs (common/word_pair.glsl): (a_min.xy), (a_min.z, a_index),
// (a_max.xy), (a_max.z, a_count), then the same for b; a primitive's box (six floats) as
// three, (min x, min y), (min z, max x), (max y, max z). Kernels that move whole nodes or
// boxes declare `WORD_PAIR` arrays and move them in half the trips where PAIRS64.
#ifndef VKRT_ACCEL_BVH_PAIRS_GLSL
#define VKRT_ACCEL_BVH_PAIRS_GLSL

#include "common/word_pair.glsl"
#include "include/vkrt/bvh_node.glsl"

#define NODE_PAIRS 8u

VkrtBvhNode node_of_pairs(WORD_PAIR p0, WORD_PAIR p1, WORD_PAIR p2, WORD_PAIR p3, WORD_PAIR p4,
                      WORD_PAIR p5, WORD_PAIR p6, WORD_PAIR p7) {
    uvec2 a1 = pair_uints(p1);
    uvec2 a3 = pair_uints(p3);
    uvec2 b1 = pair_uints(p5);
    uvec2 b3 = pair_uints(p7);
    return VkrtBvhNode(vec3(pair_floats(p0), uintBitsToFloat(a1.x)), a1.y,
                   vec3(pair_floats(p2), uintBitsToFloat(a3.x)), a3.y,
                   vec3(pair_floats(p4), uintBitsToFloat(b1.x)), b1.y,
                   vec3(pair_floats(p6), uintBitsToFloat(b3.x)), b3.y);
}

WORD_PAIR box_pair(vec3 v, uint word) {
    return uints_pair(uvec2(floatBitsToUint(v.z), word));
}

// Node `i` of the pair array `arr`.
#define LOAD_NODE(arr, i)                                                                  \
    node_of_pairs(arr[NODE_PAIRS * (i)], arr[NODE_PAIRS * (i) + 1u],                       \
                  arr[NODE_PAIRS * (i) + 2u], arr[NODE_PAIRS * (i) + 3u],                  \
                  arr[NODE_PAIRS * (i) + 4u], arr[NODE_PAIRS * (i) + 5u],                  \
                  arr[NODE_PAIRS * (i) + 6u], arr[NODE_PAIRS * (i) + 7u])

// Stores node `n` whole as node `i` of `arr`.
#define STORE_NODE(arr, i, n)                                                              \
    {                                                                                      \
        arr[NODE_PAIRS * (i)] = floats_pair((n).a_min.xy);                                 \
        arr[NODE_PAIRS * (i) + 1u] = box_pair((n).a_min, (n).a_index);                     \
        arr[NODE_PAIRS * (i) + 2u] = floats_pair((n).a_max.xy);                            \
        arr[NODE_PAIRS * (i) + 3u] = box_pair((n).a_max, (n).a_count);                     \
        arr[NODE_PAIRS * (i) + 4u] = floats_pair((n).b_min.xy);                            \
        arr[NODE_PAIRS * (i) + 5u] = box_pair((n).b_min, (n).b_index);                     \
        arr[NODE_PAIRS * (i) + 6u] = floats_pair((n).b_max.xy);                            \
        arr[NODE_PAIRS * (i) + 7u] = box_pair((n).b_max, (n).b_count);                     \
    }

void box_of_pairs(WORD_PAIR p0, WORD_PAIR p1, WORD_PAIR p2, out vec3 lo, out vec3 hi) {
    vec2 q1 = pair_floats(p1);
    lo = vec3(pair_floats(p0), q1.x);
    hi = vec3(q1.y, pair_floats(p2));
}

// Primitive `p`'s box from the pair array `arr` (three pairs per primitive).
#define LOAD_PRIM_BOX(arr, p, lo, hi)                                                      \
    box_of_pairs(arr[3u * (p)], arr[3u * (p) + 1u], arr[3u * (p) + 2u], lo, hi)

#endif
