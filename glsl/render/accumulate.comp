#version 460
// Adds this bounce's radiance to the image. The queue is sorted by pixel (camera rays in
// pixel order, children compacted in parent order), so the first ray of each pixel's run
// sums the run in queue order and adds it: deterministic, no float atomics.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "render/common.glsl"

layout(std430, binding = 0) readonly buffer Queue { PathRay queue[]; };
layout(std430, binding = 1) readonly buffer Radiance { vec4 radiance[]; };
layout(std430, binding = 2) readonly buffer Shadows { ShadowRay shadows[]; };
layout(std430, binding = 3) readonly buffer Params { RenderParams prm; };
layout(std430, binding = 4) readonly buffer Counters { uint counters[]; };
layout(std430, binding = 5) buffer Accum { vec4 accum[]; };

void main() {
    uint i = linear_invocation_id();
    uint n = counters[CNT_QUEUE];
    if (i >= n) {
        return;
    }
    uint pixel = queue[i].pixel;
    if (i > 0u && queue[i - 1u].pixel == pixel) {
        return;
    }
    precise vec3 sum = vec3(0.0);
    uint slots = prm.shadow_slots;
    for (uint j = i; j < n && queue[j].pixel == pixel; j++) {
        sum += radiance[j].xyz;
        for (uint k = 0u; k < slots; k++) {
            ShadowRay s = shadows[j * slots + k];
            if (s.kind != SHADOW_NONE) {
                sum += s.contrib;
            }
        }
    }
    precise vec3 total = accum[pixel].xyz + sum;
    accum[pixel] = vec4(total, 1.0);
}
