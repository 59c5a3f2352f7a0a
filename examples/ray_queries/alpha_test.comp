#version 460
#extension GL_EXT_ray_query : require
#include "vkrt/ext_ray_query.glsl"
layout(local_size_x = 64) in;
layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
layout(set = 0, binding = 1, std430) readonly buffer Rays { vec4 rays[]; };
layout(set = 0, binding = 2, std430) writeonly buffer Results { uvec4 results[]; };
layout(push_constant) uniform Count { uint rayCount; };
// An alpha test: every triangle is a candidate (the ray's no-opaque flag), the odd ones
// are cut out.
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= rayCount) return;
    vec4 a = rays[2 * i];
    vec4 b = rays[2 * i + 1];
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, gl_RayFlagsNoOpaqueEXT, 0xFF, a.xyz, a.w, b.xyz, b.w);
    uint candidates = 0u;
    while (rayQueryProceedEXT(q)) {
        candidates++;
        if ((rayQueryGetIntersectionPrimitiveIndexEXT(q, false) & 1) == 0) {
            rayQueryConfirmIntersectionEXT(q);
        }
    }
    bool hit = rayQueryGetIntersectionTypeEXT(q, true) != gl_RayQueryCommittedIntersectionNoneEXT;
    results[i] = hit ? uvec4(floatBitsToUint(rayQueryGetIntersectionTEXT(q, true)),
                             rayQueryGetIntersectionInstanceIdEXT(q, true),
                             rayQueryGetIntersectionPrimitiveIndexEXT(q, true), candidates)
                     : uvec4(0xffffffffu, 0u, 0u, candidates);
}
