#version 460
// kd-tree Phase I for box input (vkrt_spheres, moving primitives, any mix): splits 6 floats per
// primitive (min x, y, z, max x, y, z) into the six SoA arrays kdtree_boxes writes for
// triangles. A plain copy, so the CPU twin (breadth_first::build_boxes) sees the same bits.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

layout(std430, binding = 0) readonly buffer Boxes { float boxes[]; }; // 6 floats per box
layout(std430, binding = 1) writeonly buffer MinX { float min_x[]; };
layout(std430, binding = 2) writeonly buffer MinY { float min_y[]; };
layout(std430, binding = 3) writeonly buffer MinZ { float min_z[]; };
layout(std430, binding = 4) writeonly buffer MaxX { float max_x[]; };
layout(std430, binding = 5) writeonly buffer MaxY { float max_y[]; };
layout(std430, binding = 6) writeonly buffer MaxZ { float max_z[]; };
layout(push_constant) uniform Push { uint n; } pc;

void main() {
    uint i = linear_invocation_id();
    if (i >= pc.n) {
        return;
    }
    min_x[i] = boxes[6 * i + 0];
    min_y[i] = boxes[6 * i + 1];
    min_z[i] = boxes[6 * i + 2];
    max_x[i] = boxes[6 * i + 3];
    max_y[i] = boxes[6 * i + 4];
    max_z[i] = boxes[6 * i + 5];
}
