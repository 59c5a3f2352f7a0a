//! A renderer's frames on its own device (adopted, under validation with synchronization
//! validation): vkrt's builds and traces recorded into the renderer's command buffer frame
//! after frame, over geometry the renderer moves between frames, each frame's structure
//! rebuilt in place.
//!
//! - After [`BindingCache::prepare`], recording a frame creates no Vulkan object
//!   (`Traffic::objects_created`, counted at every vkCreate*/vkAllocate* vkrt calls).

#[path = "../examples/common/host.rs"]
mod host;

mod common;

use ash::vk;
use glam::Vec3;
use gpu_allocator::MemoryLocation;
use host::{barrier, Host, HostBuffer};
use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::embedded::{BuildFlags, REQUIRED_BUFFER_USAGE};
use vkrt::accel::geometry::{Geometry, Triangles};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::primitives::TraceGeometry;
use vkrt::gpu::{BindingCache, Buffer, Context, Memory, RawBuffer, Recorder, Validation};
use vkrt::trace::gpu::Tracer;
use vkrt::trace::{Hit, Ray, TraceOptions};

/// Frames rendered; the geometry moves between them.
const FRAMES: usize = 3;
/// The grid's cells per side (two triangles each, some left out).
const CELLS: usize = 8;

/// The renderer's geometry at `frame`: a grid of triangles in the plane z = height, with
/// holes, shifted and lifted a little every frame.
fn grid(frame: usize) -> Vec<[Vec3; 3]> {
    let shift = Vec3::new(
        0.37 * frame as f32,
        -0.21 * frame as f32,
        0.5 * frame as f32,
    );
    let mut tris = Vec::new();
    for y in 0..CELLS {
        for x in 0..CELLS {
            if (x * 7 + y * 3) % 5 == 0 {
                continue;
            }
            let p = |dx: usize, dy: usize| {
                Vec3::new((x + dx) as f32, (y + dy) as f32, 0.0) - Vec3::splat(CELLS as f32 / 2.0)
                    + shift
            };
            tris.push([p(0, 0), p(1, 0), p(1, 1)]);
            if (x + y) % 3 != 0 {
                tris.push([p(0, 0), p(1, 1), p(0, 1)]);
            }
        }
    }
    tris
}

/// Vertex words of `tris` (every frame has as many triangles: only positions move).
fn vertex_words(tris: &[[Vec3; 3]]) -> Vec<f32> {
    tris.iter()
        .flatten()
        .flat_map(|p| p.to_array())
        .collect::<Vec<_>>()
}

fn raw(b: &HostBuffer, size: u64) -> RawBuffer {
    RawBuffer {
        raw: b.raw,
        offset: 0,
        size,
    }
}

/// Rays straight down onto the grid, from points spread over a square a little larger.
fn down_rays(n: usize) -> Vec<Ray> {
    let mut rng = common::Rng(11);
    let half = CELLS as f32 / 2.0 + 2.0;
    (0..n)
        .map(|_| {
            let (x, y) = (rng.next_f32() * half, rng.next_f32() * half);
            Ray::new(Vec3::new(x, y, 10.0), -Vec3::Z, 0.0, f32::INFINITY)
        })
        .collect()
}

/// `(hit, primitive)` per ray by brute force on the CPU.
fn expected(tris: &[[Vec3; 3]], rays: &[Ray]) -> Vec<Option<u32>> {
    let g = TraceGeometry::from_triangles(tris);
    let opt = TraceOptions {
        exact: false,
        ..TraceOptions::default()
    };
    rays.iter()
        .map(|r| {
            let h = vkrt::trace::cpu::brute_force(&g, r, 0.0, &opt);
            h.is_hit().then_some(h.prim)
        })
        .collect()
}

/// One structure of the renderer's, in its memory, over its vertex buffer.
struct Structure {
    builder: AccelBuilder,
    geometry: GpuGeometry,
    scratch: RawBuffer,
    tracer: Tracer,
    hits: Buffer<Hit>,
    errors: Buffer<u32>,
    _memory: [HostBuffer; 2],
}

fn host_and_context() -> Option<(Host, Context)> {
    let host = match Host::new(Validation::FromEnv) {
        Ok(h) => h,
        Err(e) if common::no_gpu_allowed() => {
            eprintln!("skipped: {e}");
            return None;
        }
        Err(e) => panic!("no Vulkan device: {e}"),
    };
    // SAFETY: the handles are the host's, valid, of one instance and device; the host
    // outlives the context (the tests drop the context first) and only this thread uses the
    // queue.
    let ctx = unsafe { Context::from_raw(host.raw_parts()) }.unwrap();
    Some((host, ctx))
}

#[test]
fn recording_a_prepared_frame_creates_no_vulkan_object() {
    let _turn = common::vulkan_turn();
    let Some((host, ctx)) = host_and_context() else {
        return;
    };
    let sink = host.sink.clone();
    let tris = grid(0);
    let vertex_bytes = (tris.len() * 36) as u64;
    let mut vertices = host
        .buffer(
            "renderer.vertices",
            vertex_bytes,
            MemoryLocation::CpuToGpu,
            vk::BufferUsageFlags::STORAGE_BUFFER,
        )
        .unwrap();
    let geometries = [Geometry::Triangles(Triangles::soup(
        raw(&vertices, vertex_bytes),
        (tris.len() * 3) as u32,
    ))];
    let n = if common::quick() { 256 } else { 1024 };
    let rays = down_rays(n);
    let ray_buffer = Buffer::from_slice(&ctx, "renderer.rays", &rays).unwrap();
    let flags = BuildFlags::default();
    let mut structures: Vec<Structure> = [AccelKind::KdTree, AccelKind::Lbvh, AccelKind::Ploc]
        .into_iter()
        .map(|kind| {
            let builder = AccelBuilder::new(&ctx, kind).unwrap();
            let sizes = builder.sizes_for(&ctx, &geometries, &flags).unwrap();
            let memory = |name, bytes: u64| {
                let usage = REQUIRED_BUFFER_USAGE;
                host.buffer(name, bytes.max(4), MemoryLocation::GpuOnly, usage)
                    .unwrap()
            };
            let structure = memory("renderer.structure", sizes.structure_bytes);
            let scratch = memory("renderer.scratch", sizes.build_scratch_bytes);
            let geometry = builder
                .create_in(
                    &ctx,
                    &geometries,
                    &flags,
                    raw(&structure, sizes.structure_bytes),
                )
                .unwrap();
            let opt = TraceOptions {
                exact: false,
                ..TraceOptions::default()
            };
            Structure {
                tracer: Tracer::for_accel(&ctx, &opt, kind.walked(Default::default())).unwrap(),
                scratch: raw(&scratch, sizes.build_scratch_bytes.max(4)),
                hits: Buffer::with_memory(&ctx, "renderer.hits", n, Memory::Readback).unwrap(),
                errors: Buffer::with_memory(&ctx, "renderer.errors", 1, Memory::Readback).unwrap(),
                builder,
                geometry,
                _memory: [structure, scratch],
            }
        })
        .collect();

    // The frame: each structure rebuilt in place over the moved vertices, then traced.
    let frame = |rec: &mut Recorder, structures: &mut [Structure]| -> vkrt::gpu::Result<()> {
        for s in structures.iter_mut() {
            rec.fill(&s.errors, 0);
        }
        rec.transfer_to_compute();
        for s in structures.iter_mut() {
            let scratch = s.scratch;
            s.builder
                .record_build_from(rec, &geometries, &mut s.geometry, scratch)?;
        }
        for s in structures.iter() {
            let (hits, errors) = (&s.hits, &s.errors);
            s.tracer
                .record(rec, &s.geometry, &ray_buffer, hits, errors, n, 0.0)?;
        }
        rec.compute_to_host();
        Ok(())
    };

    // Without preparation the recording makes descriptor sets (and compiles kernels): the
    // count sees what a frame would create.
    let cache = BindingCache::new(&ctx);
    let before = ctx.traffic();
    cache.prepare(|rec| frame(rec, &mut structures)).unwrap();
    let prepared = ctx.traffic() - before;
    assert!(
        prepared.objects_created > 0 && cache.sets() > 0,
        "preparing created {} objects, {} sets",
        prepared.objects_created,
        cache.sets()
    );

    for f in 0..FRAMES {
        let tris = grid(f);
        vertices.write(bytemuck::cast_slice(&vertex_words(&tris)));
        let commands = host.command_buffer().unwrap();
        let before = ctx.traffic();
        // SAFETY: the host's command buffer, recording, outside a render pass; every buffer
        // outlives its execution; the work is completed after the host's fence below.
        let mut rec = unsafe { Recorder::from_raw_with(&ctx, commands.cmd, &cache) }.unwrap();
        // The previous frame's trace read the structures this frame rebuilds in place.
        // SAFETY: the host's recording command buffer.
        unsafe {
            barrier(
                &host.device,
                commands.cmd,
                (
                    vk::PipelineStageFlags::COMPUTE_SHADER,
                    vk::AccessFlags::SHADER_READ,
                ),
                (
                    vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER,
                    vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE,
                ),
            )
        };
        frame(&mut rec, &mut structures).unwrap();
        let work = rec.finish().unwrap();
        let recorded = ctx.traffic() - before;
        host.submit_and_wait(commands.cmd).unwrap();
        // SAFETY: the host waited for its command buffer.
        unsafe { work.complete() }.unwrap();
        let frame_traffic = ctx.traffic() - before;
        assert_eq!(
            recorded.objects_created, 0,
            "frame {f}: objects created while recording"
        );
        assert_eq!(
            frame_traffic.objects_created, 0,
            "frame {f}: objects created"
        );
        assert_eq!(frame_traffic.submits, 0, "frame {f}: vkrt submitted");
        assert_eq!(frame_traffic.device_allocations, 0, "frame {f}");
        let want = expected(&tris, &rays);
        for s in &structures {
            let kind = s.builder.kind().name();
            let hits = s.hits.download().unwrap();
            assert_eq!(s.errors.download().unwrap()[0], 0, "{kind}: exhausted rays");
            let got: Vec<Option<u32>> = hits.iter().map(|h| h.is_hit().then_some(h.prim)).collect();
            let wrong = got.iter().zip(&want).filter(|(g, w)| g != w).count();
            assert_eq!(wrong, 0, "frame {f}, {kind}: hits differ from brute force");
            assert!(want.iter().any(Option::is_some) && want.iter().any(Option::is_none));
        }
        drop(commands);
    }
    drop(structures);
    drop(cache);
    drop(ray_buffer);
    drop(ctx);
    drop(vertices);
    drop(host);
    let messages = std::mem::take(&mut *sink.lock().unwrap());
    assert!(messages.is_empty(), "validation: {messages:#?}");
}
