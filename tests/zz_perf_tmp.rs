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


fn timed(ctx: &Context, source: &str, handle: u64, rays: &[Ray], label: &str) -> f64 {
    let spirv: &'static [u32] = Box::leak(compile(source, &[]).into_boxed_slice());
    let name: &'static str = Box::leak(label.to_string().into_boxed_str());
    let blob: &'static ShaderBlob = Box::leak(Box::new(ShaderBlob {
        name,
        source: "perf",
        defines: &[],
        bindings: &[0, 1, 2],
        texel_bindings: &[0],
        spec_constants: &[(STEPS_CONSTANT_ID, 60000)],
        local_size: [64, 1, 1],
        local_size_spec_ids: [None; 3],
        push_constants: true,
        spirv,
    }));
    let kernel = ctx.kernel(blob, &Spec::new().u32(STEPS_CONSTANT_ID, ctx.info().max_traversal_steps)).unwrap();
    let texel = Buffer::from_slice(ctx, "h", &[[handle as u32, (handle >> 32) as u32, 0, 0]]).unwrap();
    let ray_buf = Buffer::from_slice(ctx, "r", rays).unwrap();
    let out = Buffer::<[u32; 4]>::zeroed(ctx, "o", rays.len()).unwrap();
    let push = [rays.len() as u32];
    let mut best = f64::MAX;
    for round in 0..4 {
        let mut rec = Recorder::new(ctx).unwrap();
        let groups = rec.groups_1d(rays.len() as u64, 64);
        let b: [&dyn BufferArg; 3] = [&texel, &ray_buf, &out];
        rec.scope("t", |rec| rec.dispatch(&kernel, groups, &b, &push));
        let p = rec.submit_and_wait().unwrap();
        if round > 0 { best = best.min(p.ms("t").unwrap()); }
    }
    let o = out.download().unwrap();
    let hits = o.iter().filter(|h| h[0] != u32::MAX).count();
    let cands: u64 = o.iter().map(|h| h[3] as u64).sum();
    eprintln!("{label}: {best:.2} ms, {hits} hits, sum w {cands}");
    best
}

#[test]
fn perf_probe() {
    let Some(ctx) = common::context() else { return };
    let (_, tris) = vkrt::trace::bench::scenes::mesh_triangles(std::path::Path::new("/work/shared/scenes/stanford-bunny.obj")).unwrap();
    let level = bottom(&ctx, AccelKind::Lbvh, &tris);
    let bytes = std::fs::read("/var/tmp/rqbench/bunny_primary.rays").unwrap();
    let f: &[f32] = bytemuck::cast_slice(&bytes);
    let rays: Vec<Ray> = f.chunks(8).map(|c| Ray::new(Vec3::new(c[0], c[1], c[2]), Vec3::new(c[4], c[5], c[6]), c[3], c[7])).collect();
    let refs = [&level];
    let top = TopLevelBuilder::new(&ctx, AccelKind::Lbvh).unwrap()
        .build(&ctx, &refs, &[Instance::new(0, Instance::IDENTITY)], &BuildFlags::default()).unwrap();
    let handle = top.handle_address();
    let ext = std::fs::read_to_string("/var/tmp/rqbench/ext_closest.comp").unwrap();
    let own = std::fs::read_to_string("/var/tmp/rqbench/vkrt_closest.comp").unwrap();
    let alpha = std::fs::read_to_string("/var/tmp/rqbench/alpha.comp").unwrap();
    for _ in 0..2 {
        let a = timed(&ctx, &ext, handle, &rays, "ext");
        let b = timed(&ctx, &own, handle, &rays, "own");
        let c = timed(&ctx, &alpha, handle, &rays, "alpha");
        eprintln!("ext/own time {:.3}  alpha/ext {:.3}", a / b, c / a);
    }
}

fn bottom(ctx: &Context, kind: AccelKind, tris: &[[Vec3; 3]]) -> GpuGeometry {
    let builder = AccelBuilder::new(ctx, kind).unwrap();
    let g = TraceGeometry::from_triangles(tris);
    let mut rec = Recorder::new(ctx).unwrap();
    let (out, _) = GpuGeometry::record_build(&mut rec, &builder, &g, 0).unwrap();
    rec.submit_and_wait().unwrap();
    out
}
