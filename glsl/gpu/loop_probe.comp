#version 460
// How many iterations a loop of `n` trips really runs: llvmpipe (Mesa's lavapipe) ends
// loops silently once an invocation has run 65,535 iterations; other drivers run them all.
// `DeviceInfo::loop_budget` states the fact per driver; `vkrt verify` checks it here.
layout(local_size_x = 1) in;

layout(std430, binding = 0) writeonly buffer Out { uint result[]; };
layout(push_constant) uniform Push { uint n; } pc;

void main() {
    uint trips = 0u;
    uint h = pc.n;
    for (uint i = 0u; i < pc.n; i++) {
        trips++;
        h = h * 1664525u + 1013904223u;
    }
    result[0] = trips;
    result[1] = h;
}
