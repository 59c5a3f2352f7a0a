#version 460
#extension GL_KHR_shader_subgroup_basic : require
// PLOC, before the rounds: one cluster per primitive in Morton order (a leaf over sorted
// position i, its primitive's box), and the rounds' state.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "include/vkrt/kdtree.glsl"
#include "accel/bvh/ploc_common.glsl"

layout(std430, binding = 0) readonly buffer Boxes { float boxes[]; };
layout(std430, binding = 1) readonly buffer Refs { uint refs[]; };
layout(std430, binding = 2) writeonly buffer Clusters { Cluster clusters[]; };
layout(std430, binding = 3) buffer State { uint state[]; };
// `wg`: the workgroup size of the rounds' kernels.
layout(push_constant) uniform Push { uint n; uint wg; } pc;

void main() {
    uint i = linear_invocation_id();
    if (i < pc.n) {
        uint p = refs[i];
        clusters[i] = Cluster(vec3(boxes[6u * p], boxes[6u * p + 1u], boxes[6u * p + 2u]),
                              i | LEAF_BIT,
                              vec3(boxes[6u * p + 3u], boxes[6u * p + 4u], boxes[6u * p + 5u]),
                              0u);
    }
    if (i == 0u) {
        state[ST_COUNT] = pc.n;
        state[ST_COUNT + 1u] = 0u;
        state[ST_NODES_LEFT] = pc.n - 1u;
        state[ST_BASE] = 0u;
        state[ST_ROUNDS] = 0u;
        state[ST_PAIRING] = 0u;
        uvec3 a = dispatch_for(pc.n, pc.wg);
        state[ST_ARGS] = a.x;
        state[ST_ARGS + 1u] = a.y;
        state[ST_ARGS + 2u] = a.z;
        state[ST_ARGS + 3u] = 0u;
        state[ST_ARGS + 4u] = 1u;
        state[ST_ARGS + 5u] = 1u;
    }
}
