#version 460
// A path tracer as renderers write one, in the interface of `vkrt shader-check`
// (docs/cli.md) with its instance data: a two-dimensional dispatch over an image (the
// camera's rays, row by row), 64 samples a pixel of up to three diffuse bounces, each with a
// shadow query toward the sun; normals from the meshes' own vertices, read at device
// addresses through binding 3, and spheres intersected by the shader from the same records.
// Each pixel's record: its colour (three floats) and the samples taken.
//   vkrt shader-check examples/ray_queries/path_tracer.comp SCENE --rays CAMERA.rays --width W
#extension GL_EXT_ray_query : require
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#include "vkrt/ext_ray_query.glsl"
layout(local_size_x = 8, local_size_y = 8) in;
layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
layout(set = 0, binding = 1, std430) readonly buffer Rays { vec4 rays[]; };
layout(set = 0, binding = 2, std430) writeonly buffer Results { uvec4 results[]; };
struct InstanceData {
    uint64_t positions;
    uint64_t triangles;
    uint triangleCount;
    uint vertexCount;
    uint reserved0;
    uint reserved1;
};
layout(set = 0, binding = 3, std430) readonly buffer Instances { InstanceData instances[]; };
layout(push_constant) uniform Frame { uint rayCount; uint width; };
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer Floats { float f[]; };
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer Uints { uint u[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer Spheres { vec4 s[]; };

const uint SAMPLES = 64u;
const uint BOUNCES = 3u;
const vec3 SUN = vec3(0.36, 0.8, 0.48);

uint hash(uint x) {
    x ^= x >> 16u;
    x *= 0x7feb352du;
    x ^= x >> 15u;
    x *= 0x846ca68bu;
    x ^= x >> 16u;
    return x;
}

float rnd(inout uint state) {
    state = hash(state);
    return float(state >> 8u) * (1.0 / 16777216.0);
}

vec3 vertex(Floats p, uint v) {
    return vec3(p.f[3u * v], p.f[3u * v + 1u], p.f[3u * v + 2u]);
}

// The nearest hit (or, for a shadow ray, any) of the segment; its world normal.
bool trace(vec3 o, vec3 d, float tmax, bool shadow, out float t, out vec3 n) {
    rayQueryEXT q;
    uint flags = shadow ? gl_RayFlagsTerminateOnFirstHitEXT : gl_RayFlagsNoneEXT;
    rayQueryInitializeEXT(q, scene, flags, 0xFF, o, 1e-4, d, tmax);
    while (rayQueryProceedEXT(q)) {
        if (rayQueryGetIntersectionTypeEXT(q, false) == gl_RayQueryCandidateIntersectionAABBEXT) {
            InstanceData inst = instances[rayQueryGetIntersectionInstanceIdEXT(q, false)];
            vec4 s = Spheres(inst.positions).s[rayQueryGetIntersectionPrimitiveIndexEXT(q, false)];
            vec3 oc = rayQueryGetIntersectionObjectRayOriginEXT(q, false) - s.xyz;
            vec3 dir = rayQueryGetIntersectionObjectRayDirectionEXT(q, false);
            float a = dot(dir, dir);
            float b = dot(oc, dir);
            float disc = b * b - a * (dot(oc, oc) - s.w * s.w);
            if (disc >= 0.0) {
                float root = (-b - sqrt(disc)) / a;
                float limit = rayQueryGetIntersectionTypeEXT(q, true) == gl_RayQueryCommittedIntersectionNoneEXT
                    ? tmax : rayQueryGetIntersectionTEXT(q, true);
                if (root >= 1e-4 && root <= limit) {
                    rayQueryGenerateIntersectionEXT(q, root);
                }
            }
        }
    }
    uint type = rayQueryGetIntersectionTypeEXT(q, true);
    if (type == gl_RayQueryCommittedIntersectionNoneEXT) {
        return false;
    }
    t = rayQueryGetIntersectionTEXT(q, true);
    InstanceData inst = instances[rayQueryGetIntersectionInstanceIdEXT(q, true)];
    uint prim = rayQueryGetIntersectionPrimitiveIndexEXT(q, true);
    vec3 object_n;
    if (type == gl_RayQueryCommittedIntersectionTriangleEXT) {
        Uints tri = Uints(inst.triangles);
        Floats p = Floats(inst.positions);
        vec3 a = vertex(p, tri.u[3u * prim]);
        vec3 b = vertex(p, tri.u[3u * prim + 1u]);
        vec3 c = vertex(p, tri.u[3u * prim + 2u]);
        object_n = cross(b - a, c - a);
    } else {
        vec4 s = Spheres(inst.positions).s[prim];
        object_n = rayQueryGetIntersectionObjectRayOriginEXT(q, true)
            + t * rayQueryGetIntersectionObjectRayDirectionEXT(q, true) - s.xyz;
    }
    // Normals transform by the inverse transpose: the world-to-object matrix, transposed.
    n = normalize(object_n * mat3(rayQueryGetIntersectionWorldToObjectEXT(q, true)));
    return true;
}

void main() {
    uvec2 px = gl_GlobalInvocationID.xy;
    uint i = px.y * width + px.x;
    if (px.x >= width || i >= rayCount) {
        return;
    }
    vec3 origin = rays[2u * i].xyz;
    vec3 dir = normalize(rays[2u * i + 1u].xyz);
    vec3 sum = vec3(0.0);
    uint samples = 0u;
    for (uint s = 0u; s < SAMPLES; s++) {
        uint state = hash(i * SAMPLES + s);
        vec3 o = origin;
        vec3 d = dir;
        vec3 throughput = vec3(1.0);
        for (uint bounce = 0u; bounce < BOUNCES; bounce++) {
            float t;
            vec3 n;
            if (!trace(o, d, 1e30, false, t, n)) {
                sum += throughput * mix(vec3(0.9), vec3(0.4, 0.6, 1.0), max(d.y, 0.0));
                break;
            }
            if (dot(n, d) > 0.0) {
                n = -n;
            }
            o = o + t * d + 1e-4 * n;
            throughput *= 0.7;
            float lit = max(dot(n, SUN), 0.0);
            float ts;
            vec3 ns;
            if (lit > 0.0 && !trace(o, SUN, 1e30, true, ts, ns)) {
                sum += throughput * lit * vec3(1.0, 0.95, 0.8);
            }
            // A cosine-weighted direction about n.
            float r1 = 6.2831853 * rnd(state);
            float r2 = rnd(state);
            vec3 u = normalize(abs(n.x) > 0.5 ? cross(n, vec3(0.0, 1.0, 0.0)) : cross(n, vec3(1.0, 0.0, 0.0)));
            vec3 v = cross(n, u);
            d = normalize(cos(r1) * sqrt(r2) * u + sin(r1) * sqrt(r2) * v + sqrt(1.0 - r2) * n);
        }
        samples++;
    }
    sum /= float(SAMPLES);
    results[i] = uvec4(floatBitsToUint(sum.r), floatBitsToUint(sum.g), floatBitsToUint(sum.b), samples);
}
