#version 460
// BVH refit (CPU twin: src/accel/bvh/refit.rs): every child box recomputed bottom-up from
// the primitives' boxes after they moved, the topology kept. One invocation per node; those
// whose children are all leaves start, refit their node and climb: at each parent an atomic
// visit counter lets the last child to arrive refit it (Karras 2012's scheme), so no
// invocation waits for another (no forward-progress assumption). The buffer writes of the
// child are made visible before its arrival is counted (memoryBarrierBuffer on coherent
// buffers), and the arriving invocation reads them after. Unions use the total order on ±0
// (vkrt_fmin_total), so the result is bit for bit the CPU twin's, whatever the order.
// Variant `boxes64` moves nodes and boxes as 64-bit pairs (accel/bvh/pairs.glsl), where the
// device has shaderInt64. (The LBVH's build climbs in accel/bvh/lbvh_climb.comp.)
//! variant boxes
//! variant boxes64 PAIRS64=1
layout(local_size_x_id = 0) in;
#extension GL_KHR_shader_subgroup_vote : require
#include "common/grid.glsl"
#include "accel/bvh/pairs.glsl"

layout(std430, binding = 0) coherent buffer Nodes { WORD_PAIR node_pairs[]; };
// References, then one parent link per node from `parents_at` on.
layout(std430, binding = 1) readonly buffer Refs { uint refs[]; };
// Six floats per primitive, min x, y, z, max x, y, z: three pairs.
layout(std430, binding = 2) readonly buffer Boxes { WORD_PAIR box_pairs[]; };
// One counter per node, zero before the dispatch.
layout(std430, binding = 3) coherent buffer Visits { uint visits[]; };
// `SceneInfo` (src/accel/primitives.rs): the root box is rewritten.
layout(std430, binding = 4) buffer VkrtSceneInfoBinding {
    vec4 bounds_min;
    vec4 bounds_max;
    uint n_tris;
    uint n_spheres;
    uint has_motion;
    uint parents_at;
} info;
layout(push_constant) uniform Push { uint n_nodes; } pc;

#include "accel/bvh/refit.glsl"

void main() {
    uint i = linear_invocation_id();
    // Slots a leaf collapse freed (parent VKRT_DEAD) hold no node.
    bool climbing = i < pc.n_nodes && refs[info.parents_at + i] != VKRT_DEAD &&
                    vkrt_node_children(LOAD_NODE(node_pairs, i)) == 0u;
    uint cur = i;
    // Rounds in subgroup-uniform control flow, every memory barrier reached by every lane:
    // Mesa 22.3's lavapipe makes memoryBarrierBuffer (or an atomic with acquire/release
    // semantics) a coroutine switch, and a subgroup that runs more of them than the others
    // of its workgroup is never resumed (glsl/gpu/memory_barrier_probe.comp); a workgroup
    // is one subgroup here (AccelBuilder dispatches the subgroup size), so there are no
    // others. One round: refit (stores), memory barrier, arrive at the parent (atomic),
    // memory barrier; the subgroup stops when none of its lanes climbs. A bound of one
    // round per node: never a spin.
    for (uint round = 0u; round <= pc.n_nodes; round++) {
        if (!subgroupAny(climbing)) {
            break;
        }
        VkrtBvhNode n;
        if (climbing) {
            n = refit_node(cur);
        }
        memoryBarrierBuffer(); // the boxes are visible before the arrival is counted
        if (climbing) {
            uint parent = refs[info.parents_at + cur];
            if (parent == VKRT_NO_NODE) {
                info.bounds_min = vec4(vkrt_vmin(n.a_min, n.b_min), 0.0);
                info.bounds_max = vec4(vkrt_vmax(n.a_max, n.b_max), 0.0);
                climbing = false;
            } else {
                // The sibling, arriving last, refits the parent.
                uint arrived = atomicAdd(visits[parent], 1u) + 1u;
                climbing = arrived >= vkrt_node_children(LOAD_NODE(node_pairs, parent));
                cur = parent;
            }
        }
        memoryBarrierBuffer(); // ... and read after it
    }
}
