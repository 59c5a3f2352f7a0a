//! Building from the renderer's device buffers against the host-soup path, one run.
//!
//! For the Stanford bunny (../shared/scenes) and a 2 M-triangle icosphere, for the GPU
//! kd-tree (the bunny only), LBVH and PLOC: the same triangles built
//!
//! - **host soup**: `GpuGeometry::record_build` uploads a host `TraceGeometry` (vertices,
//!   boxes) and builds over it, in one submission — what a renderer had to do before;
//! - **device input**: the indexed mesh already lies in a device buffer (the renderer's);
//!   `AccelBuilder::record_build_from` reads it where it lies (`accel.geometry_gather`) and
//!   builds in memory the caller allocated.
//!
//! Per path: the GPU milliseconds of the recorded work (timestamps: upload + build, or
//! gather + build), the wall milliseconds of the submission, and the bytes uploaded
//! (`Context::traffic`). Best of 3 after a warm-up; the ratio device / host is taken in the
//! same run.
//!
//! Then, for the bunny, the two ways a shader reaches a structure through
//! `vkrt/ray_query.glsl` (`gpu.handle_probe`, closest hits of 256² rays from around the
//! mesh): its seven arrays bound as storage buffers, or read at the device addresses of its
//! handle (`VKRT_DEVICE_ADDRESS`); GPU ms of each, best of 3 interleaved rounds, and the
//! ratio address / bindings.
//!
//! `cargo bench --bench device_input [-- --json] [-- --quick]` (`--quick`: the bunny only)

use std::time::Instant;

use glam::Vec3;
use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::embedded::BuildFlags;
use vkrt::accel::geometry::{Geometry, IndexType, Triangles};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::primitives::TraceGeometry;
use vkrt::gpu::{kernels, BufferArg, Spec};
use vkrt::gpu::{Buffer, Context, ContextOptions, Recorder};
use vkrt::trace::Ray;

#[derive(serde::Serialize)]
struct Row {
    scene: String,
    triangles: usize,
    kind: &'static str,
    host_gpu_ms: f64,
    host_wall_ms: f64,
    host_upload_bytes: u64,
    device_gpu_ms: f64,
    device_wall_ms: f64,
    device_upload_bytes: u64,
    /// GPU ms of the device path's read of the caller's buffers (`accel.geometry_gather`).
    gather_ms: f64,
    /// device_gpu_ms / host_gpu_ms (below 1: the device path is faster).
    gpu_ratio: f64,
    wall_ratio: f64,
}

struct Mesh {
    name: String,
    positions: Vec<Vec3>,
    indices: Vec<[u32; 3]>,
}

fn meshes(quick: bool) -> Vec<Mesh> {
    let mut out = Vec::new();
    // `$VKRT_MESH`, else the Stanford bunny beside the checkout.
    let bunny = std::env::var_os("VKRT_MESH").map_or_else(
        || {
            std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../shared/scenes/stanford-bunny.obj")
        },
        std::path::PathBuf::from,
    );
    if bunny.exists() {
        let scene = vkrt::scene::Scene::load(&bunny).expect("the bunny").scene;
        let m = &scene.meshes[0];
        out.push(Mesh {
            name: "bunny".into(),
            positions: m.positions.to_vec(),
            indices: m.indices.to_vec(),
        });
    } else {
        eprintln!("skipped the bunny: {} not present", bunny.display());
    }
    if !quick {
        let m = vkrt::scene::gen::icosphere_with_at_least(2_000_000).expect("icosphere");
        out.push(Mesh {
            name: "icosphere 2M".into(),
            positions: m.positions.to_vec(),
            indices: m.indices.to_vec(),
        });
    }
    out
}

/// Best of 3 after a warm-up: (GPU ms of the whole recording, wall ms, bytes uploaded, GPU
/// ms of the gather).
fn best_of(ctx: &Context, mut record: impl FnMut(&mut Recorder)) -> (f64, f64, u64, f64) {
    let mut best = (f64::INFINITY, f64::INFINITY, 0, f64::INFINITY);
    for i in 0..4 {
        let before = ctx.traffic();
        let t = Instant::now();
        let mut rec = Recorder::new(ctx).expect("recorder");
        rec.begin_scope("all");
        record(&mut rec);
        rec.end_scope();
        let p = rec.submit_and_wait().expect("submit");
        let wall = t.elapsed().as_secs_f64() * 1e3;
        let up = (ctx.traffic() - before).upload_bytes;
        if i > 0 {
            best = (
                best.0.min(p.ms("all").unwrap_or(f64::NAN)),
                best.1.min(wall),
                up,
                best.3.min(p.ms("gather").unwrap_or(0.0)),
            );
        }
    }
    best
}

#[derive(serde::Serialize)]
struct BindingRow {
    kind: &'static str,
    rays: usize,
    bindings_ms: f64,
    /// The first three bindings as texel buffers (`VKRT_TEXEL_BUFFERS`).
    texel_ms: f64,
    address_ms: f64,
    /// address_ms / bindings_ms (above 1: the handle is slower).
    ratio: f64,
    /// texel_ms / bindings_ms (below 1: the texel buffers are faster).
    texel_ratio: f64,
}

/// 256² rays from points around the mesh's box towards points inside it.
fn rays_around(tris: &[[Vec3; 3]]) -> Vec<Ray> {
    let (lo, hi) = tris.iter().flatten().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    );
    let (c, r) = ((lo + hi) * 0.5, (hi - lo).length());
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
    };
    (0..256 * 256)
        .map(|_| {
            let o = c + Vec3::new(next(), next(), next()).normalize_or(Vec3::X) * r;
            let t = c + Vec3::new(next(), next(), next()) * (hi - lo) * 0.5;
            Ray::new(o, t - o, 0.0, f32::INFINITY)
        })
        .collect()
}

/// GPU ms of tracing `rays` through the bindings, through texel buffers and through the
/// handle, best of 3 interleaved rounds.
fn bindings_vs_address(ctx: &Context, g: &GpuGeometry, rays: &[Ray]) -> (f64, f64, f64) {
    let spec = Spec::new().workgroup(64);
    let set = ctx.kernel(&kernels::GPU_HANDLE_PROBE_SET, &spec).unwrap();
    let texel = ctx.kernel(&kernels::GPU_HANDLE_PROBE_TEXEL, &spec).unwrap();
    let address = ctx
        .kernel(&kernels::GPU_HANDLE_PROBE_ADDRESS, &spec)
        .unwrap();
    let ray_buf = Buffer::from_slice(ctx, "probe.rays", rays).unwrap();
    let out = Buffer::<[u32; 4]>::zeroed(ctx, "probe.hits", rays.len()).unwrap();
    let handle = Buffer::from_slice(ctx, "probe.handle", &g.handle_words().unwrap()).unwrap();
    let at = handle.device_address().unwrap();
    let push = [rays.len() as u32, 0, at as u32, (at >> 32) as u32, 0, 0];
    let [b0, b1, b2, b3, b4, b5, b6] = g.bindings();
    let all: [&dyn BufferArg; 9] = [&ray_buf, &out, b0, b1, b2, b3, b4, b5, b6];
    let mut best = (f64::INFINITY, f64::INFINITY, f64::INFINITY);
    for round in 0..4 {
        let mut rec = Recorder::new(ctx).unwrap();
        let groups = rec.groups_1d(rays.len() as u64, 64);
        rec.scope("bindings", |rec| rec.dispatch(&set, groups, &all, &push));
        rec.compute_to_compute();
        rec.scope("texel", |rec| rec.dispatch(&texel, groups, &all, &push));
        rec.compute_to_compute();
        rec.scope("address", |rec| {
            rec.dispatch(&address, groups, &all[..2], &push)
        });
        let p = rec.submit_and_wait().unwrap();
        if round > 0 {
            best.0 = best.0.min(p.ms("bindings").unwrap_or(f64::NAN));
            best.1 = best.1.min(p.ms("texel").unwrap_or(f64::NAN));
            best.2 = best.2.min(p.ms("address").unwrap_or(f64::NAN));
        }
    }
    best
}

#[path = "common/args.rs"]
mod args;

fn main() {
    let args::BenchArgs { json, quick, .. } = args::parse();
    let ctx = Context::new(&ContextOptions::default()).expect("a Vulkan device");
    let mut rows = Vec::new();
    for mesh in meshes(quick) {
        let tris: Vec<[Vec3; 3]> = mesh
            .indices
            .iter()
            .map(|t| t.map(|v| mesh.positions[v as usize]))
            .collect();
        // The renderer's buffers, on the device before anything is timed.
        let vertices = Buffer::from_slice(&ctx, "renderer.vertices", &mesh.positions).unwrap();
        let flat: Vec<u32> = mesh.indices.iter().flatten().copied().collect();
        let indices = Buffer::from_slice(&ctx, "renderer.indices", &flat).unwrap();
        let geometries = [Geometry::Triangles(Triangles::indexed(
            unsafe { vertices.as_raw() },
            mesh.positions.len() as u32,
            unsafe { indices.as_raw() },
            IndexType::U32,
            mesh.indices.len() as u32,
        ))];
        // The kd-tree's scratch for 2 M triangles (several GiB in one buffer) is above what
        // lavapipe allocates at once: the kd-tree is measured on the bunny.
        let kinds: &[AccelKind] = if tris.len() > 1_000_000 {
            &[AccelKind::Lbvh, AccelKind::Ploc]
        } else {
            &[AccelKind::KdTree, AccelKind::Lbvh, AccelKind::Ploc]
        };
        for &kind in kinds {
            let builder = AccelBuilder::new(&ctx, kind).unwrap();
            // The host path starts from the renderer's host copy of its mesh: the soup (nine
            // floats and a box per triangle) is made, uploaded and built over.
            let (host_gpu, host_wall, host_up, _) = best_of(&ctx, |rec| {
                let soup = TraceGeometry::from_triangles(&tris);
                let (g, _) = GpuGeometry::record_build(rec, &builder, &soup, 0).unwrap();
                rec.keep_alive(g);
            });
            let flags = BuildFlags::default();
            let s = builder.sizes_for(&ctx, &geometries, &flags).unwrap();
            let mem =
                Buffer::<u8>::arena(&ctx, "caller.structure", s.structure_bytes as usize).unwrap();
            let scratch =
                Buffer::<u8>::arena(&ctx, "caller.scratch", s.build_scratch_bytes as usize)
                    .unwrap();
            let mut g = builder
                .create_in(&ctx, &geometries, &flags, unsafe { mem.as_raw() })
                .unwrap();
            let (dev_gpu, dev_wall, dev_up, gather_ms) = best_of(&ctx, |rec| {
                builder
                    .record_build_from(rec, &mut g, &geometries, unsafe { scratch.as_raw() })
                    .unwrap();
            });
            let row = Row {
                scene: mesh.name.clone(),
                triangles: tris.len(),
                kind: kind.name(),
                host_gpu_ms: host_gpu,
                host_wall_ms: host_wall,
                host_upload_bytes: host_up,
                device_gpu_ms: dev_gpu,
                device_wall_ms: dev_wall,
                device_upload_bytes: dev_up,
                gather_ms,
                gpu_ratio: dev_gpu / host_gpu,
                wall_ratio: dev_wall / host_wall,
            };
            if !json {
                println!(
                    "{:14} {:7} host soup: {:8.1} ms GPU {:8.1} ms wall {:>11} B up | device input: \
                     {:8.1} ms GPU (gather {:.1}) {:8.1} ms wall {:>3} B up | ×{:.2} GPU ×{:.2} wall",
                    row.scene,
                    row.kind,
                    row.host_gpu_ms,
                    row.host_wall_ms,
                    row.host_upload_bytes,
                    row.device_gpu_ms,
                    row.gather_ms,
                    row.device_wall_ms,
                    row.device_upload_bytes,
                    row.gpu_ratio,
                    row.wall_ratio
                );
            }
            rows.push(row);
        }
    }
    let mut bindings = Vec::new();
    if ctx.info().features.buffer_device_address {
        if let Some(mesh) = meshes(true).first() {
            let tris: Vec<[Vec3; 3]> = mesh
                .indices
                .iter()
                .map(|t| t.map(|v| mesh.positions[v as usize]))
                .collect();
            let soup = TraceGeometry::from_triangles(&tris);
            let rays = rays_around(&tris);
            for kind in [AccelKind::KdTree, AccelKind::Lbvh, AccelKind::Ploc] {
                let builder = AccelBuilder::new(&ctx, kind).unwrap();
                let mut rec = Recorder::new(&ctx).unwrap();
                let (g, _) = GpuGeometry::record_build(&mut rec, &builder, &soup, 0).unwrap();
                rec.submit_and_wait().unwrap();
                let (b, t, a) = bindings_vs_address(&ctx, &g, &rays);
                let row = BindingRow {
                    kind: kind.name(),
                    rays: rays.len(),
                    bindings_ms: b,
                    texel_ms: t,
                    address_ms: a,
                    ratio: a / b,
                    texel_ratio: t / b,
                };
                if !json {
                    println!(
                        "{} {:7} {} rays through the library: bindings {:7.1} ms, texel buffers \
                         {:7.1} ms (×{:.2}), device-address handle {:7.1} ms (×{:.2})",
                        mesh.name, row.kind, row.rays, b, t, row.texel_ratio, a, row.ratio
                    );
                }
                bindings.push(row);
            }
        }
    }
    if json {
        println!(
            "{}",
            serde_json::json!({ "builds": rows, "bindings": bindings })
        );
    }
}
