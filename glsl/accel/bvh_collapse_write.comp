#version 460
// The SAH leaf collapse's last pass (CPU twin: collapse::collapse): every live node written
// at its new index (the exclusive scan of the live flags) with its children renamed, its leaf
// references copied from its first reference (the scan of the leaf reference counts) on —
// child `a`'s before `b`'s, a collapsed subtree's depth first — and its parent renamed; every
// removed node marks one slot at the tail DEAD. The builder's tree is read from
// scratch and the structure written, so nothing is copied.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "accel/bvh_collapse.glsl"

// Deep enough for any collapsed subtree: at most MAX_COLLAPSE_LEAF (32) primitives, so at
// most 33 children wait at once.
#define GATHER_STACK 64u

layout(std430, binding = 0) readonly buffer Nodes { BvhNode nodes[]; };
layout(std430, binding = 1) readonly buffer Refs { uint refs[]; };
layout(std430, binding = 2) readonly buffer Costs { uint costs[]; };
layout(std430, binding = 3) readonly buffer Live { uint live[]; };
layout(std430, binding = 4) readonly buffer Index { uint new_index[]; };
layout(std430, binding = 5) readonly buffer First { uint first_ref[]; };
layout(std430, binding = 6) writeonly buffer OutNodes { BvhNode out_nodes[]; };
// References, then the parent links from `parents_at` on.
layout(std430, binding = 7) writeonly buffer OutRefs { uint out_refs[]; };
layout(push_constant) uniform Push {
    uint n_nodes;
    uint parents_at;
} pc;

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
        } else if (child.x != NO_NODE && top + 2u <= GATHER_STACK) {
            BvhNode n = nodes[child.x];
            stack[top++] = uvec2(n.b_index, n.b_count);
            stack[top++] = uvec2(n.a_index, n.a_count);
        }
    }
}

void rename(inout uint index, inout uint count, inout uint at) {
    if (count > 0u) {
        uint first = at;
        for (uint k = 0u; k < count; k++) {
            out_refs[at++] = refs[index + k];
        }
        index = first;
    } else if (index != NO_NODE) {
        if (costs[COST_COLLAPSE(index)] != 0u) {
            uint first = at;
            gather(index, at);
            count = at - first;
            index = first;
        } else {
            index = new_index[index];
        }
    }
}

void main() {
    uint i = linear_invocation_id();
    if (i >= pc.n_nodes) {
        return;
    }
    if (live[i] == 0u) {
        // A freed slot at the tail, one per removed node (i - new_index[i] removed before
        // it), marked DEAD: the refits skip it, and its node is never read.
        uint slot = pc.n_nodes - 1u - (i - new_index[i]);
        out_refs[pc.parents_at + slot] = DEAD;
        return;
    }
    BvhNode n = nodes[i];
    uint at = first_ref[i];
    rename(n.a_index, n.a_count, at);
    rename(n.b_index, n.b_count, at);
    uint j = new_index[i];
    out_nodes[j] = n;
    uint parent = refs[pc.parents_at + i];
    out_refs[pc.parents_at + j] = parent == NO_NODE ? NO_NODE : new_index[parent];
}
