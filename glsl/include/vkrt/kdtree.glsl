// The kd-tree node, byte for byte the Rust `KdNode` (keep in sync with
// src/accel/kdtree/mod.rs): 16 bytes, std430.
//   inner: kind = split axis 0..2, split = plane, children a (below) and a + 1 (above);
//   leaf:  kind = KD_LEAF, primitives prim_refs[a .. a + b].
#ifndef VKRT_COMMON_KDTREE_GLSL
#define VKRT_COMMON_KDTREE_GLSL

#define KD_LEAF 3u

struct KdNode {
    float split;
    uint kind;
    uint a;
    uint b;
};

bool sign_bit(float x) {
    return (floatBitsToUint(x) >> 31) != 0u;
}

// min / max with -0.0 below +0.0 (GLSL's min/max leave that case open), as the CPU twin
// (`breadth_first::fmin`, `breadth_first::fmax`) and the reductions.
float fmin_total(float a, float b) {
    return (a < b || (a == b && sign_bit(a))) ? a : b;
}

float fmax_total(float a, float b) {
    return (a > b || (a == b && sign_bit(b))) ? a : b;
}

#endif
