#version 460
// The plain copy kernel: the ceiling for any kernel that must read and write n elements,
// the baseline that `vkrt bench` reports kernels against. ELEM is the per-invocation width;
// PER granules per invocation (block-strided: neighbouring invocations, neighbouring bytes),
// or with RUNS each invocation's PER granules back to back: the layout of the chained scan's
// lanes and of the radix sort's runs, to measure what that layout costs a plain copy.
//! variant u32 ELEM=uint
//! variant uvec4 ELEM=uvec4
//! variant uvec4x4 ELEM=uvec4 PER=4
//! variant u64vec4 ELEM=u64vec4 INT64=1
//! variant u64vec4x4 ELEM=u64vec4 INT64=1 PER=4
//! variant u64vec4run16 ELEM=u64vec4 INT64=1 PER=16 RUNS=1
#ifdef INT64
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#endif
#ifndef PER
#define PER 1
#endif
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

layout(std430, binding = 0) readonly buffer Src { ELEM src[]; };
layout(std430, binding = 1) writeonly buffer Dst { ELEM dst[]; };
layout(push_constant) uniform Push { uint n; } pc;

void main() {
#if PER == 1
    uint i = linear_invocation_id();
    if (i < pc.n) {
        dst[i] = src[i];
    }
#elif defined(RUNS)
    uint base = linear_invocation_id() * PER;
    for (uint k = 0; k < PER; k++) {
        uint i = base + k;
        if (i < pc.n) {
            dst[i] = src[i];
        }
    }
#else
    uint base = linear_group_id() * gl_WorkGroupSize.x * PER + gl_LocalInvocationID.x;
    for (uint k = 0; k < PER; k++) {
        uint i = base + k * gl_WorkGroupSize.x;
        if (i < pc.n) {
            dst[i] = src[i];
        }
    }
#endif
}
