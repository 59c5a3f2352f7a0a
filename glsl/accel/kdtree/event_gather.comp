#version 460
// kd-tree Phase I: the SoA event records of one axis in sorted order. One invocation per
// four events, so the 0/1 kind bytes are written as whole words.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "accel/kdtree/level.glsl"

layout(std430, binding = 0) readonly buffer SortedKeys { float sorted_keys[]; };
layout(std430, binding = 1) readonly buffer SortedValues { uint sorted_values[]; };
layout(std430, binding = 2) readonly buffer MinX { float min_x[]; };
layout(std430, binding = 3) readonly buffer MinY { float min_y[]; };
layout(std430, binding = 4) readonly buffer MinZ { float min_z[]; };
layout(std430, binding = 5) readonly buffer MaxX { float max_x[]; };
layout(std430, binding = 6) readonly buffer MaxY { float max_y[]; };
layout(std430, binding = 7) readonly buffer MaxZ { float max_z[]; };
layout(std430, binding = 8) writeonly buffer Plane { float plane[]; };
layout(std430, binding = 9) writeonly buffer Kind { uint kind_bytes[]; }; // 4 x u8 per word
layout(std430, binding = 10) writeonly buffer Prim { uint prim_out[]; };
layout(std430, binding = 11) writeonly buffer Node { uint node_out[]; };
// The event boxes: three arrays of component pairs (accel/kdtree/level.glsl), one buffer each
// (each within maxStorageBufferRange).
layout(std430, binding = 12) writeonly buffer Box0 { WORD_PAIR box0[]; };
layout(std430, binding = 13) writeonly buffer Box1 { WORD_PAIR box1[]; };
layout(std430, binding = 14) writeonly buffer Box2 { WORD_PAIR box2[]; };
layout(push_constant) uniform Push { uint n; } pc; // primitives

void main() {
    uint word = linear_invocation_id();
    uint events = 2 * pc.n;
    if (4 * word >= events) {
        return;
    }
    uint packed = 0;
    for (uint k = 0; k < 4; k++) {
        uint j = 4 * word + k;
        if (j >= events) {
            break;
        }
        uint i = sorted_values[j];
        uint kind = i / pc.n;
        uint prim = i - kind * pc.n;
        packed |= kind << (8 * k);
        plane[j] = sorted_keys[j];
        prim_out[j] = prim;
        node_out[j] = 0;
        box0[j] = floats_pair(vec2(min_x[prim], min_y[prim]));
        box1[j] = floats_pair(vec2(min_z[prim], max_x[prim]));
        box2[j] = floats_pair(vec2(max_y[prim], max_z[prim]));
    }
    kind_bytes[word] = packed;
}
