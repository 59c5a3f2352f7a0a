// vkrt's ray queries for the renderer's own shaders: the walk vkrt's kernels run, over any
// structure vkrt builds (kd-tree, LBVH, PLOC, SAH BVH; the driver's where the shader is
// compiled with VKRT_RAY_QUERY), on any Vulkan 1.2 device.
//
// Use:
//     #define VKRT_SET 1        // the descriptor set holding the structure (default 0)
//     #define VKRT_BINDING 0    // its first binding (default 0)
//     #include "vkrt/ray_query.glsl"
//     ...
//     VkrtHit h = vkrtTraceClosest(origin, tMin, direction, tMax);
//     if (h.hit) { ... h.t, h.barycentrics, h.geometryIndex, h.primitiveIndex ... }
//     bool blocked = vkrtTraceAny(origin, tMin, direction, tMax);
//     // the full form: a time, a cull mask for instances, closest or any hit
//     VkrtHit a = vkrtTrace(origin, tMin, direction, tMax, time, cullMask, anyHit);
//
// The structure is seven read-only storage buffers at bindings VKRT_BINDING + 0 .. + 6 of set
// VKRT_SET, in the order vkrt's `StructureBindings` lists them (the host fills them from
// `GpuGeometry::bindings()`). One layout serves every kind: the kind and its walk are read
// from the structure itself, so one pipeline traces any of them.
//
// Options (define before the include):
//   VKRT_STACK_SIZE   the kd-tree walk's short-stack entries (default 64: deeper than any
//                     kd-tree vkrt builds with its default depth limit, so no restarts)
//   VKRT_MOLLER_TRUMBORE  use the Moller-Trumbore test instead of the watertight one
//   VKRT_WALK         compile one walk only: VKRT_WALK_KDTREE, VKRT_WALK_BVH (stack),
//                     VKRT_WALK_BVH_BITSTACK or VKRT_WALK_BVH_WIDE (a BVH built with 4-wide
//                     nodes; default: every walk, chosen per structure at run time). A
//                     structure of another kind then reports `exhausted`.
//   VKRT_EXACT        hits equal to vkrt's CPU twin bit for bit on any device: divisions
//                     and square roots rounded correctly (Vulkan lets a driver's be 2.5 and
//                     3 ulp off) and the watertight test's double-precision fallback; needs
//                     shaderFloat64 and shaderInt64 (vkrt's own kernels do the same where the
//                     device has them)
//   VKRT_REFINE_DIVISION  with VKRT_EXACT: false where the driver's division and square
//                     root are known to round correctly (`DeviceInfo::ieee_division`, e.g.
//                     through the includer's specialization constant), which leaves out the
//                     check (a loop per division: on Mesa 22.3's lavapipe every iteration
//                     counts against its 65,535-iteration budget); default true
//   VKRT_MAX_TRAVERSAL_STEPS  node visits + primitive tests per ray before the walk gives
//                     up and reports `exhausted`. Without it the cap is the
//                     specialization constant VKRT_STEPS_CONSTANT_ID (default 1900): set
//                     it to the device's `DeviceInfo::max_traversal_steps`
//                     (`shader_library::steps_specialization`); unset it is 60000, within
//                     lavapipe's loop budget but short of what a GPU allows
//   VKRT_RAY_QUERY    also walk the driver's structure with GL_EXT_ray_query (needs the
//                     device's VK_KHR_ray_query; without it such a structure reports
//                     `exhausted`)
//   VKRT_DEVICE_ADDRESS  read the structure at device addresses instead of seven bindings:
//                     call vkrtUseStructure(handle) before the queries, with the address
//                     of the structure's handle (`GpuGeometry::handle_words()`, 56 bytes
//                     the host writes where it likes); needs bufferDeviceAddress. One
//                     64-bit value per structure, as a TLAS is, and no binding limit; on
//                     lavapipe as fast as the bindings or up to 14 % slower
//                     (docs/performance.md). A top level over instances
//                     (`TopLevel::handle_address`, vkrt/instances.glsl) is traced this way
//                     only: hits then also name the instance (`instanceIndex`,
//                     `instanceCustomIndex`), vkrtTrace's cull mask selects instances, and
//                     moving instances (`TopLevelBuilder::build_moving`) are placed at the
//                     query's time
//   VKRT_TEXEL_BUFFERS  read the nodes, references and triangle vertices (bindings + 0,
//                     + 1, + 2) through uniform texel buffers instead of storage buffers:
//                     RGBA32UI views of the same ranges (`GpuGeometry::texel_views()`,
//                     `descriptor_set_layout_bindings_for(.., NodeAccess::Texel)`); the same
//                     hits bit for bit. On lavapipe a texel fetch is a branch-free gather
//                     where a storage load at a divergent offset loops over the lanes (Mesa
//                     < 25.1): up to 2.3x faster walks (docs/performance.md)
//   VKRT_AABB_INTERSECTION  the shader intersects box primitives itself (procedural
//                     geometry, as a ray query's AABB candidates): it defines, anywhere in
//                     the file,
//                       bool vkrtIntersectAabb(uint geometryIndex, uint primitiveIndex,
//                           vec3 origin, vec3 direction, float tMin, float tMax,
//                           vec3 boxMin, vec3 boxMax, out float t, out vec2 attributes);
//                     returning whether the primitive is hit at a t in [tMin, tMax] (tMax
//                     is the closest hit so far); `attributes` become the hit's
//                     barycentrics. The walk finds the box, so t must lie within it along
//                     the ray. Without it a box is hit where the ray enters it (or leaves
//                     it, from inside).
//
// What each mode asks of the device (SPIR-V capabilities, and the feature that enables
// them; checked by tests/include_names.rs):
//   storage bindings (default), VKRT_AABB_INTERSECTION, VKRT_MOLLER_TRUMBORE, VKRT_WALK:
//                       Shader only
//   VKRT_TEXEL_BUFFERS  + SampledBuffer (core)
//   VKRT_DEVICE_ADDRESS + PhysicalStorageBufferAddresses, Int64 (bufferDeviceAddress,
//                       shaderInt64)
//   VKRT_EXACT          + Float64, Int64 (shaderFloat64, shaderInt64)
//   VKRT_RAY_QUERY      + RayQueryKHR, Int64 (VK_KHR_ray_query's rayQuery, shaderInt64)
//
// Rays follow VK_KHR_ray_query: t in [tMin, tMax], tMax may be +inf; a ray with a NaN or
// infinite origin or direction, a zero direction or tMin > tMax is a miss. A walk that ran
// out of its step budget reports `exhausted` (its answer is then a miss): never a silent
// wrong answer.
//
// Names: every macro, function, type, block and global this file and the files it includes
// declare starts with `vkrt`, `Vkrt` or `VKRT_`; the public ones are camelCase (vkrtTrace,
// VkrtHit), the internal ones snake_case (vkrt_trace_walk, vkrt_hit_sphere) or VKRT_ macros.
// An includer's own `VkrtRay`, `VkrtWalkHit`, `FLT_MIN`, `vkrt_spheres` or `vkrt_dot3` cannot clash with them.
#ifndef VKRT_RAY_QUERY_GLSL
#define VKRT_RAY_QUERY_GLSL

// The library's version, its crate's: major * 10000 + minor * 100 + patch (0.1.0: 100), for
// `#if VKRT_VERSION >= ...` in an includer; the SPIR-V pass checks its library's against
// its own.
#define VKRT_VERSION 100

#define VKRT_LIBRARY 1
#ifndef VKRT_BINDING
#define VKRT_BINDING 0
#endif
#define VKRT_GEOM_BINDING VKRT_BINDING
#ifdef VKRT_RAY_QUERY
#define VKRT_HAS_RAY_QUERY 1
#endif

#ifdef VKRT_EXACT
#define VKRT_FP64_FALLBACK 1
#endif
#ifdef VKRT_TEXEL_BUFFERS
#ifdef VKRT_DEVICE_ADDRESS
#error "VKRT_TEXEL_BUFFERS reads the structure through bindings; VKRT_DEVICE_ADDRESS through addresses: choose one"
#endif
#define VKRT_TEXEL_NODES 1
#endif
#include "ray.glsl"
#include "kdtree.glsl"

#ifdef VKRT_MOLLER_TRUMBORE
const uint VKRT_INTERSECTOR = VKRT_INTERSECT_MOLLER_TRUMBORE;
#else
const uint VKRT_INTERSECTOR = VKRT_INTERSECT_WATERTIGHT;
#endif
#ifdef VKRT_STACK_SIZE
const uint VKRT_KD_STACK = VKRT_STACK_SIZE;
#else
const uint VKRT_KD_STACK = 64u;
#endif

#include "traverse.glsl"

// What a query found. A miss has hit == false and t == +inf.
struct VkrtHit {
    bool hit;
    float t;
    // The weights of the triangle's second and third vertices (as VK_KHR_ray_query's
    // barycentrics); 0 for vkrt_spheres and boxes (a box's are its intersection's attributes
    // under VKRT_AABB_INTERSECTION).
    vec2 barycentrics;
    // The geometry (its index in the build's list) and the primitive within it: a triangle
    // index (index buffer order), a sphere index, a box index.
    uint geometryIndex;
    uint primitiveIndex;
    // The walk gave up (its step budget ran out): the answer is a miss, not to be trusted.
    bool exhausted;
    // Through a top level: the instance hit (its index in the top level's list) and its
    // custom index; 0xffffffff and 0 for a structure without instances.
    uint instanceIndex;
    uint instanceCustomIndex;
};

#ifdef VKRT_DEVICE_ADDRESS
// A top level's instance as its walk reads it (`InstanceRecord` in src/accel/instances.rs):
// world-to-object rows, then (bottom level's handle address lo, hi, custom index | mask <<
// 24, flags | bottom-level index << 8), then its motion (steps, the first step's index, the
// first step's time, (steps - 1) / the interval; one step: it does not move).
struct VkrtInstanceRecord {
    vec4 rows[3];
    uvec4 meta;
    uvec4 motion;
};
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer VkrtInstances {
    VkrtInstanceRecord v[];
};
VkrtInstances vkrt_instances;
// A moving top level's object-to-world rows per instance and step.
struct VkrtRows {
    vec4 rows[3];
};
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer VkrtSteps {
    VkrtRows v[];
};
VkrtSteps vkrt_steps;

layout(buffer_reference, std430, buffer_reference_align = 8) readonly buffer VkrtHandle {
    // Seven arrays; a top level's eighth is its instance records, its ninth its steps,
    // its tenth the caller's records as given (vkrt/ext_ray_query.glsl).
    uint64_t addresses[];
};
// The structure in use (vkrtUseStructure): a top level's walk comes back to it after each
// instance.
uint64_t vkrt_top;

// The arrays of the structure whose handle lies at `handle`.
void vkrt_use(uint64_t handle) {
    VkrtHandle h = VkrtHandle(handle);
    vkrt_kd_nodes_ref = VkrtKdNodes(h.addresses[0]);
    vkrt_bvh_nodes_ref = VkrtBvhNodes(h.addresses[0]);
#if !VKRT_FP64_FALLBACK
    vkrt_wide_nodes_ref = VkrtWideNodes(h.addresses[0]);
#endif
    vkrt_kd_refs_ref = VkrtWords(h.addresses[1]);
    vkrt_tri_verts_ref = VkrtFloats(h.addresses[2]);
    vkrt_spheres_ref = VkrtVec4s(h.addresses[3]);
    vkrt_prim_motion_ref = VkrtWords(h.addresses[4]);
    vkrt_motions_ref = VkrtMotions(h.addresses[5]);
    vkrt_scene_info = VkrtSceneInfo(h.addresses[6]);
#if VKRT_FP64_FALLBACK
    vkrt_tri_verts64_ref = VkrtWords64(h.addresses[2]);
    vkrt_bvh_nodes64_ref = VkrtBvhNodes64(h.addresses[0]);
#endif
#ifdef VKRT_HAS_RAY_QUERY
    vkrt_tlas_ref = VkrtU64s(h.addresses[0]);
#endif
    if (vkrt_scene_info.walk == VKRT_ACCEL_INSTANCES) {
        vkrt_instances = VkrtInstances(h.addresses[7]);
        vkrt_steps = VkrtSteps(h.addresses[8]);
    }
}

// Makes the structure whose handle lies at `handle` the one the queries that follow trace:
// `GpuGeometry::handle_words` (its seven arrays' addresses, written where the shader reads
// them), or a top level's `TopLevel::handle_address` (written by its build).
void vkrtUseStructure(uint64_t handle) {
    vkrt_top = handle;
    vkrt_use(handle);
}
#endif

#define VKRT_WALK_KDTREE 0u
#define VKRT_WALK_BVH 1u
#define VKRT_WALK_BVH_BITSTACK 2u
#define VKRT_WALK_BVH_WIDE 4u

// The structure's own walk (a bottom level's, under a top level).
VkrtWalkHit vkrt_walk(VkrtRay r, float time, bool any_hit) {
#ifdef VKRT_WALK
    // One walk compiled in: a structure it does not serve is reported, never misread.
    uint kind = vkrt_scene_info.walk;
    // (the bitstack walks a binary BVH, whose structures say VKRT_ACCEL_BVH_STACK)
    if (kind != (VKRT_WALK == VKRT_WALK_BVH_BITSTACK ? VKRT_ACCEL_BVH_STACK : VKRT_WALK)) {
        vkrt_trace_steps_exhausted = true;
        return vkrt_miss_hit();
    }
    return vkrt_trace_walk(VKRT_WALK, r, time, any_hit);
#else
    return vkrt_trace_walk(vkrt_scene_info.walk, r, time, any_hit);
#endif
}

#ifdef VKRT_DEVICE_ADDRESS
#include "instances.glsl"
#endif

VkrtHit vkrt_trace(vec3 origin, float tMin, vec3 direction, float tMax, float time,
                   uint cull_mask, bool any_hit) {
    vkrt_trace_steps_exhausted = false;
    VkrtRay r = VkrtRay(origin, tMin, direction, tMax);
    VkrtWalkHit h;
    uvec2 g = uvec2(0xffffffffu);
    uvec2 instance = uvec2(0xffffffffu, 0u);
#ifdef VKRT_DEVICE_ADDRESS
    if (vkrt_scene_info.walk == VKRT_ACCEL_INSTANCES) {
        h = vkrt_trace_instances(r, time, any_hit, cull_mask, g, instance);
    } else
#endif
    {
        // (a top level read through bindings: vkrt_trace_walk reports it exhausted)
        h = vkrt_walk(r, time, any_hit);
        if (h.prim != VKRT_NO_HIT) {
            g = vkrt_geometry_of(h.prim);
        }
    }
    VkrtHit o;
    o.exhausted = vkrt_trace_steps_exhausted;
    o.hit = h.prim != VKRT_NO_HIT && !o.exhausted;
    o.t = o.hit ? h.t : vkrt_positive_inf();
    o.barycentrics = o.hit ? vec2(h.u, h.v) : vec2(0.0);
    o.geometryIndex = o.hit ? g.x : 0xffffffffu;
    o.primitiveIndex = o.hit ? g.y : 0xffffffffu;
    o.instanceIndex = o.hit ? instance.x : 0xffffffffu;
    o.instanceCustomIndex = o.hit ? instance.y : 0u;
    return o;
}

// The full form: the closest (or, with anyHit, any) hit with t in [tMin, tMax] at `time`,
// among the instances whose mask shares a bit with `cullMask` (as VK_KHR_ray_query's
// cullMask; a structure without instances ignores it).
VkrtHit vkrtTrace(vec3 origin, float tMin, vec3 direction, float tMax, float time,
                  uint cullMask, bool anyHit) {
    return vkrt_trace(origin, tMin, direction, tMax, time, cullMask, anyHit);
}

// The closest hit with t in [tMin, tMax] (ties: the lowest primitive id).
VkrtHit vkrtTraceClosest(vec3 origin, float tMin, vec3 direction, float tMax) {
    return vkrt_trace(origin, tMin, direction, tMax, 0.0, 0xffu, false);
}

// vkrtTraceClosest at `time` (scenes with moving primitives; 0 otherwise).
VkrtHit vkrtTraceClosestAt(vec3 origin, float tMin, vec3 direction, float tMax, float time) {
    return vkrt_trace(origin, tMin, direction, tMax, time, 0xffu, false);
}

// Any hit with t in [tMin, tMax] (the first found; for shadows and occlusion): the whole
// answer of an any-hit query, with the hit's data.
VkrtHit vkrtTraceAnyHit(vec3 origin, float tMin, vec3 direction, float tMax) {
    return vkrt_trace(origin, tMin, direction, tMax, 0.0, 0xffu, true);
}

// Whether anything lies on the ray in [tMin, tMax].
bool vkrtTraceAny(vec3 origin, float tMin, vec3 direction, float tMax) {
    return vkrt_trace(origin, tMin, direction, tMax, 0.0, 0xffu, true).hit;
}

// Whether the last query on this invocation gave up (its answer was then a miss).
bool vkrtExhausted() {
    return vkrt_trace_steps_exhausted;
}

#undef VkrtRay
#undef VkrtWalkHit
#undef VkrtShear
#undef VkrtKdNode
#undef VkrtBvhNode
#undef VkrtMotionRecord
#endif
