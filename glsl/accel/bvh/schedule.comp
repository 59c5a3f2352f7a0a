#version 460
// The refit schedule of a BVH built to be updated (AccelBuilder::allow_update): every node's
// depth (its parent links walked to the root) as a sort key, its id as the value, and the
// count of nodes per depth. The refit then runs one dispatch per depth, deepest first
// (accel.bvh_refit_level): no atomics and no waiting, every lane busy.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

#include "include/vkrt/bvh_node.glsl"

#define MAX_DEPTH 128u

layout(std430, binding = 0) readonly buffer Refs { uint refs[]; };
layout(std430, binding = 1) writeonly buffer Keys { uint keys[]; };
layout(std430, binding = 2) writeonly buffer Order { uint order[]; };
// [0, 128): nodes per depth, zero before the dispatch.
layout(std430, binding = 3) buffer Levels { uint levels[]; };
layout(push_constant) uniform Push { uint n_nodes; uint parents_at; } pc;

void main() {
    uint i = linear_invocation_id();
    if (i >= pc.n_nodes) {
        return;
    }
    uint depth = 0u;
    uint p = refs[pc.parents_at + i];
    if (p == VKRT_DEAD) {
        // A slot the leaf collapse freed: sorted after every depth, refit at none.
        keys[i] = MAX_DEPTH;
        order[i] = i;
        return;
    }
    while (p != VKRT_NO_NODE && depth < MAX_DEPTH - 1u) {
        depth++;
        p = refs[pc.parents_at + p];
    }
    keys[i] = depth;
    order[i] = i;
    atomicAdd(levels[depth], 1u);
}
