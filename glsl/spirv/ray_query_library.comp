// The SPIR-V library `vkrt::spirv` links into a shader whose ray queries it rewrites: the
// standard's ray query (vkrt/ext_ray_query.glsl, the walk vkrtTrace and vkrt's kernels run)
// behind one function per SPV_KHR_ray_query instruction. A query is the index of its state
// (the pass numbers the shader's query variables), a structure the address of its handle.
//
// Compiled unoptimised to SPIR-V 1.3, so that every function stays a function the pass can
// call; `main` only keeps them alive. The pass reads the functions by their names
// (vkrt_spv_*), turns the count of states (specialization constant VKRT_RQ_STATIC_SLOTS)
// into a constant, as it does the choice of the loop-budget walk (VKRT_LOOP_BUDGET_CONSTANT_ID,
// LowerOptions::loop_budget), and keeps the step cap (VKRT_STEPS_CONSTANT_ID) a
// specialization constant.
//! library
#version 460
#extension GL_EXT_ray_query : enable
#define VKRT_RQ_STATIC_SLOTS 1899
#define VKRT_LOOP_BUDGET_CONSTANT_ID 1897
#include "include/vkrt/ext_ray_query.glsl"

layout(local_size_x = 1) in;

// The library's version (VKRT_VERSION), which the pass checks against its crate's.
uint vkrt_spv_version() {
    return uint(VKRT_VERSION);
}

void vkrt_spv_initialize(uint q, uint64_t as_, uint flags, uint cull_mask, vec3 origin, float tmin,
                         vec3 direction, float tmax) {
    uint h = q;
    vkrtRayQueryInitialize(h, vkrt_structure_at(as_), flags, cull_mask, origin, tmin, direction,
                           tmax);
}

bool vkrt_spv_proceed(uint q) {
    return vkrtRayQueryProceed(q);
}

void vkrt_spv_confirm(uint q) {
    vkrtRayQueryConfirmIntersection(q);
}

void vkrt_spv_generate(uint q, float t) {
    vkrtRayQueryGenerateIntersection(q, t);
}

void vkrt_spv_terminate(uint q) {
    vkrtRayQueryTerminate(q);
}

bool vkrt_spv_exhausted(uint q) {
    return vkrtRayQueryExhausted(q);
}

uint vkrt_spv_type(uint q, uint c) {
    return vkrtRayQueryGetIntersectionType(q, c != 0u);
}

float vkrt_spv_t(uint q, uint c) {
    return vkrtRayQueryGetIntersectionT(q, c != 0u);
}

uint vkrt_spv_instance_custom_index(uint q, uint c) {
    return uint(vkrtRayQueryGetIntersectionInstanceCustomIndex(q, c != 0u));
}

uint vkrt_spv_instance_id(uint q, uint c) {
    return uint(vkrtRayQueryGetIntersectionInstanceId(q, c != 0u));
}

uint vkrt_spv_sbt_record_offset(uint q, uint c) {
    return vkrtRayQueryGetIntersectionInstanceShaderBindingTableRecordOffset(q, c != 0u);
}

uint vkrt_spv_geometry_index(uint q, uint c) {
    return uint(vkrtRayQueryGetIntersectionGeometryIndex(q, c != 0u));
}

uint vkrt_spv_primitive_index(uint q, uint c) {
    return uint(vkrtRayQueryGetIntersectionPrimitiveIndex(q, c != 0u));
}

vec2 vkrt_spv_barycentrics(uint q, uint c) {
    return vkrtRayQueryGetIntersectionBarycentrics(q, c != 0u);
}

bool vkrt_spv_front_face(uint q, uint c) {
    return vkrtRayQueryGetIntersectionFrontFace(q, c != 0u);
}

bool vkrt_spv_candidate_aabb_opaque(uint q) {
    return vkrtRayQueryGetIntersectionCandidateAABBOpaque(q);
}

vec3 vkrt_spv_object_ray_direction(uint q, uint c) {
    return vkrtRayQueryGetIntersectionObjectRayDirection(q, c != 0u);
}

vec3 vkrt_spv_object_ray_origin(uint q, uint c) {
    return vkrtRayQueryGetIntersectionObjectRayOrigin(q, c != 0u);
}

mat4x3 vkrt_spv_object_to_world(uint q, uint c) {
    return vkrtRayQueryGetIntersectionObjectToWorld(q, c != 0u);
}

mat4x3 vkrt_spv_world_to_object(uint q, uint c) {
    return vkrtRayQueryGetIntersectionWorldToObject(q, c != 0u);
}

vec3[3] vkrt_spv_triangle_vertex_positions(uint q, uint c) {
    vec3 p[3];
    vkrtRayQueryGetIntersectionTriangleVertexPositions(q, c != 0u, p);
    return p;
}

float vkrt_spv_ray_tmin(uint q) {
    return vkrtRayQueryGetRayTMin(q);
}

uint vkrt_spv_ray_flags(uint q) {
    return vkrtRayQueryGetRayFlags(q);
}

vec3 vkrt_spv_world_ray_origin(uint q) {
    return vkrtRayQueryGetWorldRayOrigin(q);
}

vec3 vkrt_spv_world_ray_direction(uint q) {
    return vkrtRayQueryGetWorldRayDirection(q);
}

// Keeps every function above in the module (never true at run time).
layout(constant_id = 1898) const bool vkrt_spv_keep = false;

void main() {
    if (vkrt_spv_keep) {
        uint q = vkrt_spv_version();
        vkrt_spv_initialize(q, 0ul, 0u, 0u, vec3(0.0), 0.0, vec3(0.0), 0.0);
        bool b = vkrt_spv_proceed(q) || vkrt_spv_exhausted(q) || vkrt_spv_front_face(q, 1u)
            || vkrt_spv_candidate_aabb_opaque(q);
        vkrt_spv_confirm(q);
        vkrt_spv_generate(q, 0.0);
        vkrt_spv_terminate(q);
        uint u = vkrt_spv_type(q, 1u) + vkrt_spv_instance_custom_index(q, 1u)
            + vkrt_spv_instance_id(q, 1u) + vkrt_spv_sbt_record_offset(q, 1u)
            + vkrt_spv_geometry_index(q, 1u) + vkrt_spv_primitive_index(q, 1u)
            + vkrt_spv_ray_flags(q);
        float f = vkrt_spv_t(q, 1u) + vkrt_spv_barycentrics(q, 1u).x
            + vkrt_spv_object_ray_direction(q, 1u).x + vkrt_spv_object_ray_origin(q, 1u).x
            + vkrt_spv_object_to_world(q, 1u)[0].x + vkrt_spv_world_to_object(q, 1u)[0].x
            + vkrt_spv_ray_tmin(q) + vkrt_spv_world_ray_origin(q).x
            + vkrt_spv_world_ray_direction(q).x + vkrt_spv_triangle_vertex_positions(q, 1u)[2].y;
        if (b && u == 0u && f == 0.0) {
            vkrt_spv_terminate(u);
        }
    }
}
