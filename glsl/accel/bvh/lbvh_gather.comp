#version 460
// LBVH: words of the codes in the order the ids are in now. Variant `one`, before each sort of
// the whole 63-bit codes (lbvh_ties.comp's fallback): the low words, then the high words, the
// keys of the sort that follows. Variants
// `codes`, after the sort: each code's (high, low) words as one pair in sorted order
// (common/word_pair.glsl; `codes64` moves it as one 64-bit component), so that the climb
// (accel/bvh/lbvh_climb.comp) reads a neighbour's code in one load.
//! variant one
//! variant codes CODES=1
//! variant codes64 CODES=1 PAIRS64=1
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "common/word_pair.glsl"

layout(std430, binding = 0) readonly buffer Ids { uint ids[]; };
#ifdef CODES
layout(std430, binding = 1) readonly buffer Hi { uint hi[]; };
layout(std430, binding = 2) readonly buffer Lo { uint lo[]; };
layout(std430, binding = 3) writeonly buffer Codes { WORD_PAIR codes[]; };
#else
layout(std430, binding = 1) readonly buffer Src { uint src[]; };
layout(std430, binding = 2) writeonly buffer Dst { uint dst[]; };
#endif
layout(push_constant) uniform Push { uint n; } pc;

void main() {
    uint i = linear_invocation_id();
    if (i < pc.n) {
        uint p = ids[i];
#ifdef CODES
        codes[i] = uints_pair(uvec2(hi[p], lo[p]));
#else
        dst[i] = src[p];
#endif
    }
}
