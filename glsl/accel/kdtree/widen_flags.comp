#version 460
// Ablation baseline only (KdTreeBuilder::ablation.u32_event_scan): the event types of one
// axis list (END = 0 / START = 1, one byte each) widened to one u32 each, so the START
// counts can be taken by the plain u32 scan instead of the byte-flag scan. Same counts, same
// tree; the twin is the identity (breadth_first scans the bytes).
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "accel/kdtree/level.glsl"

layout(std430, binding = 0) readonly buffer State { uint state[]; };
layout(std430, binding = 1) readonly buffer Kinds { uint kinds4[]; }; // 4 bytes per word
layout(std430, binding = 2) writeonly buffer Wide { uint wide[]; };

void main() {
    uint i = linear_invocation_id();
    if (i >= 2u * state[ST_REFS]) {
        return;
    }
    wide[i] = kind_of(kinds4[i >> 2], i);
}
