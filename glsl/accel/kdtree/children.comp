#version 460
// kd-tree Phase II: the next level's nodes — boxes split at the plane, event ranges and
// counts from the scanned virtual slots of axis 0 (twin: breadth_first "children").
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "accel/kdtree/level.glsl"

layout(std430, binding = 0) readonly buffer State { uint state[]; };
layout(std430, binding = 1) readonly buffer NodeBox { float node_box[]; };
layout(std430, binding = 2) readonly buffer NodeRange { uint node_range[]; };
layout(std430, binding = 3) readonly buffer NodeSplit { uint node_split[]; };
layout(std430, binding = 4) readonly buffer InnerBefore { uint inner_before[]; };
layout(std430, binding = 5) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 6) readonly buffer Total { uint slot_total[]; };
layout(std430, binding = 7) writeonly buffer NextBox { float next_box[]; };
layout(std430, binding = 8) writeonly buffer NextRange { uint next_range[]; };
layout(std430, binding = 9) writeonly buffer NextOffsets { uint next_offsets[]; }; // 2·first
layout(push_constant) uniform Push { uint node_capacity; } pc; // per level

void main() {
    uint i = linear_invocation_id();
    if (i >= state[ST_NODES]) {
        return;
    }
    uint s = node_split[2u * i];
    if (s == VKRT_KD_LEAF) {
        return;
    }
    uint first = node_range[2u * i];
    uint count = node_range[2u * i + 1u];
    uint base = 4u * first;
    uint end = base + 4u * count;
    uint lo = offsets[base];
    uint mid = offsets[base + 2u * count];
    uint hi = end == 4u * state[ST_REFS] ? slot_total[0] : offsets[end];
    float p = uintBitsToFloat(node_split[2u * i + 1u]);
    uint c = 2u * inner_before[i];
    if (c + 1u >= pc.node_capacity) {
        return; // kdtree_advance raises the overflow flag
    }
    for (uint k = 0u; k < 6u; k++) {
        float x = node_box[6u * i + k];
        next_box[6u * c + k] = k == 3u + s ? p : x;      // below: max[s] = plane
        next_box[6u * (c + 1u) + k] = k == s ? p : x;   // above: min[s] = plane
    }
    next_range[2u * c] = lo / 2u;
    next_range[2u * c + 1u] = (mid - lo) / 2u;
    next_range[2u * c + 2u] = mid / 2u;
    next_range[2u * c + 3u] = (hi - mid) / 2u;
    next_offsets[c] = lo;
    next_offsets[c + 1u] = mid;
}
