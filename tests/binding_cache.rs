//! A [`BindingCache`] across buffers that come and go, as a streaming renderer's do: a
//! buffer destroyed and another created in its place — with the same `VkBuffer` handle,
//! which lavapipe hands out again — never binds the first one's descriptor set; the sets of
//! dropped and forgotten buffers are freed, so the cache holds the live buffers' sets only;
//! and a sealed cache refuses a frame it was not prepared for with `GpuError::CacheMiss`,
//! creating nothing. On the renderer's own device, under validation — and again without
//! the layer, whose handle wrapping never gives a handle twice: only there does the driver's
//! reuse of a freed handle, the hazard itself, happen (on lavapipe it must, or the test
//! would prove nothing).

#[path = "../examples/common/host.rs"]
mod host;

mod common;

use ash::vk;
use glam::Vec3;
use gpu_allocator::MemoryLocation;
use host::{Host, HostBuffer};
use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::primitives::TraceGeometry;
use vkrt::gpu::{
    BindingCache, Buffer, BufferArg, Context, GpuError, Memory, RawBuffer, Recorder, Validation,
};
use vkrt::trace::gpu::Tracer;
use vkrt::trace::{Hit, Ray, TraceOptions};

const RAYS: usize = 64;

fn host_and_context(validation: Validation) -> Option<(Host, Context)> {
    context_on(Host::new(validation))
}

/// vkrt's context on `host`, the renderer's device (`None`: skipped, where no device is
/// allowed).
fn context_on(host: host::BoxResult<Host>) -> Option<(Host, Context)> {
    let host = match host {
        Ok(h) => h,
        Err(e) if common::no_gpu_allowed() => {
            eprintln!("skipped: {e}");
            return None;
        }
        Err(e) => panic!("no Vulkan device: {e}"),
    };
    // SAFETY: the host's handles, of one instance and device; the host outlives the context
    // (dropped first in each test) and only this thread uses the queue.
    let ctx = unsafe { Context::from_raw(host.raw_parts()) }.unwrap();
    Some((host, ctx))
}

/// A unit square in the plane z = 0 (two triangles).
fn square() -> TraceGeometry {
    let p = |x: f32, y: f32| Vec3::new(x, y, 0.0);
    TraceGeometry::from_triangles(&[
        [p(0.0, 0.0), p(1.0, 0.0), p(1.0, 1.0)],
        [p(0.0, 0.0), p(1.0, 1.0), p(0.0, 1.0)],
    ])
}

/// Rays from z = 1 at points over the square, down (`hit`: every one hits it at t = 1) or up
/// (every one misses).
fn rays(hit: bool) -> Vec<Ray> {
    let dir = if hit { -Vec3::Z } else { Vec3::Z };
    (0..RAYS)
        .map(|i| {
            let (x, y) = ((i % 8) as f32 + 0.5, (i / 8) as f32 + 0.5);
            Ray::new(Vec3::new(x / 8.0, y / 8.0, 1.0), dir, 0.0, f32::INFINITY)
        })
        .collect()
}

/// What a frame traced: hits, and the rays that ran out of steps.
struct Traced {
    hits: Buffer<Hit>,
    errors: Buffer<u32>,
}

impl Traced {
    fn new(ctx: &Context) -> Self {
        Self {
            hits: Buffer::with_memory(ctx, "frame.hits", RAYS, Memory::Readback).unwrap(),
            errors: Buffer::with_memory(ctx, "frame.errors", 1, Memory::Readback).unwrap(),
        }
    }

    fn hits(&self) -> usize {
        assert_eq!(self.errors.download().unwrap()[0], 0, "exhausted rays");
        let hits = self.hits.download().unwrap();
        hits.iter().filter(|h| h.is_hit()).count()
    }
}

/// Records one trace of `rays` into the host's command buffer through `cache` and runs it:
/// the recording's error, if any (its command buffer then discarded unsubmitted).
fn frame(
    host: &Host,
    ctx: &Context,
    cache: &BindingCache,
    trace: impl FnOnce(&mut Recorder) -> vkrt::gpu::Result<()>,
) -> vkrt::gpu::Result<()> {
    let commands = host.command_buffer().unwrap();
    // SAFETY: the host's command buffer, recording, outside a render pass; the buffers
    // outlive its execution; the work is completed after the host's fence (or never
    // submitted).
    let mut rec = unsafe { Recorder::from_raw_with(ctx, commands.cmd, cache) }?;
    let recorded = trace(&mut rec).and_then(|()| rec.finish());
    // On an error the command buffer is the caller's to reset: here it is dropped
    // unsubmitted.
    let work = recorded?;
    host.submit_and_wait(commands.cmd).unwrap();
    // SAFETY: the host waited for its command buffer.
    unsafe { work.complete() }.map(drop)
}

/// The frame's work: a trace of `rays` into `out`.
fn record_trace(
    rec: &mut Recorder,
    (geometry, tracer): &(GpuGeometry, Tracer),
    rays: &dyn BufferArg,
    out: &Traced,
) -> vkrt::gpu::Result<()> {
    rec.fill(&out.errors, 0);
    rec.transfer_to_compute();
    tracer.record(rec, geometry, rays, &out.hits, &out.errors, RAYS, 0.0)?;
    rec.compute_to_host();
    Ok(())
}

fn structure(ctx: &Context) -> (GpuGeometry, Tracer) {
    let builder = AccelBuilder::new(ctx, AccelKind::Lbvh).unwrap();
    let (geometry, _) = GpuGeometry::build_fitting(ctx, &builder, &square()).unwrap();
    let opt = TraceOptions {
        exact: false,
        ..TraceOptions::default()
    };
    let tracer = Tracer::for_accel(ctx, &opt, AccelKind::Lbvh.walked(Default::default())).unwrap();
    (geometry, tracer)
}

/// Whether the replacement buffer got the handle of the one destroyed: for a caller's
/// buffer on lavapipe without the layer it must (`required`: the case the test is for, the
/// renderer's buffer alone destroyed and created, and the freed handle back at once); for a
/// vkrt buffer, whose memory comes and goes with it, it does on Mesa 25 and 26 but not on
/// 22.3, and is reported.
fn check_reused(ctx: &Context, validation: Validation, reused: bool, required: bool) {
    let lavapipe = ctx.info().device.contains("llvmpipe");
    eprintln!("the replacement reuses the destroyed buffer's handle: {reused}");
    if required && validation == Validation::Off && lavapipe {
        assert!(
            reused,
            "lavapipe gave the replacement a new handle: nothing was tested"
        );
    }
}

#[test]
fn a_vkrt_buffer_recreated_with_the_same_handle_binds_its_own_set() {
    streaming_vkrt_buffers(Validation::FromEnv);
}

#[test]
fn a_vkrt_buffer_recreated_with_the_same_handle_binds_its_own_set_without_the_layer() {
    streaming_vkrt_buffers(Validation::Off);
}

#[test]
fn a_forgotten_caller_buffer_frees_its_sets_and_its_handle_binds_anew() {
    streaming_caller_buffers(Validation::FromEnv);
}

#[test]
fn a_forgotten_caller_buffer_frees_its_sets_and_its_handle_binds_anew_without_the_layer() {
    streaming_caller_buffers(Validation::Off);
}

/// What each test starts from: the renderer's device, vkrt on it, a structure and its
/// tracer, the hit buffers and an empty cache.
struct Setup {
    host: Host,
    ctx: Context,
    s: (GpuGeometry, Tracer),
    out: Traced,
    cache: BindingCache,
}

fn setup(validation: Validation) -> Option<Setup> {
    let (host, ctx) = host_and_context(validation)?;
    Some(Setup {
        s: structure(&ctx),
        out: Traced::new(&ctx),
        cache: BindingCache::new(&ctx),
        host,
        ctx,
    })
}

fn streaming_vkrt_buffers(validation: Validation) {
    let _turn = common::vulkan_turn();
    let Some(Setup {
        host,
        ctx,
        s,
        out,
        cache,
    }) = setup(validation)
    else {
        return;
    };
    let sink = host.sink.clone();
    let trace = |rays: &Buffer<Ray>| {
        let (s, out) = (&s, &out);
        // A copy of the range: the frame records with the buffer, which the test keeps.
        // SAFETY: each buffer outlives the frames recorded with it.
        let rays = unsafe { rays.as_raw() };
        move |rec: &mut Recorder| record_trace(rec, s, &rays, out)
    };

    let down = Buffer::from_slice(&ctx, "frame.rays", &rays(true)).unwrap();
    cache.prepare(trace(&down)).unwrap();
    let prepared = cache.sets();
    frame(&host, &ctx, &cache, trace(&down)).unwrap();
    assert_eq!(out.hits(), RAYS, "the rays down hit the square");

    // The streaming renderer's buffer goes, and its replacement comes: lavapipe's handles
    // are its objects' addresses, and the allocator hands the freed one out again.
    let handle = down.raw();
    drop(down);
    assert!(
        cache.evicted() > 0,
        "the dropped buffer's set was not freed"
    );
    assert!(
        cache.sets() < prepared,
        "the cache kept the dropped buffer's set"
    );
    let mut spare = Vec::new();
    let up = loop {
        // Created empty, so that no staging buffer takes the handle first.
        let b = Buffer::<Ray>::new(&ctx, "frame.rays", RAYS).unwrap();
        if b.raw() == handle || spare.len() == 16 {
            break b;
        }
        spare.push(b);
    };
    up.upload(&rays(false)).unwrap();
    check_reused(&ctx, validation, up.raw() == handle, false);
    cache.prepare(trace(&up)).unwrap();
    frame(&host, &ctx, &cache, trace(&up)).unwrap();
    // Through the dropped buffer's set the rays would be the old ones (or freed memory).
    assert_eq!(
        out.hits(),
        0,
        "the rays up miss: a stale set bound the old rays"
    );
    assert_eq!(cache.sets(), prepared, "one set per live buffer");

    // Sealed: a buffer the cache was not prepared for is an error, and nothing is created.
    cache.seal();
    let again = Buffer::from_slice(&ctx, "frame.rays", &rays(true)).unwrap();
    let before = ctx.traffic();
    let missed = frame(&host, &ctx, &cache, trace(&again));
    assert!(
        matches!(missed, Err(GpuError::CacheMiss { .. })),
        "a sealed cache's miss: {missed:?}"
    );
    assert_eq!((ctx.traffic() - before).objects_created, 0);
    // Preparing still adds; the prepared frame then records.
    cache.prepare(trace(&again)).unwrap();
    frame(&host, &ctx, &cache, trace(&again)).unwrap();
    assert_eq!(out.hits(), RAYS);

    drop((spare, up, again, cache, out, s, ctx));
    let messages = sink.lock().unwrap();
    assert!(messages.is_empty(), "validation messages: {messages:?}");
}

fn streaming_caller_buffers(validation: Validation) {
    let _turn = common::vulkan_turn();
    let Some(Setup {
        host,
        ctx,
        s,
        out,
        cache,
    }) = setup(validation)
    else {
        return;
    };
    let sink = host.sink.clone();
    let bytes = std::mem::size_of_val(rays(true).as_slice()) as u64;
    let caller_rays = |hit: bool| -> HostBuffer {
        let mut b = host
            .buffer(
                "renderer.rays",
                bytes,
                MemoryLocation::CpuToGpu,
                vk::BufferUsageFlags::STORAGE_BUFFER,
            )
            .unwrap();
        b.write(bytemuck::cast_slice(&rays(hit)));
        b
    };
    let trace = |rays: RawBuffer| {
        let (s, out) = (&s, &out);
        move |rec: &mut Recorder| record_trace(rec, s, &rays, out)
    };
    // SAFETY: each host buffer is live, storage usage, `bytes` long, and outlives the
    // frames recorded with it; the cache forgets it before it is destroyed.
    let range = |b: &HostBuffer| unsafe { RawBuffer::new(b.raw, 0, bytes) };

    let down = caller_rays(true);
    cache.prepare(trace(range(&down))).unwrap();
    let prepared = cache.sets();
    frame(&host, &ctx, &cache, trace(range(&down))).unwrap();
    assert_eq!(out.hits(), RAYS);

    // The renderer destroys its buffer after its frame's fence, telling the cache first.
    let handle = down.raw;
    // SAFETY: the frame that bound it has completed.
    unsafe { cache.forget(handle) };
    assert!(cache.evicted() > 0 && cache.sets() < prepared);
    drop(down);
    let mut spare = Vec::new();
    let up = loop {
        let b = caller_rays(false);
        if b.raw == handle || spare.len() == 16 {
            break b;
        }
        spare.push(b);
    };
    check_reused(&ctx, validation, up.raw == handle, true);
    frame(&host, &ctx, &cache, trace(range(&up))).unwrap();
    assert_eq!(
        out.hits(),
        0,
        "the rays up miss: a stale set bound the old rays"
    );
    assert_eq!(cache.sets(), prepared);
    // SAFETY: its frame has completed.
    unsafe { cache.forget(up.raw) };

    drop((spare, up, cache, out, s, ctx));
    let messages = sink.lock().unwrap();
    assert!(messages.is_empty(), "validation messages: {messages:?}");
}

/// With `VK_KHR_push_descriptor` enabled on the renderer's device, vkrt's kernels without
/// texel bindings (every builder's) push the ranges they bind: a build records into the
/// renderer's command buffer through a sealed, empty cache, and the structure traces as the
/// square says. On the same device without the extension, the same frame is a cache miss
/// (what the pushes spare).
#[test]
fn with_push_descriptors_a_build_binds_no_descriptor_set() {
    let _turn = common::vulkan_turn();
    for push in [true, false] {
        let host = match push {
            true => Host::with_push_descriptors(Validation::FromEnv),
            false => Host::new(Validation::FromEnv),
        };
        let Some((host, ctx)) = context_on(host) else {
            return;
        };
        if push && !host.features.push_descriptor {
            eprintln!("skipped: the device has no VK_KHR_push_descriptor");
            return;
        }
        let sink = host.sink.clone();
        let builder = AccelBuilder::new(&ctx, AccelKind::Lbvh).unwrap();
        let cache = BindingCache::new(&ctx);
        cache.seal();
        let mut built = None;
        let recorded = frame(&host, &ctx, &cache, |rec| {
            built = Some(GpuGeometry::record_build(rec, &builder, &square(), 0)?.0);
            rec.compute_to_host();
            Ok(())
        });
        match push {
            true => {
                recorded.unwrap();
                assert_eq!(cache.sets(), 0);
                let (_, tracer) = structure(&ctx);
                let geometry = built.take().unwrap();
                let hits = tracer
                    .trace(&ctx, &geometry, &rays(true), 0.0)
                    .unwrap()
                    .hits;
                assert!(hits.iter().all(Hit::is_hit), "the rays down hit the square");
                drop((geometry, tracer));
            }
            false => assert!(
                matches!(recorded, Err(GpuError::CacheMiss { .. })),
                "without push descriptors a sealed, empty cache misses: {recorded:?}"
            ),
        }
        drop((built, cache, builder, ctx));
        let messages = sink.lock().unwrap();
        assert!(messages.is_empty(), "validation messages: {messages:?}");
    }
}
