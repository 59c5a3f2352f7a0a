//! Embedding vkrt in a host program that owns its Vulkan objects.
//!
//! The host (standing in for a renderer) creates its own instance, device, queue and
//! gpu-allocator `Allocator`, hands them to vkrt with `Context::from_raw`, and records into
//! ITS OWN command buffer, in this order:
//!
//! (a) its own pass: it zeroes vkrt's error counter and copies its rays from its own
//!     host-visible buffer into vkrt's ray buffer, then places its own barrier;
//! (b) vkrt's GPU build of an LBVH over the scene and the trace of the rays;
//! (c) its own pass: a copy of the hits into its own host-visible buffer.
//!
//! It submits once, waits, reads back only its own buffer, prints a summary with the
//! per-pass GPU times vkrt recorded (timestamps in the host's command buffer) and destroys
//! everything it created, in order.
//!
//! ```text
//! cargo run --release --example embed [MESH.obj] [RAYS]
//! VKRT_VALIDATION=1 cargo run --release --example embed   # Khronos layer + sync validation
//! ```
//!
//! The scene is `MESH.obj`, else `../shared/scenes/stanford-bunny.obj` when present, else an
//! icosphere. `tests/example_embed.rs` runs [`run`] and checks the hits against brute force.

use std::path::PathBuf;

use ash::vk;
use glam::Vec3;
use gpu_allocator::MemoryLocation;
use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::primitives::TraceGeometry;
use vkrt::gpu::{
    Buffer, BufferArg, Context, Profile, Recorder, Validation, DEFAULT_QUERY_CAPACITY,
};
use vkrt::trace::gpu::Tracer;
use vkrt::trace::{Hit, Ray, TraceOptions};

#[path = "common/host.rs"]
mod host;
use host::{barrier, BoxResult, Host};

/// What one run did.
pub struct Summary {
    pub device: String,
    pub triangles: usize,
    /// The hits, as the host read them from its own buffer.
    pub hits: Vec<Hit>,
    /// Rays that ran out of traversal steps (vkrt's error counter).
    pub exhausted: u32,
    /// The options the tracer really ran with (the CPU twin must use the same).
    pub options: TraceOptions,
    /// vkrt's passes, timed in the host's command buffer (`ms` is `None` without timestamps).
    pub profile: Profile,
    /// Queue submissions vkrt made on its own while recording: 0, the host submits.
    pub vkrt_submits: u64,
    /// Whether the validation layer was on, and what it reported (teardown included).
    pub validation: bool,
    pub messages: Vec<String>,
}

/// `n` rays from a sphere around the triangles' bounds, aimed near their centre.
pub fn rays_toward(tris: &[[Vec3; 3]], n: usize, seed: u64) -> Vec<Ray> {
    let (lo, hi) = tris.iter().flatten().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    );
    let centre = (lo + hi) * 0.5;
    let radius = ((hi - lo).length() * 0.5).max(1e-3);
    let mut rng = vkrt::scene::gen::Rng::new(seed);
    (0..n)
        .map(|_| {
            let on_sphere = loop {
                let v = rng.vec3_signed();
                if (0.01..=1.0).contains(&v.length_squared()) {
                    break v.normalize();
                }
            };
            let origin = centre + on_sphere * (2.0 * radius);
            let target = centre + rng.vec3_signed() * (0.5 * radius);
            Ray::new(origin, target - origin, 0.0, f32::INFINITY)
        })
        .collect()
}

/// Creates the host's Vulkan objects, builds and traces `rays` against `tris` through vkrt
/// inside the host's command buffer, destroys everything and reports.
pub fn run(tris: &[[Vec3; 3]], rays: &[Ray], validation: Validation) -> BoxResult<Summary> {
    let host = Host::new(validation)?;
    let sink = host.sink.clone();
    let result = build_and_trace(&host, tris, rays);
    // Destroys the allocator, device, messenger and instance; the layer reports leaks then.
    drop(host);
    let mut summary = result?;
    summary.messages = std::mem::take(&mut *sink.lock().unwrap());
    Ok(summary)
}

/// Everything between the host's device and its teardown. Locals drop in reverse order:
/// vkrt's buffers, tracer, builder and context, then the host's buffers and command pool.
fn build_and_trace(host: &Host, tris: &[[Vec3; 3]], rays: &[Ray]) -> BoxResult<Summary> {
    let n = rays.len();
    let hit_bytes = (n * size_of::<Hit>()) as u64;
    // The host's own buffers: its rays (written on the host) and its read-back of the hits,
    // followed by vkrt's error counter.
    let mut host_rays = host.buffer(
        "host.rays",
        (size_of_val(rays) as u64).max(4),
        MemoryLocation::CpuToGpu,
        vk::BufferUsageFlags::TRANSFER_SRC,
    )?;
    host_rays.write(bytemuck::cast_slice(rays));
    let host_out = host.buffer(
        "host.out",
        hit_bytes + 4,
        MemoryLocation::GpuToCpu,
        vk::BufferUsageFlags::TRANSFER_DST,
    )?;
    let commands = host.command_buffer()?;

    // SAFETY: every handle in `parts` is the host's, valid, of one instance and device;
    // `family` supports compute and `queue` is its queue; `features` and `debug_utils` are
    // what was enabled; the host outlives the context (dropped at the end of this function)
    // and this thread is the only one using the queue.
    let ctx = unsafe { Context::from_raw(host.raw_parts()) }?;
    let geometry = TraceGeometry::from_triangles(tris);
    let builder = AccelBuilder::new(&ctx, AccelKind::Lbvh)?;
    let tracer = Tracer::for_accel(
        &ctx,
        &TraceOptions::default(),
        AccelKind::Lbvh.walked(Default::default()),
    )?;
    let ray_buf = Buffer::<Ray>::new(&ctx, "embed.rays", n)?;
    let hits = Buffer::<Hit>::new(&ctx, "embed.hits", n)?;
    let errors = Buffer::<u32>::new(&ctx, "embed.errors", 1)?;

    let device = &host.device;
    let cmd = commands.cmd;
    let before = ctx.traffic();
    // SAFETY: `cmd` is the host's primary command buffer of the context's queue family, in
    // the recording state, outside a render pass; every buffer bound below outlives its
    // execution (they drop after the fence wait); `complete` is called after that wait.
    let mut rec = unsafe { Recorder::from_raw(&ctx, cmd, DEFAULT_QUERY_CAPACITY) }?;

    // (a) The host's own pass, timed in a vkrt scope: it zeroes vkrt's error counter and
    // copies its rays into vkrt's ray buffer, then orders both before vkrt's kernels.
    rec.scope("host.rays", |_| {
        // SAFETY: `cmd` is recording; the regions lie inside the buffers, which have the
        // transfer usages (vkrt's buffers have every usage).
        unsafe {
            device.cmd_fill_buffer(cmd, errors.raw(), 0, 4, 0);
            if n > 0 {
                let region = vk::BufferCopy::default().size(size_of_val(rays) as u64);
                device.cmd_copy_buffer(cmd, host_rays.raw, ray_buf.raw(), &[region]);
            }
            barrier(
                device,
                cmd,
                (
                    vk::PipelineStageFlags::TRANSFER,
                    vk::AccessFlags::TRANSFER_WRITE,
                ),
                (
                    vk::PipelineStageFlags::COMPUTE_SHADER,
                    vk::AccessFlags::SHADER_READ | vk::AccessFlags::SHADER_WRITE,
                ),
            );
        }
    });

    // (b) vkrt: upload the triangles, build the LBVH on the GPU (scope `build`, ending with
    // the barrier that lets kernels trace it), trace the rays.
    let (built, _) = GpuGeometry::record_build(&mut rec, &builder, &geometry, 0)?;
    rec.scope("trace", |rec| {
        tracer.record(rec, &built, &ray_buf, &hits, &errors, n, 0.0)
    })?;

    // (c) The host's own pass: the hits and the error counter into its own buffer.
    rec.scope("host.readback", |_| {
        // SAFETY: `cmd` is recording; both copies land inside `host_out` (hit_bytes + 4).
        unsafe {
            barrier(
                device,
                cmd,
                (
                    vk::PipelineStageFlags::COMPUTE_SHADER,
                    vk::AccessFlags::SHADER_WRITE,
                ),
                (
                    vk::PipelineStageFlags::TRANSFER,
                    vk::AccessFlags::TRANSFER_READ,
                ),
            );
            if n > 0 {
                let region = vk::BufferCopy::default().size(hit_bytes);
                device.cmd_copy_buffer(cmd, hits.raw(), host_out.raw, &[region]);
            }
            let region = vk::BufferCopy::default().dst_offset(hit_bytes).size(4);
            device.cmd_copy_buffer(cmd, errors.raw(), host_out.raw, &[region]);
            barrier(
                device,
                cmd,
                (
                    vk::PipelineStageFlags::TRANSFER,
                    vk::AccessFlags::TRANSFER_WRITE,
                ),
                (vk::PipelineStageFlags::HOST, vk::AccessFlags::HOST_READ),
            );
        }
    });
    let work = rec.finish()?;
    let vkrt_submits = (ctx.traffic() - before).submits;

    // One submission, by the host, on its queue.
    host.submit_and_wait(cmd)?;
    // SAFETY: the command buffer has finished executing (the fence was waited for).
    let profile = unsafe { work.complete() }?;

    let bytes = host_out.read();
    let hits_back: Vec<Hit> = bytemuck::pod_collect_to_vec(&bytes[..hit_bytes as usize]);
    let exhausted = bytemuck::pod_read_unaligned(&bytes[hit_bytes as usize..][..4]);
    Ok(Summary {
        device: ctx.info().device.clone(),
        triangles: tris.len(),
        hits: hits_back,
        exhausted,
        options: tracer.options(),
        profile,
        vkrt_submits,
        validation: host.messenger.is_some(),
        messages: Vec::new(),
    })
}

fn main() -> BoxResult<()> {
    let mut args = std::env::args().skip(1);
    let bunny =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes/stanford-bunny.obj");
    let mesh = args
        .next()
        .map(PathBuf::from)
        .or_else(|| bunny.exists().then_some(bunny));
    let n_rays: usize = args.next().map_or(Ok(4096), |s| s.parse())?;
    let (name, tris) = match &mesh {
        Some(path) => (
            path.display().to_string(),
            vkrt::scene::Scene::load(path)?.scene.triangles_world(0.0),
        ),
        None => {
            let sphere = vkrt::scene::gen::icosphere(4)?;
            let tris = sphere
                .indices
                .iter()
                .map(|t| t.map(|i| sphere.positions[i as usize]))
                .collect();
            (sphere.name, tris)
        }
    };
    let rays = rays_toward(&tris, n_rays, 1);
    let validation = if std::env::var("VKRT_VALIDATION").is_ok_and(|v| v == "1") {
        Validation::On
    } else {
        Validation::Off
    };
    let s = run(&tris, &rays, validation)?;
    let hits = s.hits.iter().filter(|h| h.is_hit()).count();
    println!("device: {}", s.device);
    println!(
        "scene: {name}, {} triangles, LBVH built on the GPU",
        s.triangles
    );
    println!(
        "rays: {}, hits: {hits}, out of traversal steps: {} (exact fallback: {})",
        s.hits.len(),
        s.exhausted,
        s.options.exact
    );
    println!(
        "submissions: 1 by the host, {} by vkrt while recording",
        s.vkrt_submits
    );
    // vkrt writes timestamps around its scopes in the host's command buffer too; a device
    // without timestamps on this queue gives `None` and the passes are listed untimed.
    println!(
        "GPU passes (timestamps in the host's command buffer; {} scopes in all, two levels shown):",
        s.profile.passes.len()
    );
    for p in s.profile.passes.iter().filter(|p| p.depth <= 1) {
        let ms = p.ms.map_or("untimed".into(), |ms| format!("{ms:8.3} ms"));
        let indent = "  ".repeat(p.depth as usize + 1);
        println!("{indent}{:<20} {ms}", p.name);
    }
    println!(
        "validation: {}",
        if s.validation {
            format!("on, {} message(s)", s.messages.len())
        } else {
            "off (VKRT_VALIDATION=1 turns it on)".into()
        }
    );
    if !s.messages.is_empty() {
        return Err(format!(
            "the validation layer reported {} message(s)",
            s.messages.len()
        )
        .into());
    }
    Ok(())
}
