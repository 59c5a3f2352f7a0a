#version 460
// One invocation: the compacted child count becomes the queue count, and the workgroup
// counts of the next bounce's indirect dispatches follow from it.
layout(local_size_x = 1) in;
#include "render/common.glsl"

layout(std430, binding = 0) readonly buffer Live { uint live_count[]; };
layout(std430, binding = 1) readonly buffer Params { RenderParams prm; };
layout(std430, binding = 2) buffer Counters { uint counters[]; };
layout(push_constant) uniform Push { uint wg; uint capacity; } pc;

void main() {
    uint n = live_count[0];
    if (n > pc.capacity) {
        // Stop the wave cleanly; the host sees the flag and redoes the sample smaller.
        counters[CNT_OVERFLOW] = 1u;
        n = 0u;
    }
    counters[CNT_QUEUE] = n;
    uvec3 g = fold_groups(n, pc.wg);
    counters[CNT_ARGS_QUEUE] = g.x;
    counters[CNT_ARGS_QUEUE + 1u] = g.y;
    counters[CNT_ARGS_QUEUE + 2u] = g.z;
    uvec3 s = fold_groups(n * prm.shadow_slots, pc.wg);
    counters[CNT_ARGS_SHADOW] = s.x;
    counters[CNT_ARGS_SHADOW + 1u] = s.y;
    counters[CNT_ARGS_SHADOW + 2u] = s.z;
}
