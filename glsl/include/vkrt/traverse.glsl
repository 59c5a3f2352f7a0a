// Geometry buffers and the traversal of the structure they hold: the kd-tree (closest hit
// and any hit with a short stack and restart, Horn et al. 2007; Rust twin src/trace/cpu.rs)
// or the BVH (glsl/include/vkrt/bvh.glsl; twin src/trace/bvh_cpu.rs), chosen by VKRT_ACCEL_KIND when the
// pipeline is created, so every kernel that includes this file serves every structure.
//
// The including kernel defines VKRT_GEOM_BINDING (first of seven bindings of set VKRT_SET, default
// 0, in this order: nodes, prim_refs, triangle vertices, vkrt_spheres, per-primitive motion slot,
// vkrt_motions, scene info) and the specialization constants VKRT_INTERSECTOR, VKRT_ANY_HIT and VKRT_KD_STACK,
// then includes this file. With VKRT_LIBRARY defined (vkrt/ray_query.glsl, the public entry
// point) the walk is chosen at run time from the scene constants, so one shader traces every
// kind of structure, and VKRT_ANY_HIT is not used (each query says which it wants).
// A BVH's parent links follow its primitive references in the prim_refs buffer, from
// `vkrt_scene_info.parents_at` on.
//
// Primitive ids: 0 .. n_tris are triangles, then n_spheres vkrt_spheres, then n_aabbs axis-aligned
// boxes (stored after the vkrt_spheres in the vkrt_spheres binding, two vec4s each: min, max).
#ifndef VKRT_COMMON_TRAVERSE_GLSL
#define VKRT_COMMON_TRAVERSE_GLSL

#include "kdtree.glsl"
#include "ray.glsl"
#if VKRT_FP64_FALLBACK || defined(VKRT_HAS_RAY_QUERY)
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#endif
#ifdef VKRT_HAS_RAY_QUERY
#extension GL_EXT_ray_query : require
#endif

#ifndef VKRT_SET
#define VKRT_SET 0
#endif
#ifndef VKRT_TEXEL_NODES
#define VKRT_TEXEL_NODES 0
#endif

#define VKRT_NO_MOTION 0xffffffffu
// Node visits + primitive tests per ray before giving up; a ray that gives up is reported
// through `vkrt_trace_steps_exhausted`. A device fact (`DeviceInfo::max_traversal_steps`): within
// llvmpipe's loop budget (it silently ends an invocation's loops after 65,535 iterations),
// 2^24 elsewhere. vkrt's kernels take it as specialization constant 22; the library takes
// VKRT_MAX_TRAVERSAL_STEPS where the includer defines it (a number, or its own
// specialization constant), else the specialization constant VKRT_STEPS_CONSTANT_ID
// (default 1900; `shader_library::STEPS_CONSTANT_ID`), 60,000 unless the pipeline sets it.
#if defined(VKRT_LIBRARY) && defined(VKRT_MAX_TRAVERSAL_STEPS)
#define VKRT_STEP_LIMIT (VKRT_MAX_TRAVERSAL_STEPS)
#elif defined(VKRT_LIBRARY)
#ifndef VKRT_STEPS_CONSTANT_ID
#define VKRT_STEPS_CONSTANT_ID 1900
#endif
layout(constant_id = VKRT_STEPS_CONSTANT_ID) const uint VKRT_STEP_LIMIT = 60000u;
#else
layout(constant_id = 22) const uint VKRT_STEP_LIMIT = 60000u;
#endif
// Relative slack on split-plane crossings: a cell whose interval only touches the ray's
// within rounding is visited rather than skipped (visiting costs time, skipping loses hits).
#define VKRT_PLANE_SLACK 4e-7

// 48 bytes: `VkrtMotionRecord` in src/accel/primitives.rs.
struct VkrtMotionRecord {
    vec4 velocity;   // xyz: units/s; w: angular speed, radians/s
    vec4 center;     // xyz: a point on the rotation axis
    vec4 axis;       // xyz: unit rotation axis
};

#ifdef VKRT_DEVICE_ADDRESS
// The structure read at device addresses (the library's VKRT_DEVICE_ADDRESS): the same seven
// arrays, reached through references that vkrtUseStructure sets from the structure's handle
// (a record of their seven addresses), instead of bindings.
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer VkrtKdNodes { VkrtKdNode v[]; };
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer VkrtWords { uint v[]; };
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer VkrtFloats { float v[]; };
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer VkrtVec4s { vec4 v[]; };
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer VkrtMotions { VkrtMotionRecord v[]; };
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer VkrtSceneInfo {
    vec4 bounds_min;
    vec4 bounds_max;
    uint n_tris;
    uint n_spheres;
    uint has_motion;
    uint parents_at;
    uint walk;
    uint n_geometries;
    uint invalid;
    uint n_aabbs;
    uvec2 geometry_first[];
};
VkrtKdNodes vkrt_kd_nodes_ref;
VkrtWords vkrt_kd_refs_ref;
VkrtFloats vkrt_tri_verts_ref;
VkrtVec4s vkrt_spheres_ref;
VkrtWords vkrt_prim_motion_ref;
VkrtMotions vkrt_motions_ref;
VkrtSceneInfo vkrt_scene_info;
#define vkrt_kd_nodes vkrt_kd_nodes_ref.v
#define vkrt_kd_refs vkrt_kd_refs_ref.v
#define vkrt_tri_verts vkrt_tri_verts_ref.v
#define vkrt_spheres vkrt_spheres_ref.v
#define vkrt_prim_motion vkrt_prim_motion_ref.v
#define vkrt_motions vkrt_motions_ref.v
#else
#if VKRT_TEXEL_NODES
// The nodes through the sampler path: a uniform texel buffer of RGBA32UI texels (a kd-tree
// node is one, a BVH node four). On lavapipe a texel fetch is a branch-free gather, where a
// storage-buffer load at a divergent offset is a loop over the lanes with a bounds check
// each (Mesa < 25.1); Aila & Laine's GPU walks fetched nodes through textures for the same
// reason. vkrt's `texel` kernel variants; the same node bits either way.
// A texture without a sampler (`utextureBuffer`): SPIR-V 1.6 forbids the sampled-image type
// glslang makes of a `usamplerBuffer`, and Mesa warns of it.
#extension GL_EXT_samplerless_texture_functions : require
layout(set = VKRT_SET, binding = VKRT_GEOM_BINDING + 0) uniform utextureBuffer vkrt_node_texels;
#define VKRT_NODE_UNIT(t) texelFetch(vkrt_node_texels, int(t))
#elif VKRT_FP64_FALLBACK
// Every structure's nodes (a kd-tree's, a binary or wide BVH's, the driver's top-level
// address) through one block of 16-byte units, whole nodes being whole units: one block type
// per binding, which SPIR-V's translators (SPIRV-Cross, naga) and validators ask for. Units
// of two 64-bit words: on lavapipe every load is a loop over its components, so half the
// trips of four 32-bit ones.
layout(std430, set = VKRT_SET, binding = VKRT_GEOM_BINDING + 0) readonly buffer VkrtNodesBinding { u64vec2 vkrt_node_units[]; };
#define VKRT_NODE_UNIT(t) \
    uvec4(unpack32(vkrt_node_units[t].x), unpack32(vkrt_node_units[t].y))
#else
// As above, in 32-bit words.
layout(std430, set = VKRT_SET, binding = VKRT_GEOM_BINDING + 0) readonly buffer VkrtNodesBinding { uvec4 vkrt_node_units[]; };
#define VKRT_NODE_UNIT(t) vkrt_node_units[t]
#endif
#if VKRT_TEXEL_NODES
// The references and the triangle vertices as texels too (four words each).
layout(set = VKRT_SET, binding = VKRT_GEOM_BINDING + 1) uniform utextureBuffer vkrt_ref_texels;
layout(set = VKRT_SET, binding = VKRT_GEOM_BINDING + 2) uniform utextureBuffer vkrt_vertex_texels;
#else
layout(std430, set = VKRT_SET, binding = VKRT_GEOM_BINDING + 1) readonly buffer VkrtKdRefsBinding { uint vkrt_kd_refs[]; };
layout(std430, set = VKRT_SET, binding = VKRT_GEOM_BINDING + 2) readonly buffer VkrtTriVertsBinding { float vkrt_tri_verts[]; };
#endif
layout(std430, set = VKRT_SET, binding = VKRT_GEOM_BINDING + 3) readonly buffer VkrtSpheresBinding { vec4 vkrt_spheres[]; };
layout(std430, set = VKRT_SET, binding = VKRT_GEOM_BINDING + 4) readonly buffer VkrtPrimMotionBinding { uint vkrt_prim_motion[]; };
layout(std430, set = VKRT_SET, binding = VKRT_GEOM_BINDING + 5) readonly buffer VkrtMotionsBinding { VkrtMotionRecord vkrt_motions[]; };
// `SceneInfo` in src/accel/primitives.rs.
layout(std430, set = VKRT_SET, binding = VKRT_GEOM_BINDING + 6) readonly buffer VkrtSceneInfoBinding {
    vec4 bounds_min;
    vec4 bounds_max;
    uint n_tris;
    uint n_spheres;
    uint has_motion;
    uint parents_at; // BVH: index of node 0's parent link in vkrt_kd_refs
    uint walk;       // VKRT_ACCEL_KDTREE, VKRT_ACCEL_BVH_STACK or VKRT_ACCEL_RAY_QUERY: how to walk it
    uint n_geometries;
    uint invalid;    // primitives the gather could not read (the host reports them)
    uint n_aabbs;
    // Per geometry, ordered by first id: (first primitive id, the caller's geometry index).
    uvec2 geometry_first[];
} vkrt_scene_info;

#endif

#ifdef VKRT_HAS_RAY_QUERY
// The driver's structure (src/accel/driver.rs): the nodes binding holds the device address
// of its top level, which the query converts (OpConvertUToAccelerationStructureKHR), so no
// acceleration-structure descriptor is needed; the prim_refs binding (vkrt_kd_refs) holds the
// first primitive id of each instance.
#ifdef VKRT_DEVICE_ADDRESS
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer VkrtU64s { uint64_t v[]; };
VkrtU64s vkrt_tlas_ref;
#define vkrt_tlas_address vkrt_tlas_ref.v[0]
#elif VKRT_TEXEL_NODES
// The nodes binding is a texel buffer: the address is the first texel's two low words.
#define vkrt_tlas_address packUint2x32(texelFetch(vkrt_node_texels, 0).xy)
#elif VKRT_FP64_FALLBACK
// The nodes binding's first word (its 8 bytes alone are read).
#define vkrt_tlas_address vkrt_node_units[0].x
#else
#define vkrt_tlas_address packUint2x32(uvec2(vkrt_node_units[0].x, vkrt_node_units[0].y))
#endif
#endif

// 0: kd-tree; 1: BVH with a stack; 2: BVH with the bitstack walk; 3: the driver's ray query
// (AccelTraversal::spec; kernels compiled with VKRT_HAS_RAY_QUERY walk only that); 4: the 4-wide BVH
// with a stack.
#define VKRT_ACCEL_KDTREE 0u
#define VKRT_ACCEL_BVH_STACK 1u
#define VKRT_ACCEL_BVH_BITSTACK 2u
#define VKRT_ACCEL_RAY_QUERY 3u
#define VKRT_ACCEL_BVH_WIDE 4u
// A top level over instances (vkrt/instances.glsl; read at device addresses only).
#define VKRT_ACCEL_INSTANCES 8u
#ifndef VKRT_LIBRARY
layout(constant_id = 20) const uint VKRT_ACCEL_KIND = 0u;
#endif

bool vkrt_trace_steps_exhausted = false;

// `nd = node i`. A statement, not a function: glslang takes minutes and gigabytes to
// compile the kd-tree walk when a call there returns its node (its `precise` propagation).
#ifdef VKRT_DEVICE_ADDRESS
#define VKRT_LOAD_KD_NODE(nd, i) nd = vkrt_kd_nodes[i];
#else
#define VKRT_LOAD_KD_NODE(nd, i)                                                  \
    {                                                                        \
        uvec4 unit_ = VKRT_NODE_UNIT(i);                                     \
        nd = VkrtKdNode(uintBitsToFloat(unit_.x), unit_.y, unit_.z, unit_.w); \
    }
#endif

// The rigid motion at `time`: rotate about the orbit axis, then translate (Motion::at).
vec3 vkrt_move_point(vec3 p, uint slot, float time) {
    VkrtMotionRecord m = vkrt_motions[slot];
    precise float angle = m.velocity.w * time;
    precise vec3 q = p;
    if (angle != 0.0) {
        vec3 k = m.axis.xyz;
        precise vec3 r = p - m.center.xyz;
        float c = cos(angle);
        float s = sin(angle);
        precise vec3 rot = r * c + vkrt_cross3(k, r) * s + k * (vkrt_dot3(k, r) * (1.0 - c));
        q = rot + m.center.xyz;
    }
    precise vec3 moved = q + m.velocity.xyz * time;
    return moved;
}

#if VKRT_TEXEL_NODES
// Reference `i` (of the structure's references, then a BVH's parent links).
uint vkrt_ref_at(uint i) {
    return texelFetch(vkrt_ref_texels, int(i >> 2u))[i & 3u];
}
#define VKRT_KD_REF(i) vkrt_ref_at(i)

// A triangle's nine floats lie in three texels: three fetches instead of nine loads. Shifted
// into place by selects, not a loop over an array: llvmpipe before Mesa 25 counts every
// iteration of every loop against its budget of 65,535 per invocation, and a loop per
// triangle tested exhausts it on big leaves.
void vkrt_load_triangle(uint tri, out vec3 p0, out vec3 p1, out vec3 p2) {
    uint first = 9u * tri;
    int t = int(first >> 2u);
    uint o = first & 3u;
    uvec4 a = texelFetch(vkrt_vertex_texels, t);
    uvec4 b = texelFetch(vkrt_vertex_texels, t + 1);
    uvec4 c = texelFetch(vkrt_vertex_texels, t + 2);
    uvec4 x = o == 0u ? a : (o == 1u ? uvec4(a.yzw, b.x) : (o == 2u ? uvec4(a.zw, b.xy) : uvec4(a.w, b.xyz)));
    uvec4 y = o == 0u ? b : (o == 1u ? uvec4(b.yzw, c.x) : (o == 2u ? uvec4(b.zw, c.xy) : uvec4(b.w, c.xyz)));
    uint z = o == 0u ? c.x : (o == 1u ? c.y : (o == 2u ? c.z : c.w));
    p0 = uintBitsToFloat(x.xyz);
    p1 = uintBitsToFloat(uvec3(x.w, y.xy));
    p2 = uintBitsToFloat(uvec3(y.zw, z));
}
#else
#define VKRT_KD_REF(i) vkrt_kd_refs[i]

vec3 vkrt_tri_vertex(uint tri, uint corner) {
    uint i = 9u * tri + 3u * corner;
    return vec3(vkrt_tri_verts[i], vkrt_tri_verts[i + 1u], vkrt_tri_verts[i + 2u]);
}
#endif

#if VKRT_TEXEL_NODES
#elif VKRT_FP64_FALLBACK
// The same vertices as 64-bit words: a triangle's nine floats lie in five of them (the
// buffer holds four padding floats, DevicePrimitives), five loads instead of nine — on
// lavapipe every load is a loop over lanes.
#ifdef VKRT_DEVICE_ADDRESS
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer VkrtWords64 { uint64_t v[]; };
VkrtWords64 vkrt_tri_verts64_ref;
#define vkrt_tri_verts64 vkrt_tri_verts64_ref.v
#else
layout(std430, set = VKRT_SET, binding = VKRT_GEOM_BINDING + 2) readonly buffer VkrtTriVerts64Binding { uint64_t vkrt_tri_verts64[]; };
#endif

void vkrt_load_triangle(uint tri, out vec3 p0, out vec3 p1, out vec3 p2) {
    uint first = 9u * tri;
    uint base = first >> 1u;
    uint w[10];
    for (uint k = 0u; k < 5u; k++) {
        uvec2 pair = unpack32(vkrt_tri_verts64[base + k]);
        w[2u * k] = pair.x;
        w[2u * k + 1u] = pair.y;
    }
    bool odd = (first & 1u) != 0u;
    float f[9];
    for (uint k = 0u; k < 9u; k++) {
        f[k] = uintBitsToFloat(odd ? w[k + 1u] : w[k]);
    }
    p0 = vec3(f[0], f[1], f[2]);
    p1 = vec3(f[3], f[4], f[5]);
    p2 = vec3(f[6], f[7], f[8]);
}
#else
void vkrt_load_triangle(uint tri, out vec3 p0, out vec3 p1, out vec3 p2) {
    p0 = vkrt_tri_vertex(tri, 0u);
    p1 = vkrt_tri_vertex(tri, 1u);
    p2 = vkrt_tri_vertex(tri, 2u);
}
#endif

// The three vertices of triangle `tri` at `time`.
void vkrt_triangle_at(uint tri, float time, out vec3 p0, out vec3 p1, out vec3 p2) {
    vkrt_load_triangle(tri, p0, p1, p2);
    if (vkrt_scene_info.has_motion != 0u) {
        uint slot = vkrt_prim_motion[tri];
        if (slot != VKRT_NO_MOTION) {
            p0 = vkrt_move_point(p0, slot, time);
            p1 = vkrt_move_point(p1, slot, time);
            p2 = vkrt_move_point(p2, slot, time);
        }
    }
}

vec4 vkrt_sphere_at(uint sphere, float time) {
    vec4 s = vkrt_spheres[sphere];
    if (vkrt_scene_info.has_motion != 0u) {
        uint slot = vkrt_prim_motion[vkrt_scene_info.n_tris + sphere];
        if (slot != VKRT_NO_MOTION) {
            s.xyz = vkrt_move_point(s.xyz, slot, time);
        }
    }
    return s;
}

// Every primitive of the structure.
uint vkrt_primitive_count() {
    return vkrt_scene_info.n_tris + vkrt_scene_info.n_spheres + vkrt_scene_info.n_aabbs;
}

// Box primitive `b`: (min, max).
void vkrt_aabb_at(uint b, out vec3 lo, out vec3 hi) {
    uint at = vkrt_scene_info.n_spheres + 2u * b;
    lo = vkrt_spheres[at].xyz;
    hi = vkrt_spheres[at + 1u].xyz;
}

// The geometry table's entry of primitive id `prim`: (first id, geometry word), or (0, 0)
// for a structure without a table (one geometry, opaque).
uvec2 vkrt_geometry_entry(uint prim) {
    uint n = vkrt_scene_info.n_geometries;
    if (n == 0u) {
        return uvec2(0u);
    }
    // The last geometry whose first id is <= prim (binary search over the ordered table).
    uint lo = 0u;
    uint hi = n - 1u;
    while (lo < hi) {
        uint mid = (lo + hi + 1u) >> 1u;
        if (vkrt_scene_info.geometry_first[mid].x <= prim) {
            lo = mid;
        } else {
            hi = mid - 1u;
        }
    }
    return vkrt_scene_info.geometry_first[lo];
}

// The caller's (geometry index, primitive index within it) of primitive id `prim`.
uvec2 vkrt_geometry_of(uint prim) {
    uvec2 g = vkrt_geometry_entry(prim);
    // (bit 31 marks a non-opaque geometry: vkrt/ext_ray_query.glsl reads it)
    return uvec2(g.y & 0x7fffffffu, prim - g.x);
}

#if defined(VKRT_LIBRARY) && defined(VKRT_AABB_INTERSECTION)
// The includer's intersection for box primitives (vkrt/ray_query.glsl).
bool vkrtIntersectAabb(uint geometryIndex, uint primitiveIndex, vec3 origin, vec3 direction,
                       float tMin, float tMax, vec3 boxMin, vec3 boxMax, out float t,
                       out vec2 attributes);
#endif

bool vkrt_hit_primitive(uint prim, VkrtRay r, VkrtShear sh, float time, float tmin, float tmax,
                   out float t, out float u, out float v) {
    if (prim < vkrt_scene_info.n_tris) {
        vec3 p0, p1, p2;
        vkrt_triangle_at(prim, time, p0, p1, p2);
        if (VKRT_INTERSECTOR == VKRT_INTERSECT_MOLLER_TRUMBORE) {
            return vkrt_hit_triangle_moller(r.o, r.d, p0, p1, p2, tmin, tmax, t, u, v);
        }
        return vkrt_hit_triangle_watertight(r.o, sh, p0, p1, p2, tmin, tmax, t, u, v);
    }
    u = 0.0;
    v = 0.0;
    uint s = prim - vkrt_scene_info.n_tris;
    if (s < vkrt_scene_info.n_spheres) {
        return vkrt_hit_sphere(r.o, r.d, vkrt_sphere_at(s, time), tmin, tmax, t);
    }
    vec3 lo, hi;
    vkrt_aabb_at(s - vkrt_scene_info.n_spheres, lo, hi);
#if defined(VKRT_LIBRARY) && defined(VKRT_AABB_INTERSECTION)
    if (!all(lessThanEqual(lo, hi))) {
        return false; // inactive
    }
    uvec2 g = vkrt_geometry_of(prim);
    vec2 a = vec2(0.0);
    bool found = vkrtIntersectAabb(g.x, g.y, r.o, r.d, tmin, tmax, lo, hi, t, a);
    u = a.x;
    v = a.y;
    return found && t >= tmin && t <= tmax;
#else
    return vkrt_hit_aabb(r.o, r.d, lo, hi, tmin, tmax, t);
#endif
}

// Clips [t0, t1] to the box [bmin, bmax]; false if the ray misses it. Axes the ray is
// parallel to only test the origin (no 0 * inf); the slab bounds are widened by a few ulps
// (Ize 2013). `inv_d` is 1 / r.d. The scene box of the kd-tree walk and every child box of
// the BVH walk.
bool vkrt_clip_to_box(vec3 bmin, vec3 bmax, VkrtRay r, vec3 inv_d, inout float t0, inout float t1) {
    // Branch-free on the three axes (lavapipe runs both sides of every branch under a mask):
    // an axis the ray runs parallel to only decides inside or outside, as in the CPU twin;
    // the others narrow [t0, t1] in the order x, y, z. On a miss t0 and t1 are unspecified.
    bvec3 parallel = equal(r.d, vec3(0.0));
    bvec3 off_slab = bvec3(uvec3(lessThan(r.o, bmin)) | uvec3(greaterThan(r.o, bmax)));
    if (any(bvec3(uvec3(parallel) & uvec3(off_slab)))) {
        return false;
    }
    precise vec3 ta = (bmin - r.o) * inv_d;
    precise vec3 tb = (bmax - r.o) * inv_d;
    precise vec3 lo = min(ta, tb);
    precise vec3 hi = max(ta, tb);
    precise vec3 lo_w = mix(lo - abs(lo) * VKRT_PLANE_SLACK, vec3(-1.0 / 0.0), parallel);
    precise vec3 hi_w = mix(hi + abs(hi) * VKRT_PLANE_SLACK, vec3(1.0 / 0.0), parallel);
    t0 = max(max(max(t0, lo_w.x), lo_w.y), lo_w.z);
    t1 = min(min(min(t1, hi_w.x), hi_w.y), hi_w.z);
    return t0 <= t1;
}

bool vkrt_clip_to_scene(VkrtRay r, inout float t0, inout float t1) {
    precise vec3 inv_d = vkrt_recip3(r.d);
    return vkrt_clip_to_box(vkrt_scene_info.bounds_min.xyz, vkrt_scene_info.bounds_max.xyz, r, inv_d, t0, t1);
}

// Tests a leaf's `count` references from `first` on against the ray up to `best_t`, keeping
// the closest hit (the lowest primitive id among equal t); true when an any-hit query is
// answered.
bool vkrt_test_leaf(uint first, uint count, VkrtRay r, VkrtShear sh, float time, float tmin, bool any_hit,
               inout VkrtWalkHit best, inout float best_t) {
    for (uint i = first; i < first + count; i++) {
        uint prim = VKRT_KD_REF(i);
        float t, u, v;
        if (vkrt_hit_primitive(prim, r, sh, time, tmin, best_t, t, u, v)) {
            if (best.prim == VKRT_NO_HIT || t < best_t || (t == best_t && prim < best.prim)) {
                best = VkrtWalkHit(t, prim, u, v);
                best_t = t;
            }
            if (any_hit) {
                return true;
            }
        }
    }
    return false;
}

// The start every walk shares: a miss for an invalid ray or an empty structure, then the
// ray's start (t >= 0), its shear for the watertight test, its reciprocal direction and the
// closest hit so far (`best`, at `best_t`).
#define VKRT_WALK_START(r)                                       \
    VkrtWalkHit best = vkrt_miss_hit();                          \
    if (!vkrt_ray_is_valid(r) || vkrt_primitive_count() == 0u) { \
        return best;                                             \
    }                                                            \
    float tmin = max(r.tmin, 0.0);                               \
    VkrtShear sh = vkrt_make_shear(r.d);                         \
    vec3 inv_d = vkrt_recip3(r.d);                               \
    float best_t = r.tmax

// The state of a stack walk (Aila & Laine's while-while loop, VKRT_BVH_DESCEND): entries
// (index, count) — count 0 an interior node, count > 0 a leaf's references — with the
// distance at which the ray enters each (vkrt_stack_entry, bvh.glsl), the entry in hand, and
// the steps taken.
#define VKRT_STACK_WALK_STATE(size) \
    uvec2 stack[size];              \
    uint top = 0u;                  \
    uvec2 cur = uvec2(0u, 0u);      \
    bool have = true;               \
    uint steps = 0u

#include "bvh.glsl"

// The kd-tree walk in two steps both walks share (vkrt_trace_kdtree here, the ray query's
// resumable walk in ext_ray_query.glsl), over the walk's state: the cell in hand (`node`
// over [n0, n1]), the scene's far end `scene_t1`, the node loaded `nd`, the steps taken, and
// a ring of cells still to visit (`st_top` one past the newest, `st_count` held, `dropped`
// once a push overwrote the oldest), reached through RING_NODE(i), RING_T0(i), RING_T1(i)
// and RING_PUT(i, node, t0, t1) (a ring of `size` entries).
//
// VKRT_KD_DESCEND_ON: from the cell in hand through interior nodes until `nd` is a leaf,
// pushing each far cell; it stops with steps == VKRT_STEP_LIMIT at the cap instead.
#define VKRT_KD_DESCEND_ON(RING, size)                                                     \
    while (steps < VKRT_STEP_LIMIT) {                                                     \
        VKRT_LOAD_KD_NODE(nd, node)                                                       \
        if (nd.kind == VKRT_KD_LEAF) {                                                    \
            break;                                                                        \
        }                                                                                 \
        steps++;                                                                          \
        uint axis_ = nd.kind;                                                             \
        float o_ = r.o[axis_];                                                            \
        float d_ = r.d[axis_];                                                            \
        bool below_first_ = o_ < nd.split || (o_ == nd.split && d_ <= 0.0);               \
        uint first_ = below_first_ ? nd.a : nd.a + 1u;                                    \
        uint second_ = below_first_ ? nd.a + 1u : nd.a;                                   \
        /* Where to go now, and the cell to visit later (if any) over [far0_, far1_]. */  \
        node = first_;                                                                    \
        bool push_ = false;                                                               \
        uint far_node_ = second_;                                                         \
        float far0_ = n0;                                                                 \
        float far1_ = n1;                                                                 \
        if (d_ == 0.0) {                                                                  \
            /* Parallel to the plane: the origin's side, or both when lying in it. */     \
            push_ = o_ == nd.split;                                                       \
        } else if (o_ == nd.split && n0 <= 0.0) {                                         \
            /* Starting on the plane: the ray enters `first` at once and touches */       \
            /* `second` at t = 0 only (primitives lying in the plane): `second` over */   \
            /* [n0, n0] first, then `first` over the whole interval. */                   \
            push_ = true;                                                                 \
            far_node_ = first_;                                                           \
            node = second_;                                                               \
            n1 = n0;                                                                      \
        } else {                                                                          \
            precise float tp_ = (nd.split - o_) * inv_d[axis_];                           \
            precise float tp_lo_ = tp_ - abs(tp_) * VKRT_PLANE_SLACK;                     \
            precise float tp_hi_ = tp_ + abs(tp_) * VKRT_PLANE_SLACK;                     \
            if (tp_ > 0.0 && tp_lo_ <= n1) {                                              \
                if (tp_hi_ < n0) {                                                        \
                    node = second_;                                                       \
                } else {                                                                  \
                    /* the far child starts at the (widened) crossing, the near one */    \
                    /* ends there */                                                      \
                    push_ = true;                                                         \
                    far0_ = max(tp_lo_, n0);                                              \
                    n1 = min(tp_hi_, n1);                                                 \
                }                                                                         \
            }                                                                             \
        }                                                                                 \
        if (push_) {                                                                      \
            if (st_count == (size)) {                                                     \
                dropped = true;                                                           \
            } else {                                                                      \
                st_count++;                                                               \
            }                                                                             \
            RING##_PUT(st_top, far_node_, far0_, far1_);                                  \
            st_top = st_top + 1u == (size) ? 0u : st_top + 1u;                            \
        }                                                                                 \
    }

// VKRT_KD_POP_ON: after a leaf, the next cell: popped, skipping cells that start beyond the
// closest hit (at `best_t`; `no_hit` while there is none), or the root again past the last
// cell when entries were dropped; `have` false when the walk is complete. No early exit on
// best_t <= n1 before: entries pushed for rays lying in or starting on a split plane cover
// the same interval as the leaf's cell, and ties at equal t go to the lowest id.
#define VKRT_KD_POP_ON(RING, size, no_hit)                                                 \
    {                                                                                     \
        bool found_ = false;                                                              \
        while (st_count > 0u) {                                                           \
            st_top = st_top == 0u ? (size) - 1u : st_top - 1u;                            \
            st_count--;                                                                   \
            if ((no_hit) || RING##_T0(st_top) <= best_t) {                                \
                node = RING##_NODE(st_top);                                               \
                n0 = RING##_T0(st_top);                                                   \
                n1 = RING##_T1(st_top);                                                   \
                found_ = true;                                                            \
                break;                                                                    \
            }                                                                             \
        }                                                                                 \
        if (!found_) {                                                                    \
            if (!dropped || n1 >= scene_t1 || (!(no_hit) && best_t <= n1)) {              \
                have = false;                                                             \
            } else {                                                                      \
                /* Restart from the root past the last cell (entries were dropped). */    \
                dropped = false;                                                          \
                node = 0u;                                                                \
                n0 = n1;                                                                  \
                n1 = scene_t1;                                                            \
            }                                                                             \
        }                                                                                 \
    }

// The kernels' ring: three arrays of VKRT_KD_STACK entries.
#define VKRT_KD_RING_NODE(i) st_node[i]
#define VKRT_KD_RING_T0(i) st_t0[i]
#define VKRT_KD_RING_T1(i) st_t1[i]
#define VKRT_KD_RING_PUT(i, n_, a_, b_) \
    st_node[i] = n_;                    \
    st_t0[i] = a_;                      \
    st_t1[i] = b_

// Closest hit (or, with VKRT_ANY_HIT, the first hit found) with t in [max(tmin, 0), tmax] at
// `time`. Invalid rays (see vkrt_ray_is_valid) miss.
VkrtWalkHit vkrt_trace_kdtree(VkrtRay r, float time, bool any_hit) {
    VKRT_WALK_START(r);
    float t0 = tmin;
    float t1 = r.tmax;
    if (!vkrt_clip_to_scene(r, t0, t1)) {
        return best;
    }
    float scene_t1 = t1;

    // Ring buffer: when full, a push overwrites the oldest (farthest) entry and the traversal
    // restarts from the root past the last leaf when it runs out.
    uint st_node[VKRT_KD_STACK];
    float st_t0[VKRT_KD_STACK];
    float st_t1[VKRT_KD_STACK];
    uint st_top = 0u;
    uint st_count = 0u;
    bool dropped = false;

    uint node = 0u;
    float n0 = t0;
    float n1 = t1;
    uint steps = 0u;
    bool have = true;
    VkrtKdNode nd;
    while (true) {
        VKRT_KD_DESCEND_ON(VKRT_KD_RING, VKRT_KD_STACK);
        if (steps >= VKRT_STEP_LIMIT) {
            break;
        }
        // Leaf: test its primitives over the whole remaining ray interval.
        if (vkrt_test_leaf(nd.a, nd.b, r, sh, time, tmin, any_hit, best, best_t)) {
            return best;
        }
        steps += nd.b + 1u;
        VKRT_KD_POP_ON(VKRT_KD_RING, VKRT_KD_STACK, best.prim == VKRT_NO_HIT);
        if (!have) {
            return best;
        }
    }
    vkrt_trace_steps_exhausted = true;
    return best;
}

#ifdef VKRT_HAS_RAY_QUERY
// The driver traverses its own structure. Static triangles are its triangle geometry (its
// intersector, committed by the driver); vkrt_spheres, and every primitive of a scene with motion,
// are boxes (swept over the shutter for moving ones) that this loop intersects with
// vkrt_hit_primitive at `time` and commits. One instance per kind of geometry
// (DriverAccel::geometries); vkrt_kd_refs[instance] + the primitive's index is its id.
VkrtWalkHit vkrt_trace_ray_query(VkrtRay r, float time, bool any_hit) {
    // An invalid ray is a miss (src/trace/mod.rs); Vulkan leaves queries with NaN, a negative
    // tmin or tmin > tmax undefined, so none is made.
    float tmin = max(r.tmin, 0.0);
    if (!vkrt_ray_is_valid(r) || tmin > r.tmax || vkrt_primitive_count() == 0u) {
        return vkrt_miss_hit();
    }
    VkrtShear sh = vkrt_make_shear(r.d);
    // Opaque: triangle hits commit without the loop; any hit ends at the first commit.
    uint flags = gl_RayFlagsOpaqueEXT | (any_hit ? gl_RayFlagsTerminateOnFirstHitEXT : 0u);
    rayQueryEXT q;
    rayQueryInitializeEXT(q, accelerationStructureEXT(vkrt_tlas_address), flags, 0xffu, r.o, tmin,
                          r.d, r.tmax);
    float best_t = r.tmax;
    vec2 best_uv = vec2(0.0);
    // Candidates (boxes the driver found) per ray before giving up, as for vkrt's walks.
    uint candidates = 0u;
    while (rayQueryProceedEXT(q)) {
        if (++candidates > VKRT_STEP_LIMIT) {
            rayQueryTerminateEXT(q);
            vkrt_trace_steps_exhausted = true;
            return vkrt_miss_hit();
        }
        if (rayQueryGetIntersectionTypeEXT(q, false) == gl_RayQueryCandidateIntersectionAABBEXT) {
            uint prim = VKRT_KD_REF(rayQueryGetIntersectionInstanceIdEXT(q, false))
                + uint(rayQueryGetIntersectionPrimitiveIndexEXT(q, false));
            float t, u, v;
            if (vkrt_hit_primitive(prim, r, sh, time, tmin, best_t, t, u, v)) {
                rayQueryGenerateIntersectionEXT(q, t);
                best_t = t;
                best_uv = vec2(u, v);
            }
        }
    }
    uint committed = rayQueryGetIntersectionTypeEXT(q, true);
    if (committed == gl_RayQueryCommittedIntersectionNoneEXT) {
        return vkrt_miss_hit();
    }
    uint prim = VKRT_KD_REF(rayQueryGetIntersectionInstanceIdEXT(q, true))
        + uint(rayQueryGetIntersectionPrimitiveIndexEXT(q, true));
    float t = rayQueryGetIntersectionTEXT(q, true);
    if (committed == gl_RayQueryCommittedIntersectionTriangleEXT) {
        vec2 uv = rayQueryGetIntersectionBarycentricsEXT(q, true);
        return VkrtWalkHit(t, prim, uv.x, uv.y);
    }
    return VkrtWalkHit(t, prim, best_uv.x, best_uv.y);
}
#endif

// The walk `walk` (ACCEL_*) over the bound structure.
VkrtWalkHit vkrt_trace_walk(uint walk, VkrtRay r, float time, bool any_hit) {
#ifdef VKRT_HAS_RAY_QUERY
    if (walk == VKRT_ACCEL_RAY_QUERY) {
        return vkrt_trace_ray_query(r, time, any_hit);
    }
#endif
    if (walk == VKRT_ACCEL_KDTREE) {
        return vkrt_trace_kdtree(r, time, any_hit);
    }
    if (walk == VKRT_ACCEL_BVH_STACK) {
        return vkrt_trace_bvh_stack(r, time, any_hit);
    }
    if (walk == VKRT_ACCEL_BVH_BITSTACK) {
        return vkrt_trace_bvh_bitstack(r, time, any_hit);
    }
    if (walk == VKRT_ACCEL_BVH_WIDE) {
        return vkrt_trace_bvh_wide(r, time, any_hit);
    }
    // A walk this shader was not compiled for (the driver's structure without VKRT_HAS_RAY_QUERY):
    // reported like a walk that gave up, never as a silent miss.
    vkrt_trace_steps_exhausted = true;
    return vkrt_miss_hit();
}

#ifndef VKRT_LIBRARY
VkrtWalkHit vkrt_trace_ray(VkrtRay r, float time) {
#ifdef VKRT_HAS_RAY_QUERY
    return vkrt_trace_ray_query(r, time, VKRT_ANY_HIT);
#else
    return vkrt_trace_walk(VKRT_ACCEL_KIND, r, time, VKRT_ANY_HIT);
#endif
}
#endif

#endif
