#version 460
// kd-tree Phase I: the SoA event records of one axis in sorted order. One invocation per
// four events, so the 0/1 kind bytes are written as whole words.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

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
// The event boxes: one array per component (each within maxStorageBufferRange).
layout(std430, binding = 12) writeonly buffer BoxMinX { float box_min_x[]; };
layout(std430, binding = 13) writeonly buffer BoxMinY { float box_min_y[]; };
layout(std430, binding = 14) writeonly buffer BoxMinZ { float box_min_z[]; };
layout(std430, binding = 15) writeonly buffer BoxMaxX { float box_max_x[]; };
layout(std430, binding = 16) writeonly buffer BoxMaxY { float box_max_y[]; };
layout(std430, binding = 17) writeonly buffer BoxMaxZ { float box_max_z[]; };
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
        box_min_x[j] = min_x[prim];
        box_min_y[j] = min_y[prim];
        box_min_z[j] = min_z[prim];
        box_max_x[j] = max_x[prim];
        box_max_y[j] = max_y[prim];
        box_max_z[j] = max_z[prim];
    }
    kind_bytes[word] = packed;
}
