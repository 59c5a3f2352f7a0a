#version 460
// kd-tree Phase II: one compaction moves each event record of one axis list once per side,
// to its scanned slot, with its box clipped on the split axis only; lists stay sorted
// (stable subsequences), so they are never re-sorted (twin: seed001::scatter).
#extension GL_EXT_shader_8bit_storage : require
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "accel/kdtree_level.glsl"

layout(std430, binding = 0) readonly buffer State { uint state[]; };
layout(std430, binding = 1) readonly buffer NodeRange { uint node_range[]; };
layout(std430, binding = 2) readonly buffer NodeSplit { uint node_split[]; };
layout(std430, binding = 3) readonly buffer InnerBefore { uint inner_before[]; };
layout(std430, binding = 4) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 5) readonly buffer Plane { float plane[]; };
layout(std430, binding = 6) readonly buffer Kind { uint kind_words[]; };
layout(std430, binding = 7) readonly buffer Prim { uint prim[]; };
layout(std430, binding = 8) readonly buffer Node { uint node_of[]; };
layout(std430, binding = 9) readonly buffer Box { float box[]; }; // 6 arrays of `stride`
layout(std430, binding = 10) writeonly buffer OutPlane { float out_plane[]; };
layout(std430, binding = 11) writeonly buffer OutKind { uint8_t out_kind[]; };
layout(std430, binding = 12) writeonly buffer OutPrim { uint out_prim[]; };
layout(std430, binding = 13) writeonly buffer OutNode { uint out_node[]; };
layout(std430, binding = 14) writeonly buffer OutBox { float out_box[]; };
layout(push_constant) uniform Push { uint stride; } pc; // elements per box array

void main() {
    uint id = linear_invocation_id();
    if (id >= 2u * state[ST_REFS]) {
        return;
    }
    uint node = node_of[id];
    uint s = node_split[2u * node];
    if (s == KD_LEAF) {
        return;
    }
    uint first = node_range[2u * node];
    uint count = node_range[2u * node + 1u];
    float p = uintBitsToFloat(node_split[2u * node + 1u]);
    float b[6];
    for (uint k = 0u; k < 6u; k++) {
        b[k] = box[k * pc.stride + id];
    }
    bool below = b[3u + s] <= p;
    bool above = !below && b[s] >= p;
    bool both = !below && !above;
    uint v = id + 2u * first;
    for (uint side = 0u; side < 2u; side++) {
        if (!(side == 0u ? (below || both) : (above || both))) {
            continue;
        }
        uint o = offsets[v + side * 2u * count];
        if (o >= pc.stride) {
            continue; // past capacity: kdtree_advance raises the overflow flag
        }
        out_plane[o] = plane[id];
        out_kind[o] = uint8_t(kind_of(kind_words[id / 4u], id));
        out_prim[o] = prim[id];
        out_node[o] = 2u * inner_before[node] + side;
        for (uint k = 0u; k < 6u; k++) {
            float x = b[k];
            if (side == 0u && k == 3u + s) {
                x = fmin_total(x, p);
            } else if (side == 1u && k == s) {
                x = fmax_total(x, p);
            }
            out_box[k * pc.stride + o] = x;
        }
    }
}
