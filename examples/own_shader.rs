//! A renderer's own compute shader tracing vkrt's structures, on the renderer's terms.
//!
//! The host (standing in for a renderer) owns its instance, device, allocator and command
//! buffer. It puts the mesh's vertex and index buffers in its own memory (two geometries over
//! one vertex buffer: the first half of the triangles with `u32` indices, the second with
//! `u16` indices and a transform), asks vkrt for the sizes of each structure (kd-tree, LBVH,
//! PLOC, and the driver's where the device has ray query, which the host then enables),
//! allocates the structure and scratch buffers itself, records vkrt's build into its
//! own command buffer, then dispatches ITS OWN compute shader — ambient-occlusion rays,
//! compiled here with `glslc` against `vkrt/ray_query.glsl` — which traces through the
//! include. Every hit is checked against a brute-force CPU reference.
//!
//! ```text
//! cargo run --release --example own_shader [-- [--json] [--no-check] [MESH.obj] [RAYS]]
//! ```
//!
//! With `--json` it prints one line: `{"kinds": {"lbvh": {"rays": N, "mismatches": 0, ...},
//! ...}, "vkrt_submits": 0, "vkrt_upload_bytes": 0, "vkrt_allocations": 0}` — the queue
//! submissions, uploads and device allocations vkrt itself made while the host recorded the
//! builds and its trace. Each kind's entry also times the host's shader against vkrt's own
//! trace kernel on the same rays (GPU timestamps in the host's command buffer).
//! `tests/example_own_shader.rs` runs [`run`] on both lavapipes under validation.

use std::path::{Path, PathBuf};

use ash::vk;
use glam::Vec3;
use gpu_allocator::MemoryLocation;
use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::embedded::{BuildFlags, DRIVER_BUFFER_USAGE, REQUIRED_BUFFER_USAGE};
use vkrt::accel::geometry::{transform_point, Geometry, IndexType, Indices, Triangles};
use vkrt::accel::primitives::TraceGeometry;
use vkrt::accel::shader_library;
use vkrt::gpu::{Buffer, Context, RawBuffer, Recorder, Validation, DEFAULT_QUERY_CAPACITY};
use vkrt::trace::gpu::Tracer;
use vkrt::trace::{Hit, Query, Ray, TraceOptions};

#[path = "common/host.rs"]
mod host;
use host::{barrier, BoxResult, Host, HostBuffer};

/// The host's own shader: closest hit and occlusion within the AO radius, per ray.
const AO_SHADER: &str = r#"#version 460
layout(local_size_x = 64) in;
#define VKRT_SET 1
#define VKRT_BINDING 0
#include "vkrt/ray_query.glsl"

// The host's ray layout (origin and tMin, direction and tMax), its own results.
struct AoRay { vec4 origin_tmin; vec4 dir_tmax; };
layout(set = 0, binding = 0) readonly buffer Rays { AoRay rays[]; };
layout(set = 0, binding = 1) writeonly buffer Results { uvec4 results[]; };
layout(push_constant) uniform Push { uint n; float ao_radius; uint closest_only; } pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.n) {
        return;
    }
    AoRay r = rays[i];
    VkrtHit h = vkrtTraceClosest(r.origin_tmin.xyz, r.origin_tmin.w, r.dir_tmax.xyz, r.dir_tmax.w);
    bool exhausted = h.exhausted;
    uint occluded = 0u;
    if (pc.closest_only == 0u) {
        occluded = vkrtTraceAny(r.origin_tmin.xyz, r.origin_tmin.w, r.dir_tmax.xyz, pc.ao_radius)
            ? 1u : 0u;
        exhausted = exhausted || vkrtExhausted();
    }
    results[i] = uvec4(floatBitsToUint(h.t), h.primitiveIndex, h.geometryIndex,
                       occluded | (exhausted ? 2u : 0u));
}
"#;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct AoPush {
    n: u32,
    ao_radius: f32,
    closest_only: u32,
}

/// A mesh: positions and triangles.
pub struct Mesh {
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
}

/// One structure's results.
#[derive(Clone, Debug, serde::Serialize)]
pub struct KindReport {
    pub rays: usize,
    /// Closest hits that differ from the CPU reference (t, geometry or primitive); `None`
    /// when run without the check (`--no-check`, for timing many rays).
    pub mismatches: Option<usize>,
    /// Occlusion answers that differ from the CPU reference.
    pub any_mismatches: Option<usize>,
    pub exhausted: usize,
    pub structure_bytes: u64,
    pub build_scratch_bytes: u64,
    /// GPU milliseconds of the build, of the host's shader (closest hits only) and of
    /// vkrt's own trace kernel on the same rays (`None` without timestamps).
    pub build_ms: Option<f64>,
    pub own_shader_ms: Option<f64>,
    /// The host's shader compiled with the one walk this kind needs (`VKRT_WALK`).
    pub own_shader_one_walk_ms: Option<f64>,
    pub vkrt_trace_ms: Option<f64>,
}

/// What one run did.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Summary {
    pub device: String,
    pub kinds: std::collections::BTreeMap<String, KindReport>,
    /// Queue submissions, bytes uploaded and device buffers allocated by vkrt while the host
    /// recorded the builds and its own trace.
    pub vkrt_submits: u64,
    pub vkrt_upload_bytes: u64,
    pub vkrt_allocations: u64,
    /// The host enabled the driver's ray query (and so built the driver's structure too).
    pub ray_query: bool,
    #[serde(skip)]
    pub messages: Vec<String>,
}

/// The transform of the second geometry (a small shift, so that it shows).
const SHIFT: [[f32; 4]; 3] = [
    [1.0, 0.0, 0.0, 0.01],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
];

/// AO rays: from a point just above each sampled triangle, into its hemisphere.
pub fn ao_rays(mesh: &Mesh, n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = vkrt::scene::gen::Rng::new(seed);
    let tris = world_triangles(mesh);
    let (lo, hi) = tris.iter().flatten().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    );
    let eps = (hi - lo).length() * 1e-4;
    (0..n)
        .map(|i| {
            let t = &tris[(i * 7919) % tris.len().max(1)];
            let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
            let centre = (t[0] + t[1] + t[2]) / 3.0;
            let d = loop {
                let v = rng.vec3_signed();
                if (0.01..=1.0).contains(&v.length_squared()) {
                    break v.normalize();
                }
            };
            let d = if d.dot(n) < 0.0 { -d } else { d };
            Ray::new(centre + n * eps, d, eps, f32::INFINITY)
        })
        .collect()
}

/// The mesh's triangles as vkrt numbers them: the first geometry's, then the second's
/// (transformed).
fn world_triangles(mesh: &Mesh) -> Vec<[Vec3; 3]> {
    let half = mesh.triangles.len() / 2;
    mesh.triangles
        .iter()
        .enumerate()
        .map(|(k, t)| {
            t.map(|v| {
                let p = mesh.positions[v as usize];
                if k < half {
                    p
                } else {
                    transform_point(&SHIFT, p)
                }
            })
        })
        .collect()
}

/// Creates the host's Vulkan objects, builds each of `kinds` over `mesh` through vkrt in the
/// host's memory and command buffer, traces `rays` with the host's own shader, checks them,
/// destroys everything and reports.
pub fn run(
    mesh: &Mesh,
    rays: &[Ray],
    kinds: &[AccelKind],
    validation: Validation,
) -> BoxResult<Summary> {
    run_with(mesh, rays, kinds, validation, true)
}

/// [`run`], with the CPU check (`check`) or without it (for timing many rays).
pub fn run_with(
    mesh: &Mesh,
    rays: &[Ray],
    kinds: &[AccelKind],
    validation: Validation,
    check: bool,
) -> BoxResult<Summary> {
    let host = Host::new(validation)?;
    // Exact hits (equal to vkrt's CPU twin on any device) where the host enabled doubles.
    let exact = host.features.shader_float64 && host.features.shader_int64;
    let spirv = Shaders {
        generic: compile_ao_shader(None, exact)?,
        kdtree: compile_ao_shader(Some("VKRT_WALK_KDTREE"), exact)?,
        bvh: compile_ao_shader(Some("VKRT_WALK_BVH"), exact)?,
        driver: match host.features.ray_query {
            true => Some(compile_ao_shader(Some("VKRT_RAY_QUERY"), exact)?),
            false => None,
        },
    };
    let sink = host.sink.clone();
    let result = build_and_trace(&host, mesh, rays, kinds, &spirv, check);
    drop(host);
    let mut summary = result?;
    summary.messages = std::mem::take(&mut *sink.lock().unwrap());
    Ok(summary)
}

/// The host's shader: one for every kind of structure, and one per walk (`VKRT_WALK`).
pub struct Shaders {
    pub generic: Vec<u32>,
    pub kdtree: Vec<u32>,
    pub bvh: Vec<u32>,
    /// Every walk and the driver's ray query (`VKRT_RAY_QUERY`), where the device has it.
    pub driver: Option<Vec<u32>>,
}

/// The host compiles its shader with its own compiler (`glslc`), given vkrt's include
/// directory; `walk`: the one walk to compile in (`VKRT_WALK`), else every walk, or
/// `VKRT_RAY_QUERY`: every walk and the driver's ray query; `exact`: `VKRT_EXACT` (the device
/// has doubles and 64-bit integers enabled).
pub fn compile_ao_shader(walk: Option<&str>, exact: bool) -> BoxResult<Vec<u32>> {
    let dir = std::env::temp_dir().join(format!(
        "vkrt-own-shader-{}-{}",
        std::process::id(),
        walk.unwrap_or("all")
    ));
    std::fs::create_dir_all(&dir)?;
    let src = dir.join("ao.comp");
    let out = dir.join("ao.spv");
    std::fs::write(&src, AO_SHADER)?;
    let mut glslc = std::process::Command::new("glslc");
    match walk {
        Some("VKRT_RAY_QUERY") => {
            glslc.arg("-DVKRT_RAY_QUERY");
        }
        Some(w) => {
            glslc.arg(format!("-DVKRT_WALK={w}"));
        }
        None => {}
    }
    if exact {
        glslc.arg("-DVKRT_EXACT");
    }
    let result = glslc
        .arg("--target-env=vulkan1.2")
        .arg("-O")
        .arg("-I")
        .arg(shader_library::include_dir())
        .arg(&src)
        .arg("-o")
        .arg(&out)
        .output();
    let spirv = match result {
        Err(e) => Err(format!("cannot run glslc ({e}): install it (Debian: glslc)").into()),
        Ok(o) if !o.status.success() => {
            Err(format!("glslc failed:\n{}", String::from_utf8_lossy(&o.stderr)).into())
        }
        Ok(_) => std::fs::read(&out)
            .map(|b| bytemuck::pod_collect_to_vec::<u8, u32>(&b))
            .map_err(Into::into),
    };
    let _ = std::fs::remove_dir_all(&dir);
    spirv
}

/// The host's pipeline: set 0 its rays and results, set 1 vkrt's structure.
struct AoPipeline {
    device: ash::Device,
    set_layouts: [vk::DescriptorSetLayout; 2],
    layout: vk::PipelineLayout,
    pipeline: vk::Pipeline,
    pool: vk::DescriptorPool,
}

impl AoPipeline {
    fn new(device: &ash::Device, spirv: &[u32], max_traversal_steps: u32) -> BoxResult<Self> {
        let own = [0, 1].map(|b| {
            vk::DescriptorSetLayoutBinding::default()
                .binding(b)
                .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                .descriptor_count(1)
                .stage_flags(vk::ShaderStageFlags::COMPUTE)
        });
        let vkrt_bindings =
            shader_library::descriptor_set_layout_bindings(0, vk::ShaderStageFlags::COMPUTE);
        let mut p = Self {
            device: device.clone(),
            set_layouts: [vk::DescriptorSetLayout::null(); 2],
            layout: vk::PipelineLayout::null(),
            pipeline: vk::Pipeline::null(),
            pool: vk::DescriptorPool::null(),
        };
        // SAFETY: valid device; create-infos point at locals; `Drop` destroys whatever was
        // created if a later step fails.
        unsafe {
            for (i, b) in [&own[..], &vkrt_bindings[..]].iter().enumerate() {
                p.set_layouts[i] = device.create_descriptor_set_layout(
                    &vk::DescriptorSetLayoutCreateInfo::default().bindings(b),
                    None,
                )?;
            }
            let push = [vk::PushConstantRange::default()
                .stage_flags(vk::ShaderStageFlags::COMPUTE)
                .size(size_of::<AoPush>() as u32)];
            p.layout = device.create_pipeline_layout(
                &vk::PipelineLayoutCreateInfo::default()
                    .set_layouts(&p.set_layouts)
                    .push_constant_ranges(&push),
                None,
            )?;
            let module = device
                .create_shader_module(&vk::ShaderModuleCreateInfo::default().code(spirv), None)?;
            let (entries, data) = shader_library::steps_specialization(max_traversal_steps);
            let specialization = vk::SpecializationInfo::default()
                .map_entries(&entries)
                .data(&data);
            let stage = vk::PipelineShaderStageCreateInfo::default()
                .stage(vk::ShaderStageFlags::COMPUTE)
                .module(module)
                .name(c"main")
                .specialization_info(&specialization);
            let created = device.create_compute_pipelines(
                vk::PipelineCache::null(),
                &[vk::ComputePipelineCreateInfo::default()
                    .stage(stage)
                    .layout(p.layout)],
                None,
            );
            device.destroy_shader_module(module, None);
            p.pipeline = created.map_err(|(_, e)| e)?[0];
            let sizes = [vk::DescriptorPoolSize {
                ty: vk::DescriptorType::STORAGE_BUFFER,
                descriptor_count: 64,
            }];
            p.pool = device.create_descriptor_pool(
                &vk::DescriptorPoolCreateInfo::default()
                    .max_sets(16)
                    .pool_sizes(&sizes),
                None,
            )?;
        }
        Ok(p)
    }

    /// Descriptor sets: its own buffers, and vkrt's structure.
    fn sets(
        &self,
        own: [vk::DescriptorBufferInfo; 2],
        structure: [vk::DescriptorBufferInfo; 7],
    ) -> BoxResult<[vk::DescriptorSet; 2]> {
        // SAFETY: the pool has room (16 sets, 64 buffers; the example uses 2 sets per kind);
        // the writes name bindings of the layouts the sets were allocated with.
        unsafe {
            let sets = self.device.allocate_descriptor_sets(
                &vk::DescriptorSetAllocateInfo::default()
                    .descriptor_pool(self.pool)
                    .set_layouts(&self.set_layouts),
            )?;
            let mut writes = Vec::new();
            for (b, info) in own.iter().enumerate() {
                writes.push(
                    vk::WriteDescriptorSet::default()
                        .dst_set(sets[0])
                        .dst_binding(b as u32)
                        .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                        .buffer_info(std::slice::from_ref(info)),
                );
            }
            for (b, info) in structure.iter().enumerate() {
                writes.push(
                    vk::WriteDescriptorSet::default()
                        .dst_set(sets[1])
                        .dst_binding(b as u32)
                        .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                        .buffer_info(std::slice::from_ref(info)),
                );
            }
            self.device.update_descriptor_sets(&writes, &[]);
            Ok([sets[0], sets[1]])
        }
    }

    /// Records the dispatch over `n` rays.
    ///
    /// # Safety
    /// `cmd` is recording, outside a render pass; the sets' buffers outlive its execution.
    unsafe fn record(&self, cmd: vk::CommandBuffer, sets: &[vk::DescriptorSet; 2], push: AoPush) {
        // SAFETY: the caller's contract; the sets match the layout.
        unsafe {
            let d = &self.device;
            d.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::COMPUTE, self.pipeline);
            d.cmd_bind_descriptor_sets(
                cmd,
                vk::PipelineBindPoint::COMPUTE,
                self.layout,
                0,
                sets,
                &[],
            );
            d.cmd_push_constants(
                cmd,
                self.layout,
                vk::ShaderStageFlags::COMPUTE,
                0,
                bytemuck::bytes_of(&push),
            );
            d.cmd_dispatch(cmd, push.n.div_ceil(64), 1, 1);
        }
    }
}

impl Drop for AoPipeline {
    fn drop(&mut self) {
        // SAFETY: the host waited for its submissions; null handles are ignored by Vulkan.
        unsafe {
            self.device.destroy_descriptor_pool(self.pool, None);
            self.device.destroy_pipeline(self.pipeline, None);
            self.device.destroy_pipeline_layout(self.layout, None);
            for l in self.set_layouts {
                self.device.destroy_descriptor_set_layout(l, None);
            }
        }
    }
}

fn raw(b: &HostBuffer, size: u64) -> RawBuffer {
    unsafe { RawBuffer::new(b.raw, 0, size) }
}

fn info(b: &HostBuffer, size: u64) -> vk::DescriptorBufferInfo {
    vk::DescriptorBufferInfo {
        buffer: b.raw,
        offset: 0,
        range: size,
    }
}

fn build_and_trace(
    host: &Host,
    mesh: &Mesh,
    rays: &[Ray],
    kinds: &[AccelKind],
    spirv: &Shaders,
    check: bool,
) -> BoxResult<Summary> {
    let n = rays.len();
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    // The renderer's own mesh buffers: one vertex buffer, the first half of the triangles
    // with u32 indices, the second half with u16 indices.
    let half = mesh.triangles.len() / 2;
    let idx32: Vec<u32> = mesh.triangles[..half].iter().flatten().copied().collect();
    let idx16: Vec<u16> = mesh.triangles[half..]
        .iter()
        .flatten()
        .map(|&i| u16::try_from(i))
        .collect::<Result<_, _>>()
        .map_err(|_| "the second half's indices must fit 16 bits (a mesh under 65,536 vertices)")?;
    let bytes = |len: usize| (len as u64).max(4);
    let usage = storage | vk::BufferUsageFlags::TRANSFER_SRC;
    let mut vertices = host.buffer(
        "host.vertices",
        bytes(size_of_val(&mesh.positions[..])),
        MemoryLocation::CpuToGpu,
        usage,
    )?;
    vertices.write(bytemuck::cast_slice(&mesh.positions));
    let mut indices32 = host.buffer(
        "host.indices32",
        bytes(idx32.len() * 4),
        MemoryLocation::CpuToGpu,
        usage,
    )?;
    indices32.write(bytemuck::cast_slice(&idx32));
    let mut indices16 = host.buffer(
        "host.indices16",
        bytes(idx16.len() * 2),
        MemoryLocation::CpuToGpu,
        usage,
    )?;
    indices16.write(bytemuck::cast_slice(&idx16));
    let ray_bytes = bytes(size_of_val(rays));
    let mut host_rays = host.buffer("host.rays", ray_bytes, MemoryLocation::CpuToGpu, usage)?;
    host_rays.write(bytemuck::cast_slice(rays));
    let result_bytes = bytes(n * 16);
    let results = host.buffer(
        "host.results",
        result_bytes,
        MemoryLocation::GpuToCpu,
        storage,
    )?;
    let vertex_count = mesh.positions.len() as u32;
    let vertex_range = raw(&vertices, bytes(size_of_val(&mesh.positions[..])));
    let geometries = [
        Geometry::Triangles(Triangles::indexed(
            vertex_range,
            vertex_count,
            raw(&indices32, bytes(idx32.len() * 4)),
            IndexType::U32,
            half as u32,
        )),
        Geometry::Triangles(Triangles {
            indices: Some(Indices {
                data: raw(&indices16, bytes(idx16.len() * 2)).into(),
                index_type: IndexType::U16,
            }),
            triangle_count: (mesh.triangles.len() - half) as u32,
            transform: Some(SHIFT.into()),
            ..Triangles::soup(vertex_range, vertex_count)
        }),
    ];
    // The driver's structure reads its inputs at device addresses and lives in buffers of
    // the acceleration-structure kind.
    let structure_usage = match host.features.ray_query {
        true => REQUIRED_BUFFER_USAGE | DRIVER_BUFFER_USAGE,
        false => REQUIRED_BUFFER_USAGE,
    };

    // SAFETY: every handle in `parts` is the host's, valid, of one instance and device; the
    // host outlives the context (dropped before `host` at the end of `run`) and this thread
    // is the only one using the queue.
    let ctx = unsafe { Context::from_raw(host.raw_parts()) }?;
    // The walks' step cap is the device's, through the library's specialization constant.
    let steps = ctx.info().max_traversal_steps;
    let pipeline = AoPipeline::new(&host.device, &spirv.generic, steps)?;
    let kd_pipeline = AoPipeline::new(&host.device, &spirv.kdtree, steps)?;
    let bvh_pipeline = AoPipeline::new(&host.device, &spirv.bvh, steps)?;
    let driver_pipeline = match &spirv.driver {
        Some(code) => Some(AoPipeline::new(&host.device, code, steps)?),
        None => None,
    };
    let reference = if check {
        reference(mesh, rays)
    } else {
        Vec::new()
    };
    let ao_radius = ao_radius(mesh);
    let mut report = Summary {
        device: ctx.info().device.clone(),
        kinds: Default::default(),
        vkrt_submits: 0,
        vkrt_upload_bytes: 0,
        vkrt_allocations: 0,
        ray_query: host.features.ray_query,
        messages: Vec::new(),
    };
    // vkrt's own trace kernel, for the timing comparison, reads the same rays.
    let vkrt_rays = Buffer::<Ray>::new(&ctx, "own_shader.vkrt_rays", n)?;
    let vkrt_hits = Buffer::<Hit>::new(&ctx, "own_shader.vkrt_hits", n)?;
    let vkrt_errors = Buffer::<u32>::new(&ctx, "own_shader.vkrt_errors", 1)?;
    vkrt_rays.upload(rays)?;
    for &kind in kinds {
        // The driver's structure needs the driver's ray query, and its own shader.
        let (pipeline, specialized) = match (kind, &driver_pipeline) {
            (AccelKind::Driver, None) => continue,
            (AccelKind::Driver, Some(d)) => (d, d),
            (AccelKind::KdTree, _) => (&pipeline, &kd_pipeline),
            _ => (&pipeline, &bvh_pipeline),
        };
        let builder = AccelBuilder::new(&ctx, kind)?;
        let flags = BuildFlags::default();
        let sizes = builder.sizes_for(&ctx, &geometries, &flags)?;
        // The host allocates the structure and the scratch in its own memory.
        let structure_buf = host.buffer(
            "host.structure",
            sizes.structure_bytes.max(4),
            MemoryLocation::GpuOnly,
            structure_usage,
        )?;
        let scratch_buf = host.buffer(
            "host.scratch",
            sizes.build_scratch_bytes.max(4),
            MemoryLocation::GpuOnly,
            structure_usage,
        )?;
        let mut structure = builder.create_in(
            &ctx,
            &geometries,
            &flags,
            raw(&structure_buf, sizes.structure_bytes.max(4)),
        )?;
        let tracer = Tracer::for_accel(
            &ctx,
            &TraceOptions {
                exact: false,
                ..TraceOptions::default()
            },
            kind.walked(Default::default()),
        )?;
        let sets = pipeline.sets(
            [info(&host_rays, ray_bytes), info(&results, result_bytes)],
            structure.descriptor_buffer_infos(),
        )?;
        let special_sets = specialized.sets(
            [info(&host_rays, ray_bytes), info(&results, result_bytes)],
            structure.descriptor_buffer_infos(),
        )?;
        let commands = host.command_buffer()?;
        let cmd = commands.cmd;
        let before = ctx.traffic();
        // SAFETY: `cmd` is the host's primary command buffer of the context's family,
        // recording, outside a render pass; everything bound outlives its execution (dropped
        // after the fence wait); `complete` follows that wait.
        let mut rec = unsafe { Recorder::from_raw(&ctx, cmd, DEFAULT_QUERY_CAPACITY) }?;
        builder.record_build_from(
            &mut rec,
            &mut structure,
            &geometries,
            raw(&scratch_buf, sizes.build_scratch_bytes.max(4)),
        )?;
        // The host's own trace, in a vkrt profiler scope so both are timed alike: closest
        // hits and occlusion (checked), then closest hits alone (timed against vkrt's).
        let push = |closest_only| AoPush {
            n: n as u32,
            ao_radius,
            closest_only,
        };
        // Three rounds of: the host's shader (every walk), the host's shader (one walk),
        // vkrt's own kernel; the best of each is reported (lavapipe's threads vary).
        let mut after = None;
        for round in 0..3 {
            rec.scope(&format!("own_shader.{round}"), |_| {
                // SAFETY: see the recorder above.
                unsafe { pipeline.record(cmd, &sets, push(1)) }
            });
            after.get_or_insert(ctx.traffic() - before);
            rec.compute_to_compute();
            rec.scope(&format!("own_shader.one_walk.{round}"), |_| {
                // SAFETY: as above.
                unsafe { specialized.record(cmd, &special_sets, push(1)) }
            });
            rec.scope(&format!("vkrt_trace.{round}"), |rec| {
                tracer.record(
                    rec,
                    &structure,
                    &vkrt_rays,
                    &vkrt_hits,
                    &vkrt_errors,
                    n,
                    0.0,
                )
            })?;
            rec.compute_to_compute();
        }
        let after = after.unwrap_or_default();
        // SAFETY: `cmd` is recording.
        unsafe {
            barrier(
                &host.device,
                cmd,
                (
                    vk::PipelineStageFlags::COMPUTE_SHADER,
                    vk::AccessFlags::SHADER_WRITE,
                ),
                (vk::PipelineStageFlags::HOST, vk::AccessFlags::HOST_READ),
            );
        }
        let work = rec.finish()?;
        host.submit_and_wait(cmd)?;
        // SAFETY: the command buffer has finished executing (the fence was waited for).
        let profile = unsafe { work.complete() }?;
        report.vkrt_submits += after.submits;
        report.vkrt_upload_bytes += after.upload_bytes;
        report.vkrt_allocations += after.device_allocations;
        // The checked pass: closest hits and occlusion, in a command buffer of its own.
        let checked = checked_pass(host, pipeline, &sets, push(0), n, &results)?;
        let mut k = KindReport {
            rays: n,
            mismatches: check.then_some(0),
            any_mismatches: check.then_some(0),
            exhausted: 0,
            structure_bytes: sizes.structure_bytes,
            build_scratch_bytes: sizes.build_scratch_bytes,
            build_ms: profile.ms("build"),
            own_shader_ms: best(&profile, "own_shader"),
            own_shader_one_walk_ms: best(&profile, "own_shader.one_walk"),
            vkrt_trace_ms: best(&profile, "vkrt_trace"),
        };
        for (i, got) in checked.iter().enumerate() {
            k.exhausted += (got[3] & 2 != 0) as usize;
            let Some((want, want_any)) = reference.get(i) else {
                continue;
            };
            let want_row = match want {
                Some((t, g, p)) => [t.to_bits(), *p, *g],
                None => [f32::INFINITY.to_bits(), u32::MAX, u32::MAX],
            };
            // vkrt's walks give the twin's hits bit for bit; the driver's triangle test is
            // its own: the same primitive at a t within a few ulps.
            let same = match (kind, want) {
                (AccelKind::Driver, Some((t, _, _))) => {
                    got[1..3] == want_row[1..3]
                        && (f32::from_bits(got[0]) - t).abs() <= 1e-5 * t.abs()
                }
                _ => got[..3] == want_row,
            };
            *k.mismatches.get_or_insert(0) += (!same) as usize;
            *k.any_mismatches.get_or_insert(0) += ((got[3] & 1 == 1) != *want_any) as usize;
        }
        report.kinds.insert(kind.name().to_string(), k);
    }
    Ok(report)
}

/// The fastest of the rounds `{name}.0`, `.1`, `.2` in `profile`.
fn best(profile: &vkrt::gpu::Profile, name: &str) -> Option<f64> {
    (0..3)
        .filter_map(|r| profile.ms(&format!("{name}.{r}")))
        .min_by(f64::total_cmp)
}

/// The checked pass (closest and occlusion) alone, in a command buffer of the host's.
fn checked_pass(
    host: &Host,
    pipeline: &AoPipeline,
    sets: &[vk::DescriptorSet; 2],
    push: AoPush,
    n: usize,
    results: &HostBuffer,
) -> BoxResult<Vec<[u32; 4]>> {
    let commands = host.command_buffer()?;
    // SAFETY: `commands.cmd` is recording; the buffers outlive the wait below.
    unsafe {
        pipeline.record(commands.cmd, sets, push);
        barrier(
            &host.device,
            commands.cmd,
            (
                vk::PipelineStageFlags::COMPUTE_SHADER,
                vk::AccessFlags::SHADER_WRITE,
            ),
            (vk::PipelineStageFlags::HOST, vk::AccessFlags::HOST_READ),
        );
    }
    host.submit_and_wait(commands.cmd)?;
    Ok(bytemuck::pod_collect_to_vec(&results.read()[..n * 16]))
}

/// The AO radius: a tenth of the mesh's diagonal.
fn ao_radius(mesh: &Mesh) -> f32 {
    let (lo, hi) = mesh.positions.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    );
    (hi - lo).length() * 0.1
}

/// A ray's closest hit as (t, geometry, primitive within it), and its occlusion.
type Expected = (Option<(f32, u32, u32)>, bool);

/// Per ray, by brute force on the CPU: the closest hit as (t, geometry, primitive within
/// it), and whether anything lies within the AO radius.
fn reference(mesh: &Mesh, rays: &[Ray]) -> Vec<Expected> {
    let g = TraceGeometry::from_triangles(&world_triangles(mesh));
    let half = (mesh.triangles.len() / 2) as u32;
    let closest = TraceOptions {
        exact: false,
        ..TraceOptions::default()
    };
    let any = TraceOptions {
        query: Query::Any,
        ..closest
    };
    let radius = ao_radius(mesh);
    std::thread::scope(|s| {
        let chunks: Vec<_> = rays
            .chunks(rays.len().div_ceil(2).max(1))
            .map(|chunk| {
                let g = &g;
                s.spawn(move || {
                    chunk
                        .iter()
                        .map(|r| {
                            let h = vkrt::trace::cpu::brute_force(g, r, 0.0, &closest);
                            let hit = h.is_hit().then(|| {
                                let (geometry, prim) = if h.prim < half {
                                    (0, h.prim)
                                } else {
                                    (1, h.prim - half)
                                };
                                (h.t, geometry, prim)
                            });
                            let short = Ray { tmax: radius, ..*r };
                            let blocked =
                                vkrt::trace::cpu::brute_force(g, &short, 0.0, &any).is_hit();
                            (hit, blocked)
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        chunks.into_iter().flat_map(|c| c.join().unwrap()).collect()
    })
}

/// The bunny from `../shared/scenes` (or `path`), else a generated icosphere.
pub fn load_mesh(path: Option<PathBuf>) -> BoxResult<Mesh> {
    let path = path.or_else(|| {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes/stanford-bunny.obj");
        p.exists().then_some(p)
    });
    let (positions, triangles) = match path {
        Some(p) => {
            let (models, _) = tobj::load_obj(
                &p,
                &tobj::LoadOptions {
                    triangulate: true,
                    single_index: true,
                    ..Default::default()
                },
            )?;
            let mut positions = Vec::new();
            let mut triangles = Vec::new();
            for m in models {
                let base = positions.len() as u32;
                positions.extend(m.mesh.positions.chunks(3).map(Vec3::from_slice));
                triangles.extend(
                    m.mesh
                        .indices
                        .chunks(3)
                        .map(|t| [base + t[0], base + t[1], base + t[2]]),
                );
            }
            (positions, triangles)
        }
        None => {
            eprintln!("own_shader: no mesh given and ../shared absent: a generated icosphere");
            let m = vkrt::scene::gen::icosphere(4)?;
            (m.positions.to_vec(), m.indices.to_vec())
        }
    };
    Ok(Mesh {
        positions,
        triangles,
    })
}

fn main() -> BoxResult<()> {
    let mut json = false;
    let mut check = true;
    let mut rest = Vec::new();
    for a in std::env::args().skip(1) {
        match a.as_str() {
            "--json" => json = true,
            "--no-check" => check = false,
            _ => rest.push(a),
        }
    }
    let mesh = load_mesh(rest.first().map(PathBuf::from))?;
    let n: usize = match rest.get(1) {
        Some(s) => s.parse().map_err(|_| format!("RAYS: not a count: {s}"))?,
        None => 4096,
    };
    let rays = ao_rays(&mesh, n, 7);
    let kinds = [
        AccelKind::KdTree,
        AccelKind::Lbvh,
        AccelKind::Ploc,
        AccelKind::Driver,
    ];
    let s = run_with(&mesh, &rays, &kinds, Validation::FromEnv, check)?;
    if json {
        let v = serde_json::json!({
            "device": s.device,
            "kinds": s.kinds,
            "vkrt_submits": s.vkrt_submits,
            "vkrt_upload_bytes": s.vkrt_upload_bytes,
            "vkrt_allocations": s.vkrt_allocations,
        });
        println!("{v}");
    } else {
        println!(
            "{}: {} triangles, {} AO rays",
            s.device,
            mesh.triangles.len(),
            n
        );
        for (name, k) in &s.kinds {
            let ratio = |own: Option<f64>| match (own, k.vkrt_trace_ms) {
                (Some(a), Some(b)) if a > 0.0 => format!("{:.2}", b / a),
                _ => "-".into(),
            };
            println!(
                "  {name:7} mismatches {:?} (occlusion {:?}), exhausted {}, structure {} B, \
                 scratch {} B; trace ms: own shader {:.1?} (every walk, ×{} of vkrt's rate), \
                 {:.1?} (one walk, ×{}), vkrt's kernel {:.1?}",
                k.mismatches,
                k.any_mismatches,
                k.exhausted,
                k.structure_bytes,
                k.build_scratch_bytes,
                k.own_shader_ms,
                ratio(k.own_shader_ms),
                k.own_shader_one_walk_ms,
                ratio(k.own_shader_one_walk_ms),
                k.vkrt_trace_ms
            );
        }
        println!(
            "vkrt itself: {} submissions, {} bytes uploaded, {} device allocations",
            s.vkrt_submits, s.vkrt_upload_bytes, s.vkrt_allocations
        );
    }
    if !s.messages.is_empty() {
        return Err(format!("{} validation messages", s.messages.len()).into());
    }
    Ok(())
}
