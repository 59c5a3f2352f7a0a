#version 460
// kd-tree, after the last level (one invocation): the scene constants the traversal reads
// (`SceneInfo`, src/accel/primitives.rs), written on the device so that nothing is read back
// between build and trace. A build that overflowed its capacity (or has no primitives)
// leaves an empty leaf at the root: the trace that follows in the same submission misses
// everything instead of walking a truncated tree, and the host, reading the build state
// afterwards, reports or retries it.
layout(local_size_x = 1) in;
#include "include/vkrt/kdtree.glsl"
#include "accel/kdtree/level.glsl"

layout(std430, binding = 0) readonly buffer State { uint state[]; };
layout(std430, binding = 1) readonly buffer MinX { float min_x[]; };
layout(std430, binding = 2) readonly buffer MinY { float min_y[]; };
layout(std430, binding = 3) readonly buffer MinZ { float min_z[]; };
layout(std430, binding = 4) readonly buffer MaxX { float max_x[]; };
layout(std430, binding = 5) readonly buffer MaxY { float max_y[]; };
layout(std430, binding = 6) readonly buffer MaxZ { float max_z[]; };
layout(std430, binding = 7) buffer Nodes { VkrtKdNode nodes[]; };
layout(std430, binding = 8) writeonly buffer VkrtSceneInfoBinding {
    vec4 bounds_min;
    vec4 bounds_max;
    uint n_tris;
    uint n_spheres;
    uint has_motion;
    uint parents_at;
    uint walk;
    uint n_geometries;
    uint invalid;
    uint n_aabbs;
} info;
// What the host reads after the work (AccelStructure::kd_built): nodes, references, the
// overflow flag, references the overflowing level needed.
layout(std430, binding = 9) writeonly buffer Built { uint built[4]; };
layout(push_constant) uniform Push {
    uint n;
    uint n_tris;
    uint n_spheres;
    uint has_motion;
    uint n_aabbs;
} pc;

void main() {
    bool usable = pc.n > 0u && state[ST_OVERFLOW] == 0u;
    if (usable) {
        info.bounds_min = vec4(min_x[0], min_y[0], min_z[0], 0.0);
        info.bounds_max = vec4(max_x[0], max_y[0], max_z[0], 0.0);
    } else {
        // TraceGeometry::info of an empty box.
        info.bounds_min = vec4(0.0);
        info.bounds_max = vec4(0.0);
        nodes[0] = VkrtKdNode(0.0, VKRT_KD_LEAF, 0u, 0u);
    }
    built[0] = usable ? state[ST_NODE_BASE] : 1u;
    built[1] = usable ? state[ST_REF_BASE] : 0u;
    built[2] = pc.n > 0u ? state[ST_OVERFLOW] : 0u;
    built[3] = pc.n > 0u ? state[ST_NEED_REFS] : 0u;
    info.n_tris = pc.n_tris;
    info.n_spheres = pc.n_spheres;
    info.has_motion = pc.has_motion;
    info.parents_at = 0u;
    info.n_aabbs = pc.n_aabbs;
}
