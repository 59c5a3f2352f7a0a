// Shared by the per-level kernels of the GPU kd-tree build (keep in sync with
// src/accel/kdtree/gpu.rs and the CPU twin src/accel/kdtree/breadth_first.rs).
#ifndef VKRT_ACCEL_KDTREE_LEVEL_GLSL
#define VKRT_ACCEL_KDTREE_LEVEL_GLSL

#include "include/vkrt/kdtree.glsl"

// Words of the build state buffer.
#define ST_REFS 0u        // primitive references of the current level (events per axis / 2)
#define ST_NODES 1u       // nodes of the current level
#define ST_NODE_BASE 2u   // index of the level's first node in the output
#define ST_REF_BASE 3u    // leaf references written so far
#define ST_DEPTH 4u
#define ST_OVERFLOW 5u    // 1: a capacity was exceeded; the build stopped cleanly
#define ST_NEED_REFS 6u   // references the level that overflowed needed
#define ST_NEXT_REFS 7u
#define ST_LEVELS 8u
#define ST_EVENT_ARGS 12u // indirect dispatch over 2 * refs events
#define ST_NODE_ARGS 16u  // indirect dispatch over the level's nodes
#define ST_WORDS 32u

#define WG_SIZE 256u

// The event boxes are three WORD_PAIR arrays (common/word_pair.glsl), (min x, min y),
// (min z, max x), (max y, max z), one buffer each, as are a node's (split, plane), (first,
// count) and box pairs; a single component reads through a `float` view: element
// 2·event + (k & 1) of array k / 2.
#include "common/word_pair.glsl"

float f32_inf() {
    return uintBitsToFloat(0x7f800000u);
}

uint kind_of(uint word, uint id) {
    return (word >> (8u * (id & 3u))) & 0xffu;
}

// The SAH scaled by the node's half area, division-free (twin: breadth_first::sah_scaled).
float sah_scaled(vec3 mn, vec3 mx, uint axis, float plane, uint below, uint above,
                 float trav, float isect, float bonus) {
    if (!(plane > mn[axis] && plane < mx[axis])) {
        return f32_inf();
    }
    precise vec3 d = mx - mn;
    precise float area = d.x * d.y + d.y * d.z + d.z * d.x;
    precise vec3 dl = d;
    dl[axis] = plane - mn[axis];
    precise vec3 dr = d;
    dr[axis] = mx[axis] - plane;
    precise float area_l = dl.x * dl.y + dl.y * dl.z + dl.z * dl.x;
    precise float area_r = dr.x * dr.y + dr.y * dr.z + dr.z * dr.x;
    precise float cost = trav * area + isect * (area_l * float(below) + area_r * float(above));
    if (below == 0u || above == 0u) {
        cost = cost * bonus;
    }
    return cost;
}

uvec3 folded_groups(uint items) {
    uint g = (items + WG_SIZE - 1u) / WG_SIZE;
    uint x = min(g, 65535u);
    return uvec3(x, x == 0u ? 1u : (g + x - 1u) / x, 1u);
}

#endif
