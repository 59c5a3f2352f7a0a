//! What the layer costs, measured in one run: `cargo bench -p vkrt-layer --bench layer`.
//!
//! An application written against the Khronos API (ash only) builds a bottom level over the
//! Stanford bunny (../shared/scenes; `$VKRT_MESH`) and a top level over one instance of it,
//! then traces 512² orthographic primary rays with a compute shader's ray query. It runs as
//! child processes: through the layer (forced on where the driver has ray query), natively
//! (where it has), and with the layer loaded but inert. Ratios:
//!
//! - trace: the shader lowered by the layer's pass ÷ the same source through
//!   `vkrt/ext_ray_query.glsl` (both on the layer's structures, both with the loop-budget
//!   walk where the driver has a budget, as the pass lowers it there; GPU timestamps), and
//!   the layer ÷ the driver's own ray query;
//! - build: `vkCmdBuildAccelerationStructuresKHR` through the layer ÷ vkrt's own API
//!   (`AccelBuilder::record_build_from`, PLOC, in this process) on the same mesh, both
//!   `PREFER_FAST_TRACE` (the driver's too);
//! - an intercepted command's cost (`vkCmdPushConstants`, host ns per call) and a frame
//!   without builds (record, submit, wait), with the layer ÷ without;
//! - pipeline creation (module + compute pipeline, host ms) with the pass ÷ natively.
//!
//! Medians of repeats after a warm-up; the children print `key value` lines.

#[path = "../tests/common/app.rs"]
#[allow(dead_code)]
mod app;

use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Instant;

use ash::vk;
use vkrt::accel::geometry::{Geometry, IndexType, Triangles};
use vkrt::gpu::{Buffer, Recorder};
use vkrt::{AccelBuilder, AccelKind, BuildFlags, Context, ContextOptions};

const WIDTH: u32 = 512;
const REPS: usize = 7;

const SHADER: &str = r#"
#version 460
#extension GL_EXT_ray_query : require
INCLUDE
layout(local_size_x = 64) in;
layout(set = 0, binding = 0) uniform accelerationStructureEXT tlas;
layout(set = 0, binding = 1) buffer Out { vec2 hits[]; };
layout(push_constant) uniform Push { vec4 lo; vec4 hi; uint width; } pc;
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.width * pc.width) return;
    vec2 uv = (vec2(i % pc.width, i / pc.width) + 0.5) / float(pc.width);
    vec3 origin = vec3(mix(pc.lo.xy, pc.hi.xy, uv), pc.hi.z + 1.0);
    rayQueryEXT q;
    rayQueryInitializeEXT(q, tlas, gl_RayFlagsOpaqueEXT, 0xFF, origin, 0.0, vec3(0, 0, -1), 1e30);
    while (rayQueryProceedEXT(q)) {}
    bool hit = rayQueryGetIntersectionTypeEXT(q, true) != gl_RayQueryCommittedIntersectionNoneEXT;
    hits[i] = hit ? vec2(rayQueryGetIntersectionTEXT(q, true),
                         float(rayQueryGetIntersectionPrimitiveIndexEXT(q, true)))
                  : vec2(-1.0);
}
"#;

fn mesh() -> (Vec<[f32; 3]>, Vec<u32>) {
    let bunny = std::env::var_os("VKRT_MESH").map_or_else(
        || PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/scenes/stanford-bunny.obj"),
        PathBuf::from,
    );
    let m = match bunny.exists() {
        true => vkrt::scene::Scene::load(&bunny)
            .expect("the bunny")
            .scene
            .meshes[0]
            .clone(),
        false => {
            eprintln!("{} not present: a generated icosphere", bunny.display());
            vkrt::scene::gen::icosphere(7).expect("an icosphere")
        }
    };
    (
        m.positions.iter().map(|p| p.to_array()).collect(),
        m.indices.iter().flatten().copied().collect(),
    )
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

// ----- the child: the application -----

struct Timer {
    pool: vk::QueryPool,
    period_ns: f64,
}

impl Timer {
    unsafe fn ms(&self, d: &ash::Device) -> f64 {
        let mut t = [0u64; 2];
        d.get_query_pool_results(
            self.pool,
            0,
            &mut t,
            vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
        )
        .unwrap();
        (t[1] - t[0]) as f64 * self.period_ns * 1e-6
    }
}

unsafe fn submit(g: &app::Gpu, cb: vk::CommandBuffer, fence: vk::Fence) {
    let d = &g.device;
    d.end_command_buffer(cb).unwrap();
    let cbs = [cb];
    d.queue_submit(
        g.queue,
        &[vk::SubmitInfo::default().command_buffers(&cbs)],
        fence,
    )
    .unwrap();
    d.wait_for_fences(&[fence], true, u64::MAX).unwrap();
    d.reset_fences(&[fence]).unwrap();
}

/// A compute pipeline over `code`, and the host ms its module and pipeline took.
/// The module's compute pipeline and the host ms it took; `loop_budget_walk` sets the
/// include's loop-budget walk (`LOOP_BUDGET_CONSTANT_ID`), as the pass chooses it for a
/// driver with a loop budget, so that both run the same walk.
unsafe fn pipeline(
    d: &ash::Device,
    code: &[u32],
    layout: vk::PipelineLayout,
    loop_budget_walk: bool,
) -> (vk::Pipeline, f64) {
    let start = Instant::now();
    let module = d
        .create_shader_module(&vk::ShaderModuleCreateInfo::default().code(code), None)
        .unwrap();
    let entries = [vk::SpecializationMapEntry {
        constant_id: vkrt::accel::shader_library::LOOP_BUDGET_CONSTANT_ID,
        offset: 0,
        size: 4,
    }];
    let value = u32::from(loop_budget_walk).to_ne_bytes();
    let spec = vk::SpecializationInfo::default()
        .map_entries(&entries)
        .data(&value);
    let stage = vk::PipelineShaderStageCreateInfo::default()
        .stage(vk::ShaderStageFlags::COMPUTE)
        .module(module)
        .name(c"main")
        .specialization_info(&spec);
    let p = d
        .create_compute_pipelines(
            vk::PipelineCache::null(),
            &[vk::ComputePipelineCreateInfo::default()
                .stage(stage)
                .layout(layout)],
            None,
        )
        .unwrap()[0];
    let ms = start.elapsed().as_secs_f64() * 1e3;
    d.destroy_shader_module(module, None);
    (p, ms)
}

unsafe fn child(include: bool) {
    let Ok((_entry, mut g)) = app::setup(app::Validation::Off, vk::API_VERSION_1_2) else {
        // No ray query here without the layer.
        println!("unsupported 1");
        return;
    };
    let d = g.device.clone();
    let props = g.instance.get_physical_device_properties(g.physical);
    let period_ns = f64::from(props.limits.timestamp_period);
    let (verts, idx) = mesh();
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for v in &verts {
        for k in 0..3 {
            lo[k] = lo[k].min(v[k]);
            hi[k] = hi[k].max(v[k]);
        }
    }
    let b_v = g.buffer(12 * verts.len() as u64, app::INPUT);
    let b_i = g.buffer(4 * idx.len() as u64, app::INPUT);
    g.write(b_v, &verts);
    g.write(b_i, &idx);
    let n_tris = idx.len() as u32 / 3;
    let tris = vk::AccelerationStructureGeometryTrianglesDataKHR::default()
        .vertex_format(vk::Format::R32G32B32_SFLOAT)
        .vertex_data(vk::DeviceOrHostAddressConstKHR {
            device_address: g.bufs[b_v].address,
        })
        .vertex_stride(12)
        .max_vertex(verts.len() as u32 - 1)
        .index_type(vk::IndexType::UINT32)
        .index_data(vk::DeviceOrHostAddressConstKHR {
            device_address: g.bufs[b_i].address,
        });
    let geometry = [vk::AccelerationStructureGeometryKHR::default()
        .geometry_type(vk::GeometryTypeKHR::TRIANGLES)
        .geometry(vk::AccelerationStructureGeometryDataKHR { triangles: tris })
        .flags(vk::GeometryFlagsKHR::OPAQUE)];
    let flags = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE;
    let bottom_info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
        .ty(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL)
        .flags(flags)
        .geometries(&geometry);
    let mut sizes = vk::AccelerationStructureBuildSizesInfoKHR::default();
    g.accel.get_acceleration_structure_build_sizes(
        vk::AccelerationStructureBuildTypeKHR::DEVICE,
        &bottom_info,
        &[n_tris],
        &mut sizes,
    );
    let b_blas = g.buffer(
        sizes.acceleration_structure_size,
        vk::BufferUsageFlags::ACCELERATION_STRUCTURE_STORAGE_KHR,
    );
    let b_scratch = g.buffer(
        sizes.build_scratch_size,
        vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS,
    );
    let blas = g
        .accel
        .create_acceleration_structure(
            &vk::AccelerationStructureCreateInfoKHR::default()
                .buffer(g.bufs[b_blas].buffer)
                .size(sizes.acceleration_structure_size)
                .ty(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL),
            None,
        )
        .unwrap();
    let reference = g.accel.get_acceleration_structure_device_address(
        &vk::AccelerationStructureDeviceAddressInfoKHR::default().acceleration_structure(blas),
    );
    let mut record = [0u32; 16];
    for (k, v) in [
        1.0f32, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0,
    ]
    .iter()
    .enumerate()
    {
        record[k] = v.to_bits();
    }
    record[12] = 0xFF << 24;
    record[14] = reference as u32;
    record[15] = (reference >> 32) as u32;
    let b_inst = g.buffer(64, app::INPUT);
    g.write(b_inst, &record);
    let inst_geometry = [vk::AccelerationStructureGeometryKHR::default()
        .geometry_type(vk::GeometryTypeKHR::INSTANCES)
        .geometry(vk::AccelerationStructureGeometryDataKHR {
            instances: vk::AccelerationStructureGeometryInstancesDataKHR::default().data(
                vk::DeviceOrHostAddressConstKHR {
                    device_address: g.bufs[b_inst].address,
                },
            ),
        })];
    let top_info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
        .ty(vk::AccelerationStructureTypeKHR::TOP_LEVEL)
        .geometries(&inst_geometry);
    let mut top_sizes = vk::AccelerationStructureBuildSizesInfoKHR::default();
    g.accel.get_acceleration_structure_build_sizes(
        vk::AccelerationStructureBuildTypeKHR::DEVICE,
        &top_info,
        &[1],
        &mut top_sizes,
    );
    let b_tlas = g.buffer(
        top_sizes.acceleration_structure_size,
        vk::BufferUsageFlags::ACCELERATION_STRUCTURE_STORAGE_KHR,
    );
    let b_top_scratch = g.buffer(
        top_sizes.build_scratch_size,
        vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS,
    );
    let tlas = g
        .accel
        .create_acceleration_structure(
            &vk::AccelerationStructureCreateInfoKHR::default()
                .buffer(g.bufs[b_tlas].buffer)
                .size(top_sizes.acceleration_structure_size)
                .ty(vk::AccelerationStructureTypeKHR::TOP_LEVEL),
            None,
        )
        .unwrap();

    let pool = d
        .create_command_pool(
            &vk::CommandPoolCreateInfo::default()
                .queue_family_index(g.family)
                .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER),
            None,
        )
        .unwrap();
    let cb = d
        .allocate_command_buffers(
            &vk::CommandBufferAllocateInfo::default()
                .command_pool(pool)
                .command_buffer_count(1),
        )
        .unwrap()[0];
    let fence = d
        .create_fence(&vk::FenceCreateInfo::default(), None)
        .unwrap();
    let timer = Timer {
        pool: d
            .create_query_pool(
                &vk::QueryPoolCreateInfo::default()
                    .query_type(vk::QueryType::TIMESTAMP)
                    .query_count(2),
                None,
            )
            .unwrap(),
        period_ns,
    };
    let begin = |cb| {
        d.begin_command_buffer(cb, &vk::CommandBufferBeginInfo::default())
            .unwrap();
        d.cmd_reset_query_pool(cb, timer.pool, 0, 2);
    };
    let barrier = |cb, src, src_a, dst, dst_a| {
        let b = vk::MemoryBarrier::default()
            .src_access_mask(src_a)
            .dst_access_mask(dst_a);
        d.cmd_pipeline_barrier(cb, src, dst, vk::DependencyFlags::empty(), &[b], &[], &[]);
    };

    // Builds: the bottom level timed, then the top level.
    let mut build_ms = Vec::new();
    for _ in 0..REPS {
        begin(cb);
        d.cmd_write_timestamp(cb, vk::PipelineStageFlags::TOP_OF_PIPE, timer.pool, 0);
        let info =
            bottom_info
                .dst_acceleration_structure(blas)
                .scratch_data(vk::DeviceOrHostAddressKHR {
                    device_address: g.bufs[b_scratch].address,
                });
        let range = [vk::AccelerationStructureBuildRangeInfoKHR::default().primitive_count(n_tris)];
        g.accel
            .cmd_build_acceleration_structures(cb, &[info], &[&range]);
        d.cmd_write_timestamp(cb, vk::PipelineStageFlags::BOTTOM_OF_PIPE, timer.pool, 1);
        barrier(
            cb,
            vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR,
            vk::AccessFlags::ACCELERATION_STRUCTURE_WRITE_KHR,
            vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR,
            vk::AccessFlags::ACCELERATION_STRUCTURE_READ_KHR,
        );
        let top =
            top_info
                .dst_acceleration_structure(tlas)
                .scratch_data(vk::DeviceOrHostAddressKHR {
                    device_address: g.bufs[b_top_scratch].address,
                });
        let range = [vk::AccelerationStructureBuildRangeInfoKHR::default().primitive_count(1)];
        g.accel
            .cmd_build_acceleration_structures(cb, &[top], &[&range]);
        barrier(
            cb,
            vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR,
            vk::AccessFlags::ACCELERATION_STRUCTURE_WRITE_KHR,
            vk::PipelineStageFlags::COMPUTE_SHADER,
            vk::AccessFlags::ACCELERATION_STRUCTURE_READ_KHR,
        );
        submit(&g, cb, fence);
        build_ms.push(timer.ms(&d));
    }
    println!("build_ms {}", median(build_ms[1..].to_vec()));

    // The trace pipeline(s).
    let bindings = [
        vk::DescriptorSetLayoutBinding::default()
            .binding(0)
            .descriptor_type(vk::DescriptorType::ACCELERATION_STRUCTURE_KHR)
            .descriptor_count(1)
            .stage_flags(vk::ShaderStageFlags::COMPUTE),
        vk::DescriptorSetLayoutBinding::default()
            .binding(1)
            .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
            .descriptor_count(1)
            .stage_flags(vk::ShaderStageFlags::COMPUTE),
    ];
    let set_layout = d
        .create_descriptor_set_layout(
            &vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings),
            None,
        )
        .unwrap();
    let set_layouts = [set_layout];
    let push_range = [vk::PushConstantRange::default()
        .stage_flags(vk::ShaderStageFlags::COMPUTE)
        .size(36)];
    let layout = d
        .create_pipeline_layout(
            &vk::PipelineLayoutCreateInfo::default()
                .set_layouts(&set_layouts)
                .push_constant_ranges(&push_range),
            None,
        )
        .unwrap();
    let sizes_pool = [
        vk::DescriptorPoolSize {
            ty: vk::DescriptorType::ACCELERATION_STRUCTURE_KHR,
            descriptor_count: 1,
        },
        vk::DescriptorPoolSize {
            ty: vk::DescriptorType::STORAGE_BUFFER,
            descriptor_count: 1,
        },
    ];
    let dpool = d
        .create_descriptor_pool(
            &vk::DescriptorPoolCreateInfo::default()
                .max_sets(1)
                .pool_sizes(&sizes_pool),
            None,
        )
        .unwrap();
    let set = d
        .allocate_descriptor_sets(
            &vk::DescriptorSetAllocateInfo::default()
                .descriptor_pool(dpool)
                .set_layouts(&set_layouts),
        )
        .unwrap()[0];
    let rays = WIDTH * WIDTH;
    let b_out = g.buffer(8 * u64::from(rays), vk::BufferUsageFlags::STORAGE_BUFFER);
    app::write_structure(&d, set, tlas);
    let out_info = [vk::DescriptorBufferInfo::default()
        .buffer(g.bufs[b_out].buffer)
        .range(vk::WHOLE_SIZE)];
    let w1 = vk::WriteDescriptorSet::default()
        .dst_set(set)
        .dst_binding(1)
        .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
        .buffer_info(&out_info);
    d.update_descriptor_sets(&[w1], &[]);

    let mut push = [0u32; 9];
    for k in 0..3 {
        push[k] = lo[k].to_bits();
        push[4 + k] = hi[k].to_bits();
    }
    push[8] = WIDTH;
    let trace = |pipeline: vk::Pipeline| -> (f64, usize) {
        let mut ms = Vec::new();
        for _ in 0..REPS {
            begin(cb);
            d.cmd_bind_pipeline(cb, vk::PipelineBindPoint::COMPUTE, pipeline);
            d.cmd_bind_descriptor_sets(cb, vk::PipelineBindPoint::COMPUTE, layout, 0, &[set], &[]);
            d.cmd_push_constants(
                cb,
                layout,
                vk::ShaderStageFlags::COMPUTE,
                0,
                app::bytes(&push),
            );
            d.cmd_write_timestamp(cb, vk::PipelineStageFlags::TOP_OF_PIPE, timer.pool, 0);
            d.cmd_dispatch(cb, rays.div_ceil(64), 1, 1);
            d.cmd_write_timestamp(cb, vk::PipelineStageFlags::BOTTOM_OF_PIPE, timer.pool, 1);
            barrier(
                cb,
                vk::PipelineStageFlags::COMPUTE_SHADER,
                vk::AccessFlags::SHADER_WRITE,
                vk::PipelineStageFlags::HOST,
                vk::AccessFlags::HOST_READ,
            );
            submit(&g, cb, fence);
            ms.push(timer.ms(&d));
        }
        let out = std::slice::from_raw_parts(g.bufs[b_out].map.cast::<[f32; 2]>(), rays as usize);
        (
            median(ms[1..].to_vec()),
            out.iter().filter(|h| h[0] >= 0.0).count(),
        )
    };
    let loop_budget_walk = std::env::var("VKRT_LAYER_BENCH_LOOP_BUDGET").is_ok_and(|v| v == "1");
    let (khr, pipeline_ms) = pipeline(
        &d,
        &app::compile(&SHADER.replace("INCLUDE", "")),
        layout,
        false,
    );
    println!("pipeline_ms {pipeline_ms}");
    let (trace_ms, hits) = trace(khr);
    println!("trace_ms {trace_ms}");
    println!("hits {hits}");
    if include {
        let include_dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../glsl/include");
        let source = SHADER.replace(
            "INCLUDE",
            "#extension GL_GOOGLE_include_directive : require\n#include \"vkrt/ext_ray_query.glsl\"",
        );
        let code = app::compile_with(&source, &["-I", include_dir.to_str().unwrap()]);
        let (p, include_pipeline_ms) = pipeline(&d, &code, layout, loop_budget_walk);
        println!("include_pipeline_ms {include_pipeline_ms}");
        let (ms, hits) = trace(p);
        println!("include_trace_ms {ms}");
        println!("include_hits {hits}");
        d.destroy_pipeline(p, None);
    }

    // A frame without builds: record, submit, wait.
    let mut frame_ms = Vec::new();
    for _ in 0..2 * REPS {
        let start = Instant::now();
        d.begin_command_buffer(cb, &vk::CommandBufferBeginInfo::default())
            .unwrap();
        d.cmd_bind_pipeline(cb, vk::PipelineBindPoint::COMPUTE, khr);
        d.cmd_bind_descriptor_sets(cb, vk::PipelineBindPoint::COMPUTE, layout, 0, &[set], &[]);
        d.cmd_push_constants(
            cb,
            layout,
            vk::ShaderStageFlags::COMPUTE,
            0,
            app::bytes(&push),
        );
        d.cmd_dispatch(cb, rays.div_ceil(64), 1, 1);
        submit(&g, cb, fence);
        frame_ms.push(start.elapsed().as_secs_f64() * 1e3);
    }
    println!("frame_ms {}", median(frame_ms[2..].to_vec()));

    // An intercepted command's host cost.
    let calls = 200_000;
    let mut ns = Vec::new();
    for _ in 0..REPS {
        d.begin_command_buffer(cb, &vk::CommandBufferBeginInfo::default())
            .unwrap();
        let start = Instant::now();
        for _ in 0..calls {
            d.cmd_push_constants(
                cb,
                layout,
                vk::ShaderStageFlags::COMPUTE,
                0,
                app::bytes(&push[..4]),
            );
        }
        ns.push(start.elapsed().as_secs_f64() * 1e9 / f64::from(calls));
        d.end_command_buffer(cb).unwrap();
        d.reset_command_buffer(cb, vk::CommandBufferResetFlags::empty())
            .unwrap();
    }
    // The least of the repeats: a host loop's noise only adds.
    println!(
        "push_constants_ns {}",
        ns.iter().copied().fold(f64::INFINITY, f64::min)
    );
    d.device_wait_idle().unwrap();
}

// ----- the parent -----

fn manifest_dir() -> PathBuf {
    app::manifest_dir(&std::env::temp_dir())
}

/// Runs a child: `layer` (Some(force)) or none; `include` also times the include's shader.
fn run(layer: Option<bool>, include: bool) -> HashMap<String, f64> {
    let mut cmd = app::this_binary_again();
    cmd.env(
        "VKRT_LAYER_BENCH_CHILD",
        if include { "include" } else { "plain" },
    )
    .env(
        "VKRT_LAYER_BENCH_LOOP_BUDGET",
        if loop_budget() { "1" } else { "0" },
    )
    .env_remove("VK_INSTANCE_LAYERS")
    .env_remove("VKRT_LAYER_FORCE");
    if let Some(force) = layer {
        app::add_layer_path(&mut cmd, &manifest_dir());
        cmd.env("VK_INSTANCE_LAYERS", "VK_LAYER_VKRT_ray_query");
        if force {
            cmd.env("VKRT_LAYER_FORCE", "1");
        }
    }
    let o = cmd.output().expect("the bench binary, again");
    assert!(
        o.status.success(),
        "child failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout)
        .lines()
        .filter_map(|l| {
            let (k, v) = l.split_once(' ')?;
            Some((k.to_string(), v.parse().ok()?))
        })
        .collect()
}

/// Whether the device's driver ends an invocation's loops after a budget of iterations
/// (Mesa 22.3's lavapipe), where the pass lowers with the loop-budget walk.
fn loop_budget() -> bool {
    static BUDGET: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *BUDGET.get_or_init(|| {
        let ctx = Context::new(&ContextOptions::default()).expect("a device");
        ctx.info().loop_budget.is_some()
    })
}

/// The bunny built by vkrt's own API (PLOC, the layer's builder for PREFER_FAST_TRACE):
/// the GPU ms of the build, median after a warm-up.
fn vkrt_build_ms() -> f64 {
    let ctx = Context::new(&ContextOptions::default()).expect("a device");
    let (verts, idx) = mesh();
    let vb = Buffer::from_slice(&ctx, "vertices", &verts).unwrap();
    let ib = Buffer::from_slice(&ctx, "indices", &idx).unwrap();
    let geometries = [Geometry::Triangles(Triangles::indexed(
        unsafe { vb.as_raw() },
        verts.len() as u32,
        unsafe { ib.as_raw() },
        IndexType::U32,
        idx.len() as u32 / 3,
    ))];
    let builder = AccelBuilder::new(&ctx, AccelKind::Ploc).unwrap();
    let flags = BuildFlags::default();
    let sizes = builder.sizes_for(&ctx, &geometries, &flags).unwrap();
    let memory = Buffer::<u8>::arena(&ctx, "structure", sizes.structure_bytes as usize).unwrap();
    let scratch = Buffer::<u8>::arena(&ctx, "scratch", sizes.build_scratch_bytes as usize).unwrap();
    let mut out = builder
        .create_in(&ctx, &geometries, &flags, unsafe { memory.as_raw() })
        .unwrap();
    let mut ms = Vec::new();
    for _ in 0..REPS {
        let mut rec = Recorder::new(&ctx).unwrap();
        rec.scope("build", |rec| {
            builder
                .record_build_from(rec, &mut out, &geometries, unsafe { scratch.as_raw() })
                .unwrap()
        });
        ms.push(
            rec.submit_and_wait()
                .unwrap()
                .ms("build")
                .unwrap_or(f64::NAN),
        );
    }
    median(ms[1..].to_vec())
}

fn main() {
    if let Ok(mode) = std::env::var("VKRT_LAYER_BENCH_CHILD") {
        // SAFETY: the child's whole life is this one application.
        unsafe { child(mode == "include") };
        return;
    }
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    let native = run(None, false);
    let driver_has_ray_query = native.contains_key("trace_ms");
    let layer = run(Some(driver_has_ray_query), true);
    let vkrt_ms = vkrt_build_ms();
    let get = |m: &HashMap<String, f64>, k: &str| m.get(k).copied().unwrap_or(f64::NAN);
    println!("layer bench: the bunny, {WIDTH}² primary rays (medians; ms unless named)");
    println!(
        "  trace: pass {:.2}, include {:.2} -> pass / include rate {:.3} (hits {} / {})",
        get(&layer, "trace_ms"),
        get(&layer, "include_trace_ms"),
        get(&layer, "include_trace_ms") / get(&layer, "trace_ms"),
        get(&layer, "hits"),
        get(&layer, "include_hits"),
    );
    println!(
        "  build (vkCmdBuildAccelerationStructuresKHR, bottom level): layer {:.2}, vkrt's API {:.2} -> {:.3}",
        get(&layer, "build_ms"),
        vkrt_ms,
        get(&layer, "build_ms") / vkrt_ms
    );
    println!(
        "  pipeline creation: through the pass {:.1}, the include's module {:.1}",
        get(&layer, "pipeline_ms"),
        get(&layer, "include_pipeline_ms")
    );
    if driver_has_ray_query {
        let inert = run(Some(false), false);
        println!(
            "  the driver's own: trace {:.2} -> layer / driver rate {:.3}; build {:.2}; pipeline {:.1} -> pass / native {:.2}",
            get(&native, "trace_ms"),
            get(&native, "trace_ms") / get(&layer, "trace_ms"),
            get(&native, "build_ms"),
            get(&native, "pipeline_ms"),
            get(&layer, "pipeline_ms") / get(&native, "pipeline_ms"),
        );
        println!(
            "  vkCmdPushConstants: {:.1} ns without the layer, {:.1} through it (forced), {:.1} inert",
            get(&native, "push_constants_ns"),
            get(&layer, "push_constants_ns"),
            get(&inert, "push_constants_ns"),
        );
        println!(
            "  a frame without builds: {:.2} without the layer, {:.2} inert -> {:.3}; forced {:.2}",
            get(&native, "frame_ms"),
            get(&inert, "frame_ms"),
            get(&inert, "frame_ms") / get(&native, "frame_ms"),
            get(&layer, "frame_ms"),
        );
    } else {
        println!(
            "  vkCmdPushConstants through the layer: {:.1} ns; a frame without builds: {:.2}",
            get(&layer, "push_constants_ns"),
            get(&layer, "frame_ms"),
        );
    }
}
