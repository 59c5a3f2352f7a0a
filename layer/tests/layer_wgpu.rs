//! A headless application on wgpu's own ray-query API (crates.io `wgpu`, WGSL compiled by
//! naga, the Vulkan backend only), run as a child process: through `VK_LAYER_VKRT_ray_query`
//! (forced on where the driver has ray query) with the Khronos validation layer below it, and
//! natively where the driver has ray query. Every run's hits are held to a CPU reference of
//! the same scene, and the layer's to the driver's own.
//!
//! The scene: a u32-indexed grid updated in place between the frames (`PreferUpdate`), a
//! u16-indexed soup placed by a geometry transform whose odd triangles the shader rejects
//! (non-opaque candidates) and which is compacted after the first frame, four instances with
//! transforms, custom data and masks (one culled), and a top level rebuilt with a new
//! transform for the second frame.

mod common;

use std::f64::consts::PI;
use std::path::PathBuf;

use common::app;

/// Rays per side of the orthographic grid of rays.
const SIDE: u32 = 32;
/// Quads per side of the grid mesh.
const QUADS: u32 = 6;
/// The rays' cull mask: instance 3 (mask 0x02) is culled.
const RAY_MASK: u32 = 0x01;

// ----- the scene, shared by the child and the reference -----

/// The grid's vertices in frame `frame` (the second frame bends it).
fn grid_vertices(frame: u32) -> Vec<[f32; 3]> {
    let mut v = Vec::new();
    for j in 0..=QUADS {
        for i in 0..=QUADS {
            let x = -1.0 + 2.0 * i as f32 / QUADS as f32;
            let y = -1.0 + 2.0 * j as f32 / QUADS as f32;
            let z = 0.15 * frame as f32 * (x * 1.3 + y * 0.7).sin();
            v.push([x, y, z]);
        }
    }
    v
}

/// The grid's triangles, two per quad.
fn grid_indices() -> Vec<u32> {
    let mut ix = Vec::new();
    let w = QUADS + 1;
    for j in 0..QUADS {
        for i in 0..QUADS {
            let a = j * w + i;
            ix.extend_from_slice(&[a, a + 1, a + w + 1, a, a + w + 1, a + w]);
        }
    }
    ix
}

/// The soup's vertices (before its geometry transform) and u16 indices: scattered triangles
/// from a fixed linear congruential sequence.
fn soup() -> (Vec<[f32; 3]>, Vec<u16>) {
    let mut state = 0x2545_f491_u32;
    let mut next = || {
        state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (state >> 8) as f32 / (1u32 << 24) as f32
    };
    let mut vertices = Vec::new();
    for _ in 0..12 {
        let c = [next() * 2.0 - 1.0, next() * 2.0 - 1.0, next() * 0.4 - 0.2];
        for _ in 0..3 {
            vertices.push([
                c[0] + (next() - 0.5) * 0.9,
                c[1] + (next() - 0.5) * 0.9,
                c[2] + (next() - 0.5) * 0.2,
            ]);
        }
    }
    // Reversed, so that index order differs from vertex order.
    let indices = (0..vertices.len() as u16).rev().collect();
    (vertices, indices)
}

/// The soup's geometry transform (3×4, row-major): scaled by 0.8, moved up in y.
const SOUP_TRANSFORM: [f32; 12] = [0.8, 0.0, 0.0, 0.0, 0.0, 0.8, 0.0, 0.25, 0.0, 0.0, 0.8, 0.0];

/// One instance: which bottom level (0 grid, 1 soup), its 3×4 row-major transform, custom
/// data and mask.
struct Instance {
    level: usize,
    transform: [f32; 12],
    custom: u32,
    mask: u8,
}

/// A rotation by `degrees` about z, scaled by `s`, moved to (`x`, `y`, `z`).
fn placed(degrees: f64, s: f64, x: f32, y: f32, z: f32) -> [f32; 12] {
    let (sin, cos) = (degrees * PI / 180.0).sin_cos();
    let (c, n) = ((cos * s) as f32, (sin * s) as f32);
    [c, -n, 0.0, x, n, c, 0.0, y, 0.0, 0.0, s as f32, z]
}

/// The instances of frame `frame` (the second turns instance 1 further).
fn instances(frame: u32) -> Vec<Instance> {
    vec![
        Instance {
            level: 0,
            transform: placed(0.0, 1.0, 0.0, 0.0, 2.0),
            custom: 10,
            mask: 0xff,
        },
        Instance {
            level: 0,
            transform: placed(30.0 + 25.0 * frame as f64, 0.45, 0.3, -0.2, 1.0),
            custom: 11,
            mask: 0x01,
        },
        Instance {
            level: 1,
            transform: placed(-15.0, 1.0, -0.1, 0.0, 1.5),
            custom: 12,
            mask: 0x03,
        },
        Instance {
            level: 0,
            transform: placed(10.0, 1.0, 0.0, 0.0, 0.5),
            custom: 13,
            mask: 0x02,
        },
    ]
}

/// Ray `r` of the grid of rays: origin and direction (slightly oblique, along +z).
fn ray(r: u32) -> ([f32; 3], [f32; 3]) {
    let (i, j) = (r % SIDE, r / SIDE);
    let x = -1.25 + 2.5 * (i as f32 + 0.5) / SIDE as f32;
    let y = -1.25 + 2.5 * (j as f32 + 0.5) / SIDE as f32;
    ([x, y, -1.0], [0.03, -0.02, 1.0])
}

/// One ray's answer: kind (0 none, 1 triangle), t, custom data, instance, geometry,
/// primitive, barycentrics, front face.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Hit {
    kind: u32,
    t: f32,
    custom: u32,
    instance: u32,
    geometry: u32,
    primitive: u32,
    u: f32,
    v: f32,
    front: u32,
}

const SHADER: &str = r#"
@group(0) @binding(0) var scene: acceleration_structure;
@group(0) @binding(1) var<storage, read> rays: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> hits: array<vec4<u32>>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if (i >= arrayLength(&rays) / 2u) { return; }
    let o = rays[2u * i];
    let d = rays[2u * i + 1u];
    var rq: ray_query;
    rayQueryInitialize(&rq, scene, RayDesc(0u, RAY_MASK, o.w, d.w, o.xyz, d.xyz));
    while (rayQueryProceed(&rq)) {
        // The soup is not opaque: its even triangles are kept, as an alpha test would.
        let c = rayQueryGetCandidateIntersection(&rq);
        if (c.kind == RAY_QUERY_INTERSECTION_TRIANGLE && c.primitive_index % 2u == 0u) {
            rayQueryConfirmIntersection(&rq);
        }
    }
    let h = rayQueryGetCommittedIntersection(&rq);
    let front = select(0u, 1u, h.front_face);
    hits[2u * i] = vec4<u32>(h.kind | (front << 2u) | (h.instance_index << 3u) | (h.geometry_index << 9u),
                             h.instance_custom_data, h.primitive_index, bitcast<u32>(h.t));
    hits[2u * i + 1u] = vec4<u32>(bitcast<u32>(h.barycentrics.x), bitcast<u32>(h.barycentrics.y), 0u, 0u);
}
"#;

// ----- the child: the application -----

/// What the child's wgpu logged from the validation layer (warnings and errors).
static MESSAGES: std::sync::Mutex<Vec<String>> = std::sync::Mutex::new(Vec::new());
/// Lines about the adapter, written before the hits.
static MESSAGES_META: std::sync::Mutex<Vec<String>> = std::sync::Mutex::new(Vec::new());

struct Collect;

impl log::Log for Collect {
    fn enabled(&self, m: &log::Metadata) -> bool {
        m.level() <= log::Level::Warn
    }
    fn log(&self, r: &log::Record) {
        // The validation layer's messages, "VALIDATION [ID (0x...)] text" as wgpu's debug
        // messenger logs them; not the loader's notes or wgpu's own (extensions it looked
        // for and did not find).
        let text = format!("{}", r.args());
        let validation = text
            .split_once(" [")
            .is_some_and(|(types, _)| types.split(" | ").any(|t| t == "VALIDATION"));
        if self.enabled(r.metadata()) && r.target().starts_with("wgpu_hal::vulkan") && validation {
            MESSAGES.lock().unwrap().push(text);
        }
    }
    fn flush(&self) {}
}

/// Polls a future that wgpu resolves at once on native backends.
fn ready<F: std::future::Future>(f: F) -> F::Output {
    let mut f = std::pin::pin!(f);
    let mut cx = std::task::Context::from_waker(std::task::Waker::noop());
    match f.as_mut().poll(&mut cx) {
        std::task::Poll::Ready(v) => v,
        std::task::Poll::Pending => panic!("wgpu's future did not resolve at once"),
    }
}

/// The child's entry: does nothing unless a parent test started this process for a run.
#[test]
fn child() {
    let Ok(out) = std::env::var("VKRT_WGPU_APP_OUT") else {
        return;
    };
    log::set_logger(&Collect).unwrap();
    log::set_max_level(log::LevelFilter::Warn);
    let text = match run_app() {
        Ok(frames) => {
            let mut text = String::new();
            for m in MESSAGES_META.lock().unwrap().iter() {
                text += &format!("{m}\n");
            }
            for m in MESSAGES.lock().unwrap().iter() {
                text += &format!("message {}\n", m.replace('\n', " "));
            }
            for (f, hits) in frames.iter().enumerate() {
                for h in hits {
                    text += &format!(
                        "hit {f} {} {} {} {} {} {} {} {} {}\n",
                        h.kind,
                        h.t,
                        h.custom,
                        h.instance,
                        h.geometry,
                        h.primitive,
                        h.u,
                        h.v,
                        h.front
                    );
                }
            }
            text
        }
        Err(why) => format!("unsupported {why}\n"),
    };
    std::fs::write(out, text).unwrap();
}

/// Two frames of the application; `Err` where the adapter has no ray query.
fn run_app() -> Result<Vec<Vec<Hit>>, String> {
    use wgpu::util::DeviceExt;

    let instance = wgpu::Instance::new(&wgpu::InstanceDescriptor {
        backends: wgpu::Backends::VULKAN,
        flags: wgpu::InstanceFlags::VALIDATION | wgpu::InstanceFlags::DEBUG,
        ..Default::default()
    });
    let adapter = ready(instance.request_adapter(&wgpu::RequestAdapterOptions::default()))
        .map_err(|e| format!("no adapter: {e}"))?;
    if !adapter
        .features()
        .contains(wgpu::Features::EXPERIMENTAL_RAY_QUERY)
    {
        return Err("the adapter has no EXPERIMENTAL_RAY_QUERY".into());
    }
    // wgpu enables the validation layer where the loader lists it.
    // SAFETY: the system's loader, loaded once for this question.
    let validation = unsafe { ash::Entry::load() }
        .ok()
        .and_then(|entry| {
            // SAFETY: a loaded entry.
            unsafe { entry.enumerate_instance_layer_properties() }.ok()
        })
        .is_some_and(|layers| {
            layers.iter().any(|l| {
                l.layer_name_as_c_str()
                    .is_ok_and(|n| n == c"VK_LAYER_KHRONOS_validation")
            })
        });
    MESSAGES_META
        .lock()
        .unwrap()
        .push(format!("validation {}", u8::from(validation)));
    let limits = adapter.limits();
    let minimum = wgpu::Limits::default().using_minimum_supported_acceleration_structure_values();
    let meets = limits.max_blas_primitive_count >= minimum.max_blas_primitive_count
        && limits.max_blas_geometry_count >= minimum.max_blas_geometry_count
        && limits.max_tlas_instance_count >= minimum.max_tlas_instance_count
        && limits.max_acceleration_structures_per_shader_stage
            >= minimum.max_acceleration_structures_per_shader_stage;
    MESSAGES_META
        .lock()
        .unwrap()
        .push(format!("meets_minimum {}", u8::from(meets)));
    let (device, queue) = ready(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("ray-query app"),
        required_features: wgpu::Features::EXPERIMENTAL_RAY_QUERY,
        // The adapter's own: Mesa 25.0.7's ray query offers less than wgpu's minimum
        // (`using_minimum_supported_acceleration_structure_values`), which the layer meets.
        required_limits:
            wgpu::Limits::default().using_acceleration_structure_values(adapter.limits()),
        // SAFETY: the features asked for are ray queries, which this test holds to a
        // reference.
        experimental_features: unsafe { wgpu::ExperimentalFeatures::enabled() },
        ..Default::default()
    }))
    .map_err(|e| format!("no device: {e}"))?;

    let input = wgpu::BufferUsages::BLAS_INPUT | wgpu::BufferUsages::COPY_DST;
    let grid_vertex_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("grid vertices"),
        contents: bytemuck::cast_slice(&grid_vertices(0)),
        usage: input,
    });
    let grid_index = grid_indices();
    let grid_index_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("grid indices"),
        contents: bytemuck::cast_slice(&grid_index),
        usage: input,
    });
    let (soup_vertices, soup_index) = soup();
    let soup_vertex_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("soup vertices"),
        contents: bytemuck::cast_slice(&soup_vertices),
        usage: input,
    });
    let soup_index_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("soup indices"),
        contents: bytemuck::cast_slice(&soup_index),
        usage: input,
    });
    let soup_transform_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("soup transform"),
        contents: bytemuck::cast_slice(&SOUP_TRANSFORM),
        usage: input,
    });

    let grid_size = wgpu::BlasTriangleGeometrySizeDescriptor {
        vertex_format: wgpu::VertexFormat::Float32x3,
        vertex_count: (QUADS + 1) * (QUADS + 1),
        index_format: Some(wgpu::IndexFormat::Uint32),
        index_count: Some(grid_index.len() as u32),
        flags: wgpu::AccelerationStructureGeometryFlags::OPAQUE,
    };
    let soup_size = wgpu::BlasTriangleGeometrySizeDescriptor {
        vertex_format: wgpu::VertexFormat::Float32x3,
        vertex_count: soup_vertices.len() as u32,
        index_format: Some(wgpu::IndexFormat::Uint16),
        index_count: Some(soup_index.len() as u32),
        flags: wgpu::AccelerationStructureGeometryFlags::empty(),
    };
    let grid_blas = device.create_blas(
        &wgpu::CreateBlasDescriptor {
            label: Some("grid"),
            flags: wgpu::AccelerationStructureFlags::PREFER_FAST_TRACE
                | wgpu::AccelerationStructureFlags::ALLOW_UPDATE,
            update_mode: wgpu::AccelerationStructureUpdateMode::PreferUpdate,
        },
        wgpu::BlasGeometrySizeDescriptors::Triangles {
            descriptors: vec![grid_size.clone()],
        },
    );
    let mut soup_blas = device.create_blas(
        &wgpu::CreateBlasDescriptor {
            label: Some("soup"),
            flags: wgpu::AccelerationStructureFlags::PREFER_FAST_TRACE
                | wgpu::AccelerationStructureFlags::USE_TRANSFORM
                | wgpu::AccelerationStructureFlags::ALLOW_COMPACTION,
            update_mode: wgpu::AccelerationStructureUpdateMode::Build,
        },
        wgpu::BlasGeometrySizeDescriptors::Triangles {
            descriptors: vec![soup_size.clone()],
        },
    );
    let mut tlas = device.create_tlas(&wgpu::CreateTlasDescriptor {
        label: Some("scene"),
        max_instances: 4,
        flags: wgpu::AccelerationStructureFlags::PREFER_FAST_TRACE,
        update_mode: wgpu::AccelerationStructureUpdateMode::Build,
    });

    let mut ray_data = Vec::new();
    for r in 0..SIDE * SIDE {
        let (o, d) = ray(r);
        ray_data.extend_from_slice(&[o[0], o[1], o[2], 0.0, d[0], d[1], d[2], 100.0]);
    }
    let rays = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("rays"),
        contents: bytemuck::cast_slice(&ray_data),
        usage: wgpu::BufferUsages::STORAGE,
    });
    let hit_bytes = (SIDE * SIDE * 32) as u64;
    let hits = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("hits"),
        size: hit_bytes,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let readback = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size: hit_bytes,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let source = SHADER.replace("RAY_MASK", &format!("{RAY_MASK:#x}u"));
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("trace"),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some("trace"),
        layout: None,
        module: &module,
        entry_point: Some("main"),
        compilation_options: Default::default(),
        cache: None,
    });

    let mut frames = Vec::new();
    for frame in 0..2u32 {
        if frame > 0 {
            // The soup compacted (its compacted size queried, then a compacting copy), the
            // original dropped: the second frame traces the copy.
            soup_blas.prepare_compaction_async(|r| r.expect("the soup's compacted size"));
            device
                .poll(wgpu::PollType::wait_indefinitely())
                .map_err(|e| format!("poll: {e}"))?;
            assert!(
                soup_blas.ready_for_compaction(),
                "the soup is not ready to compact"
            );
            soup_blas = queue.compact_blas(&soup_blas);
            // An update in place: the grid bends, with the same vertex and index counts.
            queue.write_buffer(
                &grid_vertex_buffer,
                0,
                bytemuck::cast_slice(&grid_vertices(frame)),
            );
        }
        for (i, inst) in instances(frame).iter().enumerate() {
            let blas = [&grid_blas, &soup_blas][inst.level];
            tlas[i] = Some(wgpu::TlasInstance::new(
                blas,
                inst.transform,
                inst.custom,
                inst.mask,
            ));
        }
        let grid_entry = wgpu::BlasBuildEntry {
            blas: &grid_blas,
            geometry: wgpu::BlasGeometries::TriangleGeometries(vec![wgpu::BlasTriangleGeometry {
                size: &grid_size,
                vertex_buffer: &grid_vertex_buffer,
                first_vertex: 0,
                vertex_stride: 12,
                index_buffer: Some(&grid_index_buffer),
                first_index: Some(0),
                transform_buffer: None,
                transform_buffer_offset: None,
            }]),
        };
        let soup_entry = wgpu::BlasBuildEntry {
            blas: &soup_blas,
            geometry: wgpu::BlasGeometries::TriangleGeometries(vec![wgpu::BlasTriangleGeometry {
                size: &soup_size,
                vertex_buffer: &soup_vertex_buffer,
                first_vertex: 0,
                vertex_stride: 12,
                index_buffer: Some(&soup_index_buffer),
                first_index: Some(0),
                transform_buffer: Some(&soup_transform_buffer),
                transform_buffer_offset: Some(0),
            }]),
        };
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("trace"),
            layout: &pipeline.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: tlas.as_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: rays.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: hits.as_entire_binding(),
                },
            ],
        });
        let mut encoder = device.create_command_encoder(&Default::default());
        // The first frame builds both bottom levels; the second updates the grid only.
        let entries: Vec<&wgpu::BlasBuildEntry> = match frame {
            0 => vec![&grid_entry, &soup_entry],
            _ => vec![&grid_entry],
        };
        encoder.build_acceleration_structures(entries, [&tlas]);
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(&pipeline);
            pass.set_bind_group(0, &bind_group, &[]);
            pass.dispatch_workgroups((SIDE * SIDE).div_ceil(64), 1, 1);
        }
        encoder.copy_buffer_to_buffer(&hits, 0, &readback, 0, hit_bytes);
        queue.submit([encoder.finish()]);
        let slice = readback.slice(..);
        slice.map_async(wgpu::MapMode::Read, |r| r.expect("the hits' mapping"));
        device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| format!("poll: {e}"))?;
        let words: Vec<u32> = bytemuck::cast_slice(&slice.get_mapped_range()).to_vec();
        readback.unmap();
        frames.push(
            words
                .chunks(8)
                .map(|w| Hit {
                    kind: w[0] & 3,
                    front: (w[0] >> 2) & 1,
                    instance: (w[0] >> 3) & 63,
                    geometry: w[0] >> 9,
                    custom: w[1],
                    primitive: w[2],
                    t: f32::from_bits(w[3]),
                    u: f32::from_bits(w[4]),
                    v: f32::from_bits(w[5]),
                })
                .collect(),
        );
    }
    Ok(frames)
}

// ----- the parent: runs and checks -----

/// How the child reaches the device.
#[derive(Clone, Copy)]
enum Through {
    Native,
    Layer { force: bool },
}

/// The child's result: its frames' hits, or why it did not trace.
struct Run {
    frames: Vec<Vec<Hit>>,
    messages: Vec<String>,
    unsupported: Option<String>,
    /// Whether the adapter's acceleration-structure limits meet wgpu's minimum.
    meets_minimum: bool,
    /// Whether the validation layer was there for wgpu to enable.
    validated: bool,
    stderr: String,
}

fn run_child(through: Through) -> Run {
    static RUNS: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    let run = RUNS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let out = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("layer-wgpu-{}-{run}.txt", std::process::id()));
    let mut cmd = app::this_binary_again();
    cmd.args(["child", "--exact", "--nocapture", "--test-threads=1"])
        .env("VKRT_WGPU_APP_OUT", &out)
        // The validation layer (which wgpu enables below the layers named here) with its
        // synchronization validation.
        .env("VK_KHRONOS_VALIDATION_VALIDATE_SYNC", "true")
        .env_remove("VK_INSTANCE_LAYERS")
        .env_remove("VK_LOADER_LAYERS_ENABLE")
        .env_remove("VKRT_LAYER_FORCE");
    if let Through::Layer { force } = through {
        let dir = app::manifest_dir(std::path::Path::new(env!("CARGO_TARGET_TMPDIR")));
        app::add_layer_path(&mut cmd, &dir);
        cmd.env("VK_INSTANCE_LAYERS", "VK_LAYER_VKRT_ray_query")
            .env(vkrt_layer::STATS_VARIABLE, "1");
        if force {
            cmd.env("VKRT_LAYER_FORCE", "1");
        }
    }
    let (text, stderr) = common::run_to_file(cmd, &out, "the wgpu application");
    let mut run = Run {
        frames: Vec::new(),
        messages: Vec::new(),
        unsupported: None,
        meets_minimum: false,
        validated: false,
        stderr,
    };
    for line in text.lines() {
        if let Some(m) = line.strip_prefix("message ") {
            run.messages.push(m.to_string());
        } else if let Some(m) = line.strip_prefix("validation ") {
            run.validated = m == "1";
        } else if let Some(m) = line.strip_prefix("meets_minimum ") {
            run.meets_minimum = m == "1";
        } else if let Some(why) = line.strip_prefix("unsupported ") {
            run.unsupported = Some(why.to_string());
        } else if let Some(h) = line.strip_prefix("hit ") {
            let w: Vec<&str> = h.split(' ').collect();
            let f: usize = w[0].parse().unwrap();
            if run.frames.len() <= f {
                run.frames.resize(f + 1, Vec::new());
            }
            run.frames[f].push(Hit {
                kind: w[1].parse().unwrap(),
                t: w[2].parse().unwrap(),
                custom: w[3].parse().unwrap(),
                instance: w[4].parse().unwrap(),
                geometry: w[5].parse().unwrap(),
                primitive: w[6].parse().unwrap(),
                u: w[7].parse().unwrap(),
                v: w[8].parse().unwrap(),
                front: w[9].parse().unwrap(),
            });
        }
    }
    run
}

/// Whether the driver has its own ray query (wgpu's adapter offers it natively).
fn driver_has_ray_query() -> bool {
    static HAS: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *HAS.get_or_init(|| {
        let ctx = vkrt::Context::new(&vkrt::gpu::ContextOptions::default())
            .expect("a Vulkan device for the test");
        ctx.info().features.ray_query
    })
}

/// `m` applied to the point (`w` = 1) or direction (`w` = 0) `p`.
fn apply(m: &[f32; 12], p: [f64; 3], w: f64) -> [f64; 3] {
    let r = |k: usize| {
        m[4 * k] as f64 * p[0]
            + m[4 * k + 1] as f64 * p[1]
            + m[4 * k + 2] as f64 * p[2]
            + m[4 * k + 3] as f64 * w
    };
    [r(0), r(1), r(2)]
}

/// The reference answer of every ray of `frame`, and whether the ray is at an edge (where
/// the specification leaves the answer open to rounding), in world space from the f32
/// inputs.
fn reference(frame: u32) -> Vec<(Option<Hit>, bool)> {
    const EDGE: f64 = 1e-4;
    let grid_v = grid_vertices(frame);
    let grid_ix = grid_indices();
    let (soup_v, soup_ix) = soup();
    let to_f64 = |p: [f32; 3]| [p[0] as f64, p[1] as f64, p[2] as f64];
    // (instance, custom data, primitive, world-space corners, kept by the shader)
    type Triangle = (u32, u32, u32, [[f64; 3]; 3], bool);
    let mut triangles: Vec<Triangle> = Vec::new();
    for (i, inst) in instances(frame).iter().enumerate() {
        if u32::from(inst.mask) & RAY_MASK == 0 {
            continue;
        }
        let (positions, opaque): (Vec<[f64; 3]>, bool) = match inst.level {
            0 => (
                grid_ix
                    .iter()
                    .map(|&k| to_f64(grid_v[k as usize]))
                    .collect(),
                true,
            ),
            _ => (
                soup_ix
                    .iter()
                    .map(|&k| apply(&SOUP_TRANSFORM, to_f64(soup_v[k as usize]), 1.0))
                    .collect(),
                false,
            ),
        };
        for (p, tri) in positions.chunks(3).enumerate() {
            let world = [0, 1, 2].map(|k| apply(&inst.transform, tri[k], 1.0));
            // Non-opaque triangles are kept by the shader where their index is even.
            let kept = opaque || p % 2 == 0;
            triangles.push((i as u32, inst.custom, p as u32, world, kept));
        }
    }
    (0..SIDE * SIDE)
        .map(|r| {
            let (o, d) = ray(r);
            let (o, d) = (to_f64(o), to_f64(d));
            let mut best: Option<(f64, Hit)> = None;
            let mut edge = false;
            let mut ts = Vec::new();
            for &(instance, custom, primitive, tri, kept) in &triangles {
                let Some((t, u, v)) = common::intersect(o, d, &tri) else {
                    continue;
                };
                let inside = u >= 0.0 && v >= 0.0 && u + v <= 1.0 && (0.0..=100.0).contains(&t);
                let near = u > -EDGE && v > -EDGE && u + v < 1.0 + EDGE && t > -EDGE;
                if !kept || !near {
                    continue;
                }
                if !inside || u < EDGE || v < EDGE || u + v > 1.0 - EDGE {
                    edge = true;
                }
                ts.push(t);
                let hit = Hit {
                    kind: 1,
                    t: t as f32,
                    custom,
                    instance,
                    geometry: 0,
                    primitive,
                    u: u as f32,
                    v: v as f32,
                    front: 0,
                };
                if inside && best.is_none_or(|(bt, _)| t < bt) {
                    best = Some((t, hit));
                }
            }
            // Two surfaces at one distance: either may be the answer.
            ts.sort_by(f64::total_cmp);
            edge |= ts.windows(2).any(|w| w[1] - w[0] < 1e-4);
            (best.map(|(_, h)| h), edge)
        })
        .collect()
}

/// Whether `got` is the reference's answer (the front face is not compared: the reference
/// does not model it).
fn agrees(got: &Hit, want: &Option<Hit>) -> bool {
    match want {
        None => got.kind == 0,
        Some(w) => {
            got.kind == 1
                && got.custom == w.custom
                && got.instance == w.instance
                && got.geometry == w.geometry
                && got.primitive == w.primitive
                && (got.t - w.t).abs() <= 1e-4 * w.t.abs().max(1.0)
                && (got.u - w.u).abs() <= 1e-3
                && (got.v - w.v).abs() <= 1e-3
        }
    }
}

/// Holds every frame of `run` to the reference; returns the hits counted.
fn check_against_reference(what: &str, run: &Run) -> usize {
    assert_eq!(run.frames.len(), 2, "{what}: frames");
    let mut hits = 0;
    let mut wrong = Vec::new();
    for (f, got) in run.frames.iter().enumerate() {
        let want = reference(f as u32);
        assert_eq!(got.len(), want.len(), "{what}: rays of frame {f}");
        for (r, (g, (w, edge))) in got.iter().zip(&want).enumerate() {
            hits += usize::from(g.kind != 0);
            if !edge && !agrees(g, w) {
                wrong.push(format!("frame {f} ray {r}: got {g:?}, want {w:?}"));
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "{what}: {} rays differ from the reference:\n{}",
        wrong.len(),
        wrong[..wrong.len().min(8)].join("\n")
    );
    let edges: usize = (0..2)
        .map(|f| reference(f).iter().filter(|(_, e)| *e).count())
        .sum();
    eprintln!(
        "{what}: {hits} hits, {edges} rays at edges of {} over two frames",
        2 * SIDE * SIDE
    );
    hits
}

/// The layer's own complaints: none but the loop-budget warning (Mesa 22.3), once.
fn assert_layer_quiet(stderr: &str) {
    let lines: Vec<&str> = stderr
        .lines()
        .filter(|l| l.starts_with("vkrt layer:") && !l.starts_with(common::STATS))
        .filter(|l| !l.contains("loops once they have run a budget of iterations"))
        .collect();
    assert!(lines.is_empty(), "the layer logged:\n{}", lines.join("\n"));
}

#[test]
fn a_wgpu_application_traces_through_the_layer_as_the_reference_says() {
    let run = run_child(Through::Layer {
        force: driver_has_ray_query(),
    });
    assert_eq!(
        run.unsupported, None,
        "wgpu through the layer:\n{}",
        run.stderr
    );
    assert!(
        run.messages.is_empty(),
        "validation below the layer:\n{}",
        run.messages.join("\n")
    );
    assert!(
        run.validated || std::env::var("VKRT_VALIDATION").is_ok_and(|v| v.trim() == "0"),
        "the Khronos validation layer is not installed (VKRT_VALIDATION=0 runs without it)"
    );
    assert_layer_quiet(&run.stderr);
    // wgpu hands every build a scratch buffer of its own: with push descriptors the layer's
    // recordings still create nothing.
    let recorded = common::objects_created_while_recording(&run.stderr);
    assert!(
        recorded.len() >= 4 && recorded.iter().all(|&(_, n)| n == 0),
        "objects created while recording: {recorded:#?}"
    );
    // What wgpu's ray-query examples ask of a device.
    assert!(
        run.meets_minimum,
        "the layer's limits are below wgpu's minimum"
    );
    let hits = check_against_reference("wgpu through the layer", &run);
    // The scene is seen: every instance the mask lets through, in each frame (the second
    // through the compacted soup).
    for (f, frame) in run.frames.iter().enumerate() {
        let mut seen: Vec<u32> = frame
            .iter()
            .filter(|h| h.kind != 0)
            .map(|h| h.custom)
            .collect();
        seen.sort();
        seen.dedup();
        assert_eq!(seen, [10, 11, 12], "custom data seen in frame {f}");
    }
    assert!(hits > 1000, "{hits} hits over two frames");
    // The second frame's update and new transform change what rays see, so a stale
    // structure would be caught.
    let (a, b) = (reference(0), reference(1));
    let changed = a.iter().zip(&b).filter(|(x, y)| x.0 != y.0).count();
    assert!(changed > 100, "{changed} rays change between the frames");
}

#[test]
fn wgpu_on_the_drivers_own_ray_query_gives_what_the_layer_gives() {
    if !driver_has_ray_query() {
        // wgpu offers no ray query here without the layer; the layer's run is held to the
        // reference above.
        let native = run_child(Through::Native);
        assert!(
            native.unsupported.is_some(),
            "wgpu found ray query natively"
        );
        return;
    }
    let native = run_child(Through::Native);
    assert_eq!(
        native.unsupported, None,
        "wgpu natively:\n{}",
        native.stderr
    );
    assert!(
        native.messages.is_empty(),
        "validation of the native run:\n{}",
        native.messages.join("\n")
    );
    check_against_reference("wgpu natively", &native);
    let layered = run_child(Through::Layer { force: true });
    let mut differ = Vec::new();
    for f in 0..2 {
        let want = reference(f as u32);
        for (r, ((a, b), (_, edge))) in native.frames[f]
            .iter()
            .zip(&layered.frames[f])
            .zip(&want)
            .enumerate()
        {
            let same = a.kind == b.kind
                && (a.kind == 0
                    || (a.custom, a.instance, a.geometry, a.primitive, a.front)
                        == (b.custom, b.instance, b.geometry, b.primitive, b.front));
            if !edge && !same {
                differ.push(format!("frame {f} ray {r}: driver {a:?}, layer {b:?}"));
            }
        }
    }
    assert!(
        differ.is_empty(),
        "{} rays where the layer and the driver differ:\n{}",
        differ.len(),
        differ[..differ.len().min(8)].join("\n")
    );
}
