#version 460
// LBVH: words of the codes in the order the ids are in now. Between the two sorts of 63-bit
// codes: the high words, the keys of the second (stable) sort. After the sort: both words
// in sorted order, so that the topology pass reads neighbours' codes contiguously.
layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint WORDS = 1u;
#include "common/grid.glsl"

layout(std430, binding = 0) readonly buffer Ids { uint ids[]; };
layout(std430, binding = 1) readonly buffer SrcA { uint src_a[]; };
layout(std430, binding = 2) writeonly buffer DstA { uint dst_a[]; };
layout(std430, binding = 3) readonly buffer SrcB { uint src_b[]; };
layout(std430, binding = 4) writeonly buffer DstB { uint dst_b[]; };
layout(push_constant) uniform Push { uint n; } pc;

void main() {
    uint i = linear_invocation_id();
    if (i < pc.n) {
        uint p = ids[i];
        dst_a[i] = src_a[p];
        if (WORDS == 2u) {
            dst_b[i] = src_b[p];
        }
    }
}
