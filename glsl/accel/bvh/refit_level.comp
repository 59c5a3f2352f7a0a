#version 460
// BVH refit of one depth (CPU twin: src/accel/bvh/refit.rs): every node at that depth gets
// its children's boxes from the primitives (leaves) or from the children's nodes, which the
// dispatch of the depth below refit before. Unions in the total order on ±0, as every refit.
// Variant `pairs64` moves nodes and boxes as 64-bit pairs (accel/bvh/pairs.glsl), where the
// device has shaderInt64.
//! variant words
//! variant pairs64 PAIRS64=1
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "accel/bvh/pairs.glsl"

#define MAX_DEPTH 128u

layout(std430, binding = 0) buffer Nodes { WORD_PAIR node_pairs[]; };
layout(std430, binding = 1) readonly buffer Refs { uint refs[]; };
layout(std430, binding = 2) readonly buffer Boxes { WORD_PAIR box_pairs[]; };
layout(std430, binding = 3) readonly buffer Order { uint order[]; };
layout(std430, binding = 4) readonly buffer Levels { uint levels[]; };
layout(std430, binding = 5) buffer VkrtSceneInfoBinding {
    vec4 bounds_min;
    vec4 bounds_max;
    uint n_tris;
    uint n_spheres;
    uint has_motion;
    uint parents_at;
} info;
layout(push_constant) uniform Push { uint depth; } pc;

#include "accel/bvh/refit.glsl"

void main() {
    uint i = linear_invocation_id();
    if (i >= levels[pc.depth]) {
        return;
    }
    uint node = order[levels[MAX_DEPTH + pc.depth] + i];
    VkrtBvhNode n = refit_node(node);
    if (pc.depth == 0u) {
        info.bounds_min = vec4(vkrt_vmin(n.a_min, n.b_min), 0.0);
        info.bounds_max = vec4(vkrt_vmax(n.a_max, n.b_max), 0.0);
    }
}
