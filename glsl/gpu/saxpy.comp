#version 460
// y = a * x + y: the smallest kernel with a CPU twin (src/gpu_twins.rs style tests).
// `precise` forbids fusing into an FMA, so the result equals the CPU's bit for bit.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

layout(std430, binding = 0) readonly buffer X { float x[]; };
layout(std430, binding = 1) buffer Y { float y[]; };
layout(push_constant) uniform Push { float a; uint n; } pc;

void main() {
    uint i = linear_invocation_id();
    if (i >= pc.n) {
        return;
    }
    precise float r = pc.a * x[i] + y[i];
    y[i] = r;
}
