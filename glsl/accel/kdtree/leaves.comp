#version 460
// kd-tree Phase II: leaf primitive lists, written once — the axis-0 START events of leaf
// nodes, in list order (twin: breadth_first "leaves").
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "accel/kdtree/level.glsl"

layout(std430, binding = 0) readonly buffer State { uint state[]; };
layout(std430, binding = 1) readonly buffer NodeRange { uint node_range[]; };
layout(std430, binding = 2) readonly buffer NodeSplit { uint node_split[]; };
layout(std430, binding = 3) readonly buffer LeafBefore { uint leaf_before[]; };
layout(std430, binding = 4) readonly buffer Kind0 { uint kind0[]; };
layout(std430, binding = 5) readonly buffer Node0 { uint node0[]; };
layout(std430, binding = 6) readonly buffer Prim0 { uint prim0[]; };
layout(std430, binding = 7) readonly buffer Starts0 { uint starts0[]; };
layout(std430, binding = 8) writeonly buffer PrimRefs { uint prim_refs[]; };
layout(push_constant) uniform Push { uint ref_capacity; } pc;

void main() {
    uint id = linear_invocation_id();
    if (id >= 2u * state[ST_REFS]) {
        return;
    }
    uint node = node0[id];
    if (node_split[2u * node] != VKRT_KD_LEAF || kind_of(kind0[id / 4u], id) != 1u) {
        return;
    }
    uint rank = starts0[id] - node_range[2u * node];
    uint o = state[ST_REF_BASE] + leaf_before[node] + rank;
    if (o < pc.ref_capacity) {
        prim_refs[o] = prim0[id];
    }
}
