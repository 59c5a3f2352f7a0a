#version 460
// The boxes of vkrt_spheres, center ± radius, in the box-input format of kdtree_input_boxes
// (6 floats per primitive) starting at primitive `first` of the output, so triangles' and
// vkrt_spheres' boxes can share one buffer. Each bound is one correctly rounded f32 add or
// subtract (`precise`: no contraction), as the CPU twin breadth_first::sphere_box.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

layout(std430, binding = 0) readonly buffer VkrtSpheresBinding { float vkrt_spheres[]; }; // x, y, z, radius
layout(std430, binding = 1) writeonly buffer Boxes { float boxes[]; };
layout(push_constant) uniform Push {
    uint n;
    uint first;
} pc;

void main() {
    uint i = linear_invocation_id();
    if (i >= pc.n) {
        return;
    }
    precise vec3 c = vec3(vkrt_spheres[4 * i + 0], vkrt_spheres[4 * i + 1], vkrt_spheres[4 * i + 2]);
    precise float r = vkrt_spheres[4 * i + 3];
    precise vec3 lo = c - vec3(r);
    precise vec3 hi = c + vec3(r);
    uint o = 6 * (pc.first + i);
    boxes[o + 0] = lo.x;
    boxes[o + 1] = lo.y;
    boxes[o + 2] = lo.z;
    boxes[o + 3] = hi.x;
    boxes[o + 4] = hi.y;
    boxes[o + 5] = hi.z;
}
