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
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::instance::Instance;
use vkrt::accel::instances::{TopLevel, TopLevelBuilder};
use vkrt::accel::primitives::TraceGeometry;
use vkrt::accel::shader_library::{include_dir, STEPS_CONSTANT_ID};
use vkrt::gpu::{Buffer, BufferArg, Context, Recorder, ShaderBlob, Spec};
use vkrt::trace::Ray;

/// Compiles a compute shader with glslc against the library; the SPIR-V.
fn compile(source: &str, defines: &[&str]) -> Vec<u32> {
    static NEXT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let dir = std::env::temp_dir().join(format!("vkrt-ext-rq-{}-{n}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let src = dir.join("shader.comp");
    let out = dir.join("shader.spv");
    std::fs::write(&src, source).unwrap();
    let mut glslc = std::process::Command::new("glslc");
    for d in defines {
        glslc.arg(format!("-D{d}"));
    }
    let o = glslc
        .arg("--target-env=vulkan1.2")
        .arg("-I")
        .arg(include_dir())
        .arg(&src)
        .arg("-o")
        .arg(&out)
        .output()
        .expect("glslc (Debian: glslc) compiles the shaders of this test");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let spirv = bytemuck::pod_collect_to_vec::<u8, u32>(&std::fs::read(&out).unwrap());
    let _ = std::fs::remove_dir_all(&dir);
    spirv
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
    let source = format!(
        "{HEADER}\nvoid main() {{\n    uint i = gl_GlobalInvocationID.x;\n    if (i >= rayCount) {{ return; }}\n    vec3 o = rays[2 * i].xyz;\n    float tmin = rays[2 * i].w;\n    vec3 d = rays[2 * i + 1].xyz;\n    float tmax = rays[2 * i + 1].w;\n{body}\n}}\n"
    );
    let spirv: &'static [u32] = Box::leak(compile(&source, &[]).into_boxed_slice());
    let blob: &'static ShaderBlob = Box::leak(Box::new(ShaderBlob {
        name: "test.ext_ray_query",
        source: "tests/ext_ray_query.rs",
        defines: &[],
        bindings: &[0, 1, 2],
        texel_bindings: &[0],
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
    let kernel = ctx
        .kernel(
            &vkrt::gpu::kernels::GPU_HANDLE_PROBE_ADDRESS,
            &Spec::new().workgroup(64),
        )
        .unwrap();
    let ray_buf = Buffer::from_slice(ctx, "probe.rays", rays).unwrap();
    let out = Buffer::<[u32; 4]>::zeroed(ctx, "probe.hits", rays.len()).unwrap();
    let push = [
        rays.len() as u32,
        mode,
        handle as u32,
        (handle >> 32) as u32,
        0,
        0,
    ];
    let mut rec = Recorder::new(ctx).unwrap();
    let groups = rec.groups_1d(rays.len() as u64, 64);
    let b: [&dyn BufferArg; 2] = [&ray_buf, &out];
    rec.dispatch(&kernel, groups, &b, &push);
    rec.compute_to_transfer();
    rec.submit_and_wait().unwrap();
    out.download().unwrap()
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

fn top<'a>(ctx: &Context, levels: &'a [GpuGeometry], instances: &[Instance]) -> TopLevel<'a> {
    let refs: Vec<&GpuGeometry> = levels.iter().collect();
    TopLevelBuilder::new(ctx, AccelKind::Lbvh)
        .unwrap()
        .build(ctx, &refs, instances, &BuildFlags::default())
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
