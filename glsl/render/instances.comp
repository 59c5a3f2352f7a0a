#version 460
// The renderer's extend (closest hit of every live ray) and shadow (any hit of every
// occlusion query) passes over a scene traced as two levels (src/render/levels.rs): one
// invocation per ray through vkrt/ray_query.glsl at device addresses, the top level's handle
// in the push constants. A hit names the primitive in its bottom level, and its instance in
// `hit_instance` (what shade.comp's `levels` variant reads).
// `bitstack_*`: the bottom levels' BVHs walked with the bitstack walk (else each level's own).
//! variant exact VKRT_EXACT=1
//! variant float FLOAT=1
//! variant moller VKRT_MOLLER_TRUMBORE=1
//! variant bitstack_exact VKRT_EXACT=1 VKRT_WALK=VKRT_WALK_BVH_BITSTACK
//! variant bitstack_float VKRT_WALK=VKRT_WALK_BVH_BITSTACK
//! variant bitstack_moller VKRT_MOLLER_TRUMBORE=1 VKRT_WALK=VKRT_WALK_BVH_BITSTACK
layout(local_size_x_id = 0) in;
layout(constant_id = 22) const uint STEP_CAP = 60000u;
// False where the driver's division rounds correctly (the exact variant's check left out).
layout(constant_id = 21) const bool REFINE = true;
#define VKRT_DEVICE_ADDRESS 1
#define VKRT_MAX_TRAVERSAL_STEPS STEP_CAP
#define VKRT_REFINE_DIVISION REFINE
#include "include/vkrt/ray_query.glsl"
#include "common/grid.glsl"
#include "render/common.glsl"

// 16 bytes: extend.comp's `VkrtWalkHit` (the library keeps its own names to itself).
struct PathHit {
    float t;
    uint prim;
    float u;
    float v;
};

layout(std430, binding = 0) readonly buffer Queue { PathRay queue[]; };
layout(std430, binding = 1) writeonly buffer Hits { PathHit hits[]; };
layout(std430, binding = 2) buffer Counters { uint counters[]; };
layout(std430, binding = 3) buffer Shadows { ShadowRay shadows[]; };
layout(std430, binding = 4) readonly buffer Params { RenderParams prm; };
layout(std430, binding = 5) writeonly buffer HitInstance { uint hit_instance[]; };
layout(push_constant) uniform Push {
    uint shadow;   // 0: extend (closest hits into `hits`), 1: shadow (occlusion queries)
    uint pad;
    uvec2 handle;
} pc;

void main() {
    uint i = linear_invocation_id();
    bool shadow = pc.shadow != 0u;
    // One query per invocation, one call of the walk (each call is inlined whole).
    bool live = false;
    vec3 o = vec3(0.0), d = vec3(0.0);
    float tmin = 0.0, tmax = 0.0, time = 0.0;
    if (!shadow) {
        if (i < counters[CNT_QUEUE]) {
            PathRay p = queue[i];
            live = true;
            o = p.o;
            d = p.d;
            tmin = p.tmin;
            tmax = p.tmax;
            time = p.time;
        }
    } else {
        uint slots = prm.shadow_slots;
        if (slots != 0u && i < counters[CNT_QUEUE] * slots) {
            ShadowRay s = shadows[i];
            if (s.kind != SHADOW_NONE) {
                atomicAdd(counters[s.kind == SHADOW_AO ? CNT_AO : CNT_SHADOW], 1u);
                live = true;
                o = s.o;
                d = s.d;
                tmin = s.tmin;
                tmax = s.tmax;
                time = queue[i / slots].time;
            }
        }
    }
    // The handle per ray, null where there is none (as the include keeps it): lavapipe loads
    // through an address it proves uniform with one scalar load from one lane, even in a
    // chunk of invocations that have all returned, and an instrumented shader's guarded
    // loads (the validation layer's device-address check) leave null there.
    uint64_t handle = live ? packUint2x32(pc.handle) : 0ul;
    if (handle == 0ul) {
        return;
    }
    vkrtUseStructure(handle);
    VkrtHit h = vkrtTrace(o, tmin, d, tmax, time, 0xffu, shadow);
    if (h.exhausted) {
        atomicAdd(counters[CNT_EXHAUSTED], 1u);
    }
    if (shadow) {
        if (h.hit || h.exhausted) {
            shadows[i].contrib = vec3(0.0);
        }
    } else if (h.exhausted || !h.hit) {
        hits[i] = PathHit(uintBitsToFloat(0x7f800000u), 0xffffffffu, 0.0, 0.0);
    } else {
        hits[i] = PathHit(h.t, h.primitiveIndex, h.barycentrics.x, h.barycentrics.y);
        hit_instance[i] = h.instanceIndex;
    }
}
