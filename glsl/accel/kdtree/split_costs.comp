#version 460
// kd-tree Phase II, pass 1: per event, the SAH of its plane on each axis list (counts from
// the START flag scans), the cheapest axis kept. Twin: breadth_first::split_costs.
// Variant `wide` (where the device has shaderInt64) reads the node's box and (first, count)
// as 64-bit components (accel/kdtree/level.glsl); `narrow` as 32-bit ones.
//! variant narrow
//! variant wide PAIRS64=1
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "accel/kdtree/level.glsl"

layout(std430, binding = 0) readonly buffer State { uint state[]; };
layout(std430, binding = 1) readonly buffer NodeBox { WORD_PAIR node_box[]; };     // 3 per node
layout(std430, binding = 2) readonly buffer NodeRange { WORD_PAIR node_range[]; }; // first, count
layout(std430, binding = 3) readonly buffer Plane0 { float plane0[]; };
layout(std430, binding = 4) readonly buffer Plane1 { float plane1[]; };
layout(std430, binding = 5) readonly buffer Plane2 { float plane2[]; };
layout(std430, binding = 6) readonly buffer Kind0 { uint kind0[]; };
layout(std430, binding = 7) readonly buffer Kind1 { uint kind1[]; };
layout(std430, binding = 8) readonly buffer Kind2 { uint kind2[]; };
layout(std430, binding = 9) readonly buffer Node0 { uint node0[]; };
layout(std430, binding = 10) readonly buffer Starts0 { uint starts0[]; };
layout(std430, binding = 11) readonly buffer Starts1 { uint starts1[]; };
layout(std430, binding = 12) readonly buffer Starts2 { uint starts2[]; };
layout(std430, binding = 13) writeonly buffer Cost { float cost[]; };
layout(std430, binding = 14) writeonly buffer Axis { uint axis_of[]; };
layout(push_constant) uniform Push { float trav; float isect; float bonus; } pc;

void main() {
    uint id = linear_invocation_id();
    if (id >= 2u * state[ST_REFS]) {
        return;
    }
    uint node = node0[id];
    uvec2 range = pair_uints(node_range[node]);
    uint first = range.x;
    uint count = range.y;
    vec2 b0 = pair_floats(node_box[3u * node]);
    vec2 b1 = pair_floats(node_box[3u * node + 1u]);
    vec2 b2 = pair_floats(node_box[3u * node + 2u]);
    vec3 mn = vec3(b0, b1.x);
    vec3 mx = vec3(b1.y, b2);
    float best = f32_inf();
    uint best_axis = 0u;
    for (uint a = 0u; a < 3u; a++) {
        float plane = a == 0u ? plane0[id] : (a == 1u ? plane1[id] : plane2[id]);
        uint word = a == 0u ? kind0[id / 4u] : (a == 1u ? kind1[id / 4u] : kind2[id / 4u]);
        uint starts = a == 0u ? starts0[id] : (a == 1u ? starts1[id] : starts2[id]);
        uint below = starts - first;
        uint ends_before = id - first - starts;
        uint above = count - ends_before - (kind_of(word, id) == 0u ? 1u : 0u);
        float c = sah_scaled(mn, mx, a, plane, below, above, pc.trav, pc.isect, pc.bonus);
        if (c < best) {
            best = c;
            best_axis = a;
        }
    }
    cost[id] = best;
    axis_of[id] = best_axis;
}
