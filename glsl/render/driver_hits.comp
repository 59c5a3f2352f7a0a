#version 460
// The driver's own two levels (src/render/gpu/levels.rs): its ray query names a hit by an id
// that numbers every instance's primitives one after another (`InstancedIds`). This maps the
// extend pass's hits, in place, to the primitive in the instance's bottom level and writes
// the instance, as `render.instances` does for vkrt's levels, for `render.shade.levels`.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "render/common.glsl"

// 16 bytes: extend.comp's `VkrtWalkHit`.
struct PathHit {
    float t;
    uint prim;
    float u;
    float v;
};

layout(std430, binding = 0) buffer Hits { PathHit hits[]; };
layout(std430, binding = 1) readonly buffer Counters { uint counters[]; };
// Per vkrt instance, by first id: (first id, primitives, instance index, 0).
layout(std430, binding = 2) readonly buffer Starts { uvec4 starts[]; };
layout(std430, binding = 3) writeonly buffer HitInstance { uint hit_instance[]; };
layout(push_constant) uniform Push { uint n_starts; };

void main() {
    uint i = linear_invocation_id();
    if (i >= counters[CNT_QUEUE]) {
        return;
    }
    uint id = hits[i].prim;
    if (id == 0xffffffffu) {
        return;
    }
    // The last instance whose first id is at most `id` (`InstancedIds::instance_primitive`).
    uint lo = 0u;
    uint hi = n_starts;
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        if (starts[mid].x <= id) {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    uvec4 s = lo > 0u ? starts[lo - 1u] : uvec4(0u);
    if (lo == 0u || id - s.x >= s.y) {
        hits[i] = PathHit(uintBitsToFloat(0x7f800000u), 0xffffffffu, 0.0, 0.0);
        return;
    }
    hits[i].prim = id - s.x;
    hit_instance[i] = s.z;
}
