#version 460
// The accumulated image to 8-bit sRGB: mean over samples, clamp to [0, 1], sRGB curve.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

layout(std430, binding = 0) readonly buffer Accum { vec4 accum[]; };
layout(std430, binding = 1) writeonly buffer Pixels { uint pixels[]; };
layout(push_constant) uniform Push { uint n; float inv_spp; } pc;

float srgb(float c) {
    c = clamp(c, 0.0, 1.0);
    return c <= 0.0031308 ? 12.92 * c : 1.055 * pow(c, 1.0 / 2.4) - 0.055;
}

void main() {
    uint i = linear_invocation_id();
    if (i >= pc.n) {
        return;
    }
    precise vec3 c = accum[i].xyz * pc.inv_spp;
    uvec3 b = uvec3(floor(vec3(srgb(c.x), srgb(c.y), srgb(c.z)) * 255.0 + 0.5));
    pixels[i] = b.x | (b.y << 8u) | (b.z << 16u) | (255u << 24u);
}
