#version 460
// Compaction of a collapsed BVH, step 3 for a structure built to be updated (CPU twin:
// bvh::compact::renumber_order): the refit schedule's node ids, sorted by depth with the
// freed slots last, each replaced by its rank, and the per-depth counts, starts and indirect
// dispatches copied. The rank keeps the index order, so the ids of each depth stay sorted:
// the schedule the compacted tree's own build would record.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"

layout(std430, binding = 0) readonly buffer Order { uint order[]; };
layout(std430, binding = 1) readonly buffer Rank { uint rank[]; };
layout(std430, binding = 2) writeonly buffer OutOrder { uint out_order[]; };
layout(std430, binding = 3) readonly buffer Levels { uint levels[]; };
layout(std430, binding = 4) writeonly buffer OutLevels { uint out_levels[]; };
layout(push_constant) uniform Push {
    uint live;
    uint level_words;
} pc;

void main() {
    uint k = linear_invocation_id();
    if (k < pc.live) {
        out_order[k] = rank[order[k]];
    }
    if (k < pc.level_words) {
        out_levels[k] = levels[k];
    }
}
