// Pairs of 32-bit words moved as one: declare an array as `WORD_PAIR name[]` and convert with
// pair_uints / pair_floats / floats_pair. With PAIRS64 (where the device has shaderInt64) a
// pair is one 64-bit component: on lavapipe every load or store at a lane-varying address
// is a loop over lanes and components, so a pair moves in half the trips. Without it a
// uvec2, the same bytes (std430: 8-byte stride either way).
#ifndef VKRT_COMMON_WORD_PAIR_GLSL
#define VKRT_COMMON_WORD_PAIR_GLSL

#ifndef PAIRS64
#define PAIRS64 0
#endif
#if PAIRS64
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#define WORD_PAIR uint64_t
uvec2 pair_uints(WORD_PAIR w) {
    return unpackUint2x32(w);
}
WORD_PAIR uints_pair(uvec2 v) {
    return packUint2x32(v);
}
#else
#define WORD_PAIR uvec2
uvec2 pair_uints(WORD_PAIR w) {
    return w;
}
WORD_PAIR uints_pair(uvec2 v) {
    return v;
}
#endif
vec2 pair_floats(WORD_PAIR w) {
    return uintBitsToFloat(pair_uints(w));
}
WORD_PAIR floats_pair(vec2 v) {
    return uints_pair(floatBitsToUint(v));
}

#endif
