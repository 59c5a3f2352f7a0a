#version 460
// The refit schedule, step 2 (one invocation): where each depth's nodes start in the sorted
// order, and each depth's indirect dispatch.
layout(local_size_x = 1) in;

#define MAX_DEPTH 128u
// [0, 128) counts, [128, 256) starts, [256, 640) dispatches (x, y, z).
layout(std430, binding = 0) buffer Levels { uint levels[]; };
layout(push_constant) uniform Push { uint wg; } pc;

void main() {
    uint start = 0u;
    for (uint d = 0u; d < MAX_DEPTH; d++) {
        uint count = levels[d];
        levels[MAX_DEPTH + d] = start;
        start += count;
        uint groups = (count + pc.wg - 1u) / pc.wg;
        uint x = min(groups, 65535u);
        levels[2u * MAX_DEPTH + 3u * d] = x;
        levels[2u * MAX_DEPTH + 3u * d + 1u] = x == 0u ? 1u : (groups + x - 1u) / x;
        levels[2u * MAX_DEPTH + 3u * d + 2u] = 1u;
    }
}
