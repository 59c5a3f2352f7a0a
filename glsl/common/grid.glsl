// Linear ids for 1-D work dispatched as a 2-D grid (keep in sync with Recorder::groups_1d in
// src/gpu/recorder.rs). Large 1-D dispatches fold into y because maxComputeWorkGroupCount[0]
// is only 65,535 on many devices; the grid may then overshoot, so kernels bounds-check.
// Include after the `layout(local_size_x_id = ...) in;` line (uses gl_WorkGroupSize).
#ifndef VKRT_COMMON_GRID_GLSL
#define VKRT_COMMON_GRID_GLSL

uint linear_group_id() {
    return gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;
}

uint linear_invocation_id() {
    return linear_group_id() * gl_WorkGroupSize.x + gl_LocalInvocationID.x;
}

#endif
