#version 460
// Radix sort, after an odd number of passes: copies the sorted keys and values from the
// ping-pong buffers back into the caller's, 16 bytes per load and store where whole.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

layout(std430, binding = 0) readonly buffer KeysIn4 { uvec4 keys_in4[]; };
layout(std430, binding = 1) readonly buffer KeysIn1 { uint keys_in1[]; };
layout(std430, binding = 2) readonly buffer ValuesIn4 { uvec4 values_in4[]; };
layout(std430, binding = 3) readonly buffer ValuesIn1 { uint values_in1[]; };
layout(std430, binding = 4) writeonly buffer KeysOut4 { uvec4 keys_out4[]; };
layout(std430, binding = 5) writeonly buffer KeysOut1 { uint keys_out1[]; };
layout(std430, binding = 6) writeonly buffer ValuesOut4 { uvec4 values_out4[]; };
layout(std430, binding = 7) writeonly buffer ValuesOut1 { uint values_out1[]; };
layout(push_constant) uniform Push { uint n; } pc;

void main() {
    uint g = linear_invocation_id();
    if (4 * g + 4 <= pc.n) {
        keys_out4[g] = keys_in4[g];
        values_out4[g] = values_in4[g];
    } else {
        for (uint e = 4 * g; e < pc.n; e++) {
            keys_out1[e] = keys_in1[e];
            values_out1[e] = values_in1[e];
        }
    }
}
