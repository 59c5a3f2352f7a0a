#version 460
// The ways a shader reaches a structure through vkrt/ray_query.glsl, on the same rays:
// `set` binds its seven arrays (VKRT_BINDING), `texel` the first three of them as texel
// buffers (VKRT_TEXEL_BUFFERS), `address` reads them at the device addresses of its handle
// (VKRT_DEVICE_ADDRESS). tests/accel_device_input.rs checks that all give the CPU twin's
// hits; benches/device_input.rs times one against the other.
//! variant set
//! variant texel VKRT_TEXEL_BUFFERS=1
//! variant address VKRT_DEVICE_ADDRESS=1
layout(local_size_x_id = 0) in;

#define VKRT_BINDING 2
#include "include/vkrt/ray_query.glsl"

struct ProbeRay {
    vec4 origin_tmin;
    vec4 dir_tmax;
};
layout(std430, binding = 0) readonly buffer Rays { ProbeRay rays[]; };
// Per ray: t (bits; VKRT_NO_HIT for a miss, VKRT_NO_HIT - 1 when the walk gave up), geometry index,
// primitive index, instance index (or, with `mode` bit 0, the instance's custom index).
layout(std430, binding = 1) writeonly buffer Hits { uvec4 hits[]; };
layout(push_constant) uniform Push {
    uint n;
    // Bit 0: report custom indices; bit 1: any-hit queries; bits 8..16: the cull mask,
    // inverted (0: every instance).
    uint mode;
    uvec2 handle; // `address`: where the structure's handle lies
    float time;   // every ray's time
    uint pad;
} pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.n) {
        return;
    }
#ifdef VKRT_DEVICE_ADDRESS
    vkrtUseStructure(packUint2x32(pc.handle));
#endif
    ProbeRay r = rays[i];
    uint cull_mask = ~(pc.mode >> 8u) & 0xffu;
    VkrtHit h = vkrtTrace(r.origin_tmin.xyz, r.origin_tmin.w, r.dir_tmax.xyz, r.dir_tmax.w, pc.time,
                          cull_mask, (pc.mode & 2u) != 0u);
    if (!h.hit || h.exhausted) {
        hits[i] = uvec4(h.exhausted ? 0xfffffffeu : 0xffffffffu, 0u, 0u, 0u);
        return;
    }
    uint instance = (pc.mode & 1u) != 0u ? h.instanceCustomIndex : h.instanceIndex;
    hits[i] = uvec4(floatBitsToUint(h.t), h.geometryIndex, h.primitiveIndex, instance);
}
