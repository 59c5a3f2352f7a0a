#version 460
// vkrt_div_rn and vkrt_sqrt_rn (vkrt/ray.glsl) over pairs of floats, with the driver's division and
// square root as they are (`exact`) or made as inexact as Vulkan allows and more (`sloppy`:
// up to 3 ulps off, chosen per input), so the refinement is tested on a device whose own
// division is exact (lavapipe).
//! variant exact VKRT_FP64_FALLBACK=1
//! variant sloppy VKRT_FP64_FALLBACK=1 SLOPPY=1
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
layout(local_size_x_id = 0) in;

layout(std430, binding = 0) readonly buffer In { vec2 pairs[]; };
layout(std430, binding = 1) writeonly buffer Out { uvec2 result[]; };
layout(push_constant) uniform Push { uint n; } pc;

#ifdef SLOPPY
// x moved by -3 .. +3 ulps, picked by a hash of the operands; normal x only.
float nudge(float x, float a, float b) {
    uint h = floatBitsToUint(a) * 0x9e3779b1u ^ floatBitsToUint(b) * 0x85ebca77u;
    h ^= h >> 15;
    int k = int(h % 7u) - 3;
    uint e = floatBitsToUint(x) & 0x7f800000u;
    if (e == 0u || e >= 0x7e800000u || abs(x) < uintBitsToFloat(0x04000000u)) {
        return x;
    }
    return uintBitsToFloat(uint(int(floatBitsToUint(x)) + k));
}
#define VKRT_DRIVER_DIV(a, b) nudge((a) / (b), a, b)
#define VKRT_DRIVER_SQRT(x) nudge(sqrt(x), x, 1.0)
#endif

#include "include/vkrt/ray.glsl"

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.n) {
        return;
    }
    vec2 p = pairs[i];
    result[i] = uvec2(floatBitsToUint(vkrt_div_rn(p.x, p.y)), floatBitsToUint(vkrt_sqrt_rn(abs(p.x))));
}
