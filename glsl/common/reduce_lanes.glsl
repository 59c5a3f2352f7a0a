// Subgroup geometry for the reductions (src/prims/reduce.rs, src/prims/segmented.rs).
//
// Lanes per subgroup come from the workgroup, not from gl_SubgroupSize. Workaround (Mesa
// 22.3 lavapipe, LLVM 15, AVX2, seen 2026-11): under LP_NATIVE_VECTOR_WIDTH=1024 it reports
// gl_SubgroupSize = 32 but runs 16-lane subgroups (tests/gpu_foundation.rs probes it).
// Valid whenever the workgroup size is a multiple of the subgroup size, which vkrt requires.
//
// `reduce_lane()` numbers the invocations subgroup by subgroup. The reductions assign
// elements by this number rather than by gl_LocalInvocationIndex, whose mapping onto
// subgroups Vulkan leaves to the implementation: the f32 sum's order (a perfect binary
// tree over reduce_lane order) is then fixed, and its CPU twin can mirror it.
//
// Include after the `layout(local_size_x_id = 0) in;` line.
#ifndef VKRT_COMMON_REDUCE_LANES_GLSL
#define VKRT_COMMON_REDUCE_LANES_GLSL

#extension GL_KHR_shader_subgroup_basic : require

// Lanes per run of the flat reductions' layout (src/prims/reduce.rs, REDUCE_RUN there):
// runs of min(REDUCE_RUN, workgroup size) consecutive reduce_lane()s read consecutive
// 16-byte blocks, each run owning one contiguous chunk of the tile.
#define REDUCE_RUN 8u

// Workaround (Mesa 22.3 lavapipe / llvmpipe, LLVM 15; found 2026-11): llvmpipe stops loops
// once an invocation has run 65,535 loop iterations in total, across all its loops
// (LP_MAX_TGSI_LOOP_ITERATIONS, "shared between every loop" in gallivm), silently: a lane
// walking a long range skips its end, and nesting loops does not help. Every kernel here
// bounds its total iterations by construction: loops over data handle REDUCE_UNROLL
// 16-byte blocks per iteration, and src/prims/{reduce,segmented}.rs size the work per
// invocation to stay under REDUCE_LOOP_BUDGET (keep both in sync with the Rust constants).
#define REDUCE_UNROLL 4u
#define REDUCE_LOOP_BUDGET 60000u

uint reduce_subgroup_lanes() {
    return gl_WorkGroupSize.x / gl_NumSubgroups;
}

uint reduce_lane() {
    return gl_SubgroupID * reduce_subgroup_lanes() + gl_SubgroupInvocationID;
}

#endif
