#version 460
// Occlusion queries (hard and soft shadows, ambient occlusion): any hit; an occluded query
// contributes nothing.
//! variant exact VKRT_FP64_FALLBACK=1
//! variant float VKRT_FP64_FALLBACK=0
//! variant query VKRT_FP64_FALLBACK=0 VKRT_HAS_RAY_QUERY=1
//! variant exact_texel VKRT_FP64_FALLBACK=1 VKRT_TEXEL_NODES=1
//! variant float_texel VKRT_FP64_FALLBACK=0 VKRT_TEXEL_NODES=1
layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint VKRT_INTERSECTOR = 0u;
layout(constant_id = 2) const bool VKRT_ANY_HIT = true;
layout(constant_id = 3) const uint VKRT_KD_STACK = 32u;
#include "common/grid.glsl"
#include "render/common.glsl"
#define VKRT_GEOM_BINDING 3
#include "include/vkrt/traverse.glsl"

layout(std430, binding = 0) buffer Shadows { ShadowRay shadows[]; };
layout(std430, binding = 1) readonly buffer Params { RenderParams prm; };
layout(std430, binding = 2) buffer Counters { uint counters[]; };
layout(std430, binding = 10) readonly buffer Queue { PathRay queue[]; };

void main() {
    uint i = linear_invocation_id();
    uint slots = prm.shadow_slots;
    if (slots == 0u || i >= counters[CNT_QUEUE] * slots) {
        return;
    }
    ShadowRay s = shadows[i];
    if (s.kind == SHADOW_NONE) {
        return;
    }
    atomicAdd(counters[s.kind == SHADOW_AO ? CNT_AO : CNT_SHADOW], 1u);
    VkrtWalkHit h = vkrt_trace_ray(VkrtRay(s.o, s.tmin, s.d, s.tmax), queue[i / slots].time);
    if (h.prim != VKRT_NO_HIT || vkrt_trace_steps_exhausted) {
        if (vkrt_trace_steps_exhausted) {
            atomicAdd(counters[CNT_EXHAUSTED], 1u);
        }
        shadows[i].contrib = vec3(0.0);
    }
}
