// Workgroup-wide scan and reduction of one u32 per invocation, built from a subgroup scan
// and the subgroup totals in shared memory. Nothing assumes a subgroup size: the loop over
// subgroup totals handles any gl_NumSubgroups, from 1 to gl_WorkGroupSize.x / 4.
//
// SCAN_SHUFFLE=1 scans inside the subgroup with log2(gl_SubgroupSize) subgroupShuffleUp
// steps instead of subgroupInclusiveAdd; `vkrt bench prims` measures both.
// Requires: local_size_x_id declared before inclusion; the workgroup size a multiple of the
// subgroup size.
#ifndef VKRT_COMMON_SUBGROUP_SCAN_GLSL
#define VKRT_COMMON_SUBGROUP_SCAN_GLSL

#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_KHR_shader_subgroup_shuffle : require
#extension GL_KHR_shader_subgroup_shuffle_relative : require

#ifndef SCAN_SHUFFLE
#define SCAN_SHUFFLE 0
#endif

// Lanes per subgroup, derived from the workgroup rather than read from gl_SubgroupSize.
// Workaround (2026-11, Mesa 22.3 lavapipe, LLVM 15, AVX2): under LP_NATIVE_VECTOR_WIDTH=1024
// it reports gl_SubgroupSize = 32 but runs 16-lane subgroups (gl_SubgroupInvocationID < 16,
// gl_NumSubgroups = WG / 16); tests/gpu_foundation.rs probes it. Valid whenever the
// workgroup size is a multiple of the subgroup size, which vkrt requires.
uint subgroup_lanes() {
    return gl_WorkGroupSize.x / gl_NumSubgroups;
}

// One slot per subgroup (subgroups have at least 4 lanes), plus the workgroup total.
shared uint wg_subgroup_sums[gl_WorkGroupSize.x / 4];
shared uint wg_total;

uint subgroup_inclusive_add(uint v) {
#if SCAN_SHUFFLE
    for (uint d = 1; d < subgroup_lanes(); d <<= 1) {
        uint other = subgroupShuffleUp(v, d);
        if (gl_SubgroupInvocationID >= d) {
            v += other;
        }
    }
    return v;
#else
    return subgroupInclusiveAdd(v);
#endif
}

// Exclusive prefix sum of `v` over the workgroup (in invocation order); `total` receives
// the workgroup's sum. Contains barriers: call from uniform control flow.
uint workgroup_exclusive_add(uint v, out uint total) {
    uint inclusive = subgroup_inclusive_add(v);
    if (gl_SubgroupInvocationID == subgroup_lanes() - 1) {
        wg_subgroup_sums[gl_SubgroupID] = inclusive;
    }
    barrier();
    if (gl_SubgroupID == 0) {
        uint carry = 0;
        for (uint base = 0; base < gl_NumSubgroups; base += subgroup_lanes()) {
            uint i = base + gl_SubgroupInvocationID;
            uint s = i < gl_NumSubgroups ? wg_subgroup_sums[i] : 0;
            uint scanned = subgroup_inclusive_add(s);
            if (i < gl_NumSubgroups) {
                wg_subgroup_sums[i] = carry + scanned - s;
            }
            carry += subgroupShuffle(scanned, subgroup_lanes() - 1);
        }
        if (gl_SubgroupInvocationID == 0) {
            wg_total = carry;
        }
    }
    barrier();
    total = wg_total;
    uint result = wg_subgroup_sums[gl_SubgroupID] + inclusive - v;
    // The shared slots are reused by the next call: nobody may overwrite them before all
    // invocations have read.
    barrier();
    return result;
}

// Sum of `v` over the workgroup, returned to every invocation. Contains barriers.
uint workgroup_add(uint v) {
    uint s = subgroupAdd(v);
    if (subgroupElect()) {
        wg_subgroup_sums[gl_SubgroupID] = s;
    }
    barrier();
    if (gl_SubgroupID == 0) {
        uint carry = 0;
        for (uint base = 0; base < gl_NumSubgroups; base += subgroup_lanes()) {
            uint i = base + gl_SubgroupInvocationID;
            carry += subgroupAdd(i < gl_NumSubgroups ? wg_subgroup_sums[i] : 0);
        }
        if (subgroupElect()) {
            wg_total = carry;
        }
    }
    barrier();
    uint total = wg_total;
    barrier();
    return total;
}

#endif
