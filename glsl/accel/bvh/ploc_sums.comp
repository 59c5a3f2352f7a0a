#version 460
#extension GL_KHR_shader_subgroup_basic : require
// PLOC, round step 3 (one invocation): the exclusive scan of the workgroups' sums, the
// round's first node (node indices are handed out from the top, so the last merge is node
// 0, the root), the next round's cluster count and its indirect dispatch.
layout(local_size_x = 1) in;
layout(constant_id = 1) const bool PAIRING = false;
#include "include/vkrt/kdtree.glsl"
#include "accel/bvh/ploc_common.glsl"

layout(std430, binding = 0) buffer GroupSums { uvec2 group_sums[]; };
layout(std430, binding = 1) buffer State { uint state[]; };
layout(push_constant) uniform Push { uint parity; uint wg; } pc;

void main() {
    uint count = state[ST_COUNT + pc.parity];
    uint merges = 0u;
    uint survivors = count;
    if (count > 1u) {
        uint groups = (count + pc.wg - 1u) / pc.wg;
        uvec2 run = uvec2(0u);
        for (uint g = 0u; g < groups; g++) {
            uvec2 t = group_sums[g];
            group_sums[g] = run;
            run += t;
        }
        merges = run.x;
        survivors = run.y;
    }
    uint base = state[ST_NODES_LEFT] - merges;
    state[ST_BASE] = base;
    state[ST_NODES_LEFT] = base;
    uint next = 1u - pc.parity;
    state[ST_COUNT + next] = survivors;
    if (merges > 0u) {
        state[PAIRING ? ST_PAIRING : ST_ROUNDS] += 1u;
    }
    uvec3 a = dispatch_for(survivors, pc.wg);
    state[ST_ARGS + 3u * next] = a.x;
    state[ST_ARGS + 3u * next + 1u] = a.y;
    state[ST_ARGS + 3u * next + 2u] = a.z;
}
