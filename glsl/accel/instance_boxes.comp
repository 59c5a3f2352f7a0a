#version 460
// The caller's instances (VkAccelerationStructureInstanceKHR records) as the top level holds
// them (CPU twin: `instance_boxes` in src/accel/instances.rs, bit for bit): per instance its
// world box (the eight corners of its bottom level's box moved to the world, padded by a few
// ulps of their magnitude so that the object-space walk never finds a hit outside it) and
// its world-to-object transform for the walk. Every product and sum is `precise` and summed
// left to right, as the twin does.
//
// An instance names its bottom level by reference (`GpuGeometry::reference`: the address of
// the level's handle, whose seventh address is its scene constants, read here for its box),
// or by index into the top level's list of bottom levels, whose handles the top level keeps
// a copy of. Where the top level has a list, a reference must be one of its levels (found in
// the ordered table) and the record names the copy; without one the reference is followed
// as given, as Vulkan follows accelerationStructureReference (a reference to no live bottom
// level is undefined there and here).
//
// A moving top level (`steps` > 1) reads `steps` records per instance, step after step
// (`count` records apart), keeps each step's object-to-world for the walk, which
// interpolates them at the ray's time, and boxes the union of the steps' boxes: within a
// step's interval every point moves on a straight line, so the union holds it. An instance
// whose steps are all equal is recorded as still (one step).
//
// An instance naming no bottom level (an index out of range, 0 without a list included, a
// reference not in the list), or one of whose transforms is not finite or not invertible,
// is never hit (an inactive box, min > max, and mask 0) and counted in `status`; an instance
// of an empty bottom level or with mask 0 is never hit, not counted. The slots past this
// build's count, up to the top level's maximum, are inactive too (its tree spans them all).
// `exact`: the inverse's division rounded correctly in doubles where the driver's is not
// (specialization constant 21), so the records equal the twin's on every device; `float`
// (devices without shaderFloat64): the driver's division.
//! variant exact VKRT_FP64_FALLBACK=1
//! variant float VKRT_FP64_FALLBACK=0
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_buffer_reference_uvec2 : require
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "include/vkrt/ray.glsl"
#include "include/vkrt/affine.glsl"

// The caller's records, 16 words each, from word `first_word` on (step-major when moving).
layout(std430, binding = 0) readonly buffer Instances { uint words[]; };
// A bottom level's scene constants (`SceneInfo`, 64 bytes), read where its handle says.
struct BottomInfo {
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
};
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer BottomInfoRef {
    BottomInfo v;
};
// A bottom level's handle: its seven arrays' addresses, the seventh its scene constants.
layout(buffer_reference, std430, buffer_reference_align = 8) readonly buffer BottomHandle {
    uvec2 addresses[7];
};
// The top level's copies of its list's handles, 64 bytes (eight addresses) each.
layout(std430, binding = 1) readonly buffer Listed { uvec2 listed[]; };
// Six floats per instance: min x, y, z, max x, y, z (the top level's box primitives).
layout(std430, binding = 2) writeonly buffer Boxes { float boxes[]; };
// `InstanceRecord`: world-to-object rows (the first step's), then (handle address lo, hi,
// custom index | mask << 24, flags | bottom << 8), then (steps, the first step's index in
// `steps`, the time of the first step, (steps - 1) / the interval).
struct InstanceRecord {
    vec4 rows[3];
    uvec4 meta;
    uvec4 motion;
};
layout(std430, binding = 3) writeonly buffer Records { InstanceRecord records[]; };
layout(std430, binding = 4) buffer Status { uint invalid; } status;
// A moving top level's object-to-world rows, `steps` per instance.
struct Rows {
    vec4 rows[3];
};
layout(std430, binding = 5) writeonly buffer Steps { Rows steps[]; };
// The caller's records as given (step 0's), for the ray query's object-to-world and SBT
// record offset getters (vkrt/ext_ray_query.glsl): four texels per instance.
layout(std430, binding = 6) writeonly buffer Originals { uvec4 originals[]; };
// The bottom levels by reference (`GpuGeometry::reference`): (low word, high word, index, 0),
// ordered by reference.
layout(std430, binding = 7) readonly buffer References { uvec4 references[]; };
// The index a record gives where the top level has no list (`InstanceRecord::UNLISTED`).
const uint UNLISTED = 0xffffffu;
layout(push_constant) uniform Push {
    // This build's instances; the top level's slots (the instances it was created for).
    uint n;
    uint slots;
    uint first_word;
    // Bottom levels in the top level's list (0: none, references followed as given).
    uint n_bottoms;
    uint steps;
    // Where the copies of the list's handles lie, 64 bytes apart.
    uvec2 handles_at;
    // The time of the first step, and (steps - 1) / the interval.
    float t0;
    float scale;
} pc;

void write_inactive(uint i, uint meta_w) {
    for (uint k = 0u; k < 3u; k++) {
        boxes[6u * i + k] = 1.0;
        boxes[6u * i + 3u + k] = 0.0;
    }
    records[i] = InstanceRecord(vec4[3](vec4(0.0), vec4(0.0), vec4(0.0)),
                                uvec4(0u, 0u, 0u, meta_w), uvec4(1u, 0u, 0u, 0u));
}

// Step `s` of instance `i`'s object-to-world rows.
vec4[3] rows_of(uint i, uint s) {
    uint w = pc.first_word + 16u * (s * pc.n + i);
    vec4 m[3];
    for (uint r = 0u; r < 3u; r++) {
        m[r] = uintBitsToFloat(uvec4(words[w + 4u * r], words[w + 4u * r + 1u],
                                     words[w + 4u * r + 2u], words[w + 4u * r + 3u]));
    }
    return m;
}

// The copy of list entry `k`'s handle (64 bytes apart from handles_at) and its scene
// constants' address; true.
bool listed_handle(uint k, out uvec2 handle, out uvec2 info_at) {
    uint lo_addr = pc.handles_at.x + 64u * k;
    uint carry = lo_addr < pc.handles_at.x ? 1u : 0u;
    handle = uvec2(lo_addr, pc.handles_at.y + carry);
    info_at = listed[8u * k + 6u];
    return true;
}

// The bottom level an instance names (`Instance::bottom_index` with the list; the reference
// itself without one): its handle's address, where its scene constants lie, and its index in
// the list (UNLISTED without one).
bool find_bottom(uvec2 named, out uvec2 handle, out uvec2 info_at, out uint bottom) {
    handle = named;
    info_at = uvec2(0u);
    bottom = 0u;
    if (named.y == 0u && named.x < 0x1000000u) {
        bottom = named.x;
        return named.x < pc.n_bottoms && listed_handle(named.x, handle, info_at);
    }
    if (pc.n_bottoms == 0u) {
        bottom = UNLISTED;
        info_at = BottomHandle(named).addresses[6];
        return true;
    }
    // The first entry not below `named` (binary search over the ordered table).
    uint lo = 0u;
    uint hi = pc.n_bottoms;
    while (lo < hi) {
        uint mid = (lo + hi) >> 1u;
        uvec2 r = references[mid].xy;
        bool below = r.y < named.y || (r.y == named.y && r.x < named.x);
        if (below) {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    if (lo < pc.n_bottoms && all(equal(references[lo].xy, named))) {
        bottom = references[lo].z;
        return listed_handle(bottom, handle, info_at);
    }
    return false;
}

void main() {
    uint i = linear_invocation_id();
    if (i >= pc.slots) {
        return;
    }
    if (i >= pc.n) {
        for (uint k = 0u; k < 4u; k++) {
            originals[4u * i + k] = uvec4(0u);
        }
        write_inactive(i, 0u);
        return;
    }
    uint w = pc.first_word + 16u * i;
    for (uint k = 0u; k < 4u; k++) {
        originals[4u * i + k] = uvec4(words[w + 4u * k], words[w + 4u * k + 1u],
                                      words[w + 4u * k + 2u], words[w + 4u * k + 3u]);
    }
    uint custom_mask = words[w + 12u];
    uint flags = words[w + 13u] >> 24u;
    uint bottom;
    uvec2 handle;
    uvec2 info_at;
    bool bottom_ok = find_bottom(uvec2(words[w + 14u], words[w + 15u]), handle, info_at, bottom);
    uint meta_w = flags | ((bottom_ok ? bottom : 0u) << 8u);

    vec4 inv[3];
    bool valid = vkrt_invert_rows(rows_of(i, 0u), inv) && bottom_ok;
    for (uint s = 1u; s < pc.steps; s++) {
        vec4 unused[3];
        valid = valid && vkrt_invert_rows(rows_of(i, s), unused);
    }
    // (every instance's steps, so that none is left undefined) An instance whose steps
    // are all the same is walked as a still one: nothing to interpolate per ray.
    bool still = true;
    vec4 m0[3] = rows_of(i, 0u);
    for (uint s = 0u; s < pc.steps && pc.steps > 1u; s++) {
        vec4 m[3] = rows_of(i, s);
        steps[i * pc.steps + s] = Rows(m);
        for (uint r = 0u; r < 3u; r++) {
            still = still && all(equal(floatBitsToUint(m[r]), floatBitsToUint(m0[r])));
        }
    }
    if (!valid) {
        atomicAdd(status.invalid, 1u);
        write_inactive(i, meta_w);
        return;
    }
    BottomInfo b = BottomInfoRef(info_at).v;
    uint mask = custom_mask >> 24u;
    if (b.n_tris + b.n_spheres + b.n_aabbs == 0u || mask == 0u) {
        write_inactive(i, meta_w);
        return;
    }
    vec3 box_lo = vec3(uintBitsToFloat(0x7f800000u));
    vec3 box_hi = -box_lo;
    for (uint s = 0u; s < pc.steps; s++) {
        vec4 m[3] = rows_of(i, s);
        vec3 lo = vec3(uintBitsToFloat(0x7f800000u));
        vec3 hi = -lo;
        for (uint k = 0u; k < 8u; k++) {
            vec3 p = vec3((k & 1u) != 0u ? b.bounds_max.x : b.bounds_min.x,
                          (k & 2u) != 0u ? b.bounds_max.y : b.bounds_min.y,
                          (k & 4u) != 0u ? b.bounds_max.z : b.bounds_min.z);
            precise vec3 q = vec3(m[0].x * p.x + m[0].y * p.y + m[0].z * p.z + m[0].w,
                                  m[1].x * p.x + m[1].y * p.y + m[1].z * p.z + m[1].w,
                                  m[2].x * p.x + m[2].y * p.y + m[2].z * p.z + m[2].w);
            lo = min(lo, q);
            hi = max(hi, q);
        }
        // Each corner's coordinate is a sum of four terms, each rounded: 2^-20 of their
        // magnitudes bounds that error, and the object-space ray's, with room to spare.
        vec3 e = max(abs(b.bounds_min.xyz), abs(b.bounds_max.xyz));
        precise vec3 pad =
            vec3(abs(m[0].x) * e.x + abs(m[0].y) * e.y + abs(m[0].z) * e.z + abs(m[0].w),
                 abs(m[1].x) * e.x + abs(m[1].y) * e.y + abs(m[1].z) * e.z + abs(m[1].w),
                 abs(m[2].x) * e.x + abs(m[2].y) * e.y + abs(m[2].z) * e.z + abs(m[2].w))
            * uintBitsToFloat(0x35800000u);
        precise vec3 step_lo = lo - pad;
        precise vec3 step_hi = hi + pad;
        box_lo = min(box_lo, step_lo);
        box_hi = max(box_hi, step_hi);
    }
    for (uint k = 0u; k < 3u; k++) {
        boxes[6u * i + k] = box_lo[k];
        boxes[6u * i + 3u + k] = box_hi[k];
    }
    records[i] = InstanceRecord(inv, uvec4(handle, custom_mask, meta_w),
                                uvec4(still ? 1u : pc.steps, i * pc.steps,
                                      floatBitsToUint(pc.t0), floatBitsToUint(pc.scale)));
}
