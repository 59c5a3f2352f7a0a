// Shared by the PLOC kernels (CPU twin: src/accel/bvh/ploc.rs).
#ifndef VKRT_ACCEL_PLOC_COMMON_GLSL
#define VKRT_ACCEL_PLOC_COMMON_GLSL

#include "include/vkrt/bvh_node.glsl"

// A cluster's child word: a leaf (one reference, at that sorted position) has the top bit.
#define LEAF_BIT 0x80000000u

// 32 bytes: a cluster's box and what it is as a child.
struct Cluster {
    vec3 lo;
    uint child;
    vec3 hi;
    uint pad;
};

// The round's state (`ploc_gpu::State`): the cluster count of even and odd rounds, the
// nodes not handed out yet, this round's first node, rounds that merged, the indirect
// dispatch of even and odd rounds (x, y, z).
#define ST_COUNT 0u       // + parity
#define ST_NODES_LEFT 2u
#define ST_BASE 3u
#define ST_ROUNDS 4u
#define ST_PAIRING 5u
#define ST_ARGS 8u        // + 3 * parity

// The cluster index this invocation handles: subgroup-major, so that a subgroup's exclusive
// add is the order of the clusters whatever the driver's mapping of local invocations. The
// lanes per subgroup come from gl_NumSubgroups: lavapipe can report a gl_SubgroupSize larger
// than the subgroups it runs (common/reduce_lanes.glsl).
uint ordered_index(uint group) {
    uint lanes = gl_WorkGroupSize.x / gl_NumSubgroups;
    return group * gl_WorkGroupSize.x + gl_SubgroupID * lanes + gl_SubgroupInvocationID;
}

// Indirect dispatch for `count` items in groups of `wg`, folded into y like
// Recorder::groups_1d (maxComputeWorkGroupCount[0] may be 65,535); none for one cluster.
uvec3 dispatch_for(uint count, uint wg) {
    if (count <= 1u) {
        return uvec3(0u, 1u, 1u);
    }
    uint groups = (count + wg - 1u) / wg;
    uint x = min(groups, 65535u);
    return uvec3(x, (groups + x - 1u) / x, 1u);
}


#endif
