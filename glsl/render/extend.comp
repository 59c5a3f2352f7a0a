#version 460
// Closest hit of every live ray in the queue (count and workgroups on the GPU).
//! variant exact FP64_FALLBACK=1
//! variant float FP64_FALLBACK=0
//! variant query FP64_FALLBACK=0 RAY_QUERY=1
//! variant exact_texel FP64_FALLBACK=1 TEXEL_NODES=1
//! variant float_texel FP64_FALLBACK=0 TEXEL_NODES=1
layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint INTERSECTOR = 0u;
layout(constant_id = 2) const bool ANY_HIT = false;
layout(constant_id = 3) const uint STACK_SIZE = 32u;
#include "common/grid.glsl"
#include "render/common.glsl"
#define GEOM_BINDING 3
#include "include/vkrt/traverse.glsl"

layout(std430, binding = 0) readonly buffer Queue { PathRay queue[]; };
layout(std430, binding = 1) writeonly buffer Hits { Hit hits[]; };
layout(std430, binding = 2) buffer Counters { uint counters[]; };

void main() {
    uint i = linear_invocation_id();
    if (i >= counters[CNT_QUEUE]) {
        return;
    }
    PathRay p = queue[i];
    Hit h = trace_ray(Ray(p.o, p.tmin, p.d, p.tmax), p.time);
    if (trace_steps_exhausted) {
        atomicAdd(counters[CNT_EXHAUSTED], 1u);
        h = miss_hit();
    }
    hits[i] = h;
}
