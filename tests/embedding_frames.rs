//! A renderer's frames on its own device (adopted, under validation with synchronization
//! validation): vkrt's builds and traces recorded into the renderer's command buffer frame
//! after frame, over geometry the renderer moves between frames, each frame's structure
//! rebuilt in place.
//!
//! - After [`BindingCache::prepare`], recording a frame creates no Vulkan object
//!   (`Traffic::objects_created`, counted at every vkCreate*/vkAllocate* vkrt calls), and
//!   stages nothing: the bottom levels' builds, and (where the device has addresses) a top
//!   level's, in the renderer's memory, over instances the renderer writes in its own buffer
//!   by reference to a bottom level, a different count each frame; and after the frames,
//!   the compaction of the LBVH's and PLOC's structures.
//! - The synchronization contract ([`vkrt::accel::sync`]): the consumer of each build is the
//!   renderer's graphics pass, a fragment shader tracing through `vkrt/ray_query.glsl`;
//!   three frames in one command buffer, each rebuilding the structures in place after the
//!   previous frame's fragment shader read them, ordered by the barriers the contract names
//!   and nothing else; every pixel equals brute force on the CPU.

#[path = "../examples/common/host.rs"]
mod host;

mod common;
#[path = "common/graphics.rs"]
mod graphics;

use ash::vk;
use glam::Vec3;
use gpu_allocator::MemoryLocation;
use host::{barrier, Host, HostBuffer};
use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::embedded::{BuildFlags, DRIVER_BUFFER_USAGE, REQUIRED_BUFFER_USAGE};
use vkrt::accel::geometry::{Geometry, Triangles};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::instances::{Instance, TopLevel, TopLevelBuilder};
use vkrt::accel::primitives::TraceGeometry;
use vkrt::accel::sync::{RecordSync, StageAccess};
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
    unsafe { RawBuffer::new(b.raw, 0, size) }
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

/// The renderer's top level: in its memory, over its instance buffer.
struct Top {
    builder: TopLevelBuilder,
    top: TopLevel,
    instances: HostBuffer,
    scratch: RawBuffer,
    _memory: [HostBuffer; 2],
}

/// The instances a frame's top level reads: the LBVH's level lowered by 3, then as it is;
/// frame `f` builds over the first `TOP_COUNTS[f]`.
const TOP_COUNTS: [u32; FRAMES] = [2, 1, 2];

/// Closest hits through the top level whose handle lies at `handle` (`gpu.handle_probe`):
/// (t bits, geometry, primitive, instance) per ray.
fn probe(ctx: &Context, handle: u64, rays: &[Ray]) -> Vec<[u32; 4]> {
    common::probe_handle(ctx, handle, rays, 0, 0.0)
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
    let ray_query = host.features.ray_query;
    let tris = grid(0);
    let vertex_bytes = (tris.len() * 36) as u64;
    let mut vertices = host
        .buffer(
            "renderer.vertices",
            vertex_bytes,
            MemoryLocation::CpuToGpu,
            // The driver's structure reads its vertices at a device address.
            match ray_query {
                true => vk::BufferUsageFlags::STORAGE_BUFFER | DRIVER_BUFFER_USAGE,
                false => vk::BufferUsageFlags::STORAGE_BUFFER,
            },
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
    // The driver's own structure too, where the host enabled ray query.
    let kinds = [
        AccelKind::KdTree,
        AccelKind::Lbvh,
        AccelKind::Ploc,
        AccelKind::Driver,
    ];
    let mut structures: Vec<Structure> = kinds[..3 + ray_query as usize]
        .iter()
        .copied()
        .map(|kind| {
            let builder = AccelBuilder::new(&ctx, kind).unwrap();
            let sizes = builder.sizes_for(&ctx, &geometries, &flags).unwrap();
            let memory = |name, bytes: u64| {
                let usage = match ray_query {
                    true => REQUIRED_BUFFER_USAGE | DRIVER_BUFFER_USAGE,
                    false => REQUIRED_BUFFER_USAGE,
                };
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
    // Where the device has addresses, a top level over instances of the LBVH's level by
    // reference (the renderer's memory has SHADER_DEVICE_ADDRESS usage then).
    let mut top = ray_query.then(|| {
        structures[1].geometry.enable_references();
        let builder = TopLevelBuilder::new(&ctx, AccelKind::Lbvh).unwrap();
        let sizes = builder.sizes_for(&ctx, 2, 0, &flags).unwrap();
        let usage = REQUIRED_BUFFER_USAGE | DRIVER_BUFFER_USAGE;
        let memory = |name, bytes: u64| {
            host.buffer(name, bytes.max(4), MemoryLocation::GpuOnly, usage)
                .unwrap()
        };
        let structure = memory("renderer.top", sizes.structure_bytes);
        let scratch = memory("renderer.top_scratch", sizes.build_scratch_bytes);
        let top = builder
            .create_in(&ctx, &[], 2, &flags, raw(&structure, sizes.structure_bytes))
            .unwrap();
        let reference = structures[1].geometry.reference().unwrap();
        let lowered = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, -3.0],
        ];
        let records = [
            Instance::referencing(reference, lowered),
            Instance::referencing(reference, Instance::IDENTITY),
        ];
        let mut instances = host
            .buffer(
                "renderer.instances",
                128,
                MemoryLocation::CpuToGpu,
                vk::BufferUsageFlags::STORAGE_BUFFER,
            )
            .unwrap();
        instances.write(bytemuck::cast_slice(&records));
        Top {
            builder,
            top,
            instances,
            scratch: raw(&scratch, sizes.build_scratch_bytes.max(4)),
            _memory: [structure, scratch],
        }
    });

    // The frame: each structure rebuilt in place over the moved vertices, then the top level
    // over `count` instances, then the structures traced.
    let frame = |rec: &mut Recorder,
                 structures: &mut [Structure],
                 top: Option<&mut Top>,
                 count: u32|
     -> vkrt::gpu::Result<()> {
        for s in structures.iter_mut() {
            rec.fill(&s.errors, 0);
        }
        rec.transfer_to_compute();
        for s in structures.iter_mut() {
            let scratch = s.scratch;
            s.builder
                .record_build_from(rec, &mut s.geometry, &geometries, scratch)?;
        }
        if let Some(t) = top {
            let instances = raw(&t.instances, 128);
            t.builder
                .record_build_from(rec, &mut t.top, instances, count, t.scratch)?;
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
    cache
        .prepare(|rec| frame(rec, &mut structures, top.as_mut(), 2))
        .unwrap();
    let prepared = ctx.traffic() - before;
    assert!(
        prepared.objects_created > 0 && cache.sets() > 0,
        "preparing created {} objects, {} sets",
        prepared.objects_created,
        cache.sets()
    );

    for (f, &count) in TOP_COUNTS.iter().enumerate() {
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
        frame(&mut rec, &mut structures, top.as_mut(), count).unwrap();
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
        assert_eq!(frame_traffic.upload_bytes, 0, "frame {f}: vkrt staged");
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
        // The top level over this frame's count: the level as it is where both instances
        // are built (the lowered one lies below it), else the lowered one, 3 further down.
        if let Some(t) = &top {
            assert_eq!(t.top.instance_count(), count);
            let got = probe(&ctx, t.top.handle_address(), &rays);
            let hits = got.iter().filter(|g| g[0] != u32::MAX).count();
            eprintln!("frame {f}: the top level over {count} instances: {hits} hits");
            for (k, (g, w)) in got.iter().zip(&want).enumerate() {
                let label = format!("frame {f}, {count} instances, ray {k}");
                match w {
                    None => assert_eq!(g[0], u32::MAX, "{label}: a hit"),
                    Some(p) => {
                        assert_eq!((g[2], g[3]), (*p, count - 1), "{label}");
                        let z = tris[*p as usize][0].z - 3.0 * (2 - count) as f32;
                        let t = f32::from_bits(g[0]);
                        assert!((t - (10.0 - z)).abs() < 1e-4, "{label}: t {t}");
                    }
                }
            }
        }
        drop(commands);
    }

    // The LBVH's and PLOC's structures as the last frame left them, compacted: the size
    // query, the compacted structures (their kernels compiled then) and the cache's sets
    // prepared first, then the copies recorded into the renderer's command buffer without
    // creating anything, and traced as the frame's were.
    let usage = match ray_query {
        true => REQUIRED_BUFFER_USAGE | DRIVER_BUFFER_USAGE,
        false => REQUIRED_BUFFER_USAGE,
    };
    let mut compacted = Vec::new();
    for s in &structures[1..3] {
        let mut rec = Recorder::new(&ctx).unwrap();
        rec.compute_to_transfer();
        let query = s.geometry.record_compacted_size(&mut rec).unwrap();
        rec.transfer_to_host();
        rec.submit_and_wait().unwrap();
        let size = query.read().unwrap();
        let memory = |name, bytes: u64| {
            host.buffer(name, bytes.max(4), MemoryLocation::GpuOnly, usage)
                .unwrap()
        };
        let structure = memory("renderer.compacted", size.bytes);
        let scratch = memory("renderer.compact_scratch", size.scratch_bytes);
        let dst = s
            .geometry
            .create_compacted_in(&ctx, &size, raw(&structure, size.bytes))
            .unwrap();
        let scratch_range = raw(&scratch, size.scratch_bytes);
        compacted.push((dst, scratch_range, [structure, scratch]));
    }
    let compact = |rec: &mut Recorder,
                   compacted: &mut [(GpuGeometry, RawBuffer, [HostBuffer; 2])]| {
        for (s, (dst, scratch, _)) in structures[1..3].iter().zip(compacted.iter_mut()) {
            s.geometry.record_compact_into(rec, dst, Some(*scratch))?;
        }
        Ok(())
    };
    cache.prepare(|rec| compact(rec, &mut compacted)).unwrap();
    let commands = host.command_buffer().unwrap();
    let before = ctx.traffic();
    // SAFETY: the host's command buffer, recording, outside a render pass; every buffer
    // outlives its execution, completed after the host's fence below.
    let mut rec = unsafe { Recorder::from_raw_with(&ctx, commands.cmd, &cache) }.unwrap();
    compact(&mut rec, &mut compacted).unwrap();
    let work = rec.finish().unwrap();
    let recorded = ctx.traffic() - before;
    host.submit_and_wait(commands.cmd).unwrap();
    // SAFETY: the host waited for its command buffer.
    unsafe { work.complete() }.unwrap();
    assert_eq!(
        recorded.objects_created, 0,
        "objects created while recording the compaction"
    );
    let want = expected(&grid(TOP_COUNTS.len() - 1), &rays);
    for (s, (dst, _, _)) in structures[1..3].iter().zip(&compacted) {
        let kind = s.builder.kind().name();
        let hits = s.tracer.trace(&ctx, dst, &rays, 0.0).unwrap().hits;
        let got: Vec<Option<u32>> = hits.iter().map(|h| h.is_hit().then_some(h.prim)).collect();
        assert_eq!(got, want, "{kind}, compacted: hits differ from brute force");
    }
    drop(commands);
    drop(compacted);
    drop(top);
    drop(structures);
    drop(cache);
    drop(ray_buffer);
    drop(ctx);
    drop(vertices);
    drop(host);
    let messages = std::mem::take(&mut *sink.lock().unwrap());
    assert!(messages.is_empty(), "validation: {messages:#?}");
}

/// The renderer's vertex shader: one triangle over the whole target.
const FULL_SCREEN_VERT: &str = r#"#version 460
void main() {
    vec2 p = vec2(float((gl_VertexIndex << 1) & 2), float(gl_VertexIndex & 2));
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
"#;

/// The renderer's fragment shader: one ray per pixel, straight down from the origin the
/// renderer gives that pixel, traced through vkrt's include; the pixel is the primitive hit
/// plus one, or 0 for a miss.
const TRACE_FRAG: &str = r#"#version 460
#define VKRT_SET 0
#define VKRT_BINDING 0
#include "vkrt/ray_query.glsl"

layout(std430, set = 0, binding = 7) readonly buffer Origins { vec4 origins[]; };
layout(push_constant) uniform Push { uint width; } pc;
layout(location = 0) out uint primPlusOne;

void main() {
    uvec2 px = uvec2(gl_FragCoord.xy);
    vec3 o = origins[px.y * pc.width + px.x].xyz;
    VkrtHit h = vkrtTraceClosest(o, 0.0, vec3(0.0, 0.0, -1.0), 1.0 / 0.0);
    primPlusOne = (h.hit && !h.exhausted) ? h.primitiveIndex + 1u : 0u;
}
"#;

/// Compiles `source` (a `stage` shader: "vert", "frag") with glslc and vkrt's include
/// directory, as a renderer's build does.
fn glslc(source: &str, stage: &str) -> Vec<u32> {
    static NEXT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let dir = std::env::temp_dir().join(format!("vkrt-frames-{}-{n}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (src, out) = (dir.join(format!("s.{stage}")), dir.join("s.spv"));
    std::fs::write(&src, source).unwrap();
    let o = std::process::Command::new("glslc")
        .arg("--target-env=vulkan1.2")
        .arg("-I")
        .arg(vkrt::accel::shader_library::include_dir())
        .arg(&src)
        .arg("-o")
        .arg(&out)
        .output()
        .expect("glslc (Debian: glslc)");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let spirv = bytemuck::pod_collect_to_vec::<u8, u32>(&std::fs::read(&out).unwrap());
    let _ = std::fs::remove_dir_all(&dir);
    spirv
}

/// The renderer's graphics pass: a render pass over one R32_UINT target per structure, a
/// pipeline of the two shaders above, one descriptor set per structure (its seven bindings
/// and the origins).
struct GraphicsPass {
    device: ash::Device,
    render_pass: vk::RenderPass,
    set_layout: vk::DescriptorSetLayout,
    layout: vk::PipelineLayout,
    pipeline: vk::Pipeline,
    pool: vk::DescriptorPool,
    sets: Vec<vk::DescriptorSet>,
    targets: Vec<Target>,
}

/// A colour target: image, its memory, view and framebuffer.
struct Target {
    image: vk::Image,
    allocation: Option<gpu_allocator::vulkan::Allocation>,
    view: vk::ImageView,
    framebuffer: vk::Framebuffer,
}

const FORMAT: vk::Format = vk::Format::R32_UINT;

impl GraphicsPass {
    /// The pass for `structures`, into `targets` targets of `size`².
    fn new(
        host: &Host,
        steps: u32,
        size: u32,
        structures: &[&GpuGeometry],
        origins: &HostBuffer,
        targets: usize,
    ) -> Self {
        let device = host.device.clone();
        let vert = glslc(FULL_SCREEN_VERT, "vert");
        let frag = glslc(TRACE_FRAG, "frag");
        // SAFETY: test code standing in for a renderer: plain Vulkan on the host's device,
        // every create-info pointing at locals that outlive the call; everything is
        // destroyed in Drop after the host waited for its work.
        unsafe {
            let attachment = [vk::AttachmentDescription::default()
                .format(FORMAT)
                .samples(vk::SampleCountFlags::TYPE_1)
                .load_op(vk::AttachmentLoadOp::CLEAR)
                .store_op(vk::AttachmentStoreOp::STORE)
                .initial_layout(vk::ImageLayout::UNDEFINED)
                .final_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)];
            let colour = [vk::AttachmentReference::default()
                .attachment(0)
                .layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)];
            let subpass = [vk::SubpassDescription::default()
                .pipeline_bind_point(vk::PipelineBindPoint::GRAPHICS)
                .color_attachments(&colour)];
            // Each target is drawn once, from an undefined layout, and copied out at the end
            // of the command buffer (`copy_out`): no dependency of the render pass reaches
            // vkrt's stages, so the barriers around the builds alone order them.
            let dependencies = [vk::SubpassDependency::default()
                .src_subpass(vk::SUBPASS_EXTERNAL)
                .dst_subpass(0)
                .src_stage_mask(vk::PipelineStageFlags::COLOR_ATTACHMENT_OUTPUT)
                .dst_stage_mask(vk::PipelineStageFlags::COLOR_ATTACHMENT_OUTPUT)
                .dst_access_mask(vk::AccessFlags::COLOR_ATTACHMENT_WRITE)];
            let render_pass = device
                .create_render_pass(
                    &vk::RenderPassCreateInfo::default()
                        .attachments(&attachment)
                        .subpasses(&subpass)
                        .dependencies(&dependencies),
                    None,
                )
                .unwrap();

            let stage = vk::ShaderStageFlags::FRAGMENT;
            let mut bindings =
                vkrt::accel::shader_library::descriptor_set_layout_bindings(0, stage).to_vec();
            bindings.push(
                vk::DescriptorSetLayoutBinding::default()
                    .binding(7)
                    .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                    .descriptor_count(1)
                    .stage_flags(stage),
            );
            let set_layout = device
                .create_descriptor_set_layout(
                    &vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings),
                    None,
                )
                .unwrap();
            let set_layouts = [set_layout];
            let push = [vk::PushConstantRange::default().stage_flags(stage).size(4)];
            let layout = device
                .create_pipeline_layout(
                    &vk::PipelineLayoutCreateInfo::default()
                        .set_layouts(&set_layouts)
                        .push_constant_ranges(&push),
                    None,
                )
                .unwrap();

            // The walk's step cap: the device's, through the library's constant.
            let (entries, data) = vkrt::accel::shader_library::steps_specialization(steps);
            let spec = vk::SpecializationInfo::default()
                .map_entries(&entries)
                .data(&data);
            let pipeline = graphics::fullscreen_pipeline(
                &device,
                &vert,
                &frag,
                &spec,
                layout,
                render_pass,
                size,
                vk::ColorComponentFlags::R,
            );

            let n = structures.len() as u32;
            let sizes = [vk::DescriptorPoolSize {
                ty: vk::DescriptorType::STORAGE_BUFFER,
                descriptor_count: 8 * n,
            }];
            let pool = device
                .create_descriptor_pool(
                    &vk::DescriptorPoolCreateInfo::default()
                        .max_sets(n)
                        .pool_sizes(&sizes),
                    None,
                )
                .unwrap();
            let layouts = vec![set_layout; structures.len()];
            let sets = device
                .allocate_descriptor_sets(
                    &vk::DescriptorSetAllocateInfo::default()
                        .descriptor_pool(pool)
                        .set_layouts(&layouts),
                )
                .unwrap();
            let origins_info = [vk::DescriptorBufferInfo {
                buffer: origins.raw,
                offset: 0,
                range: vk::WHOLE_SIZE,
            }];
            for (&set, g) in sets.iter().zip(structures) {
                let infos = g.descriptor_buffer_infos();
                let mut writes: Vec<vk::WriteDescriptorSet> = infos
                    .iter()
                    .enumerate()
                    .map(|(k, info)| {
                        vk::WriteDescriptorSet::default()
                            .dst_set(set)
                            .dst_binding(k as u32)
                            .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                            .buffer_info(std::slice::from_ref(info))
                    })
                    .collect();
                writes.push(
                    vk::WriteDescriptorSet::default()
                        .dst_set(set)
                        .dst_binding(7)
                        .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                        .buffer_info(&origins_info),
                );
                device.update_descriptor_sets(&writes, &[]);
            }

            let targets = (0..targets)
                .map(|_| Target::new(host, render_pass, size))
                .collect();
            Self {
                device,
                render_pass,
                set_layout,
                layout,
                pipeline,
                pool,
                sets,
                targets,
            }
        }
    }

    /// Records the pass tracing structure `k` into target `t`.
    ///
    /// # Safety
    /// `cmd` is recording, outside a render pass.
    unsafe fn record(&self, cmd: vk::CommandBuffer, k: usize, t: usize, size: u32) {
        let d = &self.device;
        let clear = [vk::ClearValue {
            color: vk::ClearColorValue { uint32: [7; 4] },
        }];
        let area = vk::Rect2D {
            offset: vk::Offset2D::default(),
            extent: vk::Extent2D {
                width: size,
                height: size,
            },
        };
        let begin = vk::RenderPassBeginInfo::default()
            .render_pass(self.render_pass)
            .framebuffer(self.targets[t].framebuffer)
            .render_area(area)
            .clear_values(&clear);
        // SAFETY: the caller's contract; every handle is this pass's.
        unsafe {
            d.cmd_begin_render_pass(cmd, &begin, vk::SubpassContents::INLINE);
            d.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::GRAPHICS, self.pipeline);
            d.cmd_bind_descriptor_sets(
                cmd,
                vk::PipelineBindPoint::GRAPHICS,
                self.layout,
                0,
                &[self.sets[k]],
                &[],
            );
            let push = size.to_ne_bytes();
            d.cmd_push_constants(cmd, self.layout, vk::ShaderStageFlags::FRAGMENT, 0, &push);
            d.cmd_draw(cmd, 3, 1, 0, 0);
            d.cmd_end_render_pass(cmd);
        }
    }

    /// Records the copy of every target, in order, into `out` (`size`² words each), then
    /// the barrier before the host reads it.
    ///
    /// # Safety
    /// `cmd` is recording, outside a render pass, after every target was drawn.
    unsafe fn copy_out(&self, cmd: vk::CommandBuffer, size: u32, out: &HostBuffer) {
        let d = &self.device;
        let range = vk::ImageSubresourceRange {
            aspect_mask: vk::ImageAspectFlags::COLOR,
            base_mip_level: 0,
            level_count: 1,
            base_array_layer: 0,
            layer_count: 1,
        };
        let to_transfer: Vec<vk::ImageMemoryBarrier> = self
            .targets
            .iter()
            .map(|t| {
                vk::ImageMemoryBarrier::default()
                    .src_access_mask(vk::AccessFlags::COLOR_ATTACHMENT_WRITE)
                    .dst_access_mask(vk::AccessFlags::TRANSFER_READ)
                    .old_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
                    .new_layout(vk::ImageLayout::TRANSFER_SRC_OPTIMAL)
                    .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                    .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                    .image(t.image)
                    .subresource_range(range)
            })
            .collect();
        let layers = vk::ImageSubresourceLayers {
            aspect_mask: vk::ImageAspectFlags::COLOR,
            mip_level: 0,
            base_array_layer: 0,
            layer_count: 1,
        };
        // SAFETY: the caller's contract; each target is in TRANSFER_SRC_OPTIMAL after the
        // first barrier, and `out` holds every target's words.
        unsafe {
            d.cmd_pipeline_barrier(
                cmd,
                vk::PipelineStageFlags::COLOR_ATTACHMENT_OUTPUT,
                vk::PipelineStageFlags::TRANSFER,
                vk::DependencyFlags::empty(),
                &[],
                &[],
                &to_transfer,
            );
            for (i, t) in self.targets.iter().enumerate() {
                let region = [vk::BufferImageCopy::default()
                    .buffer_offset(i as u64 * u64::from(size * size) * 4)
                    .image_subresource(layers)
                    .image_extent(vk::Extent3D {
                        width: size,
                        height: size,
                        depth: 1,
                    })];
                d.cmd_copy_image_to_buffer(
                    cmd,
                    t.image,
                    vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                    out.raw,
                    &region,
                );
            }
            barrier(
                d,
                cmd,
                (
                    vk::PipelineStageFlags::TRANSFER,
                    vk::AccessFlags::TRANSFER_WRITE,
                ),
                (vk::PipelineStageFlags::HOST, vk::AccessFlags::HOST_READ),
            );
        }
    }

    fn destroy(mut self, host: &Host) {
        // SAFETY: the host waited for every command buffer that used these objects.
        unsafe {
            let d = &self.device;
            for t in self.targets.drain(..) {
                d.destroy_framebuffer(t.framebuffer, None);
                d.destroy_image_view(t.view, None);
                d.destroy_image(t.image, None);
                if let Some(a) = t.allocation {
                    host.allocator.lock().unwrap().free(a).unwrap();
                }
            }
            d.destroy_descriptor_pool(self.pool, None);
            d.destroy_pipeline(self.pipeline, None);
            d.destroy_pipeline_layout(self.layout, None);
            d.destroy_descriptor_set_layout(self.set_layout, None);
            d.destroy_render_pass(self.render_pass, None);
        }
    }
}

impl Target {
    fn new(host: &Host, render_pass: vk::RenderPass, size: u32) -> Self {
        let d = &host.device;
        // SAFETY: as in GraphicsPass::new.
        unsafe {
            let image = d
                .create_image(
                    &vk::ImageCreateInfo::default()
                        .image_type(vk::ImageType::TYPE_2D)
                        .format(FORMAT)
                        .extent(vk::Extent3D {
                            width: size,
                            height: size,
                            depth: 1,
                        })
                        .mip_levels(1)
                        .array_layers(1)
                        .samples(vk::SampleCountFlags::TYPE_1)
                        .tiling(vk::ImageTiling::OPTIMAL)
                        .usage(
                            vk::ImageUsageFlags::COLOR_ATTACHMENT
                                | vk::ImageUsageFlags::TRANSFER_SRC,
                        )
                        .initial_layout(vk::ImageLayout::UNDEFINED),
                    None,
                )
                .unwrap();
            let requirements = d.get_image_memory_requirements(image);
            let allocation = host
                .allocator
                .lock()
                .unwrap()
                .allocate(&gpu_allocator::vulkan::AllocationCreateDesc {
                    name: "renderer.target",
                    requirements,
                    location: MemoryLocation::GpuOnly,
                    linear: false,
                    allocation_scheme: gpu_allocator::vulkan::AllocationScheme::GpuAllocatorManaged,
                })
                .unwrap();
            d.bind_image_memory(image, allocation.memory(), allocation.offset())
                .unwrap();
            let view = d
                .create_image_view(
                    &vk::ImageViewCreateInfo::default()
                        .image(image)
                        .view_type(vk::ImageViewType::TYPE_2D)
                        .format(FORMAT)
                        .subresource_range(vk::ImageSubresourceRange {
                            aspect_mask: vk::ImageAspectFlags::COLOR,
                            base_mip_level: 0,
                            level_count: 1,
                            base_array_layer: 0,
                            layer_count: 1,
                        }),
                    None,
                )
                .unwrap();
            let views = [view];
            let framebuffer = d
                .create_framebuffer(
                    &vk::FramebufferCreateInfo::default()
                        .render_pass(render_pass)
                        .attachments(&views)
                        .width(size)
                        .height(size)
                        .layers(1),
                    None,
                )
                .unwrap();
            Self {
                image,
                allocation: Some(allocation),
                view,
                framebuffer,
            }
        }
    }
}

/// Records a global memory barrier.
///
/// # Safety
/// `cmd` is recording, outside a render pass.
unsafe fn sync(device: &ash::Device, cmd: vk::CommandBuffer, src: StageAccess, dst: StageAccess) {
    // SAFETY: the caller's contract.
    unsafe {
        barrier(
            device,
            cmd,
            (src.stages, src.access),
            (dst.stages, dst.access),
        )
    }
}

#[test]
fn a_fragment_shader_traces_a_structure_rebuilt_in_place_frame_after_frame() {
    let _turn = common::vulkan_turn();
    let Some((host, ctx)) = host_and_context() else {
        return;
    };
    let sink = host.sink.clone();
    let size: u32 = if common::quick() { 24 } else { 48 };
    let pixels = (size * size) as usize;
    // Every frame's vertices in one buffer of the renderer's, a region per frame: all the
    // frames are recorded into one command buffer, so nothing but barriers orders them.
    let frames: Vec<Vec<[Vec3; 3]>> = (0..FRAMES).map(grid).collect();
    let vertex_bytes = (frames[0].len() * 36) as u64;
    let region = vertex_bytes.next_multiple_of(256);
    let mut vertices = host
        .buffer(
            "renderer.vertices",
            region * FRAMES as u64,
            MemoryLocation::CpuToGpu,
            vk::BufferUsageFlags::STORAGE_BUFFER,
        )
        .unwrap();
    let mut words = vec![0u8; (region * FRAMES as u64) as usize];
    for (f, tris) in frames.iter().enumerate() {
        let tri_words = vertex_words(tris);
        let bytes: &[u8] = bytemuck::cast_slice(&tri_words);
        let at = f * region as usize;
        words[at..at + bytes.len()].copy_from_slice(bytes);
    }
    vertices.write(&words);
    let geometries_of = |f: usize| {
        let range = unsafe { RawBuffer::new(vertices.raw, f as u64 * region, vertex_bytes) };
        [Geometry::Triangles(Triangles::soup(
            range,
            (frames[f].len() * 3) as u32,
        ))]
    };
    // One origin per pixel, jittered inside it, over a square a little larger than the grid.
    let extent = CELLS as f32 + 4.0;
    let mut rng = common::Rng(5);
    let origins: Vec<[f32; 4]> = (0..pixels)
        .map(|i| {
            let (x, y) = ((i % size as usize) as f32, (i / size as usize) as f32);
            let jitter = |r: &mut common::Rng| 0.5 + 0.45 * r.next_f32();
            [
                (x + jitter(&mut rng)) / size as f32 * extent - extent / 2.0,
                (y + jitter(&mut rng)) / size as f32 * extent - extent / 2.0,
                10.0,
                0.0,
            ]
        })
        .collect();
    let mut origin_buffer = host
        .buffer(
            "renderer.origins",
            (pixels * 16) as u64,
            MemoryLocation::CpuToGpu,
            vk::BufferUsageFlags::STORAGE_BUFFER,
        )
        .unwrap();
    origin_buffer.write(bytemuck::cast_slice(&origins));
    let rays: Vec<Ray> = origins
        .iter()
        .map(|o| Ray::new(Vec3::new(o[0], o[1], o[2]), -Vec3::Z, 0.0, f32::INFINITY))
        .collect();

    let kinds = [AccelKind::KdTree, AccelKind::Lbvh, AccelKind::Ploc];
    let flags = BuildFlags::default();
    let mut memory = Vec::new();
    let mut builds: Vec<(AccelBuilder, GpuGeometry, RawBuffer)> = kinds
        .iter()
        .map(|&kind| {
            let builder = AccelBuilder::new(&ctx, kind).unwrap();
            let sizes = builder.sizes_for(&ctx, &geometries_of(0), &flags).unwrap();
            let buffer = |name, bytes: u64| {
                host.buffer(
                    name,
                    bytes.max(4),
                    MemoryLocation::GpuOnly,
                    REQUIRED_BUFFER_USAGE,
                )
                .unwrap()
            };
            let structure = buffer("renderer.structure", sizes.structure_bytes);
            let scratch = buffer("renderer.scratch", sizes.build_scratch_bytes);
            let g = builder
                .create_in(
                    &ctx,
                    &geometries_of(0),
                    &flags,
                    raw(&structure, sizes.structure_bytes),
                )
                .unwrap();
            let scratch_range = raw(&scratch, sizes.build_scratch_bytes.max(4));
            memory.push([structure, scratch]);
            (builder, g, scratch_range)
        })
        .collect();
    let pass = {
        let structures: Vec<&GpuGeometry> = builds.iter().map(|b| &b.1).collect();
        let steps = ctx.info().max_traversal_steps;
        let targets = FRAMES * kinds.len();
        GraphicsPass::new(&host, steps, size, &structures, &origin_buffer, targets)
    };
    let image_bytes = (pixels * 4) as u64;
    let readback = host
        .buffer(
            "renderer.readback",
            image_bytes * (FRAMES * kinds.len()) as u64,
            MemoryLocation::GpuToCpu,
            vk::BufferUsageFlags::TRANSFER_DST,
        )
        .unwrap();

    // Every frame's builds, prepared once.
    let cache = BindingCache::new(&ctx);
    cache
        .prepare(|rec| {
            for f in 0..FRAMES {
                for (builder, g, scratch) in builds.iter_mut() {
                    builder.record_build_from(rec, g, &geometries_of(f), *scratch)?;
                }
            }
            Ok(())
        })
        .unwrap();

    let commands = host.command_buffer().unwrap();
    let cmd = commands.cmd;
    let before = ctx.traffic();
    // SAFETY: the host's command buffer, recording; the work is completed after its fence.
    let mut rec = unsafe { Recorder::from_raw_with(&ctx, cmd, &cache) }.unwrap();
    let fragment_read = StageAccess {
        stages: vk::PipelineStageFlags::FRAGMENT_SHADER,
        access: vk::AccessFlags::SHADER_READ,
    };
    for f in 0..FRAMES {
        for (k, (builder, g, scratch)) in builds.iter_mut().enumerate() {
            let contract = RecordSync::build(builder.kind());
            // The rebuild in place writes what the previous frame's fragment shader read:
            // an execution dependency from that stage to the build's first accesses.
            let war = StageAccess {
                stages: fragment_read.stages,
                access: vk::AccessFlags::empty(),
            };
            // SAFETY: the host's recording command buffer, outside a render pass.
            unsafe { sync(&host.device, cmd, war, contract.first) };
            builder
                .record_build_from(&mut rec, g, &geometries_of(f), *scratch)
                .unwrap();
            // The build's last accesses before the fragment shader's reads.
            // SAFETY: as above.
            unsafe { sync(&host.device, cmd, contract.last, fragment_read) };
            // SAFETY: as above.
            unsafe { pass.record(cmd, k, f * kinds.len() + k, size) };
        }
    }
    // SAFETY: as above, after every pass.
    unsafe { pass.copy_out(cmd, size, &readback) };
    let work = rec.finish().unwrap();
    let recorded = ctx.traffic() - before;
    host.submit_and_wait(cmd).unwrap();
    // SAFETY: the host waited for its command buffer.
    unsafe { work.complete() }.unwrap();
    assert_eq!(
        recorded.objects_created, 0,
        "objects created while recording"
    );

    let images: Vec<u32> = bytemuck::pod_collect_to_vec(
        &readback.read()[..(image_bytes as usize * FRAMES * kinds.len())],
    );
    for (f, tris) in frames.iter().enumerate() {
        let want = expected(tris, &rays);
        assert!(want.iter().any(Option::is_some) && want.iter().any(Option::is_none));
        for (k, kind) in kinds.iter().enumerate() {
            let at = (f * kinds.len() + k) * pixels;
            let got = &images[at..at + pixels];
            let wrong: Vec<usize> = (0..pixels)
                .filter(|&i| got[i] != want[i].map_or(0, |p| p + 1))
                .collect();
            assert!(
                wrong.is_empty(),
                "frame {f}, {}: {} of {pixels} pixels differ from brute force (first: pixel {}, \
                 {} against {:?})",
                kind.name(),
                wrong.len(),
                wrong[0],
                got[wrong[0]],
                want[wrong[0]]
            );
        }
    }
    drop(commands);
    pass.destroy(&host);
    drop(builds);
    drop(cache);
    drop(ctx);
    drop((memory, vertices, origin_buffer, readback));
    drop(host);
    let messages = std::mem::take(&mut *sink.lock().unwrap());
    assert!(messages.is_empty(), "validation: {messages:#?}");
}
