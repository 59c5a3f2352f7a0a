#version 460
// Writes VkrtKdNodesBinding from GLSL so a test can read them in Rust: proves both layouts agree.
layout(local_size_x_id = 0) in;
#include "include/vkrt/kdtree.glsl"

layout(std430, binding = 0) writeonly buffer Nodes { VkrtKdNode nodes[]; };
layout(push_constant) uniform Push { uint n; } pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i < pc.n) {
        nodes[i] = VkrtKdNode(float(i) * 0.5, i % 4u, 3u * i, 7u * i + 1u);
    }
}
