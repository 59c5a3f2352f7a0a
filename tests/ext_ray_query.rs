//! A `GL_EXT_ray_query` shader through `vkrt/ext_ray_query.glsl`, on any device: its
//! answers against vkrt's own walk of the same two levels (`vkrtTrace`, bit for bit for
//! opaque closest hits) and against the CPU for what only the extension has — the
//! candidate loop, confirm, generate, terminate, ray flags, instance flags, facing, cull
//! masks, several queries in one invocation, a query passed to a function. Where the
//! driver has its own ray query, `tests/shader_check.rs` compares the two.

mod common;

use glam::{Affine3A, Vec3};
use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::embedded::BuildFlags;
use vkrt::accel::geometry::{Geometry, Triangles};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::instance::{flags, Instance};
use vkrt::accel::instances::{TopLevel, TopLevelBuilder};
use vkrt::accel::primitives::TraceGeometry;
use vkrt::accel::shader_library::STEPS_CONSTANT_ID;
use vkrt::gpu::{Buffer, BufferArg, Context, Recorder, ShaderBlob, Spec};
use vkrt::trace::Ray;

/// Compiles a compute shader with glslc against the library; the SPIR-V.
fn compile(source: &str, defines: &[&str]) -> Vec<u32> {
    common::compile_glsl(source, defines).unwrap_or_else(|e| panic!("{e}"))
}

/// The interface of `vkrt shader-check`: the structure at binding 0 (a texel buffer
/// holding its handle's address), rays at 1, results at 2, the ray count pushed.
const HEADER: &str = r#"#version 460
#extension GL_EXT_ray_query : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#include "vkrt/ext_ray_query.glsl"
layout(local_size_x = 64) in;
layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
layout(set = 0, binding = 1, std430) readonly buffer Rays { vec4 rays[]; };
layout(set = 0, binding = 2, std430) writeonly buffer Results { uvec4 results[]; };
layout(push_constant) uniform Count { uint rayCount; uint flags; uint cullMask; };
"#;

/// Runs `body` (the inside of `main` after `i`, `o`, `tmin`, `d`, `tmax` are read) over
/// `rays` through the structure whose handle lies at `handle`, with push constants
/// `flags` and `cull_mask`; its results.
fn run(
    ctx: &Context,
    body: &str,
    handle: u64,
    rays: &[Ray],
    ray_flags: u32,
    cull_mask: u32,
) -> Vec<[u32; 4]> {
    run_shader(ctx, "", body, handle, rays, ray_flags, cull_mask)
}

/// [`run`] with `functions` declared before `main`, flags 0 and every instance seen.
fn run_with_functions(
    ctx: &Context,
    functions: &str,
    body: &str,
    handle: u64,
    rays: &[Ray],
) -> Vec<[u32; 4]> {
    run_shader(ctx, functions, body, handle, rays, 0, 0xff)
}

fn run_shader(
    ctx: &Context,
    functions: &str,
    body: &str,
    handle: u64,
    rays: &[Ray],
    ray_flags: u32,
    cull_mask: u32,
) -> Vec<[u32; 4]> {
    let source = format!(
        "{HEADER}\n{functions}\nvoid main() {{\n    uint i = gl_GlobalInvocationID.x;\n    if (i >= rayCount) {{ return; }}\n    vec3 o = rays[2 * i].xyz;\n    float tmin = rays[2 * i].w;\n    vec3 d = rays[2 * i + 1].xyz;\n    float tmax = rays[2 * i + 1].w;\n{body}\n}}\n"
    );
    let spirv: &'static [u32] = Box::leak(compile(&source, &[]).into_boxed_slice());
    // Kernels are cached by name: one per source.
    let name: &'static str = Box::leak(
        format!("test.ext_ray_query.{:x}", {
            use std::hash::{Hash, Hasher};
            let mut h = std::collections::hash_map::DefaultHasher::new();
            source.hash(&mut h);
            h.finish()
        })
        .into_boxed_str(),
    );
    let blob: &'static ShaderBlob = Box::leak(Box::new(ShaderBlob {
        name,
        source: "tests/ext_ray_query.rs",
        defines: &[],
        bindings: &[0, 1, 2],
        texel_bindings: &[0],
        read_only_bindings: &[0, 1],
        write_only_bindings: &[2],
        spec_constants: &[(STEPS_CONSTANT_ID, 60000)],
        local_size: [64, 1, 1],
        local_size_spec_ids: [None; 3],
        push_constants: true,
        spirv,
    }));
    let kernel = ctx
        .kernel(
            blob,
            &Spec::new().u32(STEPS_CONSTANT_ID, ctx.info().max_traversal_steps),
        )
        .unwrap();
    let texel = Buffer::from_slice(
        ctx,
        "test.handle",
        &[[handle as u32, (handle >> 32) as u32, 0, 0]],
    )
    .unwrap();
    let ray_buf = Buffer::from_slice(ctx, "test.rays", rays).unwrap();
    let out = Buffer::<[u32; 4]>::zeroed(ctx, "test.results", rays.len().max(1)).unwrap();
    let push = [rays.len() as u32, ray_flags, cull_mask];
    let mut rec = Recorder::new(ctx).unwrap();
    let groups = rec.groups_1d(rays.len() as u64, 64);
    let b: [&dyn BufferArg; 3] = [&texel, &ray_buf, &out];
    rec.dispatch(&kernel, groups, &b, &push);
    rec.compute_to_transfer();
    rec.submit_and_wait().unwrap();
    out.download().unwrap()
}

/// vkrtTrace's closest hits through the same structure (`gpu.handle_probe`): t bits (all
/// ones for a miss), geometry, primitive, instance.
fn probe(ctx: &Context, handle: u64, rays: &[Ray], mode: u32) -> Vec<[u32; 4]> {
    common::probe_handle(ctx, handle, rays, mode, 0.0)
}

fn bottom(ctx: &Context, kind: AccelKind, tris: &[[Vec3; 3]]) -> GpuGeometry {
    let builder = AccelBuilder::new(ctx, kind).unwrap();
    let g = TraceGeometry::from_triangles(tris);
    let mut rec = Recorder::new(ctx).unwrap();
    let (out, _) = GpuGeometry::record_build(&mut rec, &builder, &g, 0).unwrap();
    rec.submit_and_wait().unwrap();
    out
}

fn sphere_tris(subdivisions: u32) -> Vec<[Vec3; 3]> {
    common::mesh_triangles(&vkrt::scene::gen::icosphere(subdivisions).unwrap())
}

fn centered(rng: &mut common::Rng) -> Vec3 {
    Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - Vec3::ONE
}

fn random_transform(rng: &mut common::Rng, spread: f32) -> Affine3A {
    let axis = centered(rng).normalize_or(Vec3::Y);
    Affine3A::from_scale_rotation_translation(
        Vec3::splat(0.5 + rng.next_f32()),
        glam::Quat::from_axis_angle(axis, rng.next_f32() * 6.0),
        centered(rng) * spread,
    )
}

/// An opaque closest-hit query, written the way a renderer writes one.
const CLOSEST: &str = r#"
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, flags, cullMask, o, tmin, d, tmax);
    while (rayQueryProceedEXT(q)) {
    }
    if (rayQueryGetIntersectionTypeEXT(q, true) == gl_RayQueryCommittedIntersectionTriangleEXT) {
        results[i] = uvec4(floatBitsToUint(rayQueryGetIntersectionTEXT(q, true)),
                           rayQueryGetIntersectionGeometryIndexEXT(q, true),
                           rayQueryGetIntersectionPrimitiveIndexEXT(q, true),
                           rayQueryGetIntersectionInstanceIdEXT(q, true));
    } else {
        results[i] = uvec4(0xffffffffu, 0u, 0u, vkrtRayQueryExhausted(q) ? 1u : 0u);
    }
"#;

/// Three meshes' bottom levels, 40 instances of them (custom index 1000 + i, mask bit
/// i % 8, flags `instance_flags(i)`), rays from afar at the instances.
fn scene(
    ctx: &Context,
    kind: AccelKind,
    instance_flags: impl Fn(usize) -> u8,
) -> (Vec<GpuGeometry>, Vec<Instance>, Vec<Ray>) {
    let mut rng = common::Rng(11);
    let meshes = [sphere_tris(2), sphere_tris(1), sphere_tris(3)];
    let levels: Vec<GpuGeometry> = meshes.iter().map(|m| bottom(ctx, kind, m)).collect();
    let instances: Vec<Instance> = (0..40)
        .map(|i| {
            Instance::new(
                (i % 3) as u32,
                Instance::rows_of(&random_transform(&mut rng, 12.0)),
            )
            .with_custom_index(1000 + i as u32)
            .with_mask(1 << (i % 8))
            .with_flags(instance_flags(i))
        })
        .collect();
    let rays: Vec<Ray> = (0..700)
        .map(|k| {
            let c = Vec3::from_array(instances[k % 40].transform.map(|r| r[3]));
            let o = centered(&mut rng).normalize_or(Vec3::X) * 30.0;
            let target = c + centered(&mut rng) * 0.7;
            match k % 7 {
                // bounded, and starting inside the scene
                5 => Ray::new(c + centered(&mut rng) * 0.3, target - o, 0.0, 2.0),
                6 => Ray::new(o, target - o, 0.5, f32::INFINITY),
                _ => Ray::new(o, target - o, 0.0, f32::INFINITY),
            }
        })
        .collect();
    (levels, instances, rays)
}

fn top(ctx: &Context, levels: &[GpuGeometry], instances: &[Instance]) -> TopLevel {
    let refs: Vec<&GpuGeometry> = levels.iter().collect();
    top_of(ctx, &refs, instances)
}

fn top_of(ctx: &Context, levels: &[&GpuGeometry], instances: &[Instance]) -> TopLevel {
    TopLevelBuilder::new(ctx, AccelKind::Lbvh)
        .unwrap()
        .build(ctx, levels, instances, &BuildFlags::default())
        .unwrap()
}

#[test]
fn opaque_closest_hits_equal_vkrt_trace_bit_for_bit() {
    let Some(ctx) = common::context() else { return };
    for kind in [AccelKind::Lbvh, AccelKind::Ploc, AccelKind::SahBvh] {
        let (levels, instances, rays) = scene(&ctx, kind, |_| 0);
        let top = top(&ctx, &levels, &instances);
        let handle = top.handle_address();
        let want = probe(&ctx, handle, &rays, 0);
        let got = run(&ctx, CLOSEST, handle, &rays, 0, 0xff);
        let hits = want.iter().filter(|h| h[0] != u32::MAX).count();
        assert!(hits > rays.len() / 4, "{kind:?}: {hits} hits");
        for (k, (g, w)) in got.iter().zip(&want).enumerate() {
            assert_eq!(g, w, "{kind:?}: ray {k}");
        }
    }
    common::assert_silent(&ctx);
}

/// The closest hit (t bits, instance, primitive, front face | committed type << 1) after a
/// candidate loop whose body is `on_candidate` (with `c` the candidate's type).
fn looped(on_candidate: &str) -> String {
    format!(
        r#"
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, flags, cullMask, o, tmin, d, tmax);
    uint candidates = 0u;
    while (rayQueryProceedEXT(q)) {{
        uint c = rayQueryGetIntersectionTypeEXT(q, false);
        candidates++;
        {on_candidate}
    }}
    uint type = rayQueryGetIntersectionTypeEXT(q, true);
    results[i] = type == gl_RayQueryCommittedIntersectionNoneEXT
        ? uvec4(0xffffffffu, candidates, 0u, vkrtRayQueryExhausted(q) ? 1u : 0u)
        : uvec4(floatBitsToUint(rayQueryGetIntersectionTEXT(q, true)),
                rayQueryGetIntersectionInstanceIdEXT(q, true),
                rayQueryGetIntersectionPrimitiveIndexEXT(q, true),
                (rayQueryGetIntersectionFrontFaceEXT(q, true) ? 1u : 0u) | (type << 1u)
                    | (candidates << 8u));
"#
    )
}

const NO_OPAQUE: u32 = 0x2;
const TERMINATE_ON_FIRST_HIT: u32 = 0x4;
const CULL_BACK: u32 = 0x10;
const CULL_FRONT: u32 = 0x20;
const CULL_NO_OPAQUE: u32 = 0x80;
const SKIP_TRIANGLES: u32 = 0x100;

/// (t bits, instance, primitive) of a result, `None` for a miss.
fn hit_of(r: &[u32; 4]) -> Option<[u32; 3]> {
    (r[0] != u32::MAX).then_some([r[0], r[1], r[2]])
}

#[test]
fn non_opaque_candidates_confirmed_give_the_opaque_answer() {
    let Some(ctx) = common::context() else { return };
    // Non-opaque three ways: the ray's flag, the instances' force-no-opaque, and (below)
    // the geometry's own flag.
    let (levels, instances, rays) = scene(&ctx, AccelKind::Lbvh, |i| {
        if i % 2 == 0 {
            flags::FORCE_NO_OPAQUE
        } else {
            0
        }
    });
    let top = top(&ctx, &levels, &instances);
    let handle = top.handle_address();
    let opaque = run(&ctx, &looped(""), handle, &rays, 0x1, 0xff);
    let confirm_all = looped("rayQueryConfirmIntersectionEXT(q);");
    for ray_flags in [0, NO_OPAQUE] {
        let got = run(&ctx, &confirm_all, handle, &rays, ray_flags, 0xff);
        let mut candidates = 0;
        for (k, (g, w)) in got.iter().zip(&opaque).enumerate() {
            assert_eq!(hit_of(g), hit_of(w), "flags {ray_flags:#x}, ray {k}");
            if g[0] != u32::MAX {
                assert_eq!((g[3] >> 1) & 0x7f, 1, "a confirmed triangle");
                candidates += g[3] >> 8;
            }
        }
        assert!(candidates > 0, "flags {ray_flags:#x}: no candidates came");
        // Ignoring every candidate leaves only the opaque instances' hits; culling the
        // non-opaque ones does the same without the loop.
        let ignored = run(&ctx, &looped(""), handle, &rays, ray_flags, 0xff);
        let culled = run(
            &ctx,
            &looped(""),
            handle,
            &rays,
            ray_flags | CULL_NO_OPAQUE,
            0xff,
        );
        for (k, (a, b)) in ignored.iter().zip(&culled).enumerate() {
            assert_eq!(hit_of(a), hit_of(b), "flags {ray_flags:#x}, ray {k}");
            if let Some([_, inst, _]) = hit_of(a) {
                assert!(ray_flags == 0 && inst % 2 == 1, "ray {k}: instance {inst}");
            }
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn an_alpha_test_equals_the_opaque_walk_of_what_it_keeps() {
    let Some(ctx) = common::context() else { return };
    let (levels, instances, rays) = scene(&ctx, AccelKind::Ploc, |_| flags::FORCE_NO_OPAQUE);
    let top_all = top(&ctx, &levels, &instances);
    let got = run(
        &ctx,
        &looped("if ((rayQueryGetIntersectionPrimitiveIndexEXT(q, false) & 1) == 0) { rayQueryConfirmIntersectionEXT(q); }"),
        top_all.handle_address(),
        &rays,
        0,
        0xff,
    );
    // The same instances of bottom levels holding the even triangles only.
    let meshes = [sphere_tris(2), sphere_tris(1), sphere_tris(3)];
    let even: Vec<GpuGeometry> = meshes
        .iter()
        .map(|m| {
            let kept: Vec<[Vec3; 3]> = m.iter().step_by(2).copied().collect();
            bottom(&ctx, AccelKind::Ploc, &kept)
        })
        .collect();
    let opaque: Vec<Instance> = instances.iter().map(|i| i.with_flags(0)).collect();
    let top_even = top(&ctx, &even, &opaque);
    let want = run(&ctx, &looped(""), top_even.handle_address(), &rays, 0, 0xff);
    let mut hits = 0;
    for (k, (g, w)) in got.iter().zip(&want).enumerate() {
        let w = hit_of(w).map(|[t, inst, p]| [t, inst, 2 * p]);
        assert_eq!(hit_of(g), w, "ray {k}");
        hits += w.is_some() as usize;
    }
    assert!(hits > rays.len() / 8, "{hits} hits");
    common::assert_silent(&ctx);
}

#[test]
fn facing_culls_as_the_instance_flags_say() {
    let Some(ctx) = common::context() else { return };
    let per_instance = [
        0,
        flags::TRIANGLE_FLIP_FACING,
        flags::TRIANGLE_FACING_CULL_DISABLE,
        flags::TRIANGLE_FLIP_FACING | flags::TRIANGLE_FACING_CULL_DISABLE,
    ];
    let (levels, instances, rays) = scene(&ctx, AccelKind::Lbvh, |i| per_instance[i % 4]);
    let top = top(&ctx, &levels, &instances);
    let handle = top.handle_address();
    let all = run(&ctx, &looped(""), handle, &rays, 0, 0xff);
    let (mut front, mut back) = (0, 0);
    for (cull, keeps_front) in [(CULL_BACK, true), (CULL_FRONT, false)] {
        let culled = run(&ctx, &looped(""), handle, &rays, cull, 0xff);
        for (k, (a, c)) in all.iter().zip(&culled).enumerate() {
            let Some([t, inst, _]) = hit_of(a) else {
                continue;
            };
            let is_front = a[3] & 1 == 1;
            let exempt =
                instances[inst as usize].flags() & flags::TRIANGLE_FACING_CULL_DISABLE != 0;
            if exempt || is_front == keeps_front {
                assert_eq!(hit_of(c), hit_of(a), "cull {cull:#x}, ray {k}");
            } else {
                // The nearest face is culled: the answer lies beyond it, or is a miss.
                assert!(
                    hit_of(c).is_none_or(|[tc, _, _]| f32::from_bits(tc) >= f32::from_bits(t)),
                    "cull {cull:#x}, ray {k}"
                );
                assert_ne!(hit_of(c), hit_of(a), "cull {cull:#x}, ray {k}");
            }
            if cull == CULL_BACK && k % 7 != 5 {
                // Flipping an instance turns what it shows the ray.
                let flipped = instances[inst as usize].flags() & flags::TRIANGLE_FLIP_FACING != 0;
                if is_front != flipped {
                    front += 1;
                } else {
                    back += 1;
                }
            }
        }
    }
    // Rays from outside the closed meshes (all but every seventh, which starts inside one)
    // meet their outsides first: one facing, unless the instance flips it.
    assert!(front > 10 * back.max(1), "{front} front, {back} back");
    common::assert_silent(&ctx);
}

#[test]
fn terminate_skip_and_cull_mask() {
    let Some(ctx) = common::context() else { return };
    let (levels, instances, rays) = scene(&ctx, AccelKind::Lbvh, |_| 0);
    let top = top(&ctx, &levels, &instances);
    let handle = top.handle_address();
    let closest = run(&ctx, &looped(""), handle, &rays, 0, 0xff);
    // Terminate on first hit: a hit exactly where there is one, never nearer than the
    // closest.
    let first = run(
        &ctx,
        &looped(""),
        handle,
        &rays,
        TERMINATE_ON_FIRST_HIT,
        0xff,
    );
    for (k, (f, c)) in first.iter().zip(&closest).enumerate() {
        assert_eq!(hit_of(f).is_some(), hit_of(c).is_some(), "ray {k}");
        if let (Some([tf, ..]), Some([tc, ..])) = (hit_of(f), hit_of(c)) {
            assert!(f32::from_bits(tf) >= f32::from_bits(tc), "ray {k}");
        }
    }
    // rayQueryTerminateEXT at the first candidate keeps what was committed before it.
    let terminated = run(
        &ctx,
        &looped("rayQueryConfirmIntersectionEXT(q); rayQueryTerminateEXT(q);"),
        handle,
        &rays,
        NO_OPAQUE,
        0xff,
    );
    for (k, (t, c)) in terminated.iter().zip(&closest).enumerate() {
        assert_eq!(hit_of(t).is_some(), hit_of(c).is_some(), "ray {k}");
        if t[0] != u32::MAX {
            assert_eq!(t[3] >> 8, 1, "ray {k}: one candidate, then the end");
        }
    }
    // Skipping triangles finds nothing in a scene of triangles; skipping boxes changes
    // nothing.
    let skipped = run(&ctx, &looped(""), handle, &rays, SKIP_TRIANGLES, 0xff);
    assert!(skipped.iter().all(|r| r[0] == u32::MAX));
    assert_eq!(run(&ctx, &looped(""), handle, &rays, 0x200, 0xff), closest);
    // The cull mask against each instance's mask (bit i % 8), as vkrtTrace's.
    for mask in [0xa5u32, 0x01, 0x00] {
        let got = run(&ctx, &looped(""), handle, &rays, 0, mask);
        let want = probe(&ctx, handle, &rays, (!mask & 0xff) << 8);
        for (k, (g, w)) in got.iter().zip(&want).enumerate() {
            assert_eq!(
                hit_of(g).map(|h| [h[0], h[1]]),
                (w[0] != u32::MAX).then_some([w[0], w[3]]),
                "mask {mask:#x}, ray {k}"
            );
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn getters_report_the_instance_as_given() {
    let Some(ctx) = common::context() else { return };
    let (levels, mut instances, rays) = scene(&ctx, AccelKind::Lbvh, |_| 0);
    for (i, inst) in instances.iter_mut().enumerate() {
        inst.sbt_offset_and_flags |= 7 * i as u32;
    }
    let top = top(&ctx, &levels, &instances);
    let handle = top.handle_address();
    let getters = r#"
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, flags, cullMask, o, tmin, d, tmax);
    while (rayQueryProceedEXT(q)) {
    }
    if (rayQueryGetIntersectionTypeEXT(q, true) == gl_RayQueryCommittedIntersectionNoneEXT) {
        results[i] = uvec4(0xffffffffu);
        return;
    }
    mat4x3 otw = rayQueryGetIntersectionObjectToWorldEXT(q, true);
    mat4x3 wto = rayQueryGetIntersectionWorldToObjectEXT(q, true);
    // The object ray moved back to the world is the world ray; the two matrices invert
    // each other; the object-to-world is the instance's, bit for bit (hashed).
    vec3 oo = rayQueryGetIntersectionObjectRayOriginEXT(q, true);
    vec3 od = rayQueryGetIntersectionObjectRayDirectionEXT(q, true);
    vec3 back_o = otw * vec4(oo, 1.0);
    vec3 back_d = otw * vec4(od, 0.0);
    mat3 id = mat3(otw) * mat3(wto);
    float err = max(length(back_o - o) / max(length(o), 1.0), length(back_d - d) / length(d));
    err = max(err, length(id[0] - vec3(1, 0, 0)) + length(id[1] - vec3(0, 1, 0)) + length(id[2] - vec3(0, 0, 1)));
    uint h = 0u;
    for (int c = 0; c < 4; c++) {
        for (int r = 0; r < 3; r++) {
            h = h * 31u + floatBitsToUint(otw[c][r]);
        }
    }
    bool same_ray = rayQueryGetWorldRayOriginEXT(q) == o && rayQueryGetWorldRayDirectionEXT(q) == d
        && rayQueryGetRayTMinEXT(q) == tmin && rayQueryGetRayFlagsEXT(q) == flags;
    results[i] = uvec4(rayQueryGetIntersectionInstanceCustomIndexEXT(q, true),
                       rayQueryGetIntersectionInstanceShaderBindingTableRecordOffsetEXT(q, true)
                           | (same_ray ? 0x80000000u : 0u),
                       h, floatBitsToUint(err));
"#;
    let got = run(&ctx, getters, handle, &rays, 0, 0xff);
    let closest = run(&ctx, &looped(""), handle, &rays, 0, 0xff);
    let mut hits = 0;
    for (k, (g, c)) in got.iter().zip(&closest).enumerate() {
        let Some([_, inst, _]) = hit_of(c) else {
            assert_eq!(g[0], u32::MAX, "ray {k}");
            continue;
        };
        hits += 1;
        let i = &instances[inst as usize];
        let mut h = 0u32;
        for c in 0..4 {
            for r in 0..3 {
                h = h.wrapping_mul(31).wrapping_add(i.transform[r][c].to_bits());
            }
        }
        assert_eq!(g[0], i.custom_index(), "ray {k}");
        assert_eq!(g[1], 0x8000_0000 | (7 * inst), "ray {k}");
        assert_eq!(g[2], h, "ray {k}: object-to-world");
        assert!(
            f32::from_bits(g[3]) < 1e-4,
            "ray {k}: error {}",
            f32::from_bits(g[3])
        );
    }
    assert!(hits > 100);
    common::assert_silent(&ctx);
}

#[test]
fn two_queries_in_one_invocation_and_a_query_passed_to_a_function() {
    let Some(ctx) = common::context() else { return };
    let (levels, instances, rays) = scene(&ctx, AccelKind::Lbvh, |i| {
        if i % 3 == 0 {
            flags::FORCE_NO_OPAQUE
        } else {
            0
        }
    });
    let top = top(&ctx, &levels, &instances);
    let handle = top.handle_address();
    // Two queries advanced in turn (a closest hit with an alpha test, a shadow query
    // through the opaque instances only), each helper advancing the caller's query.
    let body = r#"
    rayQueryEXT a;
    rayQueryEXT b;
    rayQueryInitializeEXT(a, scene, flags, cullMask, o, tmin, d, tmax);
    rayQueryInitializeEXT(b, scene, flags | gl_RayFlagsTerminateOnFirstHitEXT | gl_RayFlagsCullNoOpaqueEXT, cullMask, o, tmin, d, tmax);
    bool more_a = true;
    bool more_b = true;
    while (more_a || more_b) {
        if (more_a) {
            more_a = advance(a);
        }
        if (more_b) {
            more_b = rayQueryProceedEXT(b);
        }
    }
    results[i] = uvec4(rayQueryGetIntersectionTypeEXT(a, true) == 0u ? 0xffffffffu : floatBitsToUint(rayQueryGetIntersectionTEXT(a, true)),
                       rayQueryGetIntersectionInstanceIdEXT(a, true),
                       rayQueryGetIntersectionPrimitiveIndexEXT(a, true),
                       rayQueryGetIntersectionTypeEXT(b, true));
"#;
    let helper = r#"
bool advance(rayQueryEXT q) {
    bool more = rayQueryProceedEXT(q);
    if (more && (rayQueryGetIntersectionPrimitiveIndexEXT(q, false) % 3) != 1) {
        rayQueryConfirmIntersectionEXT(q);
    }
    return more;
}
"#;
    let got = run_with_functions(&ctx, helper, body, handle, &rays);
    let alone_a = run(
        &ctx,
        &looped("if ((rayQueryGetIntersectionPrimitiveIndexEXT(q, false) % 3) != 1) { rayQueryConfirmIntersectionEXT(q); }"),
        handle,
        &rays,
        0,
        0xff,
    );
    let alone_b = run(
        &ctx,
        &looped(""),
        handle,
        &rays,
        TERMINATE_ON_FIRST_HIT | CULL_NO_OPAQUE,
        0xff,
    );
    for (k, ((g, a), b)) in got.iter().zip(&alone_a).zip(&alone_b).enumerate() {
        assert_eq!(hit_of(g), hit_of(a), "ray {k}");
        assert_eq!(g[3], if b[0] == u32::MAX { 0 } else { 1 }, "ray {k}");
    }
    common::assert_silent(&ctx);
}

/// A bottom level over `tris` built from device buffers, its geometry `opaque` or not.
fn device_bottom(
    ctx: &Context,
    tris: &[[Vec3; 3]],
    opaque: bool,
) -> (GpuGeometry, Vec<Buffer<u8>>) {
    device_bottom_of(ctx, AccelKind::Lbvh, tris, opaque)
}

/// [`device_bottom`] of `kind`.
fn device_bottom_of(
    ctx: &Context,
    kind: AccelKind,
    tris: &[[Vec3; 3]],
    opaque: bool,
) -> (GpuGeometry, Vec<Buffer<u8>>) {
    let flat: Vec<Vec3> = tris.iter().flatten().copied().collect();
    let vertices =
        Buffer::<f32>::from_slice(ctx, "test.vertices", bytemuck::cast_slice(&flat)).unwrap();
    let geometries = [Geometry::Triangles(Triangles {
        opaque,
        ..Triangles::soup(unsafe { vertices.as_raw() }, flat.len() as u32)
    })];
    let builder = AccelBuilder::new(ctx, kind).unwrap();
    let flags = BuildFlags::default();
    let sizes = builder.sizes_for(ctx, &geometries, &flags).unwrap();
    let memory =
        Buffer::<u8>::arena(ctx, "test.structure", sizes.structure_bytes as usize).unwrap();
    let scratch =
        Buffer::<u8>::arena(ctx, "test.scratch", sizes.build_scratch_bytes as usize).unwrap();
    let mut g = builder
        .create_in(ctx, &geometries, &flags, unsafe { memory.as_raw() })
        .unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    builder
        .record_build_from(&mut rec, &mut g, &geometries, unsafe { scratch.as_raw() })
        .unwrap();
    rec.submit_and_wait().unwrap();
    // (the structure holds its own copy of the vertices: the caller's may go)
    drop(vertices);
    (g, vec![memory, scratch])
}

#[test]
fn a_non_opaque_geometry_returns_its_triangles_as_candidates() {
    let Some(ctx) = common::context() else { return };
    let (_, instances, rays) = scene(&ctx, AccelKind::Lbvh, |_| 0);
    let meshes = [sphere_tris(2), sphere_tris(1), sphere_tris(3)];
    // Bottom level 1 is non-opaque: its instances' hits come as candidates.
    let built: Vec<(GpuGeometry, Vec<Buffer<u8>>)> = meshes
        .iter()
        .enumerate()
        .map(|(k, m)| device_bottom(&ctx, m, k != 1))
        .collect();
    let levels: Vec<&GpuGeometry> = built.iter().map(|(g, _)| g).collect();
    let top = top_of(&ctx, &levels, &instances);
    let handle = top.handle_address();
    let opaque = run(&ctx, &looped(""), handle, &rays, 0x1, 0xff);
    let confirmed = run(&ctx, &looped("if (c == gl_RayQueryCandidateIntersectionTriangleEXT && !rayQueryGetIntersectionCandidateAABBOpaqueEXT(q)) { rayQueryConfirmIntersectionEXT(q); }"), handle, &rays, 0, 0xff);
    let ignored = run(&ctx, &looped(""), handle, &rays, 0, 0xff);
    let (mut from_candidates, mut skipped) = (0, 0);
    for (k, ((o, c), i)) in opaque.iter().zip(&confirmed).zip(&ignored).enumerate() {
        assert_eq!(hit_of(c), hit_of(o), "ray {k}");
        let Some([_, inst, _]) = hit_of(o) else {
            continue;
        };
        if instances[inst as usize].bottom == 1 {
            from_candidates += 1;
            assert!(c[3] >> 8 > 0, "ray {k}: its hit came as a candidate");
            // Ignored, the non-opaque hit is not committed.
            assert_ne!(hit_of(i), hit_of(o), "ray {k}");
            skipped += 1;
        } else {
            assert_eq!(hit_of(i), hit_of(o), "ray {k}");
        }
    }
    assert!(from_candidates > 10 && skipped > 10, "{from_candidates}");
    common::assert_silent(&ctx);
}

#[test]
fn procedural_spheres_by_generate_equal_vkrt_trace_s_spheres() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(5);
    let spheres: Vec<glam::Vec4> = (0..48)
        .map(|_| (centered(&mut rng) * 1.5).extend(0.4 + 0.5 * rng.next_f32()))
        .collect();
    let g = TraceGeometry::from_triangles_and_spheres(&[], &spheres);
    let builder = AccelBuilder::new(&ctx, AccelKind::Lbvh).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    let (level, _) = GpuGeometry::record_build(&mut rec, &builder, &g, 0).unwrap();
    rec.submit_and_wait().unwrap();
    let instances: Vec<Instance> = (0..12)
        .map(|i| {
            Instance::new(0, Instance::rows_of(&random_transform(&mut rng, 8.0)))
                .with_custom_index(i)
        })
        .collect();
    let rays: Vec<Ray> = (0..600)
        .map(|k| {
            let c = Vec3::from_array(instances[k % 12].transform.map(|r| r[3]));
            let o = centered(&mut rng).normalize_or(Vec3::X) * 25.0;
            Ray::new(o, c + centered(&mut rng) * 1.2 - o, 0.0, f32::INFINITY)
        })
        .collect();
    let levels = [level];
    let top = top(&ctx, &levels, &instances);
    let handle = top.handle_address();
    let list: Vec<String> = spheres
        .iter()
        .map(|s| format!("vec4({:?}, {:?}, {:?}, {:?})", s.x, s.y, s.z, s.w))
        .collect();
    let functions = format!(
        r#"
const vec4 SPHERES[{n}] = vec4[]({list});
// The sphere's nearer root in [tMin, the committed t], in object space.
void intersect(rayQueryEXT q) {{
    vec4 s = SPHERES[rayQueryGetIntersectionPrimitiveIndexEXT(q, false)];
    vec3 o = rayQueryGetIntersectionObjectRayOriginEXT(q, false) - s.xyz;
    vec3 d = rayQueryGetIntersectionObjectRayDirectionEXT(q, false);
    float a = dot(d, d);
    float b = dot(o, d);
    float c = dot(o, o) - s.w * s.w;
    float disc = b * b - a * c;
    if (disc < 0.0) {{
        return;
    }}
    float t0 = (-b - sqrt(disc)) / a;
    float t1 = (-b + sqrt(disc)) / a;
    float t = t0 >= rayQueryGetRayTMinEXT(q) ? t0 : t1;
    rayQueryGenerateIntersectionEXT(q, t);
}}
"#,
        n = spheres.len(),
        list = list.join(", ")
    );
    let body = r#"
    rayQueryEXT q;
    rayQueryInitializeEXT(q, scene, 0u, 0xffu, o, tmin, d, tmax);
    while (rayQueryProceedEXT(q)) {
        if (rayQueryGetIntersectionTypeEXT(q, false) == gl_RayQueryCandidateIntersectionAABBEXT) {
            intersect(q);
        }
    }
    results[i] = rayQueryGetIntersectionTypeEXT(q, true) == gl_RayQueryCommittedIntersectionGeneratedEXT
        ? uvec4(floatBitsToUint(rayQueryGetIntersectionTEXT(q, true)), rayQueryGetIntersectionInstanceIdEXT(q, true),
                rayQueryGetIntersectionPrimitiveIndexEXT(q, true), rayQueryGetIntersectionInstanceCustomIndexEXT(q, true))
        : uvec4(0xffffffffu);
"#;
    let got = run_with_functions(&ctx, &functions, body, handle, &rays);
    let want = probe(&ctx, handle, &rays, 0);
    let mut hits = 0;
    for (k, (g, w)) in got.iter().zip(&want).enumerate() {
        assert_eq!(
            g[0] == u32::MAX,
            w[0] == u32::MAX,
            "ray {k}: {g:?} vs {w:?}"
        );
        if w[0] == u32::MAX {
            continue;
        }
        hits += 1;
        let (tg, tw) = (f32::from_bits(g[0]), f32::from_bits(w[0]));
        assert!((tg - tw).abs() <= 1e-4 * tw, "ray {k}: t {tg} vs {tw}");
        assert_eq!([g[1], g[2], g[3]], [w[3], w[2], w[3]], "ray {k}");
    }
    assert!(hits > 100, "{hits} hits");
    common::assert_silent(&ctx);
}

#[test]
fn a_bottom_level_alone_is_one_identity_instance() {
    let Some(ctx) = common::context() else { return };
    let (levels, _, _) = scene(&ctx, AccelKind::Lbvh, |_| 0);
    let mut rng = common::Rng(3);
    let rays: Vec<Ray> = (0..300)
        .map(|_| {
            let o = centered(&mut rng).normalize_or(Vec3::X) * 5.0;
            Ray::new(o, centered(&mut rng) * 0.8 - o, 0.0, f32::INFINITY)
        })
        .collect();
    let flat =
        Buffer::from_slice(&ctx, "test.flat_handle", &levels[2].handle_words().unwrap()).unwrap();
    let handle = flat.device_address().unwrap();
    let got = run(&ctx, &looped(""), handle, &rays, 0, 0xff);
    let want = probe(&ctx, handle, &rays, 0);
    let mut hits = 0;
    for (k, (g, w)) in got.iter().zip(&want).enumerate() {
        assert_eq!(hit_of(g), hit_of(w).map(|[t, _, p]| [t, 0, p]), "ray {k}");
        hits += hit_of(g).is_some() as usize;
    }
    assert!(hits > 0);
    common::assert_silent(&ctx);
}

/// The compacted copy of `g` (`GpuGeometry::record_compact_into`) in memory of the size its
/// query reports, with that memory.
fn compacted(ctx: &Context, g: &GpuGeometry) -> (GpuGeometry, Vec<Buffer<u8>>) {
    let mut rec = Recorder::new(ctx).unwrap();
    rec.compute_to_transfer();
    let query = g.record_compacted_size(&mut rec).unwrap();
    rec.transfer_to_host();
    rec.submit_and_wait().unwrap();
    let size = query.read().unwrap();
    let memory = Buffer::<u8>::arena(ctx, "test.compacted", size.bytes as usize).unwrap();
    let scratch = Buffer::<u8>::arena(
        ctx,
        "test.compact_scratch",
        size.scratch_bytes.max(4) as usize,
    )
    .unwrap();
    let mut dst = g
        .create_compacted_in(ctx, &size, unsafe { memory.as_raw() })
        .unwrap();
    // Instances may name it by reference: the copy writes its own handle.
    dst.enable_references();
    let mut rec = Recorder::new(ctx).unwrap();
    g.record_compact_into(&mut rec, &mut dst, Some(unsafe { scratch.as_raw() }))
        .unwrap();
    rec.submit_and_wait().unwrap();
    (dst, vec![memory, scratch])
}

#[test]
fn compacted_levels_answer_as_the_structures_they_were_compacted_from() {
    // An LBVH's and a PLOC's levels compacted: through the include, alone and as the bottom
    // levels of a top level, every answer equals the original's, bit for bit.
    let Some(ctx) = common::context() else { return };
    let (_, instances, rays) = scene(&ctx, AccelKind::Lbvh, |_| 0);
    let meshes = [sphere_tris(2), sphere_tris(1), sphere_tris(3)];
    for kind in [AccelKind::Lbvh, AccelKind::Ploc] {
        let built: Vec<(GpuGeometry, Vec<Buffer<u8>>)> = meshes
            .iter()
            .map(|m| device_bottom_of(&ctx, kind, m, true))
            .collect();
        let small: Vec<(GpuGeometry, Vec<Buffer<u8>>)> =
            built.iter().map(|(g, _)| compacted(&ctx, g)).collect();
        for (k, ((a, _), (b, _))) in built.iter().zip(&small).enumerate() {
            let handle = |g: &GpuGeometry| {
                let flat = Buffer::from_slice(&ctx, "test.flat", &g.handle_words().unwrap());
                let flat = flat.unwrap();
                (flat.device_address().unwrap(), flat)
            };
            let ((ha, _fa), (hb, _fb)) = (handle(a), handle(b));
            let want = run(&ctx, &looped(""), ha, &rays, 0, 0xff);
            assert_eq!(
                run(&ctx, &looped(""), hb, &rays, 0, 0xff),
                want,
                "{kind:?} {k}"
            );
            assert_eq!(
                probe(&ctx, hb, &rays, 0),
                probe(&ctx, ha, &rays, 0),
                "{kind:?} {k}"
            );
        }
        let (levels_a, levels_b): (Vec<&GpuGeometry>, Vec<&GpuGeometry>) = (
            built.iter().map(|(g, _)| g).collect(),
            small.iter().map(|(g, _)| g).collect(),
        );
        let (top_a, top_b) = (
            top_of(&ctx, &levels_a, &instances),
            top_of(&ctx, &levels_b, &instances),
        );
        let (ha, hb) = (top_a.handle_address(), top_b.handle_address());
        let want = run(&ctx, CLOSEST, ha, &rays, 0, 0xff);
        assert!(want.iter().filter(|h| h[0] != u32::MAX).count() > rays.len() / 4);
        assert_eq!(run(&ctx, CLOSEST, hb, &rays, 0, 0xff), want, "{kind:?}");
        assert_eq!(
            probe(&ctx, hb, &rays, 0),
            probe(&ctx, ha, &rays, 0),
            "{kind:?}"
        );
        // Instances naming the compacted levels by reference, as the driver's name a BLAS by
        // its address: the reference reaches the copy's own handle, not the original's.
        let by_reference: Vec<Instance> = instances
            .iter()
            .map(|i| Instance {
                bottom: levels_b[i.bottom as usize].reference().unwrap(),
                ..*i
            })
            .collect();
        let top_r = top_of(&ctx, &levels_b, &by_reference);
        let hr = top_r.handle_address();
        drop(built);
        assert_eq!(
            run(&ctx, CLOSEST, hr, &rays, 0, 0xff),
            want,
            "{kind:?} by reference"
        );
    }
    common::assert_silent(&ctx);
}
