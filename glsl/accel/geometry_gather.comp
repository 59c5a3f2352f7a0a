#version 460
// Reads one geometry of the caller's (its vertex and index buffers where they lie, as
// VkAccelerationStructureGeometryKHR describes them) into the layout vkrt's builders and walk
// read: triangles as nine floats in primitive order, vkrt_spheres as (center, radius), axis-aligned
// box primitives as two vec4s (min, max) after the vkrt_spheres, and a bounding box per primitive; the geometry's entry of the table that maps primitive ids back to (geometry,
// primitive). One dispatch per geometry (src/accel/geometry.rs), plus one that writes the
// scene constants (MODE_HEADER).
//
// A primitive the caller's data cannot give (an index past the vertex count, a non-finite
// coordinate or radius, a negative radius) becomes a point that no ray hits, and is counted
// in `invalid` for the host to report: never a box that breaks a build. A box primitive with
// a non-finite coordinate becomes an inactive one (min > max), counted too; an inactive box
// (active in no axis) is bounded by the point at the origin for the builders.
//! variant buffers ADDRESS=0
//! variant address ADDRESS=1
// `address`: the caller's vertices and indices are read at device addresses
// (GL_EXT_buffer_reference) instead of through bindings 0 and 1.
#if ADDRESS
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_buffer_reference_uvec2 : require
#endif
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

#define MODE_TRIANGLES 0u
#define MODE_SPHERES 1u
#define MODE_HEADER 2u
#define MODE_AABBS 3u
#define INDEX_NONE 0u
#define INDEX_U16 1u
#define INDEX_U32 2u

#if ADDRESS
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer Words { uint w[]; };
#define SRC(i) Words(pc.src_address).w[i]
#define IDX(i) Words(pc.idx_address).w[i]
#else
layout(std430, binding = 0) readonly buffer Source { uint src[]; };
layout(std430, binding = 1) readonly buffer Indices { uint idx[]; };
#define SRC(i) src[i]
#define IDX(i) idx[i]
#endif
layout(std430, binding = 2) writeonly buffer VkrtTriVertsBinding { float vkrt_tri_verts[]; };
layout(std430, binding = 3) writeonly buffer VkrtSpheresBinding { vec4 vkrt_spheres[]; };
layout(std430, binding = 4) writeonly buffer Boxes { float boxes[]; };
// `SceneInfo` (src/accel/primitives.rs) and the geometry table after it.
layout(std430, binding = 5) buffer VkrtSceneInfoBinding {
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
} info;

layout(push_constant) uniform Push {
    uint mode;
    uint count;        // primitives (MODE_HEADER: n_tris)
    uint first;        // first primitive id (MODE_HEADER: n_spheres)
    uint out_first;    // first triangle / sphere slot (MODE_HEADER: parents_at)
    uint src_word;     // first vertex (sphere) word in `src` (MODE_HEADER: walk)
    uint stride_words; // words between vertices (vkrt_spheres)
    uint index_type;
    uint index_first;  // first index, in indices, within the bound range (MODE_HEADER: n_geometries)
    uint vertex_count; // (MODE_HEADER: n_aabbs)
    uint table_slot;
    uint geometry;
    uint has_transform;
    vec4 rows[3];      // the 3x4 object-to-structure transform, row-major
    uvec2 src_address; // `address`: where word 0 of the vertices (vkrt_spheres) lies
    uvec2 idx_address; // `address`: where word 0 of the indices lies
    uvec2 xf_address;  // `address`, has_transform 2: where the transform's twelve floats lie
    uint vertex_format; // FORMAT_*
    uint pad;
} pc;

// VertexFormat::code.
#define FORMAT_RGB32F 0u
#define FORMAT_RG32F 1u
#define FORMAT_RG16F 2u
#define FORMAT_RGBA16F 3u
#define FORMAT_RG16_SNORM 4u
#define FORMAT_RGBA16_SNORM 5u

// A signed 16-bit normalized value as VertexFormat::decode reads it: max(v / 32767, -1),
// divided (not multiplied by a reciprocal) as the CPU twin is.
float snorm16(uint bits) {
    precise float v = float(int(bits << 16u) >> 16);
    v = v / 32767.0;
    return max(v, -1.0);
}

uint index_at(uint k) {
    if (pc.index_type == INDEX_NONE) {
        return k;
    }
    uint e = pc.index_first + k;
    if (pc.index_type == INDEX_U16) {
        return (IDX(e >> 1u) >> (16u * (e & 1u))) & 0xffffu;
    }
    return IDX(e);
}

// Row k of the transform: from the push constants, or (has_transform 2) read where the
// caller's VkTransformMatrixKHR lies.
vec4 transform_row(uint k) {
#if ADDRESS
    if (pc.has_transform == 2u) {
        Words xf = Words(pc.xf_address);
        uint w = 4u * k;
        return uintBitsToFloat(uvec4(xf.w[w], xf.w[w + 1u], xf.w[w + 2u], xf.w[w + 3u]));
    }
#endif
    return pc.rows[k];
}

vec3 vertex_at(uint v) {
    uint w = pc.src_word + v * pc.stride_words;
    vec3 p;
    switch (pc.vertex_format) {
    case FORMAT_RG32F:
        p = vec3(uintBitsToFloat(SRC(w)), uintBitsToFloat(SRC(w + 1u)), 0.0);
        break;
    case FORMAT_RG16F:
        p = vec3(unpackHalf2x16(SRC(w)), 0.0);
        break;
    case FORMAT_RGBA16F:
        p = vec3(unpackHalf2x16(SRC(w)), unpackHalf2x16(SRC(w + 1u)).x);
        break;
    case FORMAT_RG16_SNORM: {
        uint a = SRC(w);
        p = vec3(snorm16(a & 0xffffu), snorm16(a >> 16u), 0.0);
        break;
    }
    case FORMAT_RGBA16_SNORM: {
        uint a = SRC(w);
        p = vec3(snorm16(a & 0xffffu), snorm16(a >> 16u), snorm16(SRC(w + 1u) & 0xffffu));
        break;
    }
    default:
        p = vec3(uintBitsToFloat(SRC(w)), uintBitsToFloat(SRC(w + 1u)),
                 uintBitsToFloat(SRC(w + 2u)));
        break;
    }
    if (pc.has_transform != 0u) {
        // Left to right, no fused multiply-add: the CPU twin (Triangles::transformed) rounds
        // the same way.
        precise vec3 q;
        for (uint k = 0u; k < 3u; k++) {
            vec4 m = transform_row(k);
            precise float x = m.x * p.x;
            x = x + m.y * p.y;
            x = x + m.z * p.z;
            x = x + m.w;
            q[k] = x;
        }
        p = q;
    }
    return p;
}

bool finite3(vec3 v) {
    uvec3 e = floatBitsToUint(v) & 0x7f800000u;
    return all(notEqual(e, uvec3(0x7f800000u)));
}

// The next float towards +inf / -inf, never a subnormal (a device may flush them): above
// zero and the subnormals is the smallest normal, above its negation zero (next_up /
// next_down in src/accel/primitives.rs). Tested on the bits: a flushing device would read a
// subnormal as zero.
float next_up(float x) {
    uint b = floatBitsToUint(x);
    if ((b & 0x7fffffffu) > 0x7f800000u || b == 0x7f800000u) {
        return x;
    }
    if ((b & 0x7fffffffu) < 0x00800000u) {
        return uintBitsToFloat(0x00800000u);
    }
    if (b == 0x80800000u) {
        return uintBitsToFloat(0x80000000u);
    }
    return uintBitsToFloat((b & 0x80000000u) == 0u ? b + 1u : b - 1u);
}

float next_down(float x) {
    return -next_up(-x);
}

void write_box(uint prim, vec3 lo, vec3 hi) {
    uint b = 6u * prim;
    boxes[b] = lo.x;
    boxes[b + 1u] = lo.y;
    boxes[b + 2u] = lo.z;
    boxes[b + 3u] = hi.x;
    boxes[b + 4u] = hi.y;
    boxes[b + 5u] = hi.z;
}

void main() {
    uint i = linear_invocation_id();
    if (pc.mode == MODE_HEADER) {
        if (i == 0u) {
            info.bounds_min = vec4(0.0);
            info.bounds_max = vec4(0.0);
            info.n_tris = pc.count;
            info.n_spheres = pc.first;
            info.has_motion = 0u;
            info.parents_at = pc.out_first;
            info.walk = pc.src_word;
            info.n_geometries = pc.index_first;
            info.invalid = 0u;
            info.n_aabbs = pc.vertex_count;
        }
        return;
    }
    if (i == 0u) {
        info.geometry_first[pc.table_slot] = uvec2(pc.first, pc.geometry);
    }
    if (i >= pc.count) {
        return;
    }
    uint prim = pc.first + i;
    if (pc.mode == MODE_TRIANGLES) {
        uint a = index_at(3u * i);
        uint b = index_at(3u * i + 1u);
        uint c = index_at(3u * i + 2u);
        bool ok = a < pc.vertex_count && b < pc.vertex_count && c < pc.vertex_count;
        vec3 p0 = vec3(0.0);
        vec3 p1 = vec3(0.0);
        vec3 p2 = vec3(0.0);
        if (ok) {
            p0 = vertex_at(a);
            p1 = vertex_at(b);
            p2 = vertex_at(c);
            ok = finite3(p0) && finite3(p1) && finite3(p2);
        }
        if (!ok) {
            atomicAdd(info.invalid, 1u);
            p0 = vec3(0.0);
            p1 = p0;
            p2 = p0;
        }
        vec3 lo = min(min(p0, p1), p2);
        vec3 hi = max(max(p0, p1), p2);
        // A zero-area triangle keeps its box but gets NaN vertices, which no test ever hits
        // (TraceGeometry::from_triangles does the same).
        precise vec3 e1 = p1 - p0;
        precise vec3 e2 = p2 - p0;
        // The twin's order of operations: the builtin may fuse on a GPU even under
        // `precise`, which makes cross(e, e) non-zero.
        precise vec3 n = vec3(e1.y * e2.z - e2.y * e1.z, e1.z * e2.x - e2.z * e1.x,
                              e1.x * e2.y - e2.x * e1.y);
        if (all(equal(n, vec3(0.0)))) {
            p0 = vec3(uintBitsToFloat(0x7fc00000u));
            p1 = p0;
            p2 = p0;
        }
        uint t = 9u * (pc.out_first + i);
        vkrt_tri_verts[t] = p0.x;
        vkrt_tri_verts[t + 1u] = p0.y;
        vkrt_tri_verts[t + 2u] = p0.z;
        vkrt_tri_verts[t + 3u] = p1.x;
        vkrt_tri_verts[t + 4u] = p1.y;
        vkrt_tri_verts[t + 5u] = p1.z;
        vkrt_tri_verts[t + 6u] = p2.x;
        vkrt_tri_verts[t + 7u] = p2.y;
        vkrt_tri_verts[t + 8u] = p2.z;
        write_box(prim, lo, hi);
    } else if (pc.mode == MODE_AABBS) {
        uint w = pc.src_word + i * pc.stride_words;
        vec3 lo = vec3(uintBitsToFloat(SRC(w)), uintBitsToFloat(SRC(w + 1u)),
                       uintBitsToFloat(SRC(w + 2u)));
        vec3 hi = vec3(uintBitsToFloat(SRC(w + 3u)), uintBitsToFloat(SRC(w + 4u)),
                       uintBitsToFloat(SRC(w + 5u)));
        if (!(finite3(lo) && finite3(hi))) {
            atomicAdd(info.invalid, 1u);
            lo = vec3(uintBitsToFloat(0x7f800000u));
            hi = -lo;
        }
        vkrt_spheres[pc.out_first + 2u * i] = vec4(lo, 0.0);
        vkrt_spheres[pc.out_first + 2u * i + 1u] = vec4(hi, 0.0);
        // TraceGeometry::from_primitives: an inactive box is bounded by the origin.
        bool in_use = all(lessThanEqual(lo, hi));
        write_box(prim, in_use ? lo : vec3(0.0), in_use ? hi : vec3(0.0));
    } else {
        uint w = pc.src_word + i * pc.stride_words;
        vec3 c = vec3(uintBitsToFloat(SRC(w)), uintBitsToFloat(SRC(w + 1u)),
                      uintBitsToFloat(SRC(w + 2u)));
        float r = uintBitsToFloat(SRC(w + 3u));
        bool ok = finite3(c) && finite3(vec3(r)) && r >= 0.0;
        if (!ok) {
            atomicAdd(info.invalid, 1u);
            c = vec3(0.0);
            r = 0.0;
        }
        vkrt_spheres[pc.out_first + i] = vec4(c, r);
        precise vec3 lo = c - vec3(r);
        precise vec3 hi = c + vec3(r);
        // Rounded outwards, as sphere_box in src/accel/primitives.rs.
        write_box(prim, vec3(next_down(lo.x), next_down(lo.y), next_down(lo.z)),
                  vec3(next_up(hi.x), next_up(hi.y), next_up(hi.z)));
    }
}
