#version 460
// kd-tree Phase I: the sort keys of one axis' events. Event i < 2N is END-major
// (kind = i / N: END = 0, START = 1; prim = i % N); key = its plane, value = i. A stable
// sort by plane then yields the total order (plane, END before START, primitive id).
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

layout(std430, binding = 0) readonly buffer Min { float box_min[]; }; // this axis
layout(std430, binding = 1) readonly buffer Max { float box_max[]; };
layout(std430, binding = 2) writeonly buffer Keys { float keys[]; };
layout(std430, binding = 3) writeonly buffer Values { uint values[]; };
layout(push_constant) uniform Push { uint n; } pc; // primitives

void main() {
    uint i = linear_invocation_id();
    if (i >= 2 * pc.n) {
        return;
    }
    uint kind = i / pc.n;
    uint prim = i - kind * pc.n;
    keys[i] = kind == 1u ? box_min[prim] : box_max[prim];
    values[i] = i;
}
