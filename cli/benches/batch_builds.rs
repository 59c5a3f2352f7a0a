//! Many bottom levels built by one record call against one call each, one run.
//!
//! The Stanford bunny (`$VKRT_MESH`, else ../shared/scenes; without it a generated
//! icosphere) cut into 64 runs of consecutive triangles (about a thousand each), each run
//! one structure over the renderer's index and vertex buffers, in one caller buffer at the
//! sizes vkrt reports. For the LBVH and PLOC the 64 builds are recorded
//!
//! - **separately**: `AccelBuilder::record_build_from` once per structure (each with its
//!   gather's barriers and a barrier at its end);
//! - **batched**: `AccelBuilder::record_builds_from` over all 64 (the gathers interleaved,
//!   one barrier at the end).
//!
//! Per way: the GPU milliseconds of the whole recording (timestamps around it, barriers
//! included) and the barriers recorded; best of 5 interleaved rounds after a warm-up, and
//! the ratio batched / separate taken in the same run.
//!
//! `cargo bench --bench batch_builds [-- --json] [-- --quick]` (`--quick`: 16 structures,
//! 3 rounds)

use vkrt::accel::batch::BuildTarget;
use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::embedded::BuildFlags;
use vkrt::accel::geometry::{Geometry, IndexType, Triangles};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::gpu::{Buffer, Context, ContextOptions, RawBuffer, Recorder};

#[path = "common/args.rs"]
mod args;

/// Where ranges of one caller buffer start.
const ALIGN: u64 = 256;

#[derive(serde::Serialize)]
struct Row {
    scene: String,
    kind: &'static str,
    structures: usize,
    triangles_each: usize,
    separate_gpu_ms: f64,
    batched_gpu_ms: f64,
    separate_barriers: u64,
    batched_barriers: u64,
    /// batched_gpu_ms / separate_gpu_ms (below 1: the batch is faster).
    gpu_ratio: f64,
}

/// The bunny's positions and triangles, or an icosphere's.
fn mesh() -> (String, Vec<glam::Vec3>, Vec<[u32; 3]>) {
    let bunny = std::env::var_os("VKRT_MESH").map_or_else(
        || {
            std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../shared/scenes/stanford-bunny.obj")
        },
        std::path::PathBuf::from,
    );
    let (name, m) = if bunny.exists() {
        let scene = vkrt::scene::Scene::load(&bunny).expect("the bunny").scene;
        ("bunny".to_string(), scene.meshes[0].clone())
    } else {
        eprintln!("{} not present: a generated icosphere", bunny.display());
        let m = vkrt::scene::gen::icosphere(7).expect("an icosphere");
        ("icosphere".to_string(), m)
    };
    (name, m.positions.to_vec(), m.indices.to_vec())
}

/// Ranges of `sizes` bytes laid out in one buffer, `ALIGN`-aligned.
fn ranges(ctx: &Context, name: &str, sizes: &[u64]) -> (Buffer<u8>, Vec<RawBuffer>) {
    let mut at = Vec::new();
    let mut end = 0u64;
    for &s in sizes {
        at.push(end);
        end = (end + s.max(4)).next_multiple_of(ALIGN);
    }
    let buffer = Buffer::<u8>::arena(ctx, name, end as usize).expect("caller memory");
    let whole = unsafe { buffer.as_raw() };
    let out = at
        .iter()
        .zip(sizes)
        .map(|(&o, &size)| unsafe {
            RawBuffer::new(whole.buffer(), whole.offset() + o, size.max(4))
        })
        .collect();
    (buffer, out)
}

fn main() {
    let args::BenchArgs { json, quick, .. } = args::parse();
    let ctx = Context::new(&ContextOptions::default()).expect("a Vulkan device");
    let (scene, positions, triangles) = mesh();
    let (count, rounds) = if quick { (16, 3) } else { (64, 5) };
    let per = triangles.len() / count;
    // The renderer's buffers: the whole mesh's vertices, and its indices, which each
    // structure reads a run of.
    let vertices = Buffer::from_slice(&ctx, "renderer.vertices", &positions).unwrap();
    let flat: Vec<u32> = triangles.iter().flatten().copied().collect();
    let indices = Buffer::from_slice(&ctx, "renderer.indices", &flat).unwrap();
    let lists: Vec<[Geometry; 1]> = (0..count)
        .map(|k| {
            let run = unsafe {
                RawBuffer::new(
                    indices.as_raw().buffer(),
                    indices.as_raw().offset() + (k * per * 12) as u64,
                    (per * 12) as u64,
                )
            };
            [Geometry::Triangles(Triangles::indexed(
                unsafe { vertices.as_raw() },
                positions.len() as u32,
                run,
                IndexType::U32,
                per as u32,
            ))]
        })
        .collect();
    let mut rows = Vec::new();
    for kind in [AccelKind::Lbvh, AccelKind::Ploc] {
        let builder = AccelBuilder::new(&ctx, kind).unwrap();
        let flags = BuildFlags::default();
        let sizes: Vec<_> = lists
            .iter()
            .map(|g| builder.sizes_for(&ctx, g, &flags).unwrap())
            .collect();
        let bytes: Vec<u64> = sizes.iter().map(|s| s.structure_bytes).collect();
        let (_memory, at) = ranges(&ctx, "caller.structures", &bytes);
        let scratch_bytes: Vec<u64> = sizes.iter().map(|s| s.build_scratch_bytes).collect();
        let (_scratch_memory, scratch) = ranges(&ctx, "caller.scratch", &scratch_bytes);
        let mut structures: Vec<GpuGeometry> = lists
            .iter()
            .zip(&at)
            .map(|(g, &m)| builder.create_in(&ctx, g, &flags, m).unwrap())
            .collect();
        let (mut best_separate, mut best_batched) = (f64::INFINITY, f64::INFINITY);
        let (mut separate_barriers, mut batched_barriers) = (0, 0);
        for round in 0..=rounds {
            let mut rec = Recorder::new(&ctx).unwrap();
            rec.scope("separate", |rec| {
                for ((g, out), &s) in lists.iter().zip(&mut structures).zip(&scratch) {
                    builder.record_build_from(rec, out, g, s).unwrap();
                }
            });
            separate_barriers = rec.counts().barriers;
            let p = rec.submit_and_wait().unwrap();
            let separate_ms = p.ms("separate").unwrap_or(f64::NAN);

            let mut rec = Recorder::new(&ctx).unwrap();
            let mut targets: Vec<BuildTarget<'_>> = lists
                .iter()
                .zip(&mut structures)
                .zip(&scratch)
                .map(|((g, out), &scratch)| BuildTarget {
                    geometries: g,
                    out,
                    scratch,
                })
                .collect();
            rec.scope("batched", |rec| {
                builder.record_builds_from(rec, &mut targets).unwrap();
            });
            batched_barriers = rec.counts().barriers;
            let p = rec.submit_and_wait().unwrap();
            let batched_ms = p.ms("batched").unwrap_or(f64::NAN);
            // Round 0 warms up.
            if round > 0 {
                best_separate = best_separate.min(separate_ms);
                best_batched = best_batched.min(batched_ms);
            }
        }
        let row = Row {
            scene: scene.clone(),
            kind: kind.name(),
            structures: count,
            triangles_each: per,
            separate_gpu_ms: best_separate,
            batched_gpu_ms: best_batched,
            separate_barriers,
            batched_barriers,
            gpu_ratio: best_batched / best_separate,
        };
        if !json {
            println!(
                "{} {:5} {} × {} triangles: separate {:8.2} ms GPU ({} barriers) | batched \
                 {:8.2} ms GPU ({} barriers) | ×{:.3}",
                row.scene,
                row.kind,
                row.structures,
                row.triangles_each,
                row.separate_gpu_ms,
                row.separate_barriers,
                row.batched_gpu_ms,
                row.batched_barriers,
                row.gpu_ratio
            );
        }
        rows.push(row);
    }
    if json {
        println!("{}", serde_json::json!({ "batch_builds": rows }));
    }
}
