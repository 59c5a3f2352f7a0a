#version 460
// The smallest kernel that shows Mesa 22.3 lavapipe's memory-barrier bug: memoryBarrierBuffer()
// is allowed in any control flow, so subgroup 0 may run it `trips` times in a loop while the
// other subgroups run it never, and every invocation must then write its marker. Mesa 22.3.6
// lavapipe (Debian 12) makes the barrier a coroutine switch, like barrier(): subgroup 0
// switches away and is never resumed once the others have finished — its markers stay
// unwritten. Mesa 25 writes every marker. It shaped glsl/accel/bvh/refit.comp (its barriers
// run in workgroup-uniform rounds). (tests/gpu_foundation.rs)
#extension GL_KHR_shader_subgroup_basic : require
layout(local_size_x_id = 0) in;

layout(std430, binding = 0) coherent buffer Out { uint result[]; };
layout(push_constant) uniform Push { uint trips; } pc;

void main() {
    uint i = gl_LocalInvocationIndex;
    uint rounds = gl_SubgroupID == 0u ? pc.trips : 0u;
    for (uint k = 0u; k < rounds; k++) {
        result[i] = 2u + k;
        memoryBarrierBuffer();
    }
    result[i] = 1u;
}
