// Affine transforms as three rows (row-major 3x4, VkTransformMatrixKHR): the inverse a top
// level's instances are walked with, and the interpolation of a moving instance's steps.
// Every product and sum is `precise` and summed left to right, as their CPU twins
// (`world_to_object`, `transform_at` in src/accel/instances.rs) round them; the one division
// is `vkrt_div_rn` (vkrt/ray.glsl): correctly rounded where VKRT_FP64_FALLBACK is on, as on the CPU,
// while a driver's own `/` may be 2.5 ulp off (NVIDIA's is).
#ifndef VKRT_AFFINE_GLSL
#define VKRT_AFFINE_GLSL
#include "ray.glsl"

bool vkrt_finite4(vec4 v) {
    return all(lessThanEqual(abs(v), vec4(uintBitsToFloat(0x7f7fffffu))));
}

// The inverse of object-to-world `m` by cofactors and one division; false where `m` is not
// finite or not invertible, or its inverse not finite.
bool vkrt_invert_rows(vec4 m[3], out vec4 inv[3]) {
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
    precise float inv_det = vkrt_div_rn(1.0, det);
    precise vec3 r0 = vec3(c00, c01, c02) * inv_det;
    precise vec3 r1 = vec3(c10, c11, c12) * inv_det;
    precise vec3 r2 = vec3(c20, c21, c22) * inv_det;
    vec3 t = vec3(m[0].w, m[1].w, m[2].w);
    precise float t0 = -(r0.x * t.x + r0.y * t.y + r0.z * t.z);
    precise float t1 = -(r1.x * t.x + r1.y * t.y + r1.z * t.z);
    precise float t2 = -(r2.x * t.x + r2.y * t.y + r2.z * t.z);
    inv = vec4[3](vec4(r0, t0), vec4(r1, t1), vec4(r2, t2));
    return vkrt_finite4(m[0]) && vkrt_finite4(m[1]) && vkrt_finite4(m[2]) && det != 0.0
        && vkrt_finite4(inv[0]) && vkrt_finite4(inv[1]) && vkrt_finite4(inv[2]);
}

// Where a moving instance's time `time` falls among its `steps` transforms, evenly spaced
// from `t0` with `scale` = (steps - 1) / (t1 - t0): the step before it and the weight of the
// one after (times outside the interval see the first or the last step).
uint vkrt_motion_segment(float time, float t0, float scale, uint steps, out float f) {
    precise float u = (time - t0) * scale;
    // (spelled out rather than clamp(): a time that is not a number sees the first step on
    // every driver, as on the CPU)
    u = u >= 0.0 ? min(u, float(steps - 1u)) : 0.0;
    uint k = min(uint(u), steps - 2u);
    f = u - float(k);
    return k;
}

// (1 - f) a + f b, row by row.
vec4[3] vkrt_lerp_rows(vec4 a[3], vec4 b[3], float f) {
    precise float g = 1.0 - f;
    precise vec4 r0 = g * a[0] + f * b[0];
    precise vec4 r1 = g * a[1] + f * b[1];
    precise vec4 r2 = g * a[2] + f * b[2];
    return vec4[3](r0, r1, r2);
}

#endif
