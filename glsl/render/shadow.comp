#version 460
// Occlusion queries (hard and soft shadows, ambient occlusion): any hit; an occluded query
// contributes nothing.
//! variant exact FP64_FALLBACK=1
//! variant float FP64_FALLBACK=0
//! variant query FP64_FALLBACK=0 RAY_QUERY=1
//! variant exact_texel FP64_FALLBACK=1 TEXEL_NODES=1
//! variant float_texel FP64_FALLBACK=0 TEXEL_NODES=1
layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint INTERSECTOR = 0u;
layout(constant_id = 2) const bool ANY_HIT = true;
layout(constant_id = 3) const uint STACK_SIZE = 32u;
#include "common/grid.glsl"
#include "render/common.glsl"
#define GEOM_BINDING 3
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
    Hit h = trace_ray(Ray(s.o, s.tmin, s.d, s.tmax), queue[i / slots].time);
    if (h.prim != NO_HIT || trace_steps_exhausted) {
        if (trace_steps_exhausted) {
            atomicAdd(counters[CNT_EXHAUSTED], 1u);
        }
        shadows[i].contrib = vec3(0.0);
    }
}
