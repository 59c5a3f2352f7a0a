// Shared by the LBVH kernels (CPU twin: src/accel/bvh/lbvh.rs).
#ifndef VKRT_ACCEL_LBVH_COMMON_GLSL
#define VKRT_ACCEL_LBVH_COMMON_GLSL

// An f32 as a u32 whose unsigned order is the IEEE total order (-0 below +0).
uint ordered_key(float x) {
    uint b = floatBitsToUint(x);
    return (b & 0x80000000u) != 0u ? ~b : (b | 0x80000000u);
}

uvec3 ordered_key(vec3 v) {
    return uvec3(ordered_key(v.x), ordered_key(v.y), ordered_key(v.z));
}

float from_ordered_key(uint k) {
    return uintBitsToFloat((k & 0x80000000u) != 0u ? (k & 0x7fffffffu) : ~k);
}

// The midpoint of primitive i's box (six floats per primitive in `b`).
#define centroid(b, i) \
    (precise_mid(vec3(b[6u * (i)], b[6u * (i) + 1u], b[6u * (i) + 2u]), \
                 vec3(b[6u * (i) + 3u], b[6u * (i) + 4u], b[6u * (i) + 5u])))

vec3 precise_mid(vec3 lo, vec3 hi) {
    precise vec3 c = (lo + hi) * 0.5;
    return c;
}

#endif
