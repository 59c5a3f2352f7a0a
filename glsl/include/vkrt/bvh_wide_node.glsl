// The 4-wide BVH node (`VkrtWideNode` in src/accel/bvh/wide.rs, 64 bytes, four RGBA32UI
// texels): binary node i with its grandchildren pulled up, child boxes quantized to 8 bits
// per plane in a power-of-two frame (Ylitie, Karras & Laine 2017). Texel 0: the frame's
// origin (x, y, z) and the biased exponents of its scales (8 bits each); texel 1: the low
// planes of x, y, z and the high planes of x (one byte per child); texel 2: the high planes
// of y, z and the leaf sizes (16 bits per child: 0 for an interior node or none); texel 3:
// per child its wide node, first reference, or VKRT_NO_NODE. Decoding is one multiply-add per
// plane, `p + q·s`, whose product is exact, so a fused one gives the same bits; the encoder
// (accel/bvh/widen.comp) checks every plane with this arithmetic, so a decoded box always
// contains the child's box.
#ifndef VKRT_COMMON_BVH_WIDE_NODE_GLSL
#define VKRT_COMMON_BVH_WIDE_NODE_GLSL

struct VkrtWideNode {
    uvec4 frame;  // origin bits, exponents
    uvec4 planes; // lo x, lo y, lo z, hi x
    uvec4 more;   // hi y, hi z, counts of children 0 and 1, counts of children 2 and 3
    uvec4 index;
};

// 2^(e - 127) for each biased exponent.
vec3 vkrt_wide_scales(uint exponents) {
    uvec3 e = (uvec3(exponents) >> uvec3(0u, 8u, 16u)) & 0xffu;
    return uintBitsToFloat(e << 23u);
}

// Child k's leaf size (0: an interior node or no child).
uint vkrt_wide_count(VkrtWideNode w, uint k) {
    uint word = k < 2u ? w.more.z : w.more.w;
    return (word >> (16u * (k & 1u))) & 0xffffu;
}

// Child k's decoded box.
void vkrt_wide_box(VkrtWideNode w, uint k, vec3 p, vec3 s, out vec3 bmin, out vec3 bmax) {
    uint sh = 8u * k;
    vec3 qlo = vec3((uvec3(w.planes.xyz) >> sh) & 0xffu);
    vec3 qhi = vec3((uvec3(w.planes.w, w.more.xy) >> sh) & 0xffu);
    bmin = p + qlo * s;
    bmax = p + qhi * s;
}

#endif
