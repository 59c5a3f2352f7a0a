#version 460
// kd-tree Phase I, last step (one invocation): the root node and the build state.
layout(local_size_x = 1) in;
#include "accel/kdtree/level.glsl"

layout(std430, binding = 0) writeonly buffer State { uint state[]; };
layout(std430, binding = 1) readonly buffer MinX { float min_x[]; };
layout(std430, binding = 2) readonly buffer MinY { float min_y[]; };
layout(std430, binding = 3) readonly buffer MinZ { float min_z[]; };
layout(std430, binding = 4) readonly buffer MaxX { float max_x[]; };
layout(std430, binding = 5) readonly buffer MaxY { float max_y[]; };
layout(std430, binding = 6) readonly buffer MaxZ { float max_z[]; };
layout(std430, binding = 7) writeonly buffer NodeBox { float node_box[]; };
layout(std430, binding = 8) writeonly buffer NodeRange { uint node_range[]; };
layout(std430, binding = 9) writeonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 10) writeonly buffer SegCount { uint seg_count[]; };
layout(push_constant) uniform Push { uint n; } pc;

void main() {
    for (uint i = 0u; i < ST_WORDS; i++) {
        state[i] = 0u;
    }
    state[ST_REFS] = pc.n;
    state[ST_NODES] = 1u;
    uvec3 e = folded_groups(2u * pc.n);
    state[ST_EVENT_ARGS] = e.x;
    state[ST_EVENT_ARGS + 1u] = e.y;
    state[ST_EVENT_ARGS + 2u] = e.z;
    state[ST_NODE_ARGS] = 1u;
    state[ST_NODE_ARGS + 1u] = 1u;
    state[ST_NODE_ARGS + 2u] = 1u;
    node_box[0] = min_x[0];
    node_box[1] = min_y[0];
    node_box[2] = min_z[0];
    node_box[3] = max_x[0];
    node_box[4] = max_y[0];
    node_box[5] = max_z[0];
    node_range[0] = 0u;
    node_range[1] = pc.n;
    offsets[0] = 0u;
    offsets[1] = 2u * pc.n;
    seg_count[0] = 1u;
}
