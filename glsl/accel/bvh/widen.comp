#version 460
// The 4-wide BVH from the binary one (CPU twin: src/accel/bvh/wide.rs, bit for bit): wide
// node i is binary node i with each interior child replaced by its two children, child
// boxes quantized in a power-of-two frame (include/vkrt/bvh_wide_node.glsl). One invocation
// per binary slot, no order among them: every slot gets its wide node, and the walk reaches
// those at even depth. Children past `n_slots` (stale links of slots a leaf collapse freed)
// count as missing.
layout(local_size_x_id = 0) in;
#include "common/grid.glsl"
#include "include/vkrt/bvh_node.glsl"
#include "include/vkrt/bvh_wide_node.glsl"

layout(std430, binding = 0) readonly buffer Nodes { VkrtBvhNode nodes[]; };
layout(std430, binding = 1) writeonly buffer Wide { VkrtWideNode wide[]; };
layout(push_constant) uniform Push { uint n_slots; } pc;

// Up to four children: box, index, count (count 0 and VKRT_NO_NODE: none).
vec3 c_min[4];
vec3 c_max[4];
uint c_index[4];
uint c_count[4];
uint n_children = 0u;

void add(vec3 bmin, vec3 bmax, uint index, uint count) {
    c_min[n_children] = bmin;
    c_max[n_children] = bmax;
    c_index[n_children] = index;
    c_count[n_children] = count;
    n_children++;
}

bool stale(uint index, uint count) {
    return count == 0u && index != VKRT_NO_NODE && index >= pc.n_slots;
}

void add_child(vec3 bmin, vec3 bmax, uint index, uint count) {
    if (count > 0u) {
        add(bmin, bmax, index, count);
    } else if (index != VKRT_NO_NODE && !stale(index, count)) {
        VkrtBvhNode c = nodes[index];
        if ((c.a_count > 0u || c.a_index != VKRT_NO_NODE) && !stale(c.a_index, c.a_count)) {
            add(c.a_min, c.a_max, c.a_index, c.a_count);
        }
        if ((c.b_count > 0u || c.b_index != VKRT_NO_NODE) && !stale(c.b_index, c.b_count)) {
            add(c.b_min, c.b_max, c.b_index, c.b_count);
        }
    }
}

float decode(float p, float s, uint q) {
    precise float v = p + float(q) * s;
    return v;
}

float scale_of(uint e) {
    return uintBitsToFloat(e << 23u);
}

// Origin and biased exponent of an axis spanning [lo, hi] (wide.rs `frame`).
void frame(float lo, float hi, out float p, out uint e) {
    if (!(lo <= hi) || isinf(lo) || isnan(lo)) {
        p = 0.0;
        e = 1u;
        return;
    }
    precise float extent = hi - lo;
    int biased = int((floatBitsToUint(extent) >> 23u) & 0xffu) - 7;
    e = uint(max(biased, 1));
    while (e < 254u && decode(lo, scale_of(e), 255u) < hi) {
        e++;
    }
    p = lo;
}

uint first_guess(float f) {
    return f >= 0.0 ? uint(min(f, 255.0)) : 0u;
}

uint quantize_lo(float p, float s, float inv_s, float v) {
    precise float x = (v - p) * inv_s;
    uint q = first_guess(floor(x));
    while (q > 0u && decode(p, s, q) > v) {
        q--;
    }
    return q;
}

uint quantize_hi(float p, float s, float inv_s, float v) {
    precise float x = (v - p) * inv_s;
    uint q = first_guess(ceil(x));
    while (q < 255u && decode(p, s, q) < v) {
        q++;
    }
    return q;
}

void main() {
    uint i = linear_invocation_id();
    if (i >= pc.n_slots) {
        return;
    }
    VkrtBvhNode nd = nodes[i];
    add_child(nd.a_min, nd.a_max, nd.a_index, nd.a_count);
    add_child(nd.b_min, nd.b_max, nd.b_index, nd.b_count);
    vec3 lo = vec3(1.0 / 0.0);
    vec3 hi = vec3(-1.0 / 0.0);
    for (uint k = 0u; k < n_children; k++) {
        lo = vkrt_vmin(lo, c_min[k]);
        hi = vkrt_vmax(hi, c_max[k]);
    }
    VkrtWideNode w;
    w.frame = uvec4(0u);
    w.planes = uvec4(0u);
    w.more = uvec4(0u);
    w.index = uvec4(VKRT_NO_NODE);
    uvec3 qlo = uvec3(0u);
    uvec3 qhi = uvec3(0u);
    for (uint a = 0u; a < 3u; a++) {
        float p;
        uint e;
        frame(lo[a], hi[a], p, e);
        float s = scale_of(e);
        float inv_s = scale_of(254u - e);
        w.frame[a] = floatBitsToUint(p);
        w.frame.w |= e << (8u * a);
        for (uint k = 0u; k < n_children; k++) {
            qlo[a] |= quantize_lo(p, s, inv_s, c_min[k][a]) << (8u * k);
            qhi[a] |= quantize_hi(p, s, inv_s, c_max[k][a]) << (8u * k);
        }
    }
    w.planes = uvec4(qlo, qhi.x);
    w.more.xy = qhi.yz;
    for (uint k = 0u; k < n_children; k++) {
        w.index[k] = c_index[k];
        uint count = c_count[k] & 0xffffu;
        if (k < 2u) {
            w.more.z |= count << (16u * k);
        } else {
            w.more.w |= count << (16u * (k - 2u));
        }
    }
    wide[i] = w;
}
