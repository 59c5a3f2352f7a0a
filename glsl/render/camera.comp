#version 460
// Camera rays for one wave (a tile of pixels, one sample each): pinhole or thin lens, pixel
// centre or jittered, shutter time or not — each only when the plan asks (spec constants).
// Under `--all-effects` every branch is compiled in and the data (aperture 0, no jitter, a
// closed shutter) keeps the image bit-identical.
layout(local_size_x_id = 0) in;
layout(constant_id = 1) const bool THIN_LENS = false;
layout(constant_id = 2) const bool JITTER = false;
layout(constant_id = 3) const bool MOTION = false;
#include "common/grid.glsl"
#include "render/common.glsl"

layout(std430, binding = 0) readonly buffer Params { RenderParams prm; };
layout(std430, binding = 1) writeonly buffer Queue { PathRay queue[]; };
layout(std430, binding = 2) buffer Counters { uint counters[]; };
layout(push_constant) uniform Push { uint first_pixel; uint pixels; uint sample_index; uint wg; } pc;

void main() {
    uint i = linear_invocation_id();
    if (i == 0u) {
        counters[CNT_QUEUE] = pc.pixels;
        uvec3 g = fold_groups(pc.pixels, pc.wg);
        counters[CNT_ARGS_QUEUE] = g.x;
        counters[CNT_ARGS_QUEUE + 1u] = g.y;
        counters[CNT_ARGS_QUEUE + 2u] = g.z;
        uvec3 s = fold_groups(pc.pixels * prm.shadow_slots, pc.wg);
        counters[CNT_ARGS_SHADOW] = s.x;
        counters[CNT_ARGS_SHADOW + 1u] = s.y;
        counters[CNT_ARGS_SHADOW + 2u] = s.z;
        atomicAdd(counters[CNT_PRIMARY], pc.pixels);
    }
    if (i >= pc.pixels) {
        return;
    }
    uint pixel = pc.first_pixel + i;
    uint seed = pcg(pixel ^ pcg(pc.sample_index * 0x9E3779B9u + 0x632BE5ABu));
    float jx = 0.5;
    float jy = 0.5;
    if (JITTER && prm.jitter != 0u) {
        jx = rnd(seed);
        jy = rnd(seed);
    }
    float x = float(pixel % prm.width) + jx;
    float y = float(pixel / prm.width) + jy;
    precise float sx = 2.0 * x / float(prm.width) - 1.0;
    precise float sy = 1.0 - 2.0 * y / float(prm.height);
    precise vec3 dir = prm.cam_forward.xyz + sx * prm.cam_right.xyz + sy * prm.cam_up.xyz;
    vec3 d = normalize(dir);
    vec3 o = prm.cam_pos.xyz;
    if (THIN_LENS && prm.aperture > 0.0) {
        // Concentric-free polar disk sample; the focus plane is perpendicular to forward.
        float r = prm.aperture * sqrt(rnd(seed));
        float phi = 6.28318530718 * rnd(seed);
        precise vec3 focus = o + d * (prm.focus_distance / dot(d, prm.cam_forward.xyz));
        vec3 right = normalize(prm.cam_right.xyz);
        vec3 up = normalize(prm.cam_up.xyz);
        precise vec3 lens = o + right * (r * cos(phi)) + up * (r * sin(phi));
        o = lens;
        d = normalize(focus - lens);
    }
    float time = prm.shutter_open;
    if (MOTION && prm.shutter_close > prm.shutter_open) {
        time = prm.shutter_open + rnd(seed) * (prm.shutter_close - prm.shutter_open);
    }
    // tmax = +inf: unbounded
    queue[i] = PathRay(o, 0.0, d, uintBitsToFloat(0x7f800000u), vec3(1.0), pixel, time, 0u,
                       seed, RAY_PRIMARY);
}
