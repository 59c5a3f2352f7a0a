#version 460
// Scan pass 1 of 3: the sum of every tile (reduce-then-scan; no workgroup waits for another).
//! variant u32 FLAGS=0
//! variant flags FLAGS=1
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "common/subgroup_scan.glsl"

layout(std430, binding = 0) readonly buffer In4 { uvec4 in4[]; };
layout(std430, binding = 1) readonly buffer In1 { uint in1[]; };
layout(std430, binding = 2) writeonly buffer Partials { uint partials[]; };
layout(std430, binding = 3) readonly buffer Counts { uint counts[]; };
layout(push_constant) uniform Push {
    uint capacity;
    uint count_index;
    uint count_mul;
    uint count_div; // 0: n = capacity
} pc;
#include "common/gpu_count.glsl"

#include "prims/scan_tile.glsl"

void main() {
    uint n = gpu_count(pc.capacity, pc.count_div == 0u ? 0u : counts[pc.count_index], pc.count_mul, pc.count_div);
    uint group = linear_group_id();
    uint tile_start = group * tile_elements();
    if (tile_start >= n) {
        return; // a whole workgroup of the folded grid's overshoot
    }
    uint first_granule = tile_start / EPG;
    uint sum = 0;
    for (uint r = 0; r < ROUNDS; r++) {
        uint g = first_granule + r * gl_WorkGroupSize.x + gl_SubgroupID * subgroup_lanes() + gl_SubgroupInvocationID;
        sum += granule_sum(load_granule_words(g, n));
    }
    uint total = workgroup_add(sum);
    if (gl_LocalInvocationID.x == 0) {
        partials[group] = total;
    }
}
