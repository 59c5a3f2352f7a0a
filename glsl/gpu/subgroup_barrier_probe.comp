#version 460
// The smallest kernel that shows Mesa 25.0 lavapipe's subgroup-barrier bug: subgroupBarrier()
// needs only subgroup-uniform control flow, so subgroup 0 may run it `trips` times while the
// other subgroups run it never, and every invocation must then pass the workgroup barrier
// and write its marker. Mesa 25.0.7 lavapipe (Debian bookworm-backports) treats the subgroup
// barrier as a workgroup barrier (a coroutine switch): the workgroup's barrier count goes out
// of step, the other subgroups are released early, and subgroup 0 never gets past barrier()
// - its markers stay 0. Mesa 22.3 writes every marker. (tests/gpu_foundation.rs)
#extension GL_KHR_shader_subgroup_basic : require
layout(local_size_x_id = 0) in;

layout(std430, binding = 0) writeonly buffer Out { uint result[]; };
layout(push_constant) uniform Push { uint trips; } pc;

void main() {
    if (gl_SubgroupID == 0) {
        for (uint i = 0; i < pc.trips; i++) {
            subgroupBarrier();
        }
    }
    barrier();
    result[gl_LocalInvocationIndex] = 1u;
}
