#version 460
// The SAH leaf collapse's last pass (CPU twin: collapse::collapse), in place: every live node
// lays its leaves' references out from its first reference (the exclusive scan of the leaf
// reference counts) on — child `a`'s before `b`'s, a collapsed subtree's depth first — and
// points its leaf children there; a collapsed child becomes a leaf. Nodes keep their slots:
// a removed node's parent link becomes VKRT_DEAD (the refits and the schedule skip it, the host's
// copy drops it, compaction renumbers without it), and the live nodes are counted into the
// word after the parent links (zero before). Only the references move: read from the
// builder's copy in scratch.
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_KHR_shader_subgroup_basic : require
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "include/vkrt/bvh_node.glsl"

// Deep enough for any collapsed subtree: at most MAX_COLLAPSE_LEAF (32) primitives, so at
// most 33 children wait at once.
#define GATHER_STACK 34u

// Written by this invocation only where the node lives; a removed node is only read.
layout(std430, binding = 0) buffer Nodes { VkrtBvhNode nodes[]; };
// The builder's references, then its parent links from `parents_at` on.
layout(std430, binding = 1) readonly buffer Refs { uint refs[]; };
layout(std430, binding = 2) readonly buffer Costs { uint costs[]; };
layout(std430, binding = 3) readonly buffer Live { uint live[]; };
layout(std430, binding = 4) readonly buffer First { uint first_ref[]; };
// The structure's references, parent links and live-node count.
layout(std430, binding = 5) buffer OutRefs { uint out_refs[]; };
layout(push_constant) uniform Push {
    uint n_nodes;
    uint parents_at;
} pc;

#define COLLAPSE_NO_DECIDE
#define COLLAPSE_COUNT_LIVE
#include "accel/bvh/collapse.glsl"

// Copies the references below `node` to out_refs[at...], depth first, `a` before `b`: a
// stack of children, each a node (count 0) or a leaf.
void gather(uint node, inout uint at) {
    uvec2 stack[GATHER_STACK];
    uint top = 0u;
    stack[top++] = uvec2(node, 0u);
    while (top > 0u) {
        uvec2 child = stack[--top];
        if (child.y > 0u) {
            for (uint k = 0u; k < child.y; k++) {
                out_refs[at++] = refs[child.x + k];
            }
        } else if (child.x != VKRT_NO_NODE && top + 2u <= GATHER_STACK) {
            VkrtBvhNode n = nodes[child.x];
            stack[top++] = uvec2(n.b_index, n.b_count);
            stack[top++] = uvec2(n.a_index, n.a_count);
        }
    }
}

// Lays out a leaf child's references (or a collapsed child's) from `at` on; true where the
// child changed.
bool relay(inout uint index, inout uint count, inout uint at) {
    uint first = at;
    if (count > 0u) {
        for (uint k = 0u; k < count; k++) {
            out_refs[at++] = refs[index + k];
        }
    } else if (index != VKRT_NO_NODE && costs[COST_COLLAPSE(index)] != 0u) {
        gather(index, at);
        count = at - first;
    } else {
        return false;
    }
    index = first;
    return true;
}

void main() {
    uint i = linear_invocation_id();
    count_live(i < pc.n_nodes && live[i] != 0u, pc.parents_at + pc.n_nodes);
    if (i >= pc.n_nodes) {
        return;
    }
    if (live[i] == 0u) {
        out_refs[pc.parents_at + i] = VKRT_DEAD;
        return;
    }
    out_refs[pc.parents_at + i] = refs[pc.parents_at + i];
    VkrtBvhNode n = nodes[i];
    uint at = first_ref[i];
    if (relay(n.a_index, n.a_count, at)) {
        nodes[i].a_index = n.a_index;
        nodes[i].a_count = n.a_count;
    }
    if (relay(n.b_index, n.b_count, at)) {
        nodes[i].b_index = n.b_index;
        nodes[i].b_count = n.b_count;
    }
}
