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

#endif
