#version 460
// The next bounce's queue: the live child slots, in order (their indices come from the
// compaction primitive).
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "render/common.glsl"

layout(std430, binding = 0) readonly buffer Children { PathRay children[]; };
layout(std430, binding = 1) readonly buffer Live { uint live[]; };
layout(std430, binding = 2) readonly buffer Counters { uint counters[]; };
layout(std430, binding = 3) writeonly buffer Queue { PathRay queue[]; };

void main() {
    uint i = linear_invocation_id();
    if (i >= counters[CNT_QUEUE]) {
        return;
    }
    queue[i] = children[live[i]];
}
