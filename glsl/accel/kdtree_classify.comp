#version 460
#extension GL_EXT_shader_8bit_storage : require
// kd-tree Phase II: the clip-mask of every event of one axis list, written as 0/1 flags into
// the virtual [below | above] slots of its node (node i owns [4·first, 4·first + 4·count)),
// so one scan gives every copy its place (twin: seed001 classify + virtual_slots).
//
// Variant `records` is the baseline of seed 001's clip-mask optimisation (Table 6.2,
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
layout(std430, binding = 4) readonly buffer Box { float box[]; }; // 6 arrays of `stride`
layout(std430, binding = 5) writeonly buffer Slots { uint8_t slots[]; }; // 0/1 flags
#ifdef FULL_RECORDS
layout(std430, binding = 6) readonly buffer InnerBefore { uint inner_before[]; };
layout(std430, binding = 7) readonly buffer Plane { float plane[]; };
layout(std430, binding = 8) readonly buffer Kind { uint kind_words[]; };
layout(std430, binding = 9) readonly buffer Prim { uint prim[]; };
// The temporary slot list: 2·stride records (plane, type, prim, node, box arrays of
// 2·stride floats each).
layout(std430, binding = 10) writeonly buffer TmpPlane { float tmp_plane[]; };
layout(std430, binding = 11) writeonly buffer TmpKind { uint8_t tmp_kind[]; };
layout(std430, binding = 12) writeonly buffer TmpPrim { uint tmp_prim[]; };
layout(std430, binding = 13) writeonly buffer TmpNode { uint tmp_node[]; };
layout(std430, binding = 14) writeonly buffer TmpBox { float tmp_box[]; };
#endif
layout(push_constant) uniform Push { uint stride; } pc;

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
        float lo = box[s * pc.stride + id];
        float hi = box[(3u + s) * pc.stride + id];
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
    uint st = pc.stride;
    uint ts = 2u * st; // elements per temporary box array
    float mnx = box[id], mny = box[st + id], mnz = box[2u * st + id];
    float mxx = box[3u * st + id], mxy = box[4u * st + id], mxz = box[5u * st + id];
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
        tmp_box[o] = (up && s == 0u) ? fmax_total(mnx, p) : mnx;
        tmp_box[ts + o] = (up && s == 1u) ? fmax_total(mny, p) : mny;
        tmp_box[2u * ts + o] = (up && s == 2u) ? fmax_total(mnz, p) : mnz;
        tmp_box[3u * ts + o] = (!up && s == 0u) ? fmin_total(mxx, p) : mxx;
        tmp_box[4u * ts + o] = (!up && s == 1u) ? fmin_total(mxy, p) : mxy;
        tmp_box[5u * ts + o] = (!up && s == 2u) ? fmin_total(mxz, p) : mxz;
    }
#endif
}
