#version 460
// Batch ray queries (`vkrt trace`, Tracer::trace): one invocation per ray, closest or any hit.
// `exact`: the watertight test's double-precision fallback (devices with shaderFloat64);
// `query`: the driver's ray query walks its own structure (devices with VK_KHR_ray_query);
// `*_texel`: nodes read through a texel buffer (NodeAccess::Texel).
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

#define VKRT_GEOM_BINDING 2
#include "include/vkrt/traverse.glsl"

layout(std430, binding = 0) readonly buffer Rays { VkrtRay rays[]; };
layout(std430, binding = 1) writeonly buffer Hits { VkrtWalkHit hits[]; };
// [0]: rays that ran out of traversal steps (reported as misses)
layout(std430, binding = 9) buffer Errors { uint errors[]; };
layout(push_constant) uniform Push { uint n; float time; } pc;

void main() {
    uint i = linear_invocation_id();
    if (i >= pc.n) {
        return;
    }
    VkrtWalkHit h = vkrt_trace_ray(rays[i], pc.time);
    if (vkrt_trace_steps_exhausted) {
        atomicAdd(errors[0], 1u);
        h = vkrt_miss_hit();
    }
    hits[i] = h;
}
