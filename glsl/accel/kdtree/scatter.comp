#version 460
// kd-tree Phase II: one compaction moves each event record of one axis list once per side,
// to its scanned slot, with its box clipped on the split axis only; lists stay sorted
// (stable subsequences), so they are never re-sorted (twin: breadth_first::scatter).
//
// Variant `records` (the ablation `full_record_scatter`, Kolodzey's pre-clip-mask baseline):
// the records were already clipped and written to their virtual slots of a temporary list by
// `kdtree_classify.records`; this pass moves each valid slot's complete record a second time,
// to its scanned place (one invocation per event, for its two slots).
//
// The `*64` variants (where the device has shaderInt64) move the box pairs and read the
// node's (split, plane) and (first, count) as 64-bit components (accel/kdtree/level.glsl).
#extension GL_EXT_shader_8bit_storage : require
//! variant once MOVE_ONCE=1
//! variant once64 MOVE_ONCE=1 PAIRS64=1
//! variant records FULL_RECORDS=1
//! variant records64 FULL_RECORDS=1 PAIRS64=1
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "accel/kdtree/level.glsl"

#ifdef FULL_RECORDS
layout(std430, binding = 0) readonly buffer State { uint state[]; };
layout(std430, binding = 1) readonly buffer NodeRange { uint node_range[]; };
layout(std430, binding = 2) readonly buffer NodeSplit { uint node_split[]; };
layout(std430, binding = 3) readonly buffer Node { uint node_of[]; };
layout(std430, binding = 4) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 5) readonly buffer Slots { uint slot_words[]; }; // 4 flags a word
// The temporary slot list `kdtree_classify.records` wrote.
layout(std430, binding = 6) readonly buffer TmpPlane { float tmp_plane[]; };
layout(std430, binding = 7) readonly buffer TmpKind { uint tmp_kind_words[]; };
layout(std430, binding = 8) readonly buffer TmpPrim { uint tmp_prim[]; };
layout(std430, binding = 9) readonly buffer TmpNode { uint tmp_node[]; };
layout(std430, binding = 10) readonly buffer TmpBox0 { WORD_PAIR tmp_box0[]; };
layout(std430, binding = 11) readonly buffer TmpBox1 { WORD_PAIR tmp_box1[]; };
layout(std430, binding = 12) readonly buffer TmpBox2 { WORD_PAIR tmp_box2[]; };
#else
layout(std430, binding = 0) readonly buffer State { uint state[]; };
layout(std430, binding = 1) readonly buffer NodeRange { WORD_PAIR node_range[]; }; // first, count
layout(std430, binding = 2) readonly buffer NodeSplit { WORD_PAIR node_split[]; }; // axis, plane
layout(std430, binding = 3) readonly buffer InnerBefore { uint inner_before[]; };
layout(std430, binding = 4) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 5) readonly buffer Plane { float plane[]; };
layout(std430, binding = 6) readonly buffer Kind { uint kind_words[]; };
layout(std430, binding = 7) readonly buffer Prim { uint prim[]; };
layout(std430, binding = 8) readonly buffer Node { uint node_of[]; };
layout(std430, binding = 10) readonly buffer Box0 { WORD_PAIR box0[]; };
layout(std430, binding = 11) readonly buffer Box1 { WORD_PAIR box1[]; };
layout(std430, binding = 12) readonly buffer Box2 { WORD_PAIR box2[]; };
#endif
// The next level's list of this axis (the box as three pair arrays).
layout(std430, binding = 16) writeonly buffer OutPlane { float out_plane[]; };
layout(std430, binding = 17) writeonly buffer OutKind { uint8_t out_kind[]; };
layout(std430, binding = 18) writeonly buffer OutPrim { uint out_prim[]; };
layout(std430, binding = 19) writeonly buffer OutNode { uint out_node[]; };
layout(std430, binding = 20) writeonly buffer OutBox0 { WORD_PAIR out_box0[]; };
layout(std430, binding = 21) writeonly buffer OutBox1 { WORD_PAIR out_box1[]; };
layout(std430, binding = 22) writeonly buffer OutBox2 { WORD_PAIR out_box2[]; };

layout(push_constant) uniform Push { uint capacity; } pc; // events of the output list

#ifdef FULL_RECORDS
void main() {
    uint id = linear_invocation_id();
    if (id >= 2u * state[ST_REFS]) {
        return;
    }
    uint node = node_of[id];
    if (node_split[2u * node] == VKRT_KD_LEAF) {
        return;
    }
    uint first = node_range[2u * node];
    uint count = node_range[2u * node + 1u];
    for (uint side = 0u; side < 2u; side++) {
        uint v = id + 2u * first + side * 2u * count;
        if (kind_of(slot_words[v / 4u], v) == 0u) {
            continue;
        }
        uint o = offsets[v];
        if (o >= pc.capacity) {
            continue; // past capacity: kdtree_advance raises the overflow flag
        }
        out_plane[o] = tmp_plane[v];
        out_kind[o] = uint8_t(kind_of(tmp_kind_words[v / 4u], v));
        out_prim[o] = tmp_prim[v];
        out_node[o] = tmp_node[v];
        out_box0[o] = tmp_box0[v];
        out_box1[o] = tmp_box1[v];
        out_box2[o] = tmp_box2[v];
    }
}
#else
void main() {
    uint id = linear_invocation_id();
    if (id >= 2u * state[ST_REFS]) {
        return;
    }
    uint node = node_of[id];
    uvec2 split = pair_uints(node_split[node]); // (axis or VKRT_KD_LEAF, plane)
    uint s = split.x;
    if (s == VKRT_KD_LEAF) {
        return;
    }
    uvec2 range = pair_uints(node_range[node]); // (first, count)
    uint first = range.x;
    uint count = range.y;
    float p = uintBitsToFloat(split.y);
    vec2 b0 = pair_floats(box0[id]);
    vec2 b1 = pair_floats(box1[id]);
    vec2 b2 = pair_floats(box2[id]);
    float mnx = b0.x, mny = b0.y, mnz = b1.x;
    float mxx = b1.y, mxy = b2.x, mxz = b2.y;
    float lo = s == 0u ? mnx : (s == 1u ? mny : mnz);
    float hi = s == 0u ? mxx : (s == 1u ? mxy : mxz);
    bool below = hi <= p;
    bool above = !below && lo >= p;
    bool both = !below && !above;
    uint v = id + 2u * first;
    float pl = plane[id];
    uint k = kind_of(kind_words[id / 4u], id);
    uint pr = prim[id];
    uint child = 2u * inner_before[node];
    for (uint side = 0u; side < 2u; side++) {
        if (!(side == 0u ? (below || both) : (above || both))) {
            continue;
        }
        uint o = offsets[v + side * 2u * count];
        if (o >= pc.capacity) {
            continue; // past capacity: kdtree_advance raises the overflow flag
        }
        out_plane[o] = pl;
        out_kind[o] = uint8_t(k);
        out_prim[o] = pr;
        out_node[o] = child + side;
        // Clip on the split axis only: the below copy's max, the above copy's min.
        bool up = side == 1u;
        float cmnx = (up && s == 0u) ? vkrt_fmax_total(mnx, p) : mnx;
        float cmny = (up && s == 1u) ? vkrt_fmax_total(mny, p) : mny;
        float cmnz = (up && s == 2u) ? vkrt_fmax_total(mnz, p) : mnz;
        float cmxx = (!up && s == 0u) ? vkrt_fmin_total(mxx, p) : mxx;
        float cmxy = (!up && s == 1u) ? vkrt_fmin_total(mxy, p) : mxy;
        float cmxz = (!up && s == 2u) ? vkrt_fmin_total(mxz, p) : mxz;
        out_box0[o] = floats_pair(vec2(cmnx, cmny));
        out_box1[o] = floats_pair(vec2(cmnz, cmxx));
        out_box2[o] = floats_pair(vec2(cmxy, cmxz));
    }
}
#endif
