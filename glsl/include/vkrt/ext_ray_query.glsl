// The standard's ray queries (GL_EXT_ray_query) over vkrt's structures, on any Vulkan 1.2
// device: a shader written for the extension compiles against this file with one added line
// after its #extension lines,
//
//     #include "vkrt/ext_ray_query.glsl"
//
// and needs no ray-query capability (SPIR-V: Shader, Int64, PhysicalStorageBufferAddresses,
// SampledBuffer; device features bufferDeviceAddress and shaderInt64). Where the shader is
// compiled with VKRT_NATIVE_RAY_QUERY defined, this file is empty: the same source then uses
// the driver's own ray query.
//
// The one descriptor that changes: the shader's
//     layout(set = S, binding = B) uniform accelerationStructureEXT scene;
// becomes a uniform texel buffer (VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER, a view in
// VK_FORMAT_R32G32B32A32_UINT) whose first texel holds, in .x (low word) and .y, the device
// address of the structure's handle: `TopLevel::handle_address()` for a top level (the
// instances the driver's TLAS would hold), or the address where the host wrote a bottom
// level's `GpuGeometry::handle_words()` (walked as one instance with the identity
// transform, instance id and custom index 0). `accelerationStructureEXT(uint64_t address)`
// and `accelerationStructureEXT(uvec2 address)` (low word first) take such an address
// directly.
//
// Every function and value of the extension behaves as the Vulkan specification says: the
// candidate loop (`rayQueryProceedEXT` returns each non-opaque triangle and each box in the
// ray's reach to the shader, which confirms, generates or ignores it; opaque triangles are
// committed inside it), `rayQueryTerminateEXT`, every committed and candidate getter, the
// ray flags (opaque and no-opaque overrides, terminate on first hit, cull back/front facing,
// cull opaque/no-opaque, skip triangles/AABBs), the cull mask against the instances' masks,
// and facing with the instance flags triangle-facing-cull-disable, flip-facing,
// force-opaque and force-no-opaque and the geometries' opaque flag. A query keeps its walk
// between calls: `rayQueryProceedEXT` resumes where the last candidate was found (the stack
// walks of vkrt/bvh.glsl, binary or 4-wide as the bottom level was built, the same node
// order and tests as vkrtTrace, over the top level and then each instance's bottom level).
//
// Where vkrt differs from a driver, within what the specification allows:
//   - Ties: of opaque triangles at exactly the same t, the lowest instance, then the lowest
//     primitive, is committed (vkrtTrace's rule); drivers keep the one they met first.
//   - The triangle test is vkrt's watertight one (Woop et al. 2013) with its conservative
//     lower bound: a hit nearer the origin than its own rounding error is not reported.
//   - Box candidates come wherever the segment [tMin, committed t] meets the box itself
//     (from an origin inside the box too), one box per primitive; their candidate t is
//     where the segment enters the box.
//   - Bottom levels are BVHs (LBVH, PLOC, SAH BVH; binary or 4-wide) or kd-trees of opaque
//     triangles (a kd-tree may hold a primitive in several leaves); a query meeting a
//     kd-tree's box or a triangle its flags make a candidate, or running past the step cap
//     (VKRT_MAX_TRAVERSAL_STEPS, as vkrt/ray_query.glsl), ends, and
//     `vkrtRayQueryExhausted(q)` says so.
//   - A query is a handle to one of VKRT_RAY_QUERIES (default 2, at most 4) query states
//     per invocation; `rayQueryInitializeEXT` takes the oldest when more are live. A query
//     passed to a function is the same query (as the extension's opaque type is): the
//     helper's rayQueryProceedEXT advances the caller's. Initialize a query in the function
//     that declares it or in one it passes the query to by `inout`.
//
// Options (define before the include): VKRT_RAY_QUERIES (live queries per invocation, 1..4),
// VKRT_MAX_TRAVERSAL_STEPS and VKRT_STEPS_CONSTANT_ID (vkrt/ray_query.glsl), VKRT_EXACT,
// VKRT_MOLLER_TRUMBORE.
//
// Names: everything here starts with vkrt, Vkrt or VKRT_, but for the extension's own names,
// which must keep working in the includer's source: its functions (rayQuery*EXT) are
// function-like macros onto vkrt's, so only calls are rewritten; its two types are
// object-like macros on the extension's reserved keywords (rayQueryEXT, a query's handle;
// accelerationStructureEXT, a texel buffer), which no includer can use as names of its own;
// and a function-like macro `utextureBuffer(a)` makes the constructor
// `accelerationStructureEXT(address)` work (GLSL has no constructor of a texel buffer, so no
// valid shader writes that name with parentheses).
#ifndef VKRT_EXT_RAY_QUERY_GLSL
#define VKRT_EXT_RAY_QUERY_GLSL
#ifndef VKRT_NATIVE_RAY_QUERY

// The extension's constants (gl_RayFlags*EXT, gl_RayQuery*EXT) come from the compiler; its
// types and functions are never used, so no ray-query capability is declared.
#extension GL_EXT_ray_query : enable
#extension GL_EXT_samplerless_texture_functions : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#extension GL_EXT_buffer_reference : require

#ifndef VKRT_DEVICE_ADDRESS
#define VKRT_DEVICE_ADDRESS 1
#endif
#include "ray_query.glsl"

#ifdef VKRT_RQ_STATIC_SLOTS
// The SPIR-V pass's library (vkrt::spirv): a query's handle is its state's index, which
// the pass gives each query variable from the entry point's static count, and the count
// is this specialization constant, which the pass turns into a constant.
layout(constant_id = VKRT_RQ_STATIC_SLOTS) const uint vkrt_rq_count = 1u;
#define VKRT_RAY_QUERIES vkrt_rq_count
#else
#ifndef VKRT_RAY_QUERIES
#define VKRT_RAY_QUERIES 2
#endif
#if VKRT_RAY_QUERIES < 1 || VKRT_RAY_QUERIES > 4
#error "VKRT_RAY_QUERIES: 1 to 4 live ray queries per invocation"
#endif
#endif
// Mesa 22.3's lavapipe (`DeviceInfo::loop_budget`) gives an invocation one budget of 65,535
// loop iterations for all its loops, and charges a loop each time control reaches it, even
// with every lane masked off (a loop in an untaken branch costs one). The nested descent
// reaches about a dozen loops a pass; on such a device the walk runs a loop whose pass holds
// none, at about a quarter of the cost. The specialization constant
// VKRT_LOOP_BUDGET_CONSTANT_ID (default 1901) chooses it: true on such a device (the SPIR-V
// pass makes it a constant: `LowerOptions::loop_budget`). The same nodes in the same order
// either way, so the same answers.
#ifndef VKRT_LOOP_BUDGET_CONSTANT_ID
#define VKRT_LOOP_BUDGET_CONSTANT_ID 1901
#endif
layout(constant_id = VKRT_LOOP_BUDGET_CONSTANT_ID) const bool vkrt_rq_flat = false;
// A top level (binary, at most VKRT_BVH_MAX_DEPTH entries) and a bottom level (binary, or
// 4-wide: at most VKRT_WIDE_STACK_SIZE): the stack holds both.
#ifndef VKRT_RQ_STACK
#define VKRT_RQ_STACK (VKRT_BVH_MAX_DEPTH + VKRT_WIDE_STACK_SIZE)
#endif

// A structure named by the address of its handle.
struct VkrtAccelerationStructure {
    uint64_t handle;
};

// A top level's copies of the caller's instance records (VkAccelerationStructureInstanceKHR:
// object-to-world rows, custom index | mask << 24, sbt offset | flags << 24, reference),
// four texels each, at the tenth address of its handle.
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer VkrtInstanceWords {
    uvec4 v[];
};

VkrtAccelerationStructure vkrt_structure_at(uint64_t handle) {
    return VkrtAccelerationStructure(handle);
}

// The extension's other constructor: the address as two words, low word first.
VkrtAccelerationStructure vkrt_structure_at(uvec2 address) {
    return VkrtAccelerationStructure(packUint2x32(address));
}

VkrtAccelerationStructure vkrt_structure_at(utextureBuffer texels) {
    return VkrtAccelerationStructure(packUint2x32(texelFetch(texels, 0).xy));
}

#define accelerationStructureEXT utextureBuffer
#define utextureBuffer(a) vkrt_structure_at(a)
#define rayQueryEXT uint

// Committed intersection types (gl_RayQueryCommittedIntersection*EXT) and candidate ones
// (gl_RayQueryCandidateIntersection*EXT), as the extension numbers them.
#define VKRT_COMMITTED_NONE 0u
#define VKRT_COMMITTED_TRIANGLE 1u
#define VKRT_COMMITTED_GENERATED 2u
#define VKRT_CANDIDATE_TRIANGLE 0u
#define VKRT_CANDIDATE_AABB 1u

// SpvRayFlags*KHRMask.
#define VKRT_RAY_OPAQUE 0x1u
#define VKRT_RAY_NO_OPAQUE 0x2u
#define VKRT_RAY_TERMINATE_ON_FIRST_HIT 0x4u
#define VKRT_RAY_CULL_BACK 0x10u
#define VKRT_RAY_CULL_FRONT 0x20u
#define VKRT_RAY_CULL_OPAQUE 0x40u
#define VKRT_RAY_CULL_NO_OPAQUE 0x80u
#define VKRT_RAY_SKIP_TRIANGLES 0x100u
#define VKRT_RAY_SKIP_AABBS 0x200u

// VkGeometryInstanceFlagBitsKHR.
#define VKRT_INSTANCE_CULL_DISABLE 0x1u
#define VKRT_INSTANCE_FLIP_FACING 0x2u
#define VKRT_INSTANCE_FORCE_OPAQUE 0x4u
#define VKRT_INSTANCE_FORCE_NO_OPAQUE 0x8u

// The walk's state bits.
#define VKRT_RQ_IN_BOTTOM 0x1u
#define VKRT_RQ_DONE 0x2u
#define VKRT_RQ_EXHAUSTED 0x4u
#define VKRT_RQ_LEAF_DONE 0x8u
#define VKRT_RQ_ONE_LEVEL 0x10u

// An intersection, candidate or committed.
struct VkrtRqHit {
    uint type;
    float t;
    vec2 barycentrics;
    // The instance (its index in the top level), the structure's primitive id, the
    // caller's geometry and primitive index.
    uint instance;
    uint prim;
    uint geometry;
    uint primitive;
    // Bit 0: front face; bit 1: opaque.
    uint bits;
    // The instance's custom index | mask << 24, and its flags << 24.
    uint custom_mask;
    uint instance_flags;
};

// Per query: the world ray and its flags, the top level, the walk and two intersections.
vec4 vkrt_rq_origin[VKRT_RAY_QUERIES];    // xyz; w: tMin
vec4 vkrt_rq_direction[VKRT_RAY_QUERIES]; // xyz; w: tMax as given
uvec4 vkrt_rq_setup[VKRT_RAY_QUERIES];    // flags, cull mask, handle lo, hi
// sp (entries of both levels), base (the bottom level's first entry), steps, state bits
uvec4 vkrt_rq_walk[VKRT_RAY_QUERIES];
// the bottom leaf's next reference and end, the top leaf's next reference and end
uvec4 vkrt_rq_leaf[VKRT_RAY_QUERIES];
// In an instance: its index, custom index | mask << 24, sbt offset | flags << 24, and
// its bottom level's handle.
uvec4 vkrt_rq_instance[VKRT_RAY_QUERIES];
uint64_t vkrt_rq_bottom[VKRT_RAY_QUERIES];
vec4 vkrt_rq_object_origin[VKRT_RAY_QUERIES];
vec4 vkrt_rq_object_direction[VKRT_RAY_QUERIES];
float vkrt_rq_far[VKRT_RAY_QUERIES]; // the committed t, or tMax: where the walk stops
VkrtRqHit vkrt_rq_candidate[VKRT_RAY_QUERIES];
VkrtRqHit vkrt_rq_committed[VKRT_RAY_QUERIES];
uvec2 vkrt_rq_stack[VKRT_RAY_QUERIES][VKRT_RQ_STACK]; // vkrt_stack_entry (bvh.glsl)
// A kd-tree bottom level's walk (VKRT_KD_DESCEND_ON, traverse.glsl): n0, n1 and the scene's
// far end (float bits), and the ring's top | count << 8 | dropped << 16 | fresh << 24
// (fresh: its root cell in hand, to descend from rather than pop). Its ring of cells lies
// in the stack above `base`, two entries a cell.
uvec4 vkrt_rq_kd[VKRT_RAY_QUERIES];
#ifdef VKRT_RQ_STATIC_SLOTS
// The state of query `q` (its own index), or VKRT_RAY_QUERIES when `q` names none.
uint vkrt_rq_slot(uint q) {
    return min(q, uint(VKRT_RAY_QUERIES));
}
#else
// Which handle owns each state (0: none), and how many handles were given.
uvec4 vkrt_rq_owner = uvec4(0u);
uint vkrt_rq_issued = 0u;

// The state of query `q`, or VKRT_RAY_QUERIES when `q` is not a live query.
uint vkrt_rq_slot(uint q) {
    uint s = q & 3u;
    return (s < uint(VKRT_RAY_QUERIES) && q >= 4u && vkrt_rq_owner[s] == q) ? s : uint(VKRT_RAY_QUERIES);
}
#endif

VkrtRqHit vkrt_rq_none() {
    return VkrtRqHit(0u, 0.0, vec2(0.0), 0u, VKRT_NO_HIT, 0u, 0u, 0u, 0u, 0u);
}

// The stack of the walk in hand: entries from `vkrt_rq_base` on belong to its level.
uint vkrt_rq_s;
uint vkrt_rq_base;
#define VKRT_RQ_AT(i) vkrt_rq_stack[vkrt_rq_s][vkrt_rq_base + (i)]

// The kd-tree walk's ring of cells (node, t0, t1) in the bottom level's part of the stack:
// 64 cells, 128 of its VKRT_WIDE_STACK_SIZE (192) entries.
#define VKRT_RQ_KD_RING 64u
#define VKRT_RQ_KD_NODE(i) VKRT_RQ_AT(2u * (i)).x
#define VKRT_RQ_KD_T0(i) uintBitsToFloat(VKRT_RQ_AT(2u * (i)).y)
#define VKRT_RQ_KD_T1(i) uintBitsToFloat(VKRT_RQ_AT(2u * (i) + 1u).x)
#define VKRT_RQ_KD_PUT(i, n_, a_, b_)                       \
    VKRT_RQ_AT(2u * (i)) = uvec2(n_, floatBitsToUint(a_)); \
    VKRT_RQ_AT(2u * (i) + 1u) = uvec2(floatBitsToUint(b_), 0u)
#define VKRT_RQ_KD_FRESH (1u << 24u)

// A kd-tree level's walk from its root: the ray's interval clipped to its scene box; false
// where the ray misses the box.
bool vkrt_rq_kd_start(VkrtRay r, float tmin, float far, out uvec4 kd) {
    float t0 = tmin;
    float t1 = far;
    kd = uvec4(0u);
    if (!vkrt_clip_to_scene(r, t0, t1)) {
        return false;
    }
    kd = uvec4(floatBitsToUint(t0), floatBitsToUint(t1), floatBitsToUint(t1), VKRT_RQ_KD_FRESH);
    return true;
}

void vkrtRayQueryInitialize(inout uint q, VkrtAccelerationStructure as, uint flags, uint cull_mask,
                        vec3 origin, float tmin, vec3 direction, float tmax) {
    uint s = vkrt_rq_slot(q);
    if (s == uint(VKRT_RAY_QUERIES)) {
#ifdef VKRT_RQ_STATIC_SLOTS
        return; // a handle the pass gave no state (an undefined query)
#else
        s = vkrt_rq_issued % uint(VKRT_RAY_QUERIES);
        vkrt_rq_issued++;
        q = (vkrt_rq_issued << 2u) | s;
        vkrt_rq_owner[s] = q;
#endif
    }
    vkrt_rq_origin[s] = vec4(origin, tmin);
    vkrt_rq_direction[s] = vec4(direction, tmax);
    VkrtRay r = VkrtRay(origin, tmin, direction, tmax);
    // A ray Vulkan leaves undefined (NaN or infinite origin or direction, a zero direction,
    // tMin < 0 or > tMax) and a null structure find nothing (vkrt's rule for rays). The
    // handle is kept per ray (null for those): Mesa 26's lavapipe loads through an address
    // it proves uniform from one lane, which may be one where the load before it did not
    // run, and so reads address 0.
    uint64_t handle = vkrt_ray_is_valid(r) && tmin >= 0.0 ? as.handle : 0ul;
    vkrt_rq_setup[s] = uvec4(flags, cull_mask & 0xffu, unpack32(handle));
    vkrt_rq_far[s] = tmax;
    vkrt_rq_candidate[s] = vkrt_rq_none();
    vkrt_rq_committed[s] = vkrt_rq_none();
    vkrt_rq_leaf[s] = uvec4(0u);
    uint bits = VKRT_RQ_LEAF_DONE;
    if (handle == 0ul) {
        bits |= VKRT_RQ_DONE;
    } else {
        vkrt_use(handle);
        if (vkrt_primitive_count() == 0u) {
            bits |= VKRT_RQ_DONE;
        } else if (vkrt_scene_info.walk != VKRT_ACCEL_INSTANCES) {
            // One level: its own instance, with the identity transform.
            bits |= VKRT_RQ_IN_BOTTOM | VKRT_RQ_ONE_LEVEL;
            vkrt_rq_instance[s] = uvec4(0u, 0xffu << 24u, 0u, 0u);
            vkrt_rq_bottom[s] = handle;
            vkrt_rq_object_origin[s] = vec4(origin, 0.0);
            vkrt_rq_object_direction[s] = vec4(direction, 0.0);
            if (vkrt_scene_info.walk == VKRT_ACCEL_KDTREE && !vkrt_rq_kd_start(r, tmin, tmax, vkrt_rq_kd[s])) {
                bits |= VKRT_RQ_DONE;
            }
        }
    }
    // The root entered: sp 1 (the root, popped first), base 0.
    vkrt_rq_stack[s][0] = vkrt_stack_entry(uvec2(0u), tmin);
    vkrt_rq_walk[s] = uvec4(1u, 0u, 0u, bits);
}

void vkrtRayQueryInitialize(inout uint q, utextureBuffer as, uint flags, uint cull_mask,
                            vec3 origin, float tmin, vec3 direction, float tmax) {
    vkrtRayQueryInitialize(q, vkrt_structure_at(as), flags, cull_mask, origin, tmin, direction,
                           tmax);
}

// Whether a primitive of geometry word `gw` is opaque under instance flags `inst` and ray
// flags `flags`.
bool vkrt_rq_opaque(uint gw, uint inst, uint flags) {
    bool opaque = (gw & 0x80000000u) == 0u;
    opaque = (inst & VKRT_INSTANCE_FORCE_OPAQUE) != 0u ? true : opaque;
    opaque = (inst & VKRT_INSTANCE_FORCE_NO_OPAQUE) != 0u ? false : opaque;
    opaque = (flags & VKRT_RAY_OPAQUE) != 0u ? true : opaque;
    opaque = (flags & VKRT_RAY_NO_OPAQUE) != 0u ? false : opaque;
    return opaque;
}

// Moves the walk into instance `i` of the top level in use; false where the ray misses
// it (its mask, an inactive record, a transform without inverse, an empty bottom level).
bool vkrt_rq_enter(uint s, uint i, uint cull_mask) {
    VkrtInstanceRecord rec = vkrt_instances.v[i];
    if (all(equal(rec.meta.xy, uvec2(0u))) || ((rec.meta.z >> 24u) & cull_mask) == 0u) {
        return false;
    }
    vec4 rows[3];
    if (!vkrt_world_to_object(rec, 0.0, rows)) {
        return false;
    }
    vec3 o = vkrt_rq_origin[s].xyz;
    vec3 d = vkrt_rq_direction[s].xyz;
    vkrt_rq_object_origin[s] = vec4(vkrt_to_object(rows, o, 1.0), 0.0);
    vkrt_rq_object_direction[s] = vec4(vkrt_to_object(rows, d, 0.0), 0.0);
    // (its SBT record offset is read from the caller's record only when asked for)
    vkrt_rq_instance[s] = uvec4(i, rec.meta.z, (rec.meta.w & 0xffu) << 24u, 0u);
    vkrt_rq_bottom[s] = packUint2x32(rec.meta.xy);
    return true;
}

// Whether box [lo, hi] is a candidate of the ray o + t d: as the specification has it,
// whenever the segment [tmin, tmax] (tmax: the committed t) meets the box, also from an
// origin inside it with a hit committed inside it; `t`: where the segment enters the box.
bool vkrt_rq_box_candidate(vec3 o, vec3 d, vec3 lo, vec3 hi, float tmin, float tmax, out float t) {
    t = tmin;
    if (!all(lessThanEqual(lo, hi))) {
        return false;
    }
    float near = tmin;
    float far = tmax;
    if (!vkrt_aabb_slab(o.x, d.x, lo.x, hi.x, near, far) || !vkrt_aabb_slab(o.y, d.y, lo.y, hi.y, near, far)
        || !vkrt_aabb_slab(o.z, d.z, lo.z, hi.z, near, far)) {
        return false;
    }
    t = near;
    return near <= far;
}

// Whether the bottom level in use is one this walk serves: a BVH, binary or 4-wide, or a
// kd-tree of triangles (a kd-tree may hold a primitive in several leaves: a box would come
// to the shader as a candidate more than once).
bool vkrt_rq_walkable() {
    uint walk = vkrt_scene_info.walk;
    return walk == VKRT_ACCEL_BVH_STACK || walk == VKRT_ACCEL_BVH_BITSTACK
        || walk == VKRT_ACCEL_BVH_WIDE
        || (walk == VKRT_ACCEL_KDTREE && vkrt_primitive_count() == vkrt_scene_info.n_tris);
}

// Whether the flat loop serves the bottom level in use: a BVH (binary or 4-wide) whose
// geometry table the flat search covers (VKRT_RQ_FLAT_GEOMETRIES entries).
#define VKRT_RQ_FLAT_GEOMETRIES 16u
bool vkrt_rq_flat_serves() {
    return vkrt_scene_info.walk != VKRT_ACCEL_KDTREE
        && vkrt_scene_info.n_geometries <= VKRT_RQ_FLAT_GEOMETRIES;
}

// vkrt_geometry_entry (vkrt/traverse.glsl) over a table of at most VKRT_RQ_FLAT_GEOMETRIES
// entries, with no loop: four halvings written out.
uvec2 vkrt_rq_geometry_entry_flat(uint prim) {
    uint n = vkrt_scene_info.n_geometries;
    if (n == 0u) {
        return uvec2(0u);
    }
    uint lo = 0u;
    uint hi = n - 1u;
#define VKRT_RQ_HALVE                                                   \
    if (lo < hi) {                                                      \
        uint mid = (lo + hi + 1u) >> 1u;                                \
        if (vkrt_scene_info.geometry_first[mid].x <= prim) {            \
            lo = mid;                                                   \
        } else {                                                        \
            hi = mid - 1u;                                              \
        }                                                               \
    }
    VKRT_RQ_HALVE
    VKRT_RQ_HALVE
    VKRT_RQ_HALVE
    VKRT_RQ_HALVE
#undef VKRT_RQ_HALVE
    return vkrt_scene_info.geometry_first[lo];
}

bool vkrtRayQueryProceed(uint q) {
    uint s = vkrt_rq_slot(q);
    if (s == uint(VKRT_RAY_QUERIES)) {
        return false;
    }
    uvec4 w = vkrt_rq_walk[s];
    if ((w.w & VKRT_RQ_DONE) != 0u) {
        return false;
    }
    uvec4 setup = vkrt_rq_setup[s];
    uint flags = setup.x;
    uint cull_mask = setup.y;
    uint64_t top_handle = packUint2x32(setup.zw);
    vkrt_top = top_handle;
    vkrt_rq_s = s;
    uint bits = w.w;
    bool in_bottom = (bits & VKRT_RQ_IN_BOTTOM) != 0u;
    float tmin = vkrt_rq_origin[s].w;
    float best_t = vkrt_rq_far[s];
    uint steps = w.z;
    uint base = in_bottom ? w.y : 0u;
    uint top = w.x - base;
    vkrt_rq_base = base;
    uvec4 leaf = vkrt_rq_leaf[s];
    uvec4 inst = vkrt_rq_instance[s];
    VkrtRay r;
    if (in_bottom) {
        vkrt_use(vkrt_rq_bottom[s]);
        r = VkrtRay(vkrt_rq_object_origin[s].xyz, tmin, vkrt_rq_object_direction[s].xyz, best_t);
    } else {
        vkrt_use(top_handle);
        r = VkrtRay(vkrt_rq_origin[s].xyz, tmin, vkrt_rq_direction[s].xyz, best_t);
    }
    if (in_bottom && !vkrt_rq_walkable()) {
        vkrt_rq_walk[s].w = bits | VKRT_RQ_DONE | VKRT_RQ_EXHAUSTED;
        return false;
    }
    // The level in hand has 4-wide nodes (a bottom level built for the wide walk).
    bool wide = in_bottom && vkrt_scene_info.walk == VKRT_ACCEL_BVH_WIDE;
    // Or it is a kd-tree, walked on VKRT_KD_DESCEND_ON's state (traverse.glsl).
    bool kd = in_bottom && vkrt_scene_info.walk == VKRT_ACCEL_KDTREE;
    // (read and written back only on a kd-tree level: a BVH's walk pays nothing for it)
    uvec4 kdw = kd ? vkrt_rq_kd[s] : uvec4(0u);
    uint node = 0u;
    float n0 = uintBitsToFloat(kdw.x);
    float n1 = uintBitsToFloat(kdw.y);
    float scene_t1 = uintBitsToFloat(kdw.z);
    uint st_top = kdw.w & 0xffu;
    uint st_count = (kdw.w >> 8u) & 0xffu;
    bool dropped = (kdw.w & (1u << 16u)) != 0u;
    VkrtKdNode nd;
    vec3 inv_d = vkrt_recip3(r.d);
    VkrtShear sh = vkrt_make_shear(r.d);
    uvec2 cur = uvec2(0u);
    bool have = true;
    // A level's root in hand (descend from it rather than pop).
    bool fresh = kd && (kdw.w & VKRT_RQ_KD_FRESH) != 0u;
    bool found = false;
    // Every way out of the loop but two says how the walk stands: the step cap, and a
    // driver that ends a loop on its own (Mesa 22.3's lavapipe, after 65,535 iterations of
    // an invocation's loops), both of which leave it exhausted.
    uint end = VKRT_RQ_DONE | VKRT_RQ_EXHAUSTED;
    // The flat loop where the device has a loop budget, handing the walk to the nested
    // loop at a level it does not serve; the nested loop everywhere else.
    bool nested = !vkrt_rq_flat || (in_bottom && !vkrt_rq_flat_serves());
    if (!nested) {
        while (true) {
#define VKRT_RQ_FLAT_STEP 1
#include "ext_ray_query_step.glsl"
#undef VKRT_RQ_FLAT_STEP
        }
    }
    if (nested) {
        while (true) {
#define VKRT_RQ_FLAT_STEP 0
#include "ext_ray_query_step.glsl"
#undef VKRT_RQ_FLAT_STEP
        }
    }
    bits = (bits & ~VKRT_RQ_IN_BOTTOM) | (in_bottom ? VKRT_RQ_IN_BOTTOM : 0u) | end;
    vkrt_rq_walk[s] = uvec4(base + top, base, steps, bits);
    vkrt_rq_leaf[s] = leaf;
    if (kd) {
        vkrt_rq_kd[s] = uvec4(floatBitsToUint(n0), floatBitsToUint(n1), floatBitsToUint(scene_t1),
                              st_top | (st_count << 8u) | (dropped ? 1u << 16u : 0u));
    }
    vkrt_rq_far[s] = best_t;
    return found;
}

// The candidate in hand (a triangle) committed.
void vkrtRayQueryConfirmIntersection(uint q) {
    uint s = vkrt_rq_slot(q);
    if (s == uint(VKRT_RAY_QUERIES)) {
        return;
    }
    VkrtRqHit c = vkrt_rq_candidate[s];
    if (c.prim == VKRT_NO_HIT || c.type != VKRT_CANDIDATE_TRIANGLE) {
        return;
    }
    c.type = VKRT_COMMITTED_TRIANGLE;
    vkrt_rq_committed[s] = c;
    vkrt_rq_far[s] = c.t;
    if ((vkrt_rq_setup[s].x & VKRT_RAY_TERMINATE_ON_FIRST_HIT) != 0u) {
        vkrt_rq_walk[s].w |= VKRT_RQ_DONE;
    }
}

// The candidate in hand (a box) committed at `t`, where t lies in [tMin, the committed t]
// (elsewhere nothing changes).
void vkrtRayQueryGenerateIntersection(uint q, float t) {
    uint s = vkrt_rq_slot(q);
    if (s == uint(VKRT_RAY_QUERIES)) {
        return;
    }
    VkrtRqHit c = vkrt_rq_candidate[s];
    if (c.prim == VKRT_NO_HIT || c.type != VKRT_CANDIDATE_AABB
        || !(t >= vkrt_rq_origin[s].w && t <= vkrt_rq_far[s])) {
        return;
    }
    c.type = VKRT_COMMITTED_GENERATED;
    c.t = t;
    c.barycentrics = vec2(0.0);
    c.bits &= ~1u;
    vkrt_rq_committed[s] = c;
    vkrt_rq_far[s] = t;
    if ((vkrt_rq_setup[s].x & VKRT_RAY_TERMINATE_ON_FIRST_HIT) != 0u) {
        vkrt_rq_walk[s].w |= VKRT_RQ_DONE;
    }
}

// Ends the query: rayQueryProceedEXT returns false from now on; the committed
// intersection stays.
void vkrtRayQueryTerminate(uint q) {
    uint s = vkrt_rq_slot(q);
    if (s != uint(VKRT_RAY_QUERIES)) {
        vkrt_rq_walk[s].w |= VKRT_RQ_DONE;
    }
}

// Whether query `q` ended without finishing its walk (its step cap ran out, or it met a
// bottom level or a candidate the walk does not serve): its committed intersection is then
// not to be trusted. Not part of the extension; false on the driver's own ray query.
bool vkrtRayQueryExhausted(uint q) {
    uint s = vkrt_rq_slot(q);
    return s != uint(VKRT_RAY_QUERIES) && (vkrt_rq_walk[s].w & VKRT_RQ_EXHAUSTED) != 0u;
}

VkrtRqHit vkrt_rq_hit(uint q, bool committed) {
    uint s = vkrt_rq_slot(q);
    if (s == uint(VKRT_RAY_QUERIES)) {
        return vkrt_rq_none();
    }
    return committed ? vkrt_rq_committed[s] : vkrt_rq_candidate[s];
}

uint vkrtRayQueryGetIntersectionType(uint q, bool committed) {
    return vkrt_rq_hit(q, committed).type;
}

float vkrtRayQueryGetIntersectionT(uint q, bool committed) {
    return vkrt_rq_hit(q, committed).t;
}

int vkrtRayQueryGetIntersectionInstanceCustomIndex(uint q, bool committed) {
    return int(vkrt_rq_hit(q, committed).custom_mask & 0xffffffu);
}

int vkrtRayQueryGetIntersectionInstanceId(uint q, bool committed) {
    return int(vkrt_rq_hit(q, committed).instance);
}

// From the caller's record as given (the top level's handle's tenth address); 0 for a
// one-level query.
uint vkrtRayQueryGetIntersectionInstanceShaderBindingTableRecordOffset(uint q, bool committed) {
    uint s = vkrt_rq_slot(q);
    if (s == uint(VKRT_RAY_QUERIES) || (vkrt_rq_walk[s].w & VKRT_RQ_ONE_LEVEL) != 0u) {
        return 0u;
    }
    uint64_t originals = VkrtHandle(packUint2x32(vkrt_rq_setup[s].zw)).addresses[9];
    uint i = vkrt_rq_hit(q, committed).instance;
    return originals == 0ul ? 0u : VkrtInstanceWords(originals).v[4u * i + 3u].y & 0xffffffu;
}

int vkrtRayQueryGetIntersectionGeometryIndex(uint q, bool committed) {
    return int(vkrt_rq_hit(q, committed).geometry);
}

int vkrtRayQueryGetIntersectionPrimitiveIndex(uint q, bool committed) {
    return int(vkrt_rq_hit(q, committed).primitive);
}

vec2 vkrtRayQueryGetIntersectionBarycentrics(uint q, bool committed) {
    return vkrt_rq_hit(q, committed).barycentrics;
}

bool vkrtRayQueryGetIntersectionFrontFace(uint q, bool committed) {
    return (vkrt_rq_hit(q, committed).bits & 1u) != 0u;
}

bool vkrtRayQueryGetIntersectionCandidateAABBOpaque(uint q) {
    VkrtRqHit h = vkrt_rq_hit(q, false);
    return h.type == VKRT_CANDIDATE_AABB && (h.bits & 2u) != 0u;
}

float vkrtRayQueryGetRayTMin(uint q) {
    uint s = vkrt_rq_slot(q);
    return s == uint(VKRT_RAY_QUERIES) ? 0.0 : vkrt_rq_origin[s].w;
}

uint vkrtRayQueryGetRayFlags(uint q) {
    uint s = vkrt_rq_slot(q);
    return s == uint(VKRT_RAY_QUERIES) ? 0u : vkrt_rq_setup[s].x;
}

vec3 vkrtRayQueryGetWorldRayOrigin(uint q) {
    uint s = vkrt_rq_slot(q);
    return s == uint(VKRT_RAY_QUERIES) ? vec3(0.0) : vkrt_rq_origin[s].xyz;
}

vec3 vkrtRayQueryGetWorldRayDirection(uint q) {
    uint s = vkrt_rq_slot(q);
    return s == uint(VKRT_RAY_QUERIES) ? vec3(0.0) : vkrt_rq_direction[s].xyz;
}

// The world-to-object rows of the hit's instance (the identity for a one-level query).
void vkrt_rq_world_to_object(uint q, bool committed, out vec4 rows[3]) {
    rows = vec4[3](vec4(1.0, 0.0, 0.0, 0.0), vec4(0.0, 1.0, 0.0, 0.0), vec4(0.0, 0.0, 1.0, 0.0));
    uint s = vkrt_rq_slot(q);
    if (s == uint(VKRT_RAY_QUERIES) || (vkrt_rq_walk[s].w & VKRT_RQ_ONE_LEVEL) != 0u) {
        return;
    }
    uint64_t top = packUint2x32(vkrt_rq_setup[s].zw);
    VkrtInstanceRecord rec = VkrtInstances(VkrtHandle(top).addresses[7]).v[vkrt_rq_hit(q, committed).instance];
    vec4 m[3];
    if (vkrt_world_to_object(rec, 0.0, m)) {
        rows = m;
    }
}

vec3 vkrtRayQueryGetIntersectionObjectRayOrigin(uint q, bool committed) {
    vec4 rows[3];
    vkrt_rq_world_to_object(q, committed, rows);
    return vkrt_to_object(rows, vkrtRayQueryGetWorldRayOrigin(q), 1.0);
}

vec3 vkrtRayQueryGetIntersectionObjectRayDirection(uint q, bool committed) {
    vec4 rows[3];
    vkrt_rq_world_to_object(q, committed, rows);
    return vkrt_to_object(rows, vkrtRayQueryGetWorldRayDirection(q), 0.0);
}

mat4x3 vkrt_rq_columns(vec4 rows[3]) {
    return mat4x3(vec3(rows[0].x, rows[1].x, rows[2].x), vec3(rows[0].y, rows[1].y, rows[2].y),
                  vec3(rows[0].z, rows[1].z, rows[2].z), vec3(rows[0].w, rows[1].w, rows[2].w));
}

mat4x3 vkrtRayQueryGetIntersectionWorldToObject(uint q, bool committed) {
    vec4 rows[3];
    vkrt_rq_world_to_object(q, committed, rows);
    return vkrt_rq_columns(rows);
}

// The instance's object-to-world as the caller gave it (the inverse of world-to-object
// where the top level keeps no copy of the caller's records).
mat4x3 vkrtRayQueryGetIntersectionObjectToWorld(uint q, bool committed) {
    vec4 rows[3] = vec4[3](vec4(1.0, 0.0, 0.0, 0.0), vec4(0.0, 1.0, 0.0, 0.0), vec4(0.0, 0.0, 1.0, 0.0));
    uint s = vkrt_rq_slot(q);
    if (s != uint(VKRT_RAY_QUERIES) && (vkrt_rq_walk[s].w & VKRT_RQ_ONE_LEVEL) == 0u) {
        uint64_t top = packUint2x32(vkrt_rq_setup[s].zw);
        uint64_t originals = VkrtHandle(top).addresses[9];
        uint i = vkrt_rq_hit(q, committed).instance;
        if (originals != 0ul) {
            VkrtInstanceWords words = VkrtInstanceWords(originals);
            for (uint k = 0u; k < 3u; k++) {
                rows[k] = uintBitsToFloat(words.v[4u * i + k]);
            }
        } else {
            vec4 inv[3];
            vkrt_rq_world_to_object(q, committed, inv);
            vkrt_invert_rows(inv, rows);
        }
    }
    return vkrt_rq_columns(rows);
}

// Position fetch (GL_EXT_ray_tracing_position_fetch): the vertices of the intersection's
// triangle as its bottom level holds them (its object space); zeros where the intersection
// is not a triangle.
void vkrtRayQueryGetIntersectionTriangleVertexPositions(uint q, bool committed, out vec3 positions[3]) {
    positions = vec3[3](vec3(0.0), vec3(0.0), vec3(0.0));
    uint s = vkrt_rq_slot(q);
    if (s == uint(VKRT_RAY_QUERIES)) {
        return;
    }
    VkrtRqHit h = vkrt_rq_hit(q, committed);
    if (h.prim == VKRT_NO_HIT
        || h.type != (committed ? VKRT_COMMITTED_TRIANGLE : VKRT_CANDIDATE_TRIANGLE)) {
        return;
    }
    uint64_t bottom = packUint2x32(vkrt_rq_setup[s].zw);
    if ((vkrt_rq_walk[s].w & VKRT_RQ_ONE_LEVEL) == 0u) {
        bottom = packUint2x32(VkrtInstances(VkrtHandle(bottom).addresses[7]).v[h.instance].meta.xy);
    }
    // (rayQueryProceedEXT reads its level's arrays afresh: nothing of the walk is lost here)
    vkrt_use(bottom);
    if (h.prim >= vkrt_scene_info.n_tris) {
        return;
    }
    vkrt_triangle_at(h.prim, 0.0, positions[0], positions[1], positions[2]);
}

// The extension's functions, on vkrt's: function-like macros, so that only calls are
// rewritten.
#define rayQueryInitializeEXT(q, as_, flags_, mask_, origin_, tmin_, direction_, tmax_) vkrtRayQueryInitialize(q, as_, flags_, mask_, origin_, tmin_, direction_, tmax_)
#define rayQueryProceedEXT(q) vkrtRayQueryProceed(q)
#define rayQueryConfirmIntersectionEXT(q) vkrtRayQueryConfirmIntersection(q)
#define rayQueryGenerateIntersectionEXT(q, c) vkrtRayQueryGenerateIntersection(q, c)
#define rayQueryTerminateEXT(q) vkrtRayQueryTerminate(q)
#define rayQueryGetIntersectionTypeEXT(q, c) vkrtRayQueryGetIntersectionType(q, c)
#define rayQueryGetIntersectionTEXT(q, c) vkrtRayQueryGetIntersectionT(q, c)
#define rayQueryGetIntersectionInstanceCustomIndexEXT(q, c) vkrtRayQueryGetIntersectionInstanceCustomIndex(q, c)
#define rayQueryGetIntersectionInstanceIdEXT(q, c) vkrtRayQueryGetIntersectionInstanceId(q, c)
#define rayQueryGetIntersectionInstanceShaderBindingTableRecordOffsetEXT(q, c) vkrtRayQueryGetIntersectionInstanceShaderBindingTableRecordOffset(q, c)
#define rayQueryGetIntersectionGeometryIndexEXT(q, c) vkrtRayQueryGetIntersectionGeometryIndex(q, c)
#define rayQueryGetIntersectionPrimitiveIndexEXT(q, c) vkrtRayQueryGetIntersectionPrimitiveIndex(q, c)
#define rayQueryGetIntersectionBarycentricsEXT(q, c) vkrtRayQueryGetIntersectionBarycentrics(q, c)
#define rayQueryGetIntersectionFrontFaceEXT(q, c) vkrtRayQueryGetIntersectionFrontFace(q, c)
#define rayQueryGetIntersectionCandidateAABBOpaqueEXT(q) vkrtRayQueryGetIntersectionCandidateAABBOpaque(q)
#define rayQueryGetIntersectionObjectRayDirectionEXT(q, c) vkrtRayQueryGetIntersectionObjectRayDirection(q, c)
#define rayQueryGetIntersectionObjectRayOriginEXT(q, c) vkrtRayQueryGetIntersectionObjectRayOrigin(q, c)
#define rayQueryGetIntersectionObjectToWorldEXT(q, c) vkrtRayQueryGetIntersectionObjectToWorld(q, c)
#define rayQueryGetIntersectionWorldToObjectEXT(q, c) vkrtRayQueryGetIntersectionWorldToObject(q, c)
#define rayQueryGetRayTMinEXT(q) vkrtRayQueryGetRayTMin(q)
#define rayQueryGetRayFlagsEXT(q) vkrtRayQueryGetRayFlags(q)
#define rayQueryGetWorldRayOriginEXT(q) vkrtRayQueryGetWorldRayOrigin(q)
#define rayQueryGetWorldRayDirectionEXT(q) vkrtRayQueryGetWorldRayDirection(q)
#define rayQueryGetIntersectionTriangleVertexPositionsEXT(q, c, p) vkrtRayQueryGetIntersectionTriangleVertexPositions(q, c, p)

#endif // !VKRT_NATIVE_RAY_QUERY
#endif
