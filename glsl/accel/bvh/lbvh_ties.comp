#version 460
// LBVH, 63-bit codes: after the stable sort by the high words, sorts every run of equal high
// words by its low words (stable), so the ids end in the order of a stable sort of the whole
// codes (CPU twin: the stable sort in lbvh::build). A run of at most MAX_RUN ids is sorted in
// place by its first invocation, by insertion; its ids came from one stable sort of the
// primitive order, so equal whole codes keep that order. A longer run is left alone and opens
// the gate: the fallback's three indirect grids (`args`: its gathers', its sorts' tile
// kernels' and copy's) and the length of its count tables' scans go from zero to those of the
// whole sort by both words, which then runs in their place. On a mesh few runs are longer
// than one id (the high word holds 2^31 cells), so the gate stays shut and the sort costs the
// high word's passes.
layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint MAX_RUN = 32u;
#include "common/grid.glsl"

layout(std430, binding = 0) buffer Ids { uint ids[]; };
// The high words in the ids' order (the sort's keys).
layout(std430, binding = 1) readonly buffer Hi { uint hi[]; };
// The low words in primitive order.
layout(std430, binding = 2) readonly buffer Lo { uint lo[]; };
layout(std430, binding = 3) buffer Gate { uint gate[]; };
layout(push_constant) uniform Push { uint n; uint args[10]; } pc;

void main() {
    uint i = linear_invocation_id();
    if (i >= pc.n) {
        return;
    }
    uint h = hi[i];
    if (i > 0u && hi[i - 1u] == h) {
        return; // inside a run: its first invocation sorts it
    }
    uint end = i + 1u;
    while (end < pc.n && end - i <= MAX_RUN && hi[end] == h) {
        end++;
    }
    uint len = end - i;
    if (len == 1u) {
        return;
    }
    if (len > MAX_RUN) {
        for (uint k = 0u; k < 10u; k++) {
            atomicMax(gate[k], pc.args[k]);
        }
        return;
    }
    // Insertion in place: the run's ids are this invocation's alone.
    for (uint k = i + 1u; k < end; k++) {
        uint p = ids[k];
        uint c = lo[p];
        uint j = k;
        // Strictly greater moves right: equal low words keep their order.
        while (j > i && lo[ids[j - 1u]] > c) {
            ids[j] = ids[j - 1u];
            j--;
        }
        ids[j] = p;
    }
}
