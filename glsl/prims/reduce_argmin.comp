#version 460
// One pass of the device-wide argmin (src/prims/reduce.rs, `Reduce::record_argmin`):
// workgroup g reduces tile g (TILE = workgroup size × ITEMS entries) and writes its winner,
// a (cost bits, index) pair, to dst[dst_offset + g]. The host repeats `pairs` passes over
// the partial winners until one is left. The order is common/argmin.glsl's, under which the
// winner is unique, so the tiling does not change the result.
//
// `costs` reads f32 costs (the index is the element's position); `pairs` reads the
// (cost bits, index) pairs of the previous pass, two per 16-byte load.
//! variant costs ARGMIN_FROM_COSTS
//! variant pairs ARGMIN_FROM_PAIRS
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_shuffle : require
layout(local_size_x_id = 0) in;
// Entries per invocation per tile: a multiple of 4, at most MAX_ITEMS_PER_INVOCATION
// (src/prims/reduce.rs; llvmpipe's loop budget, common/reduce_lanes.glsl).
layout(constant_id = 1) const uint ITEMS = 4;
#include "common/grid.glsl"
#include "common/argmin.glsl"

layout(std430, binding = 0) readonly buffer Src { uvec4 src[]; };
layout(std430, binding = 1) writeonly buffer Dst { uvec2 dst[]; };
// Keep in sync with `PassPush` in src/prims/reduce.rs.
layout(push_constant) uniform Push {
    uint n;           // entries (costs or pairs) to reduce
    uint src_offset4; // where they start in src, in vec4 units
    uint dst_offset;  // where the winners go in dst, in pairs
} pc;

void main() {
    // Entries per tile, in 16-byte units: 4 costs or 2 pairs each.
#if defined(ARGMIN_FROM_COSTS)
    const uint per4 = 4u;
#else
    const uint per4 = 2u;
#endif
    const uint items4 = ITEMS / per4;
    uint tile4 = gl_WorkGroupSize.x * items4;
    uint groups = max(1u, (pc.n + per4 * tile4 - 1u) / (per4 * tile4));
    uint group = linear_group_id();
    if (group >= groups) {
        return;
    }
    uint lane = reduce_lane();
    float c = ARGMIN_NONE_COST;
    uint i = ARGMIN_NONE_INDEX;
    // Run-striped as in reduce.comp: a run of RUN lanes owns a chunk of RUN·items4 16-byte
    // blocks, lane r of the run reads blocks chunk + RUN·k + r. The whole blocks in a loop
    // (llvmpipe runs both sides of a branch that is not uniform, so no per-load tail test),
    // then the partial block if this invocation has it.
    const uint run = min(REDUCE_RUN, gl_WorkGroupSize.x);
    uint chunk = group * tile4 + (lane / run) * (run * items4);
    uint begin = chunk + lane % run;
    uint whole = pc.n / per4;
    uint end = min(chunk + run * items4, whole);
    bool partial = pc.n % per4 != 0u && whole >= begin && whole < chunk + run * items4
        && (whole - begin) % run == 0u;

#if defined(ARGMIN_FROM_COSTS)
    for (uint j = begin; j < end; j += run) {
        vec4 v = uintBitsToFloat(src[pc.src_offset4 + j]);
        uint e = 4u * j;
        argmin_consider(v.x, e, c, i);
        argmin_consider(v.y, e + 1u, c, i);
        argmin_consider(v.z, e + 2u, c, i);
        argmin_consider(v.w, e + 3u, c, i);
    }
    if (partial) {
        for (uint e = 4u * whole; e < pc.n; e++) {
            argmin_consider(uintBitsToFloat(src[pc.src_offset4 + whole][e & 3u]), e, c, i);
        }
    }
#else
    for (uint j = begin; j < end; j += run) {
        uvec4 v = src[pc.src_offset4 + j];
        argmin_consider(uintBitsToFloat(v.x), v.y, c, i);
        argmin_consider(uintBitsToFloat(v.z), v.w, c, i);
    }
    if (partial) {
        uvec2 v = src[pc.src_offset4 + whole].xy;
        argmin_consider(uintBitsToFloat(v.x), v.y, c, i);
    }
#endif

    workgroup_argmin(c, i);
    if (lane == 0) {
        dst[pc.dst_offset + group] = uvec2(floatBitsToUint(c), i);
    }
}
