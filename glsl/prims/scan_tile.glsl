// Tiles of the scan kernels. A tile is ROUNDS rounds of one 16-byte granule per invocation;
// in each round the workgroup reads a contiguous span (granule g = round * WG + invocation),
// so neighbouring invocations touch neighbouring bytes (coalesced on GPUs, contiguous SIMD
// loads on lavapipe).
//
// FLAGS=0: a granule is a uvec4 of four u32 elements.
// FLAGS=1: a granule is four words of four 0/1 byte flags each: 16 elements (Kolodzey's
//          uchar4 trick, here uchar16 per load).
// Full granules load as one uvec4 (binding `in4`); the granule straddling n loads word by
// word (binding `in1`, the same buffer) and masks what lies past n.
#ifndef VKRT_PRIMS_SCAN_TILE_GLSL
#define VKRT_PRIMS_SCAN_TILE_GLSL

#ifndef FLAGS
#define FLAGS 0
#endif

#if FLAGS
#define EPG 16u
#else
#define EPG 4u
#endif

layout(constant_id = 1) const uint ROUNDS = 4;

uint tile_elements() {
    return gl_WorkGroupSize.x * ROUNDS * EPG;
}

// The four words of granule g, zero past n.
uvec4 load_granule_words(uint g, uint n) {
    if ((g + 1) * EPG <= n) {
        return in4[g];
    }
    uvec4 w = uvec4(0);
    for (uint k = 0; k < 4; k++) {
#if FLAGS
        uint first = g * EPG + 4 * k;
        if (first < n) {
            uint valid = min(n - first, 4u);
            uint mask = valid == 4 ? 0xffffffffu : ((1u << (8 * valid)) - 1);
            w[k] = in1[4 * g + k] & mask;
        }
#else
        uint e = g * EPG + k;
        if (e < n) {
            w[k] = in1[e];
        }
#endif
    }
    return w;
}

// Sum of the elements of a granule.
uint granule_sum(uvec4 w) {
#if FLAGS
    // Each byte is 0 or 1: multiplying by 0x01010101 gathers the byte sum in the top byte.
    return ((w.x * 0x01010101u) >> 24) + ((w.y * 0x01010101u) >> 24) + ((w.z * 0x01010101u) >> 24)
        + ((w.w * 0x01010101u) >> 24);
#else
    return w.x + w.y + w.z + w.w;
#endif
}

uint granule_element(uvec4 w, uint i) {
#if FLAGS
    return (w[i / 4] >> (8 * (i % 4))) & 0xffu;
#else
    return w[i];
#endif
}

#endif
