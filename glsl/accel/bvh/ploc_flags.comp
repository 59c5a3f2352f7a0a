#version 460
// PLOC, round step 2: which clusters merge (the lower of a mutual pair) and which survive
// (all but the higher of a mutual pair), and each workgroup's sums of both.
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_KHR_shader_subgroup_basic : require
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "include/vkrt/kdtree.glsl"
#include "accel/bvh/ploc_common.glsl"

layout(std430, binding = 0) readonly buffer Nearest { uint nn[]; };
// Per cluster: (merges, survives).
layout(std430, binding = 1) writeonly buffer Flags { uvec2 flags[]; };
layout(std430, binding = 2) writeonly buffer GroupSums { uvec2 group_sums[]; };
layout(std430, binding = 3) readonly buffer State { uint state[]; };
layout(push_constant) uniform Push { uint parity; } pc;

shared uint sum_merge;
shared uint sum_survive;

void main() {
    uint g = linear_group_id();
    uint i = ordered_index(g);
    uint count = state[ST_COUNT + pc.parity];
    if (gl_LocalInvocationIndex == 0u) {
        sum_merge = 0u;
        sum_survive = 0u;
    }
    barrier();
    uvec2 f = uvec2(0u);
    if (i < count) {
        uint j = nn[i];
        bool mutual = j != i && nn[j] == i;
        f = uvec2(mutual && i < j ? 1u : 0u, !mutual || i < j ? 1u : 0u);
        flags[i] = f;
    }
    // Every invocation reaches the subgroup sums and the barrier (no early return).
    uvec2 s = subgroupAdd(f);
    if (subgroupElect()) {
        atomicAdd(sum_merge, s.x);
        atomicAdd(sum_survive, s.y);
    }
    barrier();
    if (gl_LocalInvocationIndex == 0u) {
        group_sums[g] = uvec2(sum_merge, sum_survive);
    }
}
