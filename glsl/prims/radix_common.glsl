// Shared by the radix sort kernels: the pass parameters, the digit of a key and the
// order-preserving f32 bit flip. Keep `Push` in sync with `PassPush` in
// src/prims/radix_sort.rs.
// Requires: local_size_x_id declared before inclusion.
#ifndef VKRT_PRIMS_RADIX_COMMON_GLSL
#define VKRT_PRIMS_RADIX_COMMON_GLSL

// Digit width of this RadixSort (bits per pass) and elements per tile, the block of the
// digit-major count table. TILE is a multiple of the scatter's workgroup size and of 4.
layout(constant_id = 1) const uint BITS = 8;
layout(constant_id = 2) const uint TILE = 4096;
const uint RADIX = 1u << BITS;

layout(push_constant) uniform Push {
    uint n;
    uint blocks; // tiles: ceil(n / TILE), the row length of the count table
    uint shift;  // lowest key bit of this pass's digit
    uint digits; // digit values this pass: 2^(bits of this pass), at most RADIX
    uint flags;  // FLIP_IN | UNFLIP_OUT
} pc;

// First pass of an f32 sort: keys arrive as f32 bits and are flipped as they are read.
const uint FLIP_IN = 1u;
// Last pass of an f32 sort: keys are flipped back to f32 bits as they are written.
const uint UNFLIP_OUT = 2u;

// f32 bits -> u32 whose unsigned order is the float order: negative floats flip every
// bit, positive ones only the sign bit (-0.0 sorts before +0.0; NaN-free input).
uint f32_to_ordered(uint bits) {
    return bits ^ (uint(int(bits) >> 31) | 0x80000000u);
}

uint ordered_to_f32(uint key) {
    return key ^ (uint(int(~key) >> 31) | 0x80000000u);
}

uint read_key(uint raw) {
    return (pc.flags & FLIP_IN) != 0 ? f32_to_ordered(raw) : raw;
}

uint written_key(uint key) {
    return (pc.flags & UNFLIP_OUT) != 0 ? ordered_to_f32(key) : key;
}

uint digit_of(uint key) {
    return (key >> pc.shift) & (pc.digits - 1);
}

#endif
