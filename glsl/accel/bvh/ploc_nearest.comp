#version 460
#extension GL_KHR_shader_subgroup_basic : require
// PLOC, round step 1 (CPU twin: ploc::nearest): each cluster's nearest neighbour among the
// RADIUS clusters on either side, by the half area of their union, ties by a hash of the
// pair, then by index. PAIRING (the fallback after the recorded rounds): the partner is
// 2k <-> 2k + 1.
layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint RADIUS = 8u;
layout(constant_id = 2) const bool PAIRING = false;
#include "common/grid.glsl"
#include "include/vkrt/kdtree.glsl"
#include "accel/bvh/ploc_common.glsl"

layout(std430, binding = 0) readonly buffer Clusters { Cluster clusters[]; };
layout(std430, binding = 1) writeonly buffer Nearest { uint nn[]; };
layout(std430, binding = 2) readonly buffer State { uint state[]; };
layout(push_constant) uniform Push { uint parity; } pc;

uint pair_hash(uint lo, uint hi) {
    uint h = lo * 0x9E3779B1u + hi * 0x85EBCA77u;
    h ^= h >> 16u;
    h *= 0x7FEB352Du;
    return h ^ (h >> 15u);
}

float merged_area(Cluster a, Cluster b) {
    precise vec3 d = vkrt_vmax(a.hi, b.hi) - vkrt_vmin(a.lo, b.lo);
    precise float s = d.x * d.y + d.y * d.z + d.z * d.x;
    return s;
}

void main() {
    uint i = linear_invocation_id();
    uint count = state[ST_COUNT + pc.parity];
    if (i >= count) {
        return;
    }
    if (PAIRING) {
        nn[i] = (i ^ 1u) < count ? (i ^ 1u) : i;
        return;
    }
    Cluster c = clusters[i];
    uint lo = i >= RADIUS ? i - RADIUS : 0u;
    uint hi = min(i + RADIUS, count - 1u);
    float best_d = 1.0 / 0.0;
    uint best_h = 0xffffffffu;
    uint best = VKRT_NO_NODE;
    for (uint j = lo; j <= hi; j++) {
        if (j == i) {
            continue;
        }
        float d = merged_area(c, clusters[j]);
        uint h = pair_hash(min(i, j), max(i, j));
        if (best == VKRT_NO_NODE || d < best_d || (d == best_d && (h < best_h || (h == best_h && j < best)))) {
            best_d = d;
            best_h = h;
            best = j;
        }
    }
    nn[i] = best == VKRT_NO_NODE ? i : best;
}
