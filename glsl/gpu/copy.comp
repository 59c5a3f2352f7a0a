#version 460
// The plain copy kernel: the ceiling for any kernel that must read and write n elements,
// the baseline that `vkrt bench` reports kernels against. ELEM is the per-invocation width.
//! variant u32 ELEM=uint
//! variant uvec4 ELEM=uvec4
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

layout(std430, binding = 0) readonly buffer Src { ELEM src[]; };
layout(std430, binding = 1) writeonly buffer Dst { ELEM dst[]; };
layout(push_constant) uniform Push { uint n; } pc;

void main() {
    uint i = linear_invocation_id();
    if (i < pc.n) {
        dst[i] = src[i];
    }
}
