// Element counts that live on the GPU. A kernel dispatched for a host-side capacity reads
// the real count from a buffer, so a whole multi-pass build records without read-backs:
//   n = count_div == 0 ? capacity : min(capacity, ceil(counts[count_index] * count_mul / count_div))
// (ceil(ceil(c / a) / b) == ceil(c / (a * b)), so scan levels divide by the tile product).
#ifndef VKRT_COMMON_GPU_COUNT_GLSL
#define VKRT_COMMON_GPU_COUNT_GLSL

uint gpu_count(uint capacity, uint stored, uint mul, uint div) {
    if (div == 0u) {
        return capacity;
    }
    return min(capacity, (stored * mul + div - 1u) / div);
}

#endif
