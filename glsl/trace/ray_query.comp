#version 460
// Batch ray queries through the driver's own acceleration structure (issue 16's `driver`
// backend, DriverAccel in src/accel/driver.rs): one invocation per ray, closest or any hit,
// with rays and hits laid out as for render/trace.comp. The TLAS comes as a device address
// in the push constants (OpConvertUToAccelerationStructureKHR), so the kernel binds only
// storage buffers. Created only on devices with VK_KHR_ray_query.
#extension GL_EXT_ray_query : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
layout(local_size_x_id = 0) in;
layout(constant_id = 2) const bool ANY_HIT = false;
#include "common/grid.glsl"
#include "common/ray.glsl"

layout(std430, binding = 0) readonly buffer Rays { Ray rays[]; };
layout(std430, binding = 1) writeonly buffer Hits { Hit hits[]; };
layout(push_constant) uniform Push { uint64_t tlas; uint n; } pc;

void main() {
    uint i = linear_invocation_id();
    if (i >= pc.n) {
        return;
    }
    Ray r = rays[i];
    // The contract of src/trace/mod.rs: an invalid ray is a miss. Vulkan leaves a query with
    // NaN, a negative tmin or tmin > tmax undefined, so it is never made.
    float tmin = max(r.tmin, 0.0);
    if (!ray_is_valid(r) || tmin > r.tmax) {
        hits[i] = miss_hit();
        return;
    }
    // Opaque: the driver commits triangle hits itself, so the loop below never sees a
    // candidate to confirm; any hit stops at the first one it commits.
    uint flags = gl_RayFlagsOpaqueEXT | (ANY_HIT ? gl_RayFlagsTerminateOnFirstHitEXT : 0u);
    rayQueryEXT q;
    rayQueryInitializeEXT(q, accelerationStructureEXT(pc.tlas), flags, 0xffu, r.o, tmin, r.d,
                          r.tmax);
    while (rayQueryProceedEXT(q)) {
    }
    if (rayQueryGetIntersectionTypeEXT(q, true) == gl_RayQueryCommittedIntersectionTriangleEXT) {
        vec2 uv = rayQueryGetIntersectionBarycentricsEXT(q, true);
        hits[i] = Hit(rayQueryGetIntersectionTEXT(q, true),
                      uint(rayQueryGetIntersectionPrimitiveIndexEXT(q, true)), uv.x, uv.y);
    } else {
        hits[i] = miss_hit();
    }
}
