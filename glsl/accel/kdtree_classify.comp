#version 460
#extension GL_EXT_shader_8bit_storage : require
// kd-tree Phase II: the clip-mask of every event of one axis list, written as 0/1 flags into
// the virtual [below | above] slots of its node (node i owns [4·first, 4·first + 4·count)),
// so one scan gives every copy its place (twin: breadth_first classify + virtual_slots).
//
// Variant `records` is the baseline of Kolodzey's clip-mask optimisation (Table 6.2,
// "Clip-Mask"; the ablation `full_record_scatter`): besides the flags it writes the complete
// clipped record (plane, type, primitive, child node, 6 box floats = 37 bytes) into each of
// the event's valid virtual slots of a temporary list twice as long as the event list, and
// `kdtree_scatter.records` moves each record a second time, from its slot to its scanned
// place. The default (`mask`) writes only the flag bytes here; `kdtree_scatter.once` reads
// each record once and writes it, clipped, straight to its place.
//! variant mask MASK_ONLY=1
//! variant records FULL_RECORDS=1
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "accel/kdtree_level.glsl"

layout(std430, binding = 0) readonly buffer State { uint state[]; };
layout(std430, binding = 1) readonly buffer NodeRange { uint node_range[]; };
layout(std430, binding = 2) readonly buffer NodeSplit { uint node_split[]; };
layout(std430, binding = 3) readonly buffer Node { uint node_of[]; };
// The event boxes, one array per component.
layout(std430, binding = 4) readonly buffer BoxMinX { float box_min_x[]; };
layout(std430, binding = 5) readonly buffer BoxMinY { float box_min_y[]; };
layout(std430, binding = 6) readonly buffer BoxMinZ { float box_min_z[]; };
layout(std430, binding = 7) readonly buffer BoxMaxX { float box_max_x[]; };
layout(std430, binding = 8) readonly buffer BoxMaxY { float box_max_y[]; };
layout(std430, binding = 9) readonly buffer BoxMaxZ { float box_max_z[]; };
layout(std430, binding = 10) writeonly buffer Slots { uint8_t slots[]; }; // 0/1 flags
#ifdef FULL_RECORDS
layout(std430, binding = 11) readonly buffer InnerBefore { uint inner_before[]; };
layout(std430, binding = 12) readonly buffer Plane { float plane[]; };
layout(std430, binding = 13) readonly buffer Kind { uint kind_words[]; };
layout(std430, binding = 14) readonly buffer Prim { uint prim[]; };
// The temporary slot list: one record per virtual slot (twice the event list).
layout(std430, binding = 15) writeonly buffer TmpPlane { float tmp_plane[]; };
layout(std430, binding = 16) writeonly buffer TmpKind { uint8_t tmp_kind[]; };
layout(std430, binding = 17) writeonly buffer TmpPrim { uint tmp_prim[]; };
layout(std430, binding = 18) writeonly buffer TmpNode { uint tmp_node[]; };
layout(std430, binding = 19) writeonly buffer TmpMinX { float tmp_min_x[]; };
layout(std430, binding = 20) writeonly buffer TmpMinY { float tmp_min_y[]; };
layout(std430, binding = 21) writeonly buffer TmpMinZ { float tmp_min_z[]; };
layout(std430, binding = 22) writeonly buffer TmpMaxX { float tmp_max_x[]; };
layout(std430, binding = 23) writeonly buffer TmpMaxY { float tmp_max_y[]; };
layout(std430, binding = 24) writeonly buffer TmpMaxZ { float tmp_max_z[]; };
#endif

void main() {
    uint id = linear_invocation_id();
    if (id >= 2u * state[ST_REFS]) {
        return;
    }
    uint node = node_of[id];
    uint first = node_range[2u * node];
    uint count = node_range[2u * node + 1u];
    uint s = node_split[2u * node];
    uint below = 0u;
    uint above = 0u;
    float p = 0.0;
    if (s != KD_LEAF) {
        p = uintBitsToFloat(node_split[2u * node + 1u]);
        float lo = s == 0u ? box_min_x[id] : (s == 1u ? box_min_y[id] : box_min_z[id]);
        float hi = s == 0u ? box_max_x[id] : (s == 1u ? box_max_y[id] : box_max_z[id]);
        if (hi <= p) {
            below = 1u;
        } else if (lo >= p) {
            above = 1u;
        } else {
            below = 1u;
            above = 1u;
        }
    }
    uint v = id + 2u * first; // = 4·first + (id − 2·first)
    slots[v] = uint8_t(below);
    slots[v + 2u * count] = uint8_t(above);
#ifdef FULL_RECORDS
    if (s == KD_LEAF) {
        return;
    }
    float mnx = box_min_x[id], mny = box_min_y[id], mnz = box_min_z[id];
    float mxx = box_max_x[id], mxy = box_max_y[id], mxz = box_max_z[id];
    float pl = plane[id];
    uint k = kind_of(kind_words[id / 4u], id);
    uint pr = prim[id];
    uint child = 2u * inner_before[node];
    for (uint side = 0u; side < 2u; side++) {
        if ((side == 0u ? below : above) == 0u) {
            continue;
        }
        uint o = v + side * 2u * count;
        tmp_plane[o] = pl;
        tmp_kind[o] = uint8_t(k);
        tmp_prim[o] = pr;
        tmp_node[o] = child + side;
        bool up = side == 1u;
        tmp_min_x[o] = (up && s == 0u) ? fmax_total(mnx, p) : mnx;
        tmp_min_y[o] = (up && s == 1u) ? fmax_total(mny, p) : mny;
        tmp_min_z[o] = (up && s == 2u) ? fmax_total(mnz, p) : mnz;
        tmp_max_x[o] = (!up && s == 0u) ? fmin_total(mxx, p) : mxx;
        tmp_max_y[o] = (!up && s == 1u) ? fmin_total(mxy, p) : mxy;
        tmp_max_z[o] = (!up && s == 2u) ? fmin_total(mxz, p) : mxz;
    }
#endif
}
