#version 460
// Reports what the kernels see of subgroups: gl_SubgroupSize must equal the device property
// that vkrt plans with, and a subgroup reduction must count exactly the subgroup's lanes.
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
layout(local_size_x_id = 0) in;

// out[0] = gl_SubgroupSize, out[1] = gl_NumSubgroups,
// out[2 + i] = subgroupAdd(1) seen by invocation i of the workgroup.
layout(std430, binding = 0) writeonly buffer Out { uint result[]; };

void main() {
    uint lanes = subgroupAdd(1u);
    if (gl_LocalInvocationIndex == 0) {
        result[0] = gl_SubgroupSize;
        result[1] = gl_NumSubgroups;
    }
    result[2 + gl_LocalInvocationIndex] = lanes;
}
