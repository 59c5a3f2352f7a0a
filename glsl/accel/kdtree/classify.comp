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
//
// The `*64` variants (where the device has shaderInt64) read the node's (first, count) and
// (split, plane) as 64-bit components and write the records' box pairs as such
// (accel/kdtree/level.glsl).
//! variant mask MASK_ONLY=1
//! variant mask64 MASK_ONLY=1 PAIRS64=1
//! variant records FULL_RECORDS=1
//! variant records64 FULL_RECORDS=1 PAIRS64=1
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "accel/kdtree/level.glsl"

layout(std430, binding = 0) readonly buffer State { uint state[]; };
layout(std430, binding = 1) readonly buffer NodeRange { WORD_PAIR node_range[]; }; // first, count
layout(std430, binding = 2) readonly buffer NodeSplit { WORD_PAIR node_split[]; }; // axis, plane
layout(std430, binding = 3) readonly buffer Node { uint node_of[]; };
// The event boxes' three pair arrays (accel/kdtree/level.glsl), read a component at a time.
layout(std430, binding = 4) readonly buffer Box0 { float box0[]; }; // min x, min y
layout(std430, binding = 5) readonly buffer Box1 { float box1[]; }; // min z, max x
layout(std430, binding = 6) readonly buffer Box2 { float box2[]; }; // max y, max z
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
layout(std430, binding = 19) writeonly buffer TmpBox0 { WORD_PAIR tmp_box0[]; };
layout(std430, binding = 20) writeonly buffer TmpBox1 { WORD_PAIR tmp_box1[]; };
layout(std430, binding = 21) writeonly buffer TmpBox2 { WORD_PAIR tmp_box2[]; };
#endif

void main() {
    uint id = linear_invocation_id();
    if (id >= 2u * state[ST_REFS]) {
        return;
    }
    uint node = node_of[id];
    uvec2 range = pair_uints(node_range[node]); // (first, count)
    uint first = range.x;
    uint count = range.y;
    uvec2 split = pair_uints(node_split[node]); // (axis or VKRT_KD_LEAF, plane)
    uint s = split.x;
    uint below = 0u;
    uint above = 0u;
    float p = 0.0;
    if (s != VKRT_KD_LEAF) {
        p = uintBitsToFloat(split.y);
        float lo = s == 0u ? box0[2u * id] : (s == 1u ? box0[2u * id + 1u] : box1[2u * id]);
        float hi = s == 0u ? box1[2u * id + 1u] : (s == 1u ? box2[2u * id] : box2[2u * id + 1u]);
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
    if (s == VKRT_KD_LEAF) {
        return;
    }
    float mnx = box0[2u * id], mny = box0[2u * id + 1u], mnz = box1[2u * id];
    float mxx = box1[2u * id + 1u], mxy = box2[2u * id], mxz = box2[2u * id + 1u];
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
        float cmnx = (up && s == 0u) ? vkrt_fmax_total(mnx, p) : mnx;
        float cmny = (up && s == 1u) ? vkrt_fmax_total(mny, p) : mny;
        float cmnz = (up && s == 2u) ? vkrt_fmax_total(mnz, p) : mnz;
        float cmxx = (!up && s == 0u) ? vkrt_fmin_total(mxx, p) : mxx;
        float cmxy = (!up && s == 1u) ? vkrt_fmin_total(mxy, p) : mxy;
        float cmxz = (!up && s == 2u) ? vkrt_fmin_total(mxz, p) : mxz;
        tmp_box0[o] = floats_pair(vec2(cmnx, cmny));
        tmp_box1[o] = floats_pair(vec2(cmnz, cmxx));
        tmp_box2[o] = floats_pair(vec2(cmxy, cmxz));
    }
#endif
}
