#version 460
// Stream compaction, last pass: every element whose flag is 1 moves to its exclusive flag
// offset, in each of ARRAYS SoA arrays at once (the arrays share the flags and offsets, so
// the flags and offsets are read once for all of them). One invocation per four flags.
//! variant one ARRAYS=1
//! variant two ARRAYS=2
//! variant three ARRAYS=3
//! variant four ARRAYS=4
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

layout(std430, binding = 0) readonly buffer Flags { uint flags[]; }; // 4 byte-flags per word
layout(std430, binding = 1) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 2) readonly buffer Src0 { uint src0[]; };
#if ARRAYS >= 2
layout(std430, binding = 3) readonly buffer Src1 { uint src1[]; };
#endif
#if ARRAYS >= 3
layout(std430, binding = 4) readonly buffer Src2 { uint src2[]; };
#endif
#if ARRAYS >= 4
layout(std430, binding = 5) readonly buffer Src3 { uint src3[]; };
#endif
layout(std430, binding = 6) writeonly buffer Dst0 { uint dst0[]; };
#if ARRAYS >= 2
layout(std430, binding = 7) writeonly buffer Dst1 { uint dst1[]; };
#endif
#if ARRAYS >= 3
layout(std430, binding = 8) writeonly buffer Dst2 { uint dst2[]; };
#endif
#if ARRAYS >= 4
layout(std430, binding = 9) writeonly buffer Dst3 { uint dst3[]; };
#endif
// The element count: the capacity, or read from the GPU (common/gpu_count.glsl).
layout(std430, binding = 10) readonly buffer Counts { uint counts[]; };
layout(push_constant) uniform Push {
    uint capacity;
    uint count_index;
    uint count_mul;
    uint count_div;
} pc;
#include "common/gpu_count.glsl"

void main() {
    uint word = linear_invocation_id();
    uint n = gpu_count(pc.capacity, pc.count_div == 0u ? 0u : counts[pc.count_index],
                       pc.count_mul, pc.count_div);
    if (4 * word >= n) {
        return;
    }
    uint bits = flags[word];
    for (uint k = 0; k < 4; k++) {
        uint e = 4 * word + k;
        if (e < n && ((bits >> (8 * k)) & 0xffu) != 0) {
            uint o = offsets[e];
            dst0[o] = src0[e];
#if ARRAYS >= 2
            dst1[o] = src1[e];
#endif
#if ARRAYS >= 3
            dst2[o] = src2[e];
#endif
#if ARRAYS >= 4
            dst3[o] = src3[e];
#endif
        }
    }
}
