#version 460
// The caller's instances (VkAccelerationStructureInstanceKHR records) as the top level holds
// them (CPU twin: `instance_boxes` in src/accel/instances.rs, bit for bit): per instance its
// world box (the eight corners of its bottom level's box moved to the world, padded by a few
// ulps of their magnitude so that the object-space walk never finds a hit outside it) and
// its world-to-object transform for the walk. Every product and sum is `precise` and summed
// left to right, as the twin does.
//
// An instance whose bottom-level index is out of range, or whose transform is not finite or
// not invertible, is never hit (an inactive box, min > max, and mask 0) and counted in
// `status`; an instance of an empty bottom level or with mask 0 is never hit, not counted.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

// The caller's records, 16 words each, from word `first_word` on.
layout(std430, binding = 0) readonly buffer Instances { uint words[]; };
// The bottom levels' scene constants (`SceneInfo`, 64 bytes each, copied from each level).
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
layout(std430, binding = 1) readonly buffer Bottoms { BottomInfo bottoms[]; };
// Six floats per instance: min x, y, z, max x, y, z (the top level's box primitives).
layout(std430, binding = 2) writeonly buffer Boxes { float boxes[]; };
// `InstanceRecord`: world-to-object rows, then (handle address lo, hi, custom index | mask
// << 24, flags | bottom << 8).
struct InstanceRecord {
    vec4 rows[3];
    uvec4 meta;
};
layout(std430, binding = 3) writeonly buffer Records { InstanceRecord records[]; };
layout(std430, binding = 4) buffer Status { uint invalid; } status;
layout(push_constant) uniform Push {
    uint n;
    uint first_word;
    uint n_bottoms;
    uint pad;
    // Where the bottom levels' handles lie, 64 bytes apart.
    uvec2 handles_at;
} pc;

bool finite4(vec4 v) {
    return all(lessThanEqual(abs(v), vec4(uintBitsToFloat(0x7f7fffffu))));
}

void write_inactive(uint i, uint meta_w) {
    for (uint k = 0u; k < 3u; k++) {
        boxes[6u * i + k] = 1.0;
        boxes[6u * i + 3u + k] = 0.0;
    }
    records[i] = InstanceRecord(vec4[3](vec4(0.0), vec4(0.0), vec4(0.0)),
                                uvec4(0u, 0u, 0u, meta_w));
}

void main() {
    uint i = linear_invocation_id();
    if (i >= pc.n) {
        return;
    }
    uint w = pc.first_word + 16u * i;
    vec4 m[3];
    for (uint r = 0u; r < 3u; r++) {
        m[r] = uintBitsToFloat(uvec4(words[w + 4u * r], words[w + 4u * r + 1u],
                                     words[w + 4u * r + 2u], words[w + 4u * r + 3u]));
    }
    uint custom_mask = words[w + 12u];
    uint flags = words[w + 13u] >> 24u;
    uint bottom = words[w + 14u];
    bool bottom_ok = words[w + 15u] == 0u && bottom < pc.n_bottoms;
    uint meta_w = flags | ((bottom_ok ? bottom : 0u) << 8u);

    // The inverse of the 3x3 part by cofactors, then the translation.
    precise float c00 = m[1].y * m[2].z - m[1].z * m[2].y;
    precise float c01 = m[0].z * m[2].y - m[0].y * m[2].z;
    precise float c02 = m[0].y * m[1].z - m[0].z * m[1].y;
    precise float c10 = m[1].z * m[2].x - m[1].x * m[2].z;
    precise float c11 = m[0].x * m[2].z - m[0].z * m[2].x;
    precise float c12 = m[0].z * m[1].x - m[0].x * m[1].z;
    precise float c20 = m[1].x * m[2].y - m[1].y * m[2].x;
    precise float c21 = m[0].y * m[2].x - m[0].x * m[2].y;
    precise float c22 = m[0].x * m[1].y - m[0].y * m[1].x;
    precise float det = m[0].x * c00 + m[0].y * c10 + m[0].z * c20;
    precise float inv_det = 1.0 / det;
    precise vec3 r0 = vec3(c00, c01, c02) * inv_det;
    precise vec3 r1 = vec3(c10, c11, c12) * inv_det;
    precise vec3 r2 = vec3(c20, c21, c22) * inv_det;
    vec3 t = vec3(m[0].w, m[1].w, m[2].w);
    precise float t0 = -(r0.x * t.x + r0.y * t.y + r0.z * t.z);
    precise float t1 = -(r1.x * t.x + r1.y * t.y + r1.z * t.z);
    precise float t2 = -(r2.x * t.x + r2.y * t.y + r2.z * t.z);
    vec4 inv[3] = vec4[3](vec4(r0, t0), vec4(r1, t1), vec4(r2, t2));
    bool valid = bottom_ok && finite4(m[0]) && finite4(m[1]) && finite4(m[2]) && det != 0.0
        && finite4(inv[0]) && finite4(inv[1]) && finite4(inv[2]);
    if (!valid) {
        atomicAdd(status.invalid, 1u);
        write_inactive(i, meta_w);
        return;
    }
    BottomInfo b = bottoms[bottom];
    uint mask = custom_mask >> 24u;
    if (b.n_tris + b.n_spheres + b.n_aabbs == 0u || mask == 0u) {
        write_inactive(i, meta_w);
        return;
    }
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
    precise vec3 pad = vec3(abs(m[0].x) * e.x + abs(m[0].y) * e.y + abs(m[0].z) * e.z + abs(m[0].w),
                            abs(m[1].x) * e.x + abs(m[1].y) * e.y + abs(m[1].z) * e.z + abs(m[1].w),
                            abs(m[2].x) * e.x + abs(m[2].y) * e.y + abs(m[2].z) * e.z + abs(m[2].w))
        * uintBitsToFloat(0x35800000u);
    precise vec3 box_lo = lo - pad;
    precise vec3 box_hi = hi + pad;
    for (uint k = 0u; k < 3u; k++) {
        boxes[6u * i + k] = box_lo[k];
        boxes[6u * i + 3u + k] = box_hi[k];
    }
    // The bottom level's handle, 64 bytes apart.
    uint lo_addr = pc.handles_at.x + 64u * bottom;
    uint carry = lo_addr < pc.handles_at.x ? 1u : 0u;
    records[i] = InstanceRecord(inv, uvec4(lo_addr, pc.handles_at.y + carry, custom_mask,
                                           meta_w));
}
