#version 460
// LBVH, between the two sorts of 63-bit codes: the high words in the order the low-word sort
// left the ids, the keys of the second (stable) sort.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

layout(std430, binding = 0) readonly buffer CodeHi { uint code_hi[]; };
layout(std430, binding = 1) readonly buffer Ids { uint ids[]; };
layout(std430, binding = 2) writeonly buffer SortKeys { uint sort_keys[]; };
layout(push_constant) uniform Push { uint n; } pc;

void main() {
    uint i = linear_invocation_id();
    if (i < pc.n) {
        sort_keys[i] = code_hi[ids[i]];
    }
}
