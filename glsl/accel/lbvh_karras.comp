#version 460
// LBVH, pass 3 (Karras 2012; CPU twin: lbvh::topology): one invocation per internal node i
// of the n - 1, over the sorted codes. The direction of i's range comes from its neighbours'
// common prefixes, its far end from an exponential then a binary search, its split γ from a
// binary search for where the prefix of the whole range ends; child a is position γ, child b
// is γ + 1, each a leaf (one reference, at that position of the sorted ids) when its range
// is one primitive. Equal codes are told apart by their positions (Karras's rule: δ = 64 +
// the common prefix of the indices). Boxes are left empty: `accel.bvh_refit` computes them.
// Variant `pairs64` reads each code as one 64-bit component (common/word_pair.glsl).
//! variant words
//! variant pairs64 PAIRS64=1
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "common/word_pair.glsl"
#include "include/vkrt/bvh_node.glsl"

layout(std430, binding = 0) writeonly buffer Nodes { BvhNode nodes[]; };
// The sorted primitive ids (the leaves' references), then a parent link per node from n on.
layout(std430, binding = 1) buffer Refs { uint refs[]; };
// The codes in sorted order, (high, low) words.
layout(std430, binding = 2) readonly buffer Codes { WORD_PAIR codes[]; };
layout(push_constant) uniform Push { uint n; } pc;

uint clz(uint x) {
    return uint(31 - findMSB(x)); // findMSB(0) = -1: 32
}

uvec2 code_at(int i) {
    return pair_uints(codes[i]);
}

int delta(int i, uvec2 ci, int j) {
    if (j < 0 || j >= int(pc.n)) {
        return -1;
    }
    uvec2 cj = code_at(j);
    if (ci == cj) {
        return 64 + int(clz(uint(i ^ j)));
    }
    uint x = ci.x ^ cj.x;
    return int(x != 0u ? clz(x) : 32u + clz(ci.y ^ cj.y));
}

void main() {
    uint id = linear_invocation_id();
    int n = int(pc.n);
    vec3 lo = vec3(1.0 / 0.0);
    vec3 hi = vec3(-1.0 / 0.0);
    if (n == 1) {
        if (id == 0u) {
            nodes[0] = BvhNode(lo, 0u, hi, 1u, lo, NO_NODE, hi, 0u);
            refs[1] = NO_NODE;
        }
        return;
    }
    if (int(id) >= n - 1) {
        return;
    }
    int i = int(id);
    uvec2 ci = code_at(i);
    int d = delta(i, ci, i + 1) - delta(i, ci, i - 1) >= 0 ? 1 : -1;
    int d_min = delta(i, ci, i - d);
    int l_max = 2;
    while (delta(i, ci, i + l_max * d) > d_min) {
        l_max *= 2;
    }
    int l = 0;
    for (int t = l_max / 2; t >= 1; t /= 2) {
        if (delta(i, ci, i + (l + t) * d) > d_min) {
            l += t;
        }
    }
    int j = i + l * d;
    int d_node = delta(i, ci, j);
    int s = 0;
    int t = l;
    do {
        t = (t + 1) / 2;
        if (delta(i, ci, i + (s + t) * d) > d_node) {
            s += t;
        }
    } while (t > 1);
    int gamma = i + s * d + min(d, 0);
    uint a_leaf = min(i, j) == gamma ? 1u : 0u;
    uint b_leaf = max(i, j) == gamma + 1 ? 1u : 0u;
    nodes[i] = BvhNode(lo, uint(gamma), hi, a_leaf, lo, uint(gamma + 1), hi, b_leaf);
    if (a_leaf == 0u) {
        refs[n + gamma] = uint(i);
    }
    if (b_leaf == 0u) {
        refs[n + gamma + 1] = uint(i);
    }
    if (i == 0) {
        refs[n] = NO_NODE;
    }
}
