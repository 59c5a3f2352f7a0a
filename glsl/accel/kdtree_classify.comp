#version 460
#extension GL_EXT_shader_8bit_storage : require
// kd-tree Phase II: the clip-mask of every event of one axis list, written as 0/1 flags into
// the virtual [below | above] slots of its node (node i owns [4·first, 4·first + 4·count)),
// so one scan gives every copy its place (twin: seed001 classify + virtual_slots).
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "accel/kdtree_level.glsl"

layout(std430, binding = 0) readonly buffer State { uint state[]; };
layout(std430, binding = 1) readonly buffer NodeRange { uint node_range[]; };
layout(std430, binding = 2) readonly buffer NodeSplit { uint node_split[]; };
layout(std430, binding = 3) readonly buffer Node { uint node_of[]; };
layout(std430, binding = 4) readonly buffer Box { float box[]; }; // 6 arrays of `stride`
layout(std430, binding = 5) writeonly buffer Slots { uint8_t slots[]; }; // 0/1 flags
layout(push_constant) uniform Push { uint stride; } pc;

void main() {
    uint id = linear_invocation_id();
    if (id >= 2u * state[ST_REFS]) {
        return;
    }
    uint node = node_of[id];
    uint first = node_range[2u * node];
    uint count = node_range[2u * node + 1u];
    uint s = node_split[2u * node];
    uint below = 0u;
    uint above = 0u;
    if (s != KD_LEAF) {
        float p = uintBitsToFloat(node_split[2u * node + 1u]);
        float lo = box[s * pc.stride + id];
        float hi = box[(3u + s) * pc.stride + id];
        if (hi <= p) {
            below = 1u;
        } else if (lo >= p) {
            above = 1u;
        } else {
            below = 1u;
            above = 1u;
        }
    }
    uint v = id + 2u * first; // = 4·first + (id − 2·first)
    slots[v] = uint8_t(below);
    slots[v + 2u * count] = uint8_t(above);
}
