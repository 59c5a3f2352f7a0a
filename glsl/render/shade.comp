#version 460
// Shading of every live ray's hit: an area light in front of it (seen as its radiance), or
// the surface's emission and ambient (or its occlusion queries), one
// occlusion query per light (point and directional: hard; sphere and quad: one area sample
// per path vertex, soft over the samples of a pixel), Lambert + Phong, and the children —
// mirror or glossy reflection and refraction with Fresnel — into two slots per ray with 0/1
// flags for the compaction. Every effect is a specialization constant the plan sets, so a
// scene compiles only what it uses.
// `levels`: the scene traced as two levels (src/render/gpu/levels.rs). A hit names its
// instance (`hit_instance`) and the primitive in that instance's bottom level; the surface is
// the bottom level's triangle (object space, read where the bottom level holds it) placed by
// the instance, its shading normals (where its bottom level has some) moved by the inverse
// transpose, its material the instance's (or the primitive's). A moving instance is placed by
// its steps interpolated at the ray's time, as the walk placed it.
//! variant flat
//! variant levels LEVELS=1
#extension GL_EXT_shader_8bit_storage : require
#extension GL_EXT_shader_explicit_arithmetic_types_int8 : require
layout(local_size_x_id = 0) in;
layout(constant_id = 1) const uint VKRT_INTERSECTOR = 0u;
layout(constant_id = 2) const bool VKRT_ANY_HIT = false;
layout(constant_id = 3) const uint VKRT_KD_STACK = 1u;
layout(constant_id = 4) const bool LIGHTS = false;
layout(constant_id = 5) const bool AREA_LIGHTS = false;
layout(constant_id = 6) const bool REFLECTION = false;
layout(constant_id = 7) const bool REFRACTION = false;
layout(constant_id = 8) const bool GLOSSY = false;
layout(constant_id = 9) const bool AO = false;
layout(constant_id = 10) const bool EMISSION = false;
layout(constant_id = 11) const bool BOUNCES = false;
#include "common/grid.glsl"
#include "render/common.glsl"
#include "render/shading.glsl"
#if LEVELS
#include "include/vkrt/ray.glsl"
#include "include/vkrt/affine.glsl"
// 128 bytes: `Placement` in src/render/types.rs.
struct Placement {
    vec4 object_to_world[3];   // rows
    vec4 world_to_object[3];   // rows
    uvec4 info;                // bottom level, its triangles, 0, material
    uvec4 motion;              // steps (1: still), first step, first step's time, scale
};
struct Rows {
    vec4 rows[3];
};
#define PER_PRIMITIVE 0xffffffffu
// The per-primitive arrays are read at device addresses: a scene in pieces may hold more
// primitives than one storage binding reaches (maxStorageBufferRange), as its walk does.
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer LevelFloats { float v[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer LevelVec4s { vec4 v[]; };
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer LevelUints { uint v[]; };
// 32 bytes: `BottomShading` in src/render/types.rs. Where one bottom level's arrays lie: its
// triangles' object-space vertices (9 floats each) and its vkrt_spheres (centre, radius), the
// bottom level's own; its triangles' shading normals (9 floats each; 0: none) and its
// primitives' materials (its triangles then its vkrt_spheres; 0: the placement's).
struct BottomShading {
    uint64_t verts;
    uint64_t spheres;
    uint64_t normals;
    uint64_t materials;
};
layout(std430, binding = 5) readonly buffer Bottoms { BottomShading bottoms[]; };
layout(std430, binding = 7) readonly buffer Placements { Placement placements[]; };
layout(std430, binding = 8) readonly buffer HitInstance { uint hit_instance[]; };
// Per moving instance its steps' object-to-world rows.
layout(std430, binding = 9) readonly buffer Steps { Rows steps[]; };
#else
#define VKRT_GEOM_BINDING 3
#include "include/vkrt/traverse.glsl"
#endif

layout(std430, binding = 0) readonly buffer Queue { PathRay queue[]; };
layout(std430, binding = 1) readonly buffer Hits { VkrtWalkHit hits[]; };
layout(std430, binding = 2) buffer Counters { uint counters[]; };
layout(std430, binding = 10) readonly buffer Params { RenderParams prm; };
layout(std430, binding = 11) readonly buffer Materials { Material materials[]; };
layout(std430, binding = 12) readonly buffer Lights { Light lights[]; };
#if !LEVELS
layout(std430, binding = 13) readonly buffer PrimMaterial { uint prim_material[]; };
layout(std430, binding = 14) readonly buffer TriNormals { float tri_normals[]; };
#endif
layout(std430, binding = 15) writeonly buffer Radiance { vec4 radiance[]; };
layout(std430, binding = 16) writeonly buffer Shadows { ShadowRay shadows[]; };
layout(std430, binding = 17) writeonly buffer Children { PathRay children[]; };
layout(std430, binding = 18) writeonly buffer Flags { uint8_t flags[]; };

// tmax of unbounded rays (reflection, refraction, directional-light shadows): +inf.
#define FAR vkrt_positive_inf()

#if LEVELS
// Corner `corner` of triangle `tri` of an array of 9 floats per triangle.
vec3 corner_of(LevelFloats a, uint tri, uint corner) {
    uint k = 9u * tri + 3u * corner;
    return vec3(a.v[k], a.v[k + 1u], a.v[k + 2u]);
}

// The placement at `time`: a moving instance's steps around it interpolated (and inverted),
// as the two-level walk does.
Placement placement_at(Placement pl, float time) {
    if (pl.motion.x < 2u) {
        return pl;
    }
    float f;
    uint k = vkrt_motion_segment(time, uintBitsToFloat(pl.motion.z), uintBitsToFloat(pl.motion.w),
                                 pl.motion.x, f);
    uint first = pl.motion.y + k;
    pl.object_to_world = vkrt_lerp_rows(steps[first].rows, steps[first + 1u].rows, f);
    vkrt_invert_rows(pl.object_to_world, pl.world_to_object);
    return pl;
}

vec3 place_point(Placement pl, vec3 q) {
    return vec3(dot(pl.object_to_world[0].xyz, q) + pl.object_to_world[0].w,
                dot(pl.object_to_world[1].xyz, q) + pl.object_to_world[1].w,
                dot(pl.object_to_world[2].xyz, q) + pl.object_to_world[2].w);
}

// An object-space normal in the world (the inverse transpose), unit or zero.
vec3 place_normal(Placement pl, vec3 n) {
    vec3 w = n.x * pl.world_to_object[0].xyz + n.y * pl.world_to_object[1].xyz
        + n.z * pl.world_to_object[2].xyz;
    return dot(w, w) > 0.0 ? normalize(w) : vec3(0.0);
}
#else
vec3 normal_at(uint tri, uint corner) {
    uint k = 9u * tri + 3u * corner;
    return vec3(tri_normals[k], tri_normals[k + 1u], tri_normals[k + 2u]);
}

// Rotation part of a motion, for normals.
vec3 move_vector(vec3 n, uint prim, float time) {
    if (vkrt_scene_info.has_motion == 0u || vkrt_prim_motion[prim] == VKRT_NO_MOTION) {
        return n;
    }
    VkrtMotionRecord m = vkrt_motions[vkrt_prim_motion[prim]];
    float angle = m.velocity.w * time;
    if (angle == 0.0) {
        return n;
    }
    vec3 k = m.axis.xyz;
    float c = cos(angle);
    float s = sin(angle);
    return n * c + cross(k, n) * s + k * (dot(k, n) * (1.0 - c));
}
#endif

// The nearest area light the ray meets before `tmax` (and after `tmin`), with its emitted
// radiance: area lights are emitting shapes the camera and mirrors see, as in pbrt. A quad
// shows its front (edge_u × edge_v) side, a sphere every side. They are not in the traced
// structure, so shadow rays pass them. CPU twin: cpu::light_seen.
bool light_seen(vec3 o, vec3 d, float tmin, float tmax, out vec3 le) {
    le = vec3(0.0);
    float nearest = tmax;
    bool seen = false;
    for (uint li = 0u; li < prm.n_lights; li++) {
        Light lt = lights[li];
        float t = -1.0;
        if (lt.kind.x == LIGHT_QUAD) {
            vec3 n = cross(lt.u.xyz, lt.v.xyz);
            float dn = dot(d, n);
            if (dn < 0.0) {
                t = dot(lt.p.xyz - o, n) / dn;
                vec3 q = o + t * d - lt.p.xyz;
                float nn = dot(n, n);
                float a = dot(cross(q, lt.v.xyz), n) / nn;
                float b = dot(cross(lt.u.xyz, q), n) / nn;
                if (!(a >= 0.0 && a <= 1.0 && b >= 0.0 && b <= 1.0)) {
                    t = -1.0;
                }
            }
        } else if (lt.kind.x == LIGHT_SPHERE) {
            vec3 oc = o - lt.p.xyz;
            float r = lt.u.w;
            float qa = dot(d, d);
            float qb = dot(oc, d);
            float disc = qb * qb - qa * (dot(oc, oc) - r * r);
            if (disc >= 0.0) {
                float s = sqrt(disc);
                t = (-qb - s) / qa;
                if (!(t > tmin)) {
                    t = (-qb + s) / qa;
                }
            }
        }
        if (t > tmin && t < nearest) {
            nearest = t;
            le = lt.power.xyz;
            seen = true;
        }
    }
    return seen;
}

void main() {
    uint i = linear_invocation_id();
    if (i >= counters[CNT_QUEUE]) {
        return;
    }
    PathRay p = queue[i];
    VkrtWalkHit h = hits[i];
    uint slots = prm.shadow_slots;
    for (uint k = 0u; k < slots; k++) {
        shadows[i * slots + k].kind = SHADOW_NONE;
    }
    // Glossy rays leave the lights to the Phong term of light sampling (no double count).
    vec3 le;
    if (AREA_LIGHTS && p.kind != RAY_GLOSSY
        && light_seen(p.o, p.d, p.tmin, h.prim == VKRT_NO_HIT ? p.tmax : h.t, le)) {
        radiance[i] = vec4(p.weight * le, 0.0);
        return;
    }
    if (h.prim == VKRT_NO_HIT) {
        radiance[i] = vec4(p.weight * prm.background.xyz, 0.0);
        return;
    }

    // The surface: position from the primitive (more accurate than o + t·d), normals.
    vec3 x;
    vec3 ng;
    vec3 ns;
#if LEVELS
    Placement pl = placement_at(placements[hit_instance[i]], p.time);
    BottomShading bottom = bottoms[pl.info.x];
    if (h.prim < pl.info.y) {
        LevelFloats verts = LevelFloats(bottom.verts);
        vec3 p0 = place_point(pl, corner_of(verts, h.prim, 0u));
        vec3 p1 = place_point(pl, corner_of(verts, h.prim, 1u));
        vec3 p2 = place_point(pl, corner_of(verts, h.prim, 2u));
        float w = 1.0 - h.u - h.v;
        x = w * p0 + h.u * p1 + h.v * p2;
        ng = normalize(cross(p1 - p0, p2 - p0));
        ns = ng;
        if (bottom.normals != 0ul) {
            LevelFloats normals = LevelFloats(bottom.normals);
            vec3 n = w * place_normal(pl, corner_of(normals, h.prim, 0u))
                + h.u * place_normal(pl, corner_of(normals, h.prim, 1u))
                + h.v * place_normal(pl, corner_of(normals, h.prim, 2u));
            ns = dot(n, n) > 0.0 ? normalize(n) : ng;
        }
    } else {
        vec4 s = LevelVec4s(bottom.spheres).v[h.prim - pl.info.y];
        vec3 c = place_point(pl, s.xyz);
        ng = normalize(p.o + h.t * p.d - c);
        x = c + ng * s.w;
        ns = ng;
    }
    uint material = pl.info.w != PER_PRIMITIVE ? pl.info.w
                                               : LevelUints(bottom.materials).v[h.prim];
#else
    if (h.prim < vkrt_scene_info.n_tris) {
        vec3 p0, p1, p2;
        vkrt_triangle_at(h.prim, p.time, p0, p1, p2);
        float w = 1.0 - h.u - h.v;
        x = w * p0 + h.u * p1 + h.v * p2;
        ng = normalize(cross(p1 - p0, p2 - p0));
        vec3 n = w * normal_at(h.prim, 0u) + h.u * normal_at(h.prim, 1u)
            + h.v * normal_at(h.prim, 2u);
        ns = dot(n, n) > 0.0 ? normalize(move_vector(n, h.prim, p.time)) : ng;
    } else if (h.prim - vkrt_scene_info.n_tris < vkrt_scene_info.n_spheres) {
        vec4 s = vkrt_sphere_at(h.prim - vkrt_scene_info.n_tris, p.time);
        ng = normalize(p.o + h.t * p.d - s.xyz);
        x = s.xyz + ng * s.w;
        ns = ng;
    } else {
        vec3 lo, hi;
        vkrt_aabb_at(h.prim - vkrt_scene_info.n_tris - vkrt_scene_info.n_spheres, lo, hi);
        x = p.o + h.t * p.d;
        ng = vkrt_aabb_normal(lo, hi, x);
        ns = ng;
    }
    uint material = prim_material[h.prim];
#endif
    bool front = dot(p.d, ng) < 0.0;
    if (!front) {
        ng = -ng;
        ns = -ns;
    }
    if (dot(ns, p.d) >= 0.0) {
        ns = ng; // an interpolated normal facing away from the viewer: use the true one
    }
    Material m = materials[material];
    vec3 diffuse = m.diffuse.xyz;
    vec3 l = vec3(0.0);
    if (EMISSION) {
        l += m.emission.xyz;
    }
    bool ao = AO && prm.ao_samples > 0u;
    if (!ao) {
        l += prm.ambient.xyz * diffuse;
    }
    radiance[i] = vec4(p.weight * l, 0.0);

    uint rng = pcg(p.seed ^ 0xA511E9B3u);
    vec3 o_front = vkrt_offset_ray_origin(x, ng);
    if (LIGHTS) {
        for (uint li = 0u; li < prm.n_lights; li++) {
            Light lt = lights[li];
            vec3 wi;
            float dist;
            vec3 e;
            uint kind = lt.kind.x;
            if (kind == LIGHT_DIRECTIONAL) {
                wi = -normalize(lt.p.xyz);
                dist = FAR;
                e = lt.power.xyz;
            } else if (kind == LIGHT_POINT || !AREA_LIGHTS) {
                vec3 to = lt.p.xyz - x;
                dist = length(to);
                wi = to / dist;
                e = lt.power.xyz / (dist * dist);
            } else {
                vec3 q;
                vec3 nl;
                float area;
                if (kind == LIGHT_QUAD) {
                    float r1 = rnd(rng);
                    float r2 = rnd(rng);
                    q = lt.p.xyz + r1 * lt.u.xyz + r2 * lt.v.xyz;
                    vec3 c = cross(lt.u.xyz, lt.v.xyz);
                    area = length(c);
                    nl = c / area;
                } else {
                    // the hemisphere facing the point (pdf 1 / (2πr²))
                    nl = sample_sphere(rng);
                    if (dot(nl, x - lt.p.xyz) < 0.0) {
                        nl = -nl;
                    }
                    q = lt.p.xyz + nl * lt.u.w;
                    area = 2.0 * PI * lt.u.w * lt.u.w;
                }
                vec3 to = q - x;
                dist = length(to);
                wi = to / dist;
                float cos_l = -dot(nl, wi);
                e = cos_l > 0.0 ? lt.power.xyz * (cos_l * area / (dist * dist)) : vec3(0.0);
            }
            float cos_s = dot(ns, wi);
            uint slot = i * slots + li;
            if (cos_s <= 0.0 || dot(ng, wi) <= 0.0 || max(e.x, max(e.y, e.z)) <= 0.0) {
                continue;
            }
            vec3 f = diffuse * cos_s;
            if (m.specular.x + m.specular.y + m.specular.z > 0.0) {
                float rv = max(dot(reflect_dir(-wi, ns), -p.d), 0.0);
                f += m.specular.xyz * pow(rv, m.diffuse.w);
            }
            shadows[slot] = ShadowRay(o_front, 0.0, wi, dist, p.weight * f * e, SHADOW_LIGHT);
        }
    }
    if (ao) {
        vec3 c = p.weight * prm.ambient.xyz * diffuse / float(prm.ao_samples);
        for (uint k = 0u; k < prm.ao_samples; k++) {
            vec3 dir = sample_cosine(ng, rng);
            shadows[i * slots + prm.n_lights + k] =
                ShadowRay(o_front, 0.0, dir, prm.ao_radius, c, SHADOW_AO);
        }
    }

    if (!BOUNCES || p.depth >= prm.max_depth) {
        return;
    }
    vec3 refl_w = m.mirror.xyz;
    float trans = m.mirror.w;
    vec3 tdir = vec3(0.0);
    bool refracts = false;
    if (REFRACTION && trans > 0.0) {
        float eta = front ? 1.0 / m.emission.w : m.emission.w;
        float cos_i = -dot(p.d, ns);
        refracts = refract_dir(p.d, ns, eta, tdir) && dot(tdir, ng) < 0.0;
        float fr = refracts ? (m.flags.x != 0u ? fresnel(cos_i, eta) : 0.0) : 1.0;
        refl_w += vec3(trans * fr);
        trans = trans * (1.0 - fr);
    }
    vec3 rw = p.weight * refl_w;
    if ((REFLECTION || GLOSSY) && max(rw.x, max(rw.y, rw.z)) > prm.min_weight) {
        vec3 r = reflect_dir(p.d, ns);
        if (dot(r, ng) <= 0.0) {
            r = reflect_dir(p.d, ng);
        }
        uint kind = RAY_REFLECTION;
        if (GLOSSY && m.specular.w > 0.0) {
            vec3 g = sample_cone(r, m.specular.w, rng);
            r = dot(g, ng) > 0.0 ? g : r;
            kind = RAY_GLOSSY;
        }
        children[2u * i] = PathRay(o_front, 0.0, r, FAR, rw, p.pixel, p.time, p.depth + 1u,
                                   pcg(p.seed ^ 0x1B873593u), kind);
        flags[2u * i] = uint8_t(1u);
        atomicAdd(counters[kind == RAY_GLOSSY ? CNT_GLOSSY : CNT_REFLECTION], 1u);
    }
    vec3 tw = p.weight * trans;
    if (REFRACTION && refracts && max(tw.x, max(tw.y, tw.z)) > prm.min_weight) {
        vec3 t = tdir;
        if (GLOSSY && m.specular.w > 0.0) {
            vec3 g = sample_cone(t, m.specular.w, rng);
            t = dot(g, ng) < 0.0 ? g : t;
        }
        children[2u * i + 1u] = PathRay(vkrt_offset_ray_origin(x, -ng), 0.0, t, FAR, tw, p.pixel,
                                        p.time, p.depth + 1u, pcg(p.seed ^ 0xCC9E2D51u),
                                        RAY_REFRACTION);
        flags[2u * i + 1u] = uint8_t(1u);
        atomicAdd(counters[CNT_REFRACTION], 1u);
    }
}
