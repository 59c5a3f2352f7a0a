#version 460
// LBVH, pass 2: the Morton code of every primitive's centroid (CPU twin:
// lbvh::morton_codes) as (high, low) words, x the most significant axis of each bit triple,
// on a cubic grid of 2^PER_AXIS cells per axis from the centroid box's minimum. The grid's
// size is the power of two 2^e covering the largest extent: scaling by a power of two is
// exact on every device (a division is not: Vulkan allows 2.5 ulp), so the codes are the
// twin's on every driver. Also writes the first sort's keys (the high words of 63-bit codes,
// the codes of 30-bit ones) and the primitive ids the sorts carry.
layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint PER_AXIS = 21u;
#include "common/grid.glsl"
#include "accel/bvh/lbvh_common.glsl"

layout(std430, binding = 0) readonly buffer Boxes { float boxes[]; };
layout(std430, binding = 1) readonly buffer Bounds { uint bounds[]; };
layout(std430, binding = 2) writeonly buffer CodeHi { uint code_hi[]; };
layout(std430, binding = 3) writeonly buffer CodeLo { uint code_lo[]; };
layout(std430, binding = 4) writeonly buffer SortKeys { uint sort_keys[]; };
layout(std430, binding = 5) writeonly buffer Ids { uint ids[]; };
layout(push_constant) uniform Push { uint n; } pc;

// 2^(PER_AXIS - e) with 2^(e-1) <= extent < 2^e, from the exponent bits; 0 for a box
// smaller than 2^-100 (no denormal reaches the scaling).
float grid_scale(float extent) {
    if (!(extent >= uintBitsToFloat(27u << 23))) {
        return 0.0;
    }
    int e = int((floatBitsToUint(extent) >> 23) & 0xffu) - 126;
    int k = int(PER_AXIS) - e;
    return uintBitsToFloat(uint(k + 127) << 23);
}

void main() {
    uint i = linear_invocation_id();
    if (i >= pc.n) {
        return;
    }
    vec3 lo = vec3(from_ordered_key(bounds[0]), from_ordered_key(bounds[1]),
                   from_ordered_key(bounds[2]));
    vec3 hi = vec3(from_ordered_key(~bounds[3]), from_ordered_key(~bounds[4]),
                   from_ordered_key(~bounds[5]));
    precise vec3 ext = hi - lo;
    vec3 c = centroid(boxes, i);
    float top = float((1u << PER_AXIS) - 1u);
    float scale = grid_scale(max(max(ext.x, ext.y), ext.z));
    uvec3 q;
    for (uint a = 0u; a < 3u; a++) {
        precise float u = (c[a] - lo[a]) * scale;
        q[a] = uint(clamp(u, 0.0, top));
    }
    uvec2 code = uvec2(0u); // (high, low)
    for (uint k = 0u; k < PER_AXIS; k++) {
        for (uint a = 0u; a < 3u; a++) {
            uint bit = (q[a] >> k) & 1u;
            uint pos = 3u * k + 2u - a;
            if (pos < 32u) {
                code.y |= bit << pos;
            } else {
                code.x |= bit << (pos - 32u);
            }
        }
    }
    code_hi[i] = code.x;
    code_lo[i] = code.y;
    // The first sort's keys: 63-bit codes sort their high words first (lbvh_ties.comp).
    sort_keys[i] = 3u * PER_AXIS > 32u ? code.x : code.y;
    ids[i] = i;
}
