#version 460
// PLOC, round step 4 (CPU twin: ploc::merge_round): each merging cluster writes its node
// (both children's boxes, Aila & Laine's layout) at the round's first node + its rank among
// the merges, the parent links of its children, and the merged cluster; every surviving
// cluster moves to its rank among the survivors (order kept). Ranks: the subgroup's
// exclusive add, the subgroups before it, and the workgroups before (ploc_sums).
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_KHR_shader_subgroup_basic : require
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "include/vkrt/bvh_node.glsl"
#include "accel/bvh/ploc_common.glsl"

layout(std430, binding = 0) readonly buffer Src { Cluster src[]; };
layout(std430, binding = 1) writeonly buffer Dst { Cluster dst[]; };
layout(std430, binding = 2) readonly buffer Nearest { uint nn[]; };
layout(std430, binding = 3) readonly buffer Flags { uvec2 flags[]; };
layout(std430, binding = 4) readonly buffer GroupSums { uvec2 group_sums[]; };
layout(std430, binding = 5) writeonly buffer Nodes { VkrtBvhNode nodes[]; };
// Sorted ids, then a parent link per node from n on.
layout(std430, binding = 6) buffer Refs { uint refs[]; };
layout(std430, binding = 7) readonly buffer State { uint state[]; };
// `SceneInfo` (src/accel/primitives.rs): the root box is written by the last merge.
layout(std430, binding = 8) buffer VkrtSceneInfoBinding {
    vec4 bounds_min;
    vec4 bounds_max;
    uint n_tris;
    uint n_spheres;
    uint has_motion;
    uint parents_at;
} info;
layout(push_constant) uniform Push { uint parity; uint n; } pc;

shared uvec2 subgroup_sums[128];

uint child_index(uint w) {
    return (w & LEAF_BIT) != 0u ? (w & ~LEAF_BIT) : w;
}

uint child_count(uint w) {
    return (w & LEAF_BIT) != 0u ? 1u : 0u;
}

void main() {
    uint g = linear_group_id();
    uint i = ordered_index(g);
    uint count = state[ST_COUNT + pc.parity];
    uvec2 f = i < count ? flags[i] : uvec2(0u);
    // Every invocation reaches the subgroup operations and the barrier.
    uvec2 rank = subgroupExclusiveAdd(f);
    uvec2 total = subgroupAdd(f);
    if (subgroupElect()) {
        subgroup_sums[gl_SubgroupID] = total;
    }
    barrier();
    rank += group_sums[g];
    for (uint s = 0u; s < gl_SubgroupID; s++) {
        rank += subgroup_sums[s];
    }
    if (i >= count) {
        return;
    }
    Cluster c = src[i];
    if (f.x == 1u) {
        Cluster o = src[nn[i]];
        uint idx = state[ST_BASE] + rank.x;
        nodes[idx] = VkrtBvhNode(c.lo, child_index(c.child), c.hi, child_count(c.child),
                             o.lo, child_index(o.child), o.hi, child_count(o.child));
        if (child_count(c.child) == 0u) {
            refs[pc.n + c.child] = idx;
        }
        if (child_count(o.child) == 0u) {
            refs[pc.n + o.child] = idx;
        }
        Cluster m = Cluster(vkrt_vmin(c.lo, o.lo), idx, vkrt_vmax(c.hi, o.hi), 0u);
        dst[rank.y] = m;
        if (idx == 0u) {
            refs[pc.n] = VKRT_NO_NODE;
            info.bounds_min = vec4(m.lo, 0.0);
            info.bounds_max = vec4(m.hi, 0.0);
        }
    } else if (f.y == 1u) {
        dst[rank.y] = c;
    }
}
