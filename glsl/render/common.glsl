// The renderer's shared records, byte for byte the Rust ones in src/render/gpu_types.rs
// (keep in sync), and its random numbers (the CPU twin in src/render/cpu.rs draws the same).
#ifndef VKRT_RENDER_COMMON_GLSL
#define VKRT_RENDER_COMMON_GLSL

// A ray of the wavefront queue: 64 bytes.
struct PathRay {
    vec3 o;
    float tmin;
    vec3 d;
    float tmax;
    vec3 weight;   // throughput: what the radiance arriving along this ray is multiplied by
    uint pixel;
    float time;
    uint depth;    // 0 = camera ray
    uint seed;     // random stream of this path
    uint kind;     // RAY_* (for the per-pass ray counters)
};

// An occlusion query with the radiance it adds when unoccluded: 48 bytes.
struct ShadowRay {
    vec3 o;
    float tmin;
    vec3 d;
    float tmax;
    vec3 contrib;
    uint kind;     // SHADOW_NONE, SHADOW_LIGHT or SHADOW_AO
};

// 80 bytes: `GpuMaterial`.
struct Material {
    vec4 diffuse;      // w: shininess
    vec4 specular;     // w: roughness
    vec4 mirror;       // w: transmission
    vec4 emission;     // w: ior
    uvec4 flags;       // x: fresnel
};

// 80 bytes: `GpuLight`.
struct Light {
    uvec4 kind;        // x: LIGHT_*
    vec4 p;            // point / sphere centre / quad corner / direction of travel
    vec4 u;            // quad edge_u; sphere: w = radius
    vec4 v;            // quad edge_v
    vec4 power;        // colour * intensity
};

// 160 bytes: `RenderParams`.
struct RenderParams {
    vec4 cam_pos;
    vec4 cam_forward;
    vec4 cam_right;      // scaled by tan(fov / 2) * aspect
    vec4 cam_up;         // scaled by tan(fov / 2)
    vec4 background;
    vec4 ambient;
    uint width;
    uint height;
    uint spp;
    uint max_depth;
    uint n_lights;
    uint ao_samples;
    uint shadow_slots;   // occlusion queries per path vertex: n_lights + ao_samples
    uint jitter;
    float aperture;
    float focus_distance;
    float shutter_open;
    float shutter_close;
    float ao_radius;
    float min_weight;
    uint pad0;
    uint pad1;
};

#define RAY_PRIMARY 0u
#define RAY_REFLECTION 1u
#define RAY_REFRACTION 2u
#define RAY_GLOSSY 3u

#define SHADOW_NONE 0u
#define SHADOW_LIGHT 1u
#define SHADOW_AO 2u

#define LIGHT_POINT 0u
#define LIGHT_SPHERE 1u
#define LIGHT_QUAD 2u
#define LIGHT_DIRECTIONAL 3u

// Counter words (`counters` buffer, `Counter` in Rust).
#define CNT_QUEUE 0u          // live rays in the queue
#define CNT_PRIMARY 1u
#define CNT_REFLECTION 2u
#define CNT_REFRACTION 3u
#define CNT_GLOSSY 4u
#define CNT_SHADOW 5u
#define CNT_AO 6u
#define CNT_EXHAUSTED 7u
#define CNT_ARGS_QUEUE 8u     // 3 words: workgroups over the queue
#define CNT_ARGS_SHADOW 11u   // 3 words: workgroups over the queue's shadow slots
#define CNT_OVERFLOW 14u     // a wave's children outgrew the queue: redo the sample
#define CNT_WORDS 16u

// PCG hash (Jarzynski & Olano 2020).
uint pcg(uint v) {
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// Uniform in [0, 1): 24 bits.
float rnd(inout uint s) {
    s = pcg(s);
    return float(s >> 8u) * (1.0 / 16777216.0);
}

// Workgroups for `n` items, folded into 2-D like Recorder::groups_1d.
uvec3 fold_groups(uint n, uint wg) {
    uint g = (n + wg - 1u) / wg;
    if (g <= 65535u) {
        return uvec3(g, 1u, 1u);
    }
    uint y = (g + 65534u) / 65535u;
    return uvec3((g + y - 1u) / y, y, 1u);
}

#endif
