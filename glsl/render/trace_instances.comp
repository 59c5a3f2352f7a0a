#version 460
// Batch ray queries over a scene as two levels (`vkrt trace` where a mesh repeats,
// trace::instanced): one invocation per ray through vkrt/ray_query.glsl at device
// addresses, the top level's handle in the push constants. The hit's primitive becomes the
// scene's primitive id (the flat order of `TraceGeometry::at_time`): an instance of a
// repeated mesh has the mesh's index as its custom index, and `mesh_first` gives that mesh's
// first id; the bottom level of the meshes named once and the vkrt_spheres maps its ids through
// `rest_ids`.
// `exact`: VKRT_EXACT (devices with shaderFloat64 and shaderInt64); `moller`: the
// Moller-Trumbore test; `bitstack_*`: the bottom levels' BVHs walked with the bitstack walk
// (else each level's own walk: the stack walk for a binary BVH).
//! variant exact VKRT_EXACT=1
//! variant float FLOAT=1
//! variant moller VKRT_MOLLER_TRUMBORE=1
//! variant bitstack_exact VKRT_EXACT=1 VKRT_WALK=VKRT_WALK_BVH_BITSTACK
//! variant bitstack_float VKRT_WALK=VKRT_WALK_BVH_BITSTACK
//! variant bitstack_moller VKRT_MOLLER_TRUMBORE=1 VKRT_WALK=VKRT_WALK_BVH_BITSTACK
layout(local_size_x_id = 0) in;
layout(constant_id = 22) const uint STEP_CAP = 60000u;
// False where the driver's division rounds correctly (the exact variants' check left out).
layout(constant_id = 21) const bool REFINE = true;
#define VKRT_DEVICE_ADDRESS 1
#define VKRT_MAX_TRAVERSAL_STEPS STEP_CAP
#define VKRT_REFINE_DIVISION REFINE
#include "include/vkrt/ray_query.glsl"
#include "common/grid.glsl"

// 32 bytes each: `VkrtRay` and `VkrtWalkHit` in src/trace/mod.rs.
struct TraceRay {
    vec4 origin_tmin;
    vec4 dir_tmax;
};
struct TraceHit {
    float t;
    uint prim;
    float u;
    float v;
};
layout(std430, binding = 0) readonly buffer Rays { TraceRay rays[]; };
layout(std430, binding = 1) writeonly buffer Hits { TraceHit hits[]; };
// [0]: rays that ran out of traversal steps (reported as misses)
layout(std430, binding = 2) buffer Errors { uint errors[]; };
// Per mesh (an instance's custom index): its first primitive id in the scene; then per piece
// of the rest: where its primitives' entries start in `rest_ids`.
layout(std430, binding = 3) readonly buffer MeshFirst { uint mesh_first[]; };
// Per primitive of the rest's bottom levels, piece after piece: its id in the scene.
layout(std430, binding = 4) readonly buffer RestIds { uint rest_ids[]; };
layout(push_constant) uniform Push {
    uint n;
    uint any_hit;
    uvec2 handle;
    float time;
    uint n_meshes;
    uint n_pieces;
} pc;

// The custom index of the rest's first piece; piece c's is REST - c.
#define REST 0xffffffu

void main() {
    uint i = linear_invocation_id();
    // The handle per ray, null past the last (render/instances.comp says why).
    uint64_t handle = i < pc.n ? packUint2x32(pc.handle) : 0ul;
    if (handle == 0ul) {
        return;
    }
    vkrtUseStructure(handle);
    TraceRay r = rays[i];
    VkrtHit h = vkrtTrace(r.origin_tmin.xyz, r.origin_tmin.w, r.dir_tmax.xyz, r.dir_tmax.w,
                          pc.time, 0xffu, pc.any_hit != 0u);
    if (h.exhausted) {
        atomicAdd(errors[0], 1u);
    }
    if (!h.hit) {
        hits[i] = TraceHit(uintBitsToFloat(0x7f800000u), 0xffffffffu, 0.0, 0.0);
        return;
    }
    uint piece = REST - h.instanceCustomIndex;
    uint prim = piece < pc.n_pieces
        ? rest_ids[mesh_first[pc.n_meshes + piece] + h.primitiveIndex]
        : mesh_first[h.instanceCustomIndex] + h.primitiveIndex;
    hits[i] = TraceHit(h.t, prim, h.barycentrics.x, h.barycentrics.y);
}
