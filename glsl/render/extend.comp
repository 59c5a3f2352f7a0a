#version 460
// Closest hit of every live ray in the queue (count and workgroups on the GPU).
//! variant exact VKRT_FP64_FALLBACK=1
//! variant float VKRT_FP64_FALLBACK=0
//! variant query VKRT_FP64_FALLBACK=0 VKRT_HAS_RAY_QUERY=1
//! variant exact_texel VKRT_FP64_FALLBACK=1 VKRT_TEXEL_NODES=1
//! variant float_texel VKRT_FP64_FALLBACK=0 VKRT_TEXEL_NODES=1
layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint VKRT_INTERSECTOR = 0u;
layout(constant_id = 2) const bool VKRT_ANY_HIT = false;
layout(constant_id = 3) const uint VKRT_KD_STACK = 32u;
#include "common/grid.glsl"
#include "render/common.glsl"
#define VKRT_GEOM_BINDING 3
#include "include/vkrt/traverse.glsl"

layout(std430, binding = 0) readonly buffer Queue { PathRay queue[]; };
layout(std430, binding = 1) writeonly buffer Hits { VkrtWalkHit hits[]; };
layout(std430, binding = 2) buffer Counters { uint counters[]; };

void main() {
    uint i = linear_invocation_id();
    if (i >= counters[CNT_QUEUE]) {
        return;
    }
    PathRay p = queue[i];
    VkrtWalkHit h = vkrt_trace_ray(VkrtRay(p.o, p.tmin, p.d, p.tmax), p.time);
    if (vkrt_trace_steps_exhausted) {
        atomicAdd(counters[CNT_EXHAUSTED], 1u);
        h = vkrt_miss_hit();
    }
    hits[i] = h;
}
