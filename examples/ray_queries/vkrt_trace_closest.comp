#version 460
// The same rays through vkrt's own `vkrtTraceClosest` (vkrt/ray_query.glsl at device
// addresses, the handle read from the texel buffer at binding 0): `--through vkrt` only.
#extension GL_EXT_samplerless_texture_functions : require
#define VKRT_DEVICE_ADDRESS 1
#include "vkrt/ray_query.glsl"
layout(local_size_x = 64) in;
layout(set = 0, binding = 0) uniform utextureBuffer handleTexels;
layout(set = 0, binding = 1, std430) readonly buffer Rays { vec4 rays[]; };
layout(set = 0, binding = 2, std430) writeonly buffer Results { uvec4 results[]; };
layout(push_constant) uniform Count { uint rayCount; };
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= rayCount) return;
    vkrtUseStructure(packUint2x32(texelFetch(handleTexels, 0).xy));
    vec4 a = rays[2 * i];
    vec4 b = rays[2 * i + 1];
    VkrtHit h = vkrtTraceClosest(a.xyz, a.w, b.xyz, b.w);
    results[i] = h.hit ? uvec4(floatBitsToUint(h.t), h.instanceIndex, h.primitiveIndex, 1u)
                       : uvec4(0xffffffffu, 0u, 0u, 0u);
}
