#version 460
// Radix sort, pass 1 of 3 per digit: the digit counts of every tile, written digit-major
// (counts[digit * blocks + tile]) so that one exclusive scan of the whole table gives each
// (digit, tile) its first output position. Counting uses shared-memory atomics: integer
// sums, so the counts are the same in any execution order.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "prims/radix_common.glsl"

layout(std430, binding = 0) readonly buffer Keys4 { uvec4 keys4[]; };
layout(std430, binding = 1) readonly buffer Keys1 { uint keys1[]; };
layout(std430, binding = 2) writeonly buffer Counts { uint counts[]; };

shared uint hist[RADIX];

void count(uint raw) {
    atomicAdd(hist[digit_of(read_key(raw))], 1u);
}

void main() {
    uint block = linear_group_id();
    if (block >= pc.blocks) {
        return; // a whole workgroup of the folded grid's overshoot
    }
    for (uint d = gl_LocalInvocationID.x; d < pc.digits; d += gl_WorkGroupSize.x) {
        hist[d] = 0;
    }
    barrier();
    uint start = block * TILE;
    uint end = min(start + TILE, pc.n);
    // 16-byte granules, neighbouring invocations on neighbouring granules.
    for (uint g = start / 4 + gl_LocalInvocationID.x; 4 * g < end; g += gl_WorkGroupSize.x) {
        if (4 * g + 4 <= end) {
            uvec4 k = keys4[g];
            count(k.x);
            count(k.y);
            count(k.z);
            count(k.w);
        } else {
            for (uint e = 4 * g; e < end; e++) {
                count(keys1[e]);
            }
        }
    }
    barrier();
    for (uint d = gl_LocalInvocationID.x; d < pc.digits; d += gl_WorkGroupSize.x) {
        counts[d * pc.blocks + block] = hist[d];
    }
}
