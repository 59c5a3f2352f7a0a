// Where the climbing passes start (accel/bvh_refit.comp, accel/bvh_collapse_cost.comp): at
// the nodes whose children are all leaves. Each invocation owns `per_lane` node slots,
// strided by the workgroup size, and takes its next start when its climb ends, so its lane
// stays busy: with one slot per invocation a subgroup ran as many rounds as its longest
// climb, most lanes idle after the first. Include after declaring `node_pairs` (BvhNode as
// word pairs, accel/bvh_pairs.glsl) and `refs` (references, then parent links).
#ifndef VKRT_ACCEL_BVH_CLIMB_GLSL
#define VKRT_ACCEL_BVH_CLIMB_GLSL

#include "accel/bvh_pairs.glsl"
#include "common/grid.glsl"

// Takes this invocation's next start among its slots `taken..per_lane`: true with `node`
// set, false once its slots are spent. Slots a leaf collapse freed (parent DEAD) hold no
// node.
bool next_climb(uint n_nodes, uint parents_at, uint per_lane, inout uint taken, out uint node) {
    node = NO_NODE;
    while (taken < per_lane) {
        uint i = (linear_group_id() * per_lane + taken) * gl_WorkGroupSize.x +
                 gl_LocalInvocationID.x;
        taken++;
        if (i >= n_nodes) {
            taken = per_lane;
        } else if (refs[parents_at + i] != DEAD &&
                   node_children(LOAD_NODE(node_pairs, i)) == 0u) {
            node = i;
            return true;
        }
    }
    return false;
}

#endif
