#version 460
// A shader that traces through vkrt/ray_query.glsl with its own intersection for box
// primitives, as a renderer's procedural geometry would: every box holds the sphere
// inscribed in it (centre the box's centre, radius half its shortest side), and the
// intersection hands the geometry and primitive index it was given back as the hit's
// attributes. tests/accel_device_input.rs compares the hits with the CPU twin over those
// vkrt_spheres.
layout(local_size_x_id = 0) in;

#define VKRT_BINDING 2
#define VKRT_AABB_INTERSECTION 1
#include "include/vkrt/ray_query.glsl"

struct ProbeRay {
    vec4 origin_tmin;
    vec4 dir_tmax;
};
layout(std430, binding = 0) readonly buffer Rays { ProbeRay rays[]; };
// Per ray: t (bits), geometry index, primitive index, attributes (x, y as 16-bit halves),
// or VKRT_NO_HIT in the first word for a miss.
layout(std430, binding = 1) writeonly buffer Hits { uvec4 hits[]; };
layout(push_constant) uniform Push { uint n; } pc;

bool vkrtIntersectAabb(uint geometryIndex, uint primitiveIndex, vec3 origin, vec3 direction,
                       float tMin, float tMax, vec3 boxMin, vec3 boxMax, out float t,
                       out vec2 attributes) {
    vec3 c = (boxMin + boxMax) * 0.5;
    vec3 e = boxMax - boxMin;
    float r = 0.5 * min(min(e.x, e.y), e.z);
    attributes = vec2(float(geometryIndex), float(primitiveIndex));
    return vkrt_hit_sphere(origin, direction, vec4(c, r), tMin, tMax, t);
}

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.n) {
        return;
    }
    ProbeRay r = rays[i];
    VkrtHit h = vkrtTraceClosest(r.origin_tmin.xyz, r.origin_tmin.w, r.dir_tmax.xyz,
                                 r.dir_tmax.w);
    if (!h.hit || h.exhausted) {
        hits[i] = uvec4(h.exhausted ? 0xfffffffeu : 0xffffffffu, 0u, 0u, 0u);
        return;
    }
    uvec2 a = uvec2(h.barycentrics);
    hits[i] = uvec4(floatBitsToUint(h.t), h.geometryIndex, h.primitiveIndex,
                    a.x | (a.y << 16u));
}
