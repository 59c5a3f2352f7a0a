#version 460
// kd-tree Phase II, pass 3: leaf or split, per node of the level (twin: breadth_first "decide").
// node_split[2i] = split axis, or VKRT_KD_LEAF; node_split[2i + 1] = plane bits.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "accel/kdtree/level.glsl"

layout(std430, binding = 0) readonly buffer State { uint state[]; };
layout(std430, binding = 1) readonly buffer NodeBox { float node_box[]; };
layout(std430, binding = 2) readonly buffer NodeRange { uint node_range[]; };
layout(std430, binding = 3) readonly buffer Best { uvec2 best[]; }; // (cost bits, event)
layout(std430, binding = 4) readonly buffer Axis { uint axis_of[]; };
layout(std430, binding = 5) readonly buffer Plane0 { float plane0[]; };
layout(std430, binding = 6) readonly buffer Plane1 { float plane1[]; };
layout(std430, binding = 7) readonly buffer Plane2 { float plane2[]; };
layout(std430, binding = 8) writeonly buffer NodeSplit { uint node_split[]; };
layout(std430, binding = 9) writeonly buffer InnerFlag { uint inner_flag[]; };
layout(std430, binding = 10) writeonly buffer LeafCount { uint leaf_count[]; };
layout(push_constant) uniform Push {
    float isect;
    uint max_leaf_prims;
    uint depth_limit;
    uint sah_leaf_test;
} pc;

void main() {
    uint i = linear_invocation_id();
    if (i >= state[ST_NODES]) {
        return;
    }
    uint count = node_range[2u * i + 1u];
    precise vec3 d = vec3(node_box[6u * i + 3u], node_box[6u * i + 4u], node_box[6u * i + 5u])
        - vec3(node_box[6u * i], node_box[6u * i + 1u], node_box[6u * i + 2u]);
    precise float area = d.x * d.y + d.y * d.z + d.z * d.x;
    float cost = uintBitsToFloat(best[i].x);
    precise float leaf_cost = pc.isect * float(count) * area;
    bool leaf = count <= pc.max_leaf_prims || state[ST_DEPTH] >= pc.depth_limit || cost == f32_inf()
        || (pc.sah_leaf_test != 0u && cost >= leaf_cost);
    uint axis = 0u;
    float plane = 0.0;
    if (!leaf) {
        uint e = best[i].y;
        axis = axis_of[e];
        plane = axis == 0u ? plane0[e] : (axis == 1u ? plane1[e] : plane2[e]);
    }
    node_split[2u * i] = leaf ? VKRT_KD_LEAF : axis;
    node_split[2u * i + 1u] = floatBitsToUint(plane);
    inner_flag[i] = leaf ? 0u : 1u;
    leaf_count[i] = leaf ? count : 0u;
}
