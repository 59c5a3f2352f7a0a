#version 460
// kd-tree Phase II, end of a level (one invocation): the next level's sizes and indirect
// dispatch arguments, the output bases, and the capacity check. On overflow the build stops
// cleanly (no further level has work) and records what it needed; the host retries larger.
layout(local_size_x = 1) in;
#include "accel/kdtree/level.glsl"

layout(std430, binding = 0) buffer State { uint state[]; };
layout(std430, binding = 1) readonly buffer SlotTotal { uint slot_total[]; };   // axis 0
layout(std430, binding = 2) readonly buffer InnerTotal { uint inner_total[]; };
layout(std430, binding = 3) readonly buffer LeafTotal { uint leaf_total[]; };
layout(std430, binding = 4) writeonly buffer SegCount { uint seg_count[]; };    // next M
layout(std430, binding = 5) writeonly buffer NextOffsets { uint next_offsets[]; };
layout(push_constant) uniform Push {
    uint ref_capacity;        // references per level
    uint level_node_capacity; // nodes per level
    uint node_capacity;       // output nodes
    uint out_ref_capacity;    // output references
} pc;

void main() {
    uint m = state[ST_NODES];
    uint next_refs = slot_total[0] / 2u;
    uint next_nodes = 2u * inner_total[0];
    uint node_base = state[ST_NODE_BASE] + m;
    uint ref_base = state[ST_REF_BASE] + leaf_total[0];
    bool overflow = next_refs > pc.ref_capacity || next_nodes > pc.level_node_capacity
        || node_base + next_nodes > pc.node_capacity || ref_base > pc.out_ref_capacity;
    if (m != 0u) {
        state[ST_LEVELS] += 1u;
    }
    if (overflow) {
        state[ST_OVERFLOW] = 1u;
        state[ST_NEED_REFS] = max(state[ST_NEED_REFS], next_refs);
        next_refs = 0u;
        next_nodes = 0u;
    }
    state[ST_NODE_BASE] = min(node_base, pc.node_capacity);
    state[ST_REF_BASE] = min(ref_base, pc.out_ref_capacity);
    state[ST_REFS] = next_refs;
    state[ST_NODES] = next_nodes;
    state[ST_DEPTH] += 1u;
    seg_count[0] = next_nodes;
    next_offsets[next_nodes] = 2u * next_refs;
    uvec3 e = folded_groups(2u * next_refs);
    uvec3 n = folded_groups(next_nodes);
    state[ST_EVENT_ARGS] = e.x;
    state[ST_EVENT_ARGS + 1u] = e.y;
    state[ST_EVENT_ARGS + 2u] = e.z;
    state[ST_NODE_ARGS] = n.x;
    state[ST_NODE_ARGS + 1u] = n.y;
    state[ST_NODE_ARGS + 2u] = n.z;
}
