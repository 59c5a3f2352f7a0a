#version 460
// kd-tree Phase I: the box of every triangle (SoA: six arrays), from 9 floats per triangle.
// min/max are exact, so the CPU twin (breadth_first::build) gets the same bits.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

layout(std430, binding = 0) readonly buffer Tris { float verts[]; }; // 9 floats per triangle
layout(std430, binding = 1) writeonly buffer MinX { float min_x[]; };
layout(std430, binding = 2) writeonly buffer MinY { float min_y[]; };
layout(std430, binding = 3) writeonly buffer MinZ { float min_z[]; };
layout(std430, binding = 4) writeonly buffer MaxX { float max_x[]; };
layout(std430, binding = 5) writeonly buffer MaxY { float max_y[]; };
layout(std430, binding = 6) writeonly buffer MaxZ { float max_z[]; };
layout(push_constant) uniform Push { uint n; } pc;

#include "include/vkrt/kdtree.glsl"

void main() {
    uint i = linear_invocation_id();
    if (i >= pc.n) {
        return;
    }
    vec3 p0 = vec3(verts[9 * i + 0], verts[9 * i + 1], verts[9 * i + 2]);
    vec3 p1 = vec3(verts[9 * i + 3], verts[9 * i + 4], verts[9 * i + 5]);
    vec3 p2 = vec3(verts[9 * i + 6], verts[9 * i + 7], verts[9 * i + 8]);
    min_x[i] = vkrt_fmin_total(vkrt_fmin_total(p0.x, p1.x), p2.x);
    min_y[i] = vkrt_fmin_total(vkrt_fmin_total(p0.y, p1.y), p2.y);
    min_z[i] = vkrt_fmin_total(vkrt_fmin_total(p0.z, p1.z), p2.z);
    max_x[i] = vkrt_fmax_total(vkrt_fmax_total(p0.x, p1.x), p2.x);
    max_y[i] = vkrt_fmax_total(vkrt_fmax_total(p0.y, p1.y), p2.y);
    max_z[i] = vkrt_fmax_total(vkrt_fmax_total(p0.z, p1.z), p2.z);
}
