// The kd-tree node, byte for byte the Rust `VkrtKdNode` (keep in sync with
// src/accel/kdtree/mod.rs): 16 bytes, std430.
//   inner: kind = split axis 0..2, split = plane, children a (below) and a + 1 (above);
//   leaf:  kind = VKRT_KD_LEAF, primitives prim_refs[a .. a + b].
#ifndef VKRT_COMMON_KDTREE_GLSL
#define VKRT_COMMON_KDTREE_GLSL

#define VKRT_KD_LEAF 3u

struct VkrtKdNode {
    float split;
    uint kind;
    uint a;
    uint b;
};

bool vkrt_sign_bit(float x) {
    return (floatBitsToUint(x) >> 31) != 0u;
}

// min / max with -0.0 below +0.0 (GLSL's min/max leave that case open), as the CPU twin
// (`breadth_first::fmin`, `breadth_first::fmax`) and the reductions.
float vkrt_fmin_total(float a, float b) {
    return (a < b || (a == b && vkrt_sign_bit(a))) ? a : b;
}

float vkrt_fmax_total(float a, float b) {
    return (a > b || (a == b && vkrt_sign_bit(b))) ? a : b;
}

#endif
