// Shared by the leaf-collapse kernels (CPU twin: src/accel/bvh/collapse.rs): a node's
// primitive count, SAH cost and decision, three words per node in `costs`. `decide` needs
// a `costs` buffer (uint words) declared before the include.
#ifndef VKRT_ACCEL_BVH_COLLAPSE_GLSL
#define VKRT_ACCEL_BVH_COLLAPSE_GLSL

#include "include/vkrt/bvh_node.glsl"

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

#ifdef COLLAPSE_NO_DECIDE

#ifdef COLLAPSE_COUNT_LIVE
// Adds the invocation's node to the live count at `out_refs[at]` (zero before the pass): one
// atomic per set of invocations that reach it together. Needs `out_refs` (the structure's
// words), COLLAPSE_COUNT_LIVE and the subgroup extensions.
void count_live(bool alive, uint at) {
    uint live_here = subgroupAdd(uint(alive));
    if (subgroupElect() && live_here > 0u) {
        atomicAdd(out_refs[at], live_here);
    }
}
#endif

// Whether node `i` lives: neither it nor an ancestor collapsed. Only nodes of at most
// `max_leaf` primitives can, so the walk up is a few steps. Needs `refs` (references, then
// parent links from `parents_at` on).
bool node_lives(uint i, uint parents_at, uint max_leaf) {
    uint x = i;
    while (x != VKRT_NO_NODE && costs[COST_COUNT(x)] <= max_leaf) {
        if (costs[COST_COLLAPSE(x)] != 0u) {
            return false;
        }
        x = refs[parents_at + x];
    }
    return true;
}

#else

// The SAH costs (C_trav, C_isect) and the largest leaf.
struct CollapseParams {
    float c_trav;
    float c_isect;
    uint max_leaf;
};

// One child's primitives and SAH cost (collapse::node_cost).
void child_cost(CollapseParams p, uint index, uint count, vec3 lo, vec3 hi, inout uint n,
                out float cost) {
    cost = 0.0;
    if (count > 0u) {
        n += count;
        precise float c = p.c_isect * half_area(lo, hi) * float(count);
        cost = c;
    } else if (index != VKRT_NO_NODE) {
        n += costs[COST_COUNT(index)];
        cost = uintBitsToFloat(costs[COST_SAH(index)]);
    }
}

// Decides node `i` (its boxes final, its node children decided): a leaf of its parent where
// it holds at most `max_leaf` primitives and `C_isect·A·n <= C_trav·A + cost(a) + cost(b)`;
// the root never.
void decide(CollapseParams p, uint i, VkrtBvhNode node) {
    uint n = 0u;
    float ca, cb;
    child_cost(p, node.a_index, node.a_count, node.a_min, node.a_max, n, ca);
    child_cost(p, node.b_index, node.b_count, node.b_min, node.b_max, n, cb);
    float area = half_area(vkrt_vmin(node.a_min, node.b_min), vkrt_vmax(node.a_max, node.b_max));
    precise float split = p.c_trav * area + ca + cb;
    precise float leaf = p.c_isect * area * float(n);
    bool collapse = i != 0u && n <= p.max_leaf && leaf <= split;
    costs[COST_COUNT(i)] = n;
    costs[COST_SAH(i)] = floatBitsToUint(collapse ? leaf : split);
    costs[COST_COLLAPSE(i)] = uint(collapse);
}

#endif
#endif
