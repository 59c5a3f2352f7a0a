//! An application written against the Khronos API only (ash; no vkrt call): bottom levels
//! of indexed (u32, u16) and non-indexed triangles and of procedural boxes, a top level of
//! instances with transforms, masks and flags, built with vkCmdBuildAccelerationStructuresKHR
//! and traced by a compute shader's ray queries — alpha-tested candidates confirmed, boxes'
//! spheres generated — then updated (vertices and instances moved) and traced again.
//!
//! Its compute pipeline, descriptor set and push constants are bound *before* the builds
//! and used by the dispatch after them without a rebind: a layer that records builds into
//! the command buffer must put the application's compute state back.

use std::ffi::{c_void, CStr};
use std::sync::Mutex;

use ash::vk;

/// Rays per side of the grid.
pub const WIDTH: u32 = 32;
/// The rays' cull mask: instance 4 (mask 0x08) is never seen.
pub const CULL_MASK: u32 = 0x07;
pub const T_MAX: f32 = 100.0;

/// One ray's committed intersection, as the shader writes it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Hit {
    pub t: f32,
    /// 0 none, 1 triangle, 2 generated.
    pub kind: u32,
    pub custom: u32,
    pub instance: u32,
    pub geometry: u32,
    pub primitive: u32,
    pub u: f32,
    pub v: f32,
}

/// Where the validation layer sits, if anywhere.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Validation {
    Off,
    /// Enabled by the application, below a layer enabled through the environment.
    Below,
    /// Enabled by the application before vkrt's layer, which it also enables: above it.
    Above,
}

// ----- the scene, shared with the reference -----

/// A 4×4 grid of quads in z = 0 over [-2, 2]², indexed with u32, opaque; `bump` moves
/// every other vertex in z (the update).
pub fn grid(bump: f32) -> (Vec<[f32; 3]>, Vec<u32>) {
    let mut v = Vec::new();
    for j in 0..5 {
        for i in 0..5 {
            let z = if (i + j) % 2 == 1 { bump } else { 0.0 };
            v.push([-2.0 + i as f32, -2.0 + j as f32, z]);
        }
    }
    let mut idx = Vec::new();
    for j in 0..4u32 {
        for i in 0..4u32 {
            let a = j * 5 + i;
            idx.extend([a, a + 1, a + 6, a, a + 6, a + 5]);
        }
    }
    (v, idx)
}

/// Geometry 0 of the second level: a fan of four triangles, u16 indices, not opaque (the
/// shader confirms even primitives), its vertices half floats (`R16G16B16A16_SFLOAT`).
pub fn fan() -> (Vec<[f32; 3]>, Vec<u16>) {
    // Values a half holds exactly: the geometry is read as R16G16B16A16_SFLOAT.
    let v = vec![
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.125],
        [0.0, 1.0, -0.125],
        [-1.0, 0.0, 0.0625],
        [0.0, -1.0, 0.0],
    ];
    let idx = vec![0, 1, 2, 0, 2, 3, 0, 3, 4, 0, 4, 1];
    (v, idx)
}

/// Geometry 1 of the second level: two triangles, no indices, opaque.
pub fn soup() -> Vec<[f32; 3]> {
    vec![
        [0.6, 0.6, 0.3],
        [1.4, 0.6, 0.3],
        [1.0, 1.4, 0.3],
        [-1.4, -0.6, 0.2],
        [-0.6, -0.6, 0.2],
        [-1.0, -1.4, 0.2],
    ]
}

/// Geometry 1's transform (transformData): a turn about z and a shift.
pub const SOUP_TRANSFORM: [[f32; 4]; 3] = [
    [0.955_336_5, -0.295_520_2, 0.0, 0.1],
    [0.295_520_2, 0.955_336_5, 0.0, -0.2],
    [0.0, 0.0, 1.0, 0.05],
];

/// The third level's spheres (centre, radius), each in its box.
pub fn spheres() -> Vec<[f32; 4]> {
    vec![
        [0.0, 0.0, 0.0, 0.6],
        [0.9, 0.2, -0.3, 0.3],
        [-0.7, -0.5, 0.2, 0.35],
    ]
}

/// An instance: its level (0 grid, 1 fan + soup, 2 spheres), row-major object-to-world,
/// custom index, mask, flags.
#[derive(Clone, Copy, Debug)]
pub struct Placement {
    pub level: usize,
    pub rows: [[f32; 4]; 3],
    pub custom: u32,
    pub mask: u32,
    pub flags: u32,
}

fn place(
    level: usize,
    angle: f32,
    scale: f32,
    at: [f32; 3],
    custom: u32,
    mask: u32,
    flags: u32,
) -> Placement {
    let (s, c) = angle.sin_cos();
    Placement {
        level,
        rows: [
            [c * scale, -s * scale, 0.0, at[0]],
            [s * scale, c * scale, 0.0, at[1]],
            [0.0, 0.0, scale, at[2]],
        ],
        custom,
        mask,
        flags,
    }
}

/// The instances of frame `frame` (0: the build, 1: the update, which moves them).
pub fn instances(frame: u32) -> Vec<Placement> {
    let d = frame as f32 * 0.3;
    let force_opaque = vk::GeometryInstanceFlagsKHR::FORCE_OPAQUE.as_raw();
    let cull_disable = vk::GeometryInstanceFlagsKHR::TRIANGLE_FACING_CULL_DISABLE.as_raw();
    vec![
        place(0, 0.0, 1.0, [0.0, 0.0, 0.0], 10, 0x01, 0),
        place(
            0,
            0.5 + d,
            0.5,
            [0.6 + d, -0.7, 1.0],
            11,
            0x02,
            cull_disable,
        ),
        place(1, 0.2, 0.8, [-1.5 + d, 1.4, 2.0], 12, 0x01, 0),
        place(2, 0.0, 1.0, [1.5, 1.5 - d, 2.5], 13, 0x04, 0),
        place(0, 0.0, 2.0, [0.0, 0.0, 3.0], 14, 0x08, 0),
        place(1, -0.4, 0.8, [1.4, -1.5, 2.0 + d], 15, 0x01, force_opaque),
    ]
}

/// Ray `i`'s origin and direction.
pub fn ray(i: u32, z: f32) -> ([f32; 3], [f32; 3]) {
    let u = ((i % WIDTH) as f32 + 0.37) / WIDTH as f32;
    let v = ((i / WIDTH) as f32 + 0.61) / WIDTH as f32;
    ([-3.0 + 6.0 * u, -3.0 + 6.0 * v, z], [0.05, 0.03, -1.0])
}

/// The declarations and the trace both shaders share: one ray (`ray(i)`) through the
/// query, even triangle candidates confirmed (an alpha test), the spheres' hits generated.
const TRACE: &str = r#"
#extension GL_EXT_ray_query : require
layout(set = 0, binding = 0) uniform accelerationStructureEXT tlas;
layout(set = 0, binding = 2) readonly buffer Spheres { vec4 spheres[]; };
layout(push_constant) uniform Push { uint count; uint width; float z; uint cull; } pc;
struct Hit { float t; uint kind; uint custom; uint instance; uint geometry; uint primitive; float u; float v; };

Hit trace_ray(uint i) {
    float u = (float(i % pc.width) + 0.37) / float(pc.width);
    float v = (float(i / pc.width) + 0.61) / float(pc.width);
    vec3 origin = vec3(-3.0 + 6.0 * u, -3.0 + 6.0 * v, pc.z);
    vec3 dir = vec3(0.05, 0.03, -1.0);
    rayQueryEXT q;
    rayQueryInitializeEXT(q, tlas, gl_RayFlagsNoneEXT, pc.cull, origin, 0.0, dir, 100.0);
    while (rayQueryProceedEXT(q)) {
        uint prim = rayQueryGetIntersectionPrimitiveIndexEXT(q, false);
        if (rayQueryGetIntersectionTypeEXT(q, false) == gl_RayQueryCandidateIntersectionTriangleEXT) {
            // An alpha test: even primitives are solid.
            if (prim % 2u == 0u) rayQueryConfirmIntersectionEXT(q);
        } else {
            vec3 o = rayQueryGetIntersectionObjectRayOriginEXT(q, false);
            vec3 d = rayQueryGetIntersectionObjectRayDirectionEXT(q, false);
            vec4 s = spheres[prim];
            vec3 oc = o - s.xyz;
            float a = dot(d, d), b = dot(oc, d), c = dot(oc, oc) - s.w * s.w;
            float disc = b * b - a * c;
            if (disc >= 0.0) {
                float t = (-b - sqrt(disc)) / a;
                float best = rayQueryGetIntersectionTypeEXT(q, true) == gl_RayQueryCommittedIntersectionNoneEXT
                    ? 100.0 : rayQueryGetIntersectionTEXT(q, true);
                if (t >= rayQueryGetRayTMinEXT(q) && t <= best) rayQueryGenerateIntersectionEXT(q, t);
            }
        }
    }
    Hit h = Hit(0.0, rayQueryGetIntersectionTypeEXT(q, true), 0u, 0u, 0u, 0u, 0.0, 0.0);
    if (h.kind != gl_RayQueryCommittedIntersectionNoneEXT) {
        h.t = rayQueryGetIntersectionTEXT(q, true);
        h.custom = rayQueryGetIntersectionInstanceCustomIndexEXT(q, true);
        h.instance = rayQueryGetIntersectionInstanceIdEXT(q, true);
        h.geometry = rayQueryGetIntersectionGeometryIndexEXT(q, true);
        h.primitive = rayQueryGetIntersectionPrimitiveIndexEXT(q, true);
        if (h.kind == gl_RayQueryCommittedIntersectionTriangleEXT) {
            vec2 b = rayQueryGetIntersectionBarycentricsEXT(q, true);
            h.u = b.x; h.v = b.y;
        }
    }
    return h;
}
"#;

/// The compute shader: one ray per invocation, its hit to the output buffer.
pub fn compute_shader() -> String {
    format!(
        "#version 460\n{TRACE}\n{}",
        r#"
layout(local_size_x = 64) in;
layout(set = 0, binding = 1) buffer Out { Hit hits[]; };
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i < pc.count) hits[i] = trace_ray(i);
}
"#
    )
}

/// The full-screen triangle.
pub const VERTEX_SHADER: &str = r#"
#version 460
void main() {
    vec2 p = vec2(float((gl_VertexIndex << 1) & 2), float(gl_VertexIndex & 2));
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
"#;

/// The fragment shader: one ray per pixel of a WIDTH² image, its hit in two RGBA32F
/// attachments.
pub fn fragment_shader() -> String {
    format!(
        "#version 460\n{TRACE}\n{}",
        r#"
layout(location = 0) out vec4 hit0;
layout(location = 1) out vec4 hit1;
void main() {
    Hit h = trace_ray(uint(gl_FragCoord.y) * pc.width + uint(gl_FragCoord.x));
    hit0 = vec4(h.t, float(h.kind), float(h.custom), float(h.instance));
    hit1 = vec4(float(h.geometry), float(h.primitive), h.u, h.v);
}
"#
    )
}

// ----- running as a child process through the layer -----

/// This process's binary. Under a runner that starts it through another glibc's dynamic
/// loader (the next Mesa's), the process's executable is that loader, and argv[0] the
/// binary.
pub fn this_binary() -> std::path::PathBuf {
    let exe = std::env::current_exe().unwrap();
    match exe.file_name().and_then(|n| n.to_str()) {
        Some(n) if n.starts_with("ld-linux") => {
            std::path::PathBuf::from(std::env::args_os().next().unwrap())
                .canonicalize()
                .unwrap()
        }
        _ => exe,
    }
}

/// A directory (under `parent`) holding the layer's manifest, pointing at the library this
/// build made: the newest of the two places cargo leaves it (deps/, and its copy beside).
pub fn manifest_dir(parent: &std::path::Path) -> std::path::PathBuf {
    let exe = this_binary();
    let deps = exe.parent().unwrap();
    let library = [
        deps.join("../libvkrt_layer.so"),
        deps.join("libvkrt_layer.so"),
    ]
    .into_iter()
    .filter_map(|p| Some((std::fs::metadata(&p).ok()?.modified().ok()?, p)))
    .max()
    .map(|(_, p)| p)
    .expect("libvkrt_layer.so beside the binary (cargo builds the cdylib with the tests)");
    let library = library.canonicalize().unwrap();
    // One folder per library (not per process: those would pile up run after run).
    let key = {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        library.hash(&mut h);
        h.finish()
    };
    let dir = parent.join(format!("vkrt-layer-{key:016x}"));
    std::fs::create_dir_all(&dir).unwrap();
    let manifest = include_str!("../../VkLayer_vkrt_ray_query.json")
        .replace("./libvkrt_layer.so", library.to_str().unwrap());
    // Written whole and renamed into place: tests run in parallel, in this process and in
    // others, and a child's loader must never read a manifest being rewritten (it would
    // start without the layer).
    let partial = dir.join(format!(
        "manifest-{}-{:?}.partial",
        std::process::id(),
        std::thread::current().id()
    ));
    std::fs::write(&partial, manifest).unwrap();
    std::fs::rename(&partial, dir.join("VkLayer_vkrt_ray_query.json")).unwrap();
    dir
}

/// Lets `cmd`'s loader find `VK_LAYER_VKRT_ray_query` in `dir`: beside the folders
/// `VK_LAYER_PATH` names where it is set (the loader then ignores `VK_ADD_LAYER_PATH`), else
/// through `VK_ADD_LAYER_PATH`.
pub fn add_layer_path(cmd: &mut std::process::Command, dir: &std::path::Path) {
    match std::env::var_os("VK_LAYER_PATH") {
        Some(paths) if !paths.is_empty() => {
            let mut all = dir.as_os_str().to_owned();
            all.push(":");
            all.push(paths);
            cmd.env("VK_LAYER_PATH", all)
        }
        _ => cmd.env("VK_ADD_LAYER_PATH", dir),
    };
}

/// A command starting this binary again, through the runner it runs under, if any.
pub fn this_binary_again() -> std::process::Command {
    let exe = this_binary();
    match std::env::var("CARGO_TARGET_X86_64_UNKNOWN_LINUX_GNU_RUNNER") {
        Ok(runner) if !runner.is_empty() => {
            let mut c = std::process::Command::new(runner);
            c.arg(&exe);
            c
        }
        _ => std::process::Command::new(&exe),
    }
}

pub fn compile(source: &str) -> Vec<u32> {
    compile_with(source, &[])
}

/// `source` compiled by glslc with `args` (include directories, say).
pub fn compile_with(source: &str, args: &[&str]) -> Vec<u32> {
    let dir = std::env::temp_dir().join(format!("vkrt-layer-app-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let src = dir.join("app.comp");
    let out = dir.join("app.spv");
    std::fs::write(&src, source).unwrap();
    let o = std::process::Command::new("glslc")
        .args(["--target-env=vulkan1.2", "-O"])
        .args(args)
        .arg(&src)
        .arg("-o")
        .arg(&out)
        .output()
        .expect("glslc (Debian: glslc)");
    assert!(
        o.status.success(),
        "glslc: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let bytes = std::fs::read(&out).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    bytes
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

// ----- the Vulkan side -----

static MESSAGES: Mutex<Vec<String>> = Mutex::new(Vec::new());

unsafe extern "system" fn on_message(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    _user: *mut c_void,
) -> vk::Bool32 {
    // SAFETY: the layer's valid message.
    let data = unsafe { &*data };
    // SAFETY: as above: null or a name.
    let id = unsafe { data.p_message_id_name.as_ref() }
        .map(|_| {
            unsafe { CStr::from_ptr(data.p_message_id_name) }
                .to_string_lossy()
                .into_owned()
        })
        .unwrap_or_default();
    // The loader's notes on the layers the environment enables are not validation.
    if id == "Loader Message" {
        return vk::FALSE;
    }
    // SAFETY: as above.
    let text = unsafe { CStr::from_ptr(data.p_message) }
        .to_string_lossy()
        .into_owned();
    MESSAGES
        .lock()
        .unwrap()
        .push(format!("{severity:?}: {text}"));
    vk::FALSE
}

/// The validation layer's messages so far.
pub fn messages() -> Vec<String> {
    MESSAGES.lock().unwrap().clone()
}

pub struct Buf {
    pub buffer: vk::Buffer,
    pub memory: vk::DeviceMemory,
    pub address: u64,
    pub map: *mut u8,
}

pub struct Gpu {
    pub instance: ash::Instance,
    pub physical: vk::PhysicalDevice,
    pub messenger: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    pub device: ash::Device,
    pub accel: ash::khr::acceleration_structure::Device,
    pub push: ash::khr::push_descriptor::Device,
    pub props: vk::PhysicalDeviceMemoryProperties,
    pub queue: vk::Queue,
    pub family: u32,
    pub bufs: Vec<Buf>,
}

impl Gpu {
    pub fn buffer(&mut self, size: u64, usage: vk::BufferUsageFlags) -> usize {
        let size = size.max(16);
        let info = vk::BufferCreateInfo::default().size(size).usage(usage);
        unsafe {
            let buffer = self.device.create_buffer(&info, None).unwrap();
            let req = self.device.get_buffer_memory_requirements(buffer);
            let wanted =
                vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT;
            let ty = (0..self.props.memory_type_count)
                .find(|&i| {
                    req.memory_type_bits & (1 << i) != 0
                        && self.props.memory_types[i as usize]
                            .property_flags
                            .contains(wanted)
                })
                .expect("a host-visible memory type");
            let mut flags = vk::MemoryAllocateFlagsInfo::default()
                .flags(vk::MemoryAllocateFlags::DEVICE_ADDRESS);
            let device_address = usage.contains(vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS);
            let mut alloc = vk::MemoryAllocateInfo::default()
                .allocation_size(req.size)
                .memory_type_index(ty);
            if device_address {
                alloc = alloc.push_next(&mut flags);
            }
            let memory = self.device.allocate_memory(&alloc, None).unwrap();
            self.device.bind_buffer_memory(buffer, memory, 0).unwrap();
            let map = self
                .device
                .map_memory(memory, 0, vk::WHOLE_SIZE, vk::MemoryMapFlags::empty())
                .unwrap()
                .cast();
            let address = match device_address {
                true => self.device.get_buffer_device_address(
                    &vk::BufferDeviceAddressInfo::default().buffer(buffer),
                ),
                false => 0,
            };
            self.bufs.push(Buf {
                buffer,
                memory,
                address,
                map,
            });
        }
        self.bufs.len() - 1
    }

    pub fn write<T: Copy>(&self, b: usize, data: &[T]) {
        unsafe {
            std::ptr::copy_nonoverlapping(
                data.as_ptr().cast::<u8>(),
                self.bufs[b].map,
                std::mem::size_of_val(data),
            )
        };
    }
}

const F32X3: vk::Format = vk::Format::R32G32B32_SFLOAT;

/// A half float's bits, for values a half holds exactly (sign, exponent, the top ten bits
/// of the mantissa).
fn half(x: f32) -> u16 {
    if x == 0.0 {
        return 0;
    }
    let b = x.to_bits();
    assert_eq!(b & 0x1fff, 0, "{x} is not exact in a half");
    let e = ((b >> 23) & 0xff) as i32 - 127 + 15;
    (((b >> 16) & 0x8000) | ((e as u32) << 10) | ((b >> 13) & 0x3ff)) as u16
}

pub const INPUT: vk::BufferUsageFlags = vk::BufferUsageFlags::from_raw(
    vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR.as_raw()
        | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS.as_raw()
        | vk::BufferUsageFlags::STORAGE_BUFFER.as_raw(),
);

fn instance_record(p: &Placement, reference: u64) -> [u32; 16] {
    let mut r = [0u32; 16];
    for (k, v) in p.rows.iter().flatten().enumerate() {
        r[k] = v.to_bits();
    }
    r[12] = p.custom | (p.mask << 24);
    r[13] = p.flags << 24;
    r[14] = reference as u32;
    r[15] = (reference >> 32) as u32;
    r
}

/// Runs the application: three frames (build, update, the same update again), each traced
/// by the compute shader, then the last frame's scene traced by a fragment shader; returns the four
/// sets of hits. `Err` where device creation fails (the code).
pub fn run(validation: Validation) -> Result<Vec<Vec<Hit>>, vk::Result> {
    unsafe { run_unsafe(validation, vk::API_VERSION_1_2, false, false, false) }
}

/// [`run`] with the first update of the grid and of the top level each written into a
/// second structure (`srcAccelerationStructure` ≠ `dstAccelerationStructure`), which the
/// instances and the descriptor then name and the third frame updates in place.
pub fn run_update_into(validation: Validation) -> Result<Vec<Vec<Hit>>, vk::Result> {
    unsafe { run_unsafe(validation, vk::API_VERSION_1_2, false, false, true) }
}

/// [`run`] with its descriptors pushed through a template (`VK_KHR_push_descriptor`,
/// `vkCmdPushDescriptorSetWithTemplateKHR`) before the builds instead of a bound set.
pub fn run_push_template(validation: Validation) -> Result<Vec<Vec<Hit>>, vk::Result> {
    unsafe { run_unsafe(validation, vk::API_VERSION_1_2, false, true, false) }
}

/// [`run`] as a Vulkan 1.3 application whose barriers are synchronization 2's
/// (`vkCmdPipelineBarrier2`, with the acceleration-structure stages and accesses of
/// `VkPipelineStageFlags2`).
pub fn run_sync2(validation: Validation) -> Result<Vec<Vec<Hit>>, vk::Result> {
    unsafe { run_unsafe(validation, vk::API_VERSION_1_3, true, false, false) }
}

/// A memory barrier, recorded with synchronization 2 where `sync2` says so (its stage and
/// access bits are synchronization 1's, which keep their values there).
unsafe fn barrier(
    d: &ash::Device,
    cb: vk::CommandBuffer,
    sync2: bool,
    src: vk::PipelineStageFlags,
    dst: vk::PipelineStageFlags,
    b: vk::MemoryBarrier<'_>,
) {
    if !sync2 {
        d.cmd_pipeline_barrier(cb, src, dst, vk::DependencyFlags::empty(), &[b], &[], &[]);
        return;
    }
    let b2 = [vk::MemoryBarrier2::default()
        .src_stage_mask(vk::PipelineStageFlags2::from_raw(u64::from(src.as_raw())))
        .src_access_mask(vk::AccessFlags2::from_raw(u64::from(
            b.src_access_mask.as_raw(),
        )))
        .dst_stage_mask(vk::PipelineStageFlags2::from_raw(u64::from(dst.as_raw())))
        .dst_access_mask(vk::AccessFlags2::from_raw(u64::from(
            b.dst_access_mask.as_raw(),
        )))];
    d.cmd_pipeline_barrier2(cb, &vk::DependencyInfo::default().memory_barriers(&b2));
}

/// Creates the instance and device only, at `api`: the result of vkCreateDevice.
pub fn create_only(api: u32) -> vk::Result {
    match unsafe { setup(Validation::Off, api) } {
        Ok(_) => vk::Result::SUCCESS,
        Err(e) => e,
    }
}

/// Misuse the layer must answer with a log line and no crash: a build into a structure too
/// small for it, a geometry of a vertex format the extension does not require, a
/// destroyed structure written to a descriptor; the application then tears down as usual.
pub fn misuse() {
    // SAFETY: the child's whole life is this application.
    unsafe { misuse_unsafe() }
}

unsafe fn misuse_unsafe() {
    let (_entry, mut g) = setup(Validation::Off, vk::API_VERSION_1_2).expect("a device");
    let d = g.device.clone();
    let (v, idx) = grid(0.0);
    let b_v = g.buffer(12 * v.len() as u64, INPUT);
    let b_i = g.buffer(4 * idx.len() as u64, INPUT);
    g.write(b_v, &v);
    g.write(b_i, &idx);
    let (v_at, i_at) = (g.bufs[b_v].address, g.bufs[b_i].address);
    let geometry = |format: vk::Format| {
        let tris = vk::AccelerationStructureGeometryTrianglesDataKHR::default()
            .vertex_format(format)
            .vertex_data(vk::DeviceOrHostAddressConstKHR {
                device_address: v_at,
            })
            .vertex_stride(12)
            .max_vertex(v.len() as u32 - 1)
            .index_type(vk::IndexType::UINT32)
            .index_data(vk::DeviceOrHostAddressConstKHR {
                device_address: i_at,
            });
        [vk::AccelerationStructureGeometryKHR::default()
            .geometry_type(vk::GeometryTypeKHR::TRIANGLES)
            .geometry(vk::AccelerationStructureGeometryDataKHR { triangles: tris })
            .flags(vk::GeometryFlagsKHR::OPAQUE)]
    };
    let good = geometry(F32X3);
    let info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
        .ty(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL)
        .geometries(&good);
    let n = idx.len() as u32 / 3;
    let mut sizes = vk::AccelerationStructureBuildSizesInfoKHR::default();
    g.accel.get_acceleration_structure_build_sizes(
        vk::AccelerationStructureBuildTypeKHR::DEVICE,
        &info,
        &[n],
        &mut sizes,
    );
    // A quarter of what the sizes ask for.
    let small = (sizes.acceleration_structure_size / 4).next_multiple_of(256);
    let storage = g.buffer(
        small,
        vk::BufferUsageFlags::ACCELERATION_STRUCTURE_STORAGE_KHR
            | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS,
    );
    let scratch = g.buffer(
        sizes.build_scratch_size,
        vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS,
    );
    let create = |size| {
        g.accel
            .create_acceleration_structure(
                &vk::AccelerationStructureCreateInfoKHR::default()
                    .buffer(g.bufs[storage].buffer)
                    .size(size)
                    .ty(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL),
                None,
            )
            .unwrap()
    };
    let too_small = create(small);
    let odd_format = create(small);
    let pool = d
        .create_command_pool(
            &vk::CommandPoolCreateInfo::default().queue_family_index(g.family),
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
    d.begin_command_buffer(cb, &vk::CommandBufferBeginInfo::default())
        .unwrap();
    let range = [vk::AccelerationStructureBuildRangeInfoKHR::default().primitive_count(n)];
    let scratch_at = vk::DeviceOrHostAddressKHR {
        device_address: g.bufs[scratch].address,
    };
    g.accel.cmd_build_acceleration_structures(
        cb,
        &[info
            .dst_acceleration_structure(too_small)
            .scratch_data(scratch_at)],
        &[&range],
    );
    let odd = geometry(vk::Format::R8G8B8A8_SNORM);
    let odd_info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
        .ty(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL)
        .geometries(&odd)
        .dst_acceleration_structure(odd_format)
        .scratch_data(scratch_at);
    g.accel
        .cmd_build_acceleration_structures(cb, &[odd_info], &[&range]);
    d.end_command_buffer(cb).unwrap();
    let fence = d
        .create_fence(&vk::FenceCreateInfo::default(), None)
        .unwrap();
    let cbs = [cb];
    d.queue_submit(
        g.queue,
        &[vk::SubmitInfo::default().command_buffers(&cbs)],
        fence,
    )
    .unwrap();
    d.wait_for_fences(&[fence], true, u64::MAX).unwrap();

    // A destroyed structure in a descriptor: the shader then finds no structure.
    g.accel.destroy_acceleration_structure(odd_format, None);
    let bindings = [vk::DescriptorSetLayoutBinding::default()
        .binding(0)
        .descriptor_type(vk::DescriptorType::ACCELERATION_STRUCTURE_KHR)
        .descriptor_count(1)
        .stage_flags(vk::ShaderStageFlags::COMPUTE)];
    let set_layout = d
        .create_descriptor_set_layout(
            &vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings),
            None,
        )
        .unwrap();
    let sizes = [vk::DescriptorPoolSize {
        ty: vk::DescriptorType::ACCELERATION_STRUCTURE_KHR,
        descriptor_count: 1,
    }];
    let dpool = d
        .create_descriptor_pool(
            &vk::DescriptorPoolCreateInfo::default()
                .max_sets(1)
                .pool_sizes(&sizes),
            None,
        )
        .unwrap();
    let set_layouts = [set_layout];
    let set = d
        .allocate_descriptor_sets(
            &vk::DescriptorSetAllocateInfo::default()
                .descriptor_pool(dpool)
                .set_layouts(&set_layouts),
        )
        .unwrap()[0];
    write_structure(&d, set, odd_format);
    d.device_wait_idle().unwrap();
    d.destroy_descriptor_pool(dpool, None);
    d.destroy_descriptor_set_layout(set_layout, None);
    d.destroy_fence(fence, None);
    d.destroy_command_pool(pool, None);
    g.accel.destroy_acceleration_structure(too_small, None);
    for b in g.bufs.drain(..) {
        d.destroy_buffer(b.buffer, None);
        d.free_memory(b.memory, None);
    }
    d.destroy_device(None);
    g.instance.destroy_instance(None);
}

pub unsafe fn setup(validation: Validation, api: u32) -> Result<(ash::Entry, Gpu), vk::Result> {
    setup_with(validation, api, false)
}

/// [`setup`], with `synchronization2` enabled where `sync2` says so (a Vulkan 1.3 device).
pub unsafe fn setup_with(
    validation: Validation,
    api: u32,
    sync2: bool,
) -> Result<(ash::Entry, Gpu), vk::Result> {
    let entry = ash::Entry::load().expect("the Vulkan loader");
    let app = vk::ApplicationInfo::default().api_version(api);
    let mut layers = Vec::new();
    match validation {
        Validation::Off => {}
        Validation::Below => layers.push(c"VK_LAYER_KHRONOS_validation".as_ptr()),
        Validation::Above => {
            layers.push(c"VK_LAYER_KHRONOS_validation".as_ptr());
            layers.push(c"VK_LAYER_VKRT_ray_query".as_ptr());
        }
    }
    let exts = [ash::ext::debug_utils::NAME.as_ptr()];
    let enables = [vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION];
    let mut features = vk::ValidationFeaturesEXT::default().enabled_validation_features(&enables);
    let make_messenger = || {
        vk::DebugUtilsMessengerCreateInfoEXT::default()
            .message_severity(
                vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
                    | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
            )
            .message_type(
                vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                    | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                    | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
            )
            .pfn_user_callback(Some(on_message))
    };
    let mut messenger = make_messenger();
    let mut info = vk::InstanceCreateInfo::default()
        .application_info(&app)
        .enabled_layer_names(&layers);
    if validation != Validation::Off {
        info = info
            .enabled_extension_names(&exts)
            .push_next(&mut features)
            .push_next(&mut messenger);
    }
    let instance = entry
        .create_instance(&info, None)
        .expect("vkCreateInstance");
    let messenger = (validation != Validation::Off).then(|| {
        let utils = ash::ext::debug_utils::Instance::new(&entry, &instance);
        let m = utils
            .create_debug_utils_messenger(&make_messenger(), None)
            .unwrap();
        (utils, m)
    });
    let pd = instance.enumerate_physical_devices().unwrap()[0];
    let family = instance
        .get_physical_device_queue_family_properties(pd)
        .iter()
        .position(|f| f.queue_flags.contains(vk::QueueFlags::COMPUTE))
        .unwrap() as u32;
    let priorities = [1.0];
    let queues = [vk::DeviceQueueCreateInfo::default()
        .queue_family_index(family)
        .queue_priorities(&priorities)];
    let dev_exts = [
        ash::khr::acceleration_structure::NAME.as_ptr(),
        ash::khr::ray_query::NAME.as_ptr(),
        ash::khr::deferred_host_operations::NAME.as_ptr(),
        ash::khr::push_descriptor::NAME.as_ptr(),
    ];
    let mut v12 = vk::PhysicalDeviceVulkan12Features::default().buffer_device_address(true);
    let mut asf =
        vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default().acceleration_structure(true);
    let mut rq = vk::PhysicalDeviceRayQueryFeaturesKHR::default().ray_query(true);
    let dinfo = vk::DeviceCreateInfo::default()
        .queue_create_infos(&queues)
        .enabled_extension_names(&dev_exts)
        .push_next(&mut v12)
        .push_next(&mut asf)
        .push_next(&mut rq);
    let mut v13 = vk::PhysicalDeviceVulkan13Features::default().synchronization2(true);
    let dinfo = match sync2 {
        true => dinfo.push_next(&mut v13),
        false => dinfo,
    };
    let device = instance.create_device(pd, &dinfo, None)?;
    let accel = ash::khr::acceleration_structure::Device::new(&instance, &device);
    let push = ash::khr::push_descriptor::Device::new(&instance, &device);
    let props = instance.get_physical_device_memory_properties(pd);
    let queue = device.get_device_queue(family, 0);
    Ok((
        entry,
        Gpu {
            instance,
            physical: pd,
            messenger,
            device,
            accel,
            push,
            props,
            queue,
            family,
            bufs: Vec::new(),
        },
    ))
}

/// Traces every ray once more from a fragment shader (one pixel each, a WIDTH² render
/// pass into two RGBA32F attachments, copied to a buffer), as the second frame left the
/// scene; returns its hits.
unsafe fn fragment_pass(
    g: &mut Gpu,
    cmd_pool: vk::CommandPool,
    fence: vk::Fence,
    tlas: vk::AccelerationStructureKHR,
    b_spheres: usize,
) -> Vec<Hit> {
    let d = g.device.clone();
    let format = vk::Format::R32G32B32A32_SFLOAT;
    let extent = vk::Extent3D {
        width: WIDTH,
        height: WIDTH,
        depth: 1,
    };
    let rays = (WIDTH * WIDTH) as usize;
    let mut images = Vec::new();
    let mut views = Vec::new();
    let mut memories = Vec::new();
    for _ in 0..2 {
        let image = d
            .create_image(
                &vk::ImageCreateInfo::default()
                    .image_type(vk::ImageType::TYPE_2D)
                    .format(format)
                    .extent(extent)
                    .mip_levels(1)
                    .array_layers(1)
                    .samples(vk::SampleCountFlags::TYPE_1)
                    .usage(
                        vk::ImageUsageFlags::COLOR_ATTACHMENT | vk::ImageUsageFlags::TRANSFER_SRC,
                    ),
                None,
            )
            .unwrap();
        let req = d.get_image_memory_requirements(image);
        let ty = (0..g.props.memory_type_count)
            .find(|&i| req.memory_type_bits & (1 << i) != 0)
            .unwrap();
        let memory = d
            .allocate_memory(
                &vk::MemoryAllocateInfo::default()
                    .allocation_size(req.size)
                    .memory_type_index(ty),
                None,
            )
            .unwrap();
        d.bind_image_memory(image, memory, 0).unwrap();
        let view = d
            .create_image_view(
                &vk::ImageViewCreateInfo::default()
                    .image(image)
                    .view_type(vk::ImageViewType::TYPE_2D)
                    .format(format)
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
        images.push(image);
        views.push(view);
        memories.push(memory);
    }
    let attachment = vk::AttachmentDescription::default()
        .format(format)
        .samples(vk::SampleCountFlags::TYPE_1)
        .load_op(vk::AttachmentLoadOp::CLEAR)
        .store_op(vk::AttachmentStoreOp::STORE)
        .initial_layout(vk::ImageLayout::UNDEFINED)
        .final_layout(vk::ImageLayout::TRANSFER_SRC_OPTIMAL);
    let attachments = [attachment, attachment];
    let refs = [
        vk::AttachmentReference {
            attachment: 0,
            layout: vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
        },
        vk::AttachmentReference {
            attachment: 1,
            layout: vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
        },
    ];
    let subpass = [vk::SubpassDescription::default()
        .pipeline_bind_point(vk::PipelineBindPoint::GRAPHICS)
        .color_attachments(&refs)];
    // The attachments' writes before the copy that follows the pass.
    let dependencies = [vk::SubpassDependency {
        src_subpass: 0,
        dst_subpass: vk::SUBPASS_EXTERNAL,
        src_stage_mask: vk::PipelineStageFlags::COLOR_ATTACHMENT_OUTPUT,
        dst_stage_mask: vk::PipelineStageFlags::TRANSFER,
        src_access_mask: vk::AccessFlags::COLOR_ATTACHMENT_WRITE,
        dst_access_mask: vk::AccessFlags::TRANSFER_READ,
        dependency_flags: vk::DependencyFlags::empty(),
    }];
    let render_pass = d
        .create_render_pass(
            &vk::RenderPassCreateInfo::default()
                .attachments(&attachments)
                .subpasses(&subpass)
                .dependencies(&dependencies),
            None,
        )
        .unwrap();
    let framebuffer = d
        .create_framebuffer(
            &vk::FramebufferCreateInfo::default()
                .render_pass(render_pass)
                .attachments(&views)
                .width(WIDTH)
                .height(WIDTH)
                .layers(1),
            None,
        )
        .unwrap();
    let bindings = [
        vk::DescriptorSetLayoutBinding::default()
            .binding(0)
            .descriptor_type(vk::DescriptorType::ACCELERATION_STRUCTURE_KHR)
            .descriptor_count(1)
            .stage_flags(vk::ShaderStageFlags::FRAGMENT),
        vk::DescriptorSetLayoutBinding::default()
            .binding(2)
            .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
            .descriptor_count(1)
            .stage_flags(vk::ShaderStageFlags::FRAGMENT),
    ];
    let set_layout = d
        .create_descriptor_set_layout(
            &vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings),
            None,
        )
        .unwrap();
    let set_layouts = [set_layout];
    let push_range = [vk::PushConstantRange::default()
        .stage_flags(vk::ShaderStageFlags::FRAGMENT)
        .size(16)];
    let layout = d
        .create_pipeline_layout(
            &vk::PipelineLayoutCreateInfo::default()
                .set_layouts(&set_layouts)
                .push_constant_ranges(&push_range),
            None,
        )
        .unwrap();
    let sizes = [
        vk::DescriptorPoolSize {
            ty: vk::DescriptorType::ACCELERATION_STRUCTURE_KHR,
            descriptor_count: 1,
        },
        vk::DescriptorPoolSize {
            ty: vk::DescriptorType::STORAGE_BUFFER,
            descriptor_count: 1,
        },
    ];
    let pool = d
        .create_descriptor_pool(
            &vk::DescriptorPoolCreateInfo::default()
                .max_sets(1)
                .pool_sizes(&sizes),
            None,
        )
        .unwrap();
    let set = d
        .allocate_descriptor_sets(
            &vk::DescriptorSetAllocateInfo::default()
                .descriptor_pool(pool)
                .set_layouts(&set_layouts),
        )
        .unwrap()[0];
    write_structure(&d, set, tlas);
    let sph_info = [vk::DescriptorBufferInfo::default()
        .buffer(g.bufs[b_spheres].buffer)
        .range(vk::WHOLE_SIZE)];
    let w1 = vk::WriteDescriptorSet::default()
        .dst_set(set)
        .dst_binding(2)
        .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
        .buffer_info(&sph_info);
    d.update_descriptor_sets(&[w1], &[]);

    let vertex = d
        .create_shader_module(
            &vk::ShaderModuleCreateInfo::default()
                .code(&compile_with(VERTEX_SHADER, &["-fshader-stage=vert"])),
            None,
        )
        .unwrap();
    let fragment = d
        .create_shader_module(
            &vk::ShaderModuleCreateInfo::default()
                .code(&compile_with(&fragment_shader(), &["-fshader-stage=frag"])),
            None,
        )
        .unwrap();
    let stages = [
        vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::VERTEX)
            .module(vertex)
            .name(c"main"),
        vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::FRAGMENT)
            .module(fragment)
            .name(c"main"),
    ];
    let vertex_input = vk::PipelineVertexInputStateCreateInfo::default();
    let assembly = vk::PipelineInputAssemblyStateCreateInfo::default()
        .topology(vk::PrimitiveTopology::TRIANGLE_LIST);
    let viewports = [vk::Viewport {
        x: 0.0,
        y: 0.0,
        width: WIDTH as f32,
        height: WIDTH as f32,
        min_depth: 0.0,
        max_depth: 1.0,
    }];
    let scissors = [vk::Rect2D {
        offset: vk::Offset2D { x: 0, y: 0 },
        extent: vk::Extent2D {
            width: WIDTH,
            height: WIDTH,
        },
    }];
    let viewport = vk::PipelineViewportStateCreateInfo::default()
        .viewports(&viewports)
        .scissors(&scissors);
    let raster = vk::PipelineRasterizationStateCreateInfo::default()
        .polygon_mode(vk::PolygonMode::FILL)
        .cull_mode(vk::CullModeFlags::NONE)
        .line_width(1.0);
    let multisample = vk::PipelineMultisampleStateCreateInfo::default()
        .rasterization_samples(vk::SampleCountFlags::TYPE_1);
    let blend_attachment = vk::PipelineColorBlendAttachmentState::default()
        .color_write_mask(vk::ColorComponentFlags::RGBA);
    let blend_attachments = [blend_attachment, blend_attachment];
    let blend = vk::PipelineColorBlendStateCreateInfo::default().attachments(&blend_attachments);
    let pipeline = d
        .create_graphics_pipelines(
            vk::PipelineCache::null(),
            &[vk::GraphicsPipelineCreateInfo::default()
                .stages(&stages)
                .vertex_input_state(&vertex_input)
                .input_assembly_state(&assembly)
                .viewport_state(&viewport)
                .rasterization_state(&raster)
                .multisample_state(&multisample)
                .color_blend_state(&blend)
                .layout(layout)
                .render_pass(render_pass)
                .subpass(0)],
            None,
        )
        .unwrap()[0];

    let b_pixels = g.buffer(2 * 16 * rays as u64, vk::BufferUsageFlags::TRANSFER_DST);
    let cb = d
        .allocate_command_buffers(
            &vk::CommandBufferAllocateInfo::default()
                .command_pool(cmd_pool)
                .command_buffer_count(1),
        )
        .unwrap()[0];
    d.begin_command_buffer(cb, &vk::CommandBufferBeginInfo::default())
        .unwrap();
    // The structures' and spheres' last writes (earlier submissions) before the fragment reads.
    let earlier = vk::MemoryBarrier::default()
        .src_access_mask(vk::AccessFlags::MEMORY_WRITE)
        .dst_access_mask(vk::AccessFlags::MEMORY_READ);
    d.cmd_pipeline_barrier(
        cb,
        vk::PipelineStageFlags::ALL_COMMANDS,
        vk::PipelineStageFlags::FRAGMENT_SHADER,
        vk::DependencyFlags::empty(),
        &[earlier],
        &[],
        &[],
    );
    let clear = [vk::ClearValue::default(), vk::ClearValue::default()];
    d.cmd_begin_render_pass(
        cb,
        &vk::RenderPassBeginInfo::default()
            .render_pass(render_pass)
            .framebuffer(framebuffer)
            .render_area(scissors[0])
            .clear_values(&clear),
        vk::SubpassContents::INLINE,
    );
    d.cmd_bind_pipeline(cb, vk::PipelineBindPoint::GRAPHICS, pipeline);
    d.cmd_bind_descriptor_sets(cb, vk::PipelineBindPoint::GRAPHICS, layout, 0, &[set], &[]);
    let push = [WIDTH * WIDTH, WIDTH, 5.0f32.to_bits(), CULL_MASK];
    d.cmd_push_constants(cb, layout, vk::ShaderStageFlags::FRAGMENT, 0, bytes(&push));
    d.cmd_draw(cb, 3, 1, 0, 0);
    d.cmd_end_render_pass(cb);
    for (k, &image) in images.iter().enumerate() {
        let region = vk::BufferImageCopy {
            buffer_offset: (k * 16 * rays) as u64,
            buffer_row_length: 0,
            buffer_image_height: 0,
            image_subresource: vk::ImageSubresourceLayers {
                aspect_mask: vk::ImageAspectFlags::COLOR,
                mip_level: 0,
                base_array_layer: 0,
                layer_count: 1,
            },
            image_offset: vk::Offset3D::default(),
            image_extent: extent,
        };
        d.cmd_copy_image_to_buffer(
            cb,
            image,
            vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
            g.bufs[b_pixels].buffer,
            &[region],
        );
    }
    let to_host = vk::MemoryBarrier::default()
        .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
        .dst_access_mask(vk::AccessFlags::HOST_READ);
    d.cmd_pipeline_barrier(
        cb,
        vk::PipelineStageFlags::TRANSFER,
        vk::PipelineStageFlags::HOST,
        vk::DependencyFlags::empty(),
        &[to_host],
        &[],
        &[],
    );
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
    let px = std::slice::from_raw_parts(g.bufs[b_pixels].map.cast::<[f32; 4]>(), 2 * rays);
    let hits = (0..rays)
        .map(|i| {
            let (a, b) = (px[i], px[rays + i]);
            Hit {
                t: a[0],
                kind: a[1] as u32,
                custom: a[2] as u32,
                instance: a[3] as u32,
                geometry: b[0] as u32,
                primitive: b[1] as u32,
                u: b[2],
                v: b[3],
            }
        })
        .collect();
    d.free_command_buffers(cmd_pool, &[cb]);
    d.destroy_pipeline(pipeline, None);
    d.destroy_shader_module(vertex, None);
    d.destroy_shader_module(fragment, None);
    d.destroy_descriptor_pool(pool, None);
    d.destroy_pipeline_layout(layout, None);
    d.destroy_descriptor_set_layout(set_layout, None);
    d.destroy_framebuffer(framebuffer, None);
    d.destroy_render_pass(render_pass, None);
    for ((image, view), memory) in images.into_iter().zip(views).zip(memories) {
        d.destroy_image_view(view, None);
        d.destroy_image(image, None);
        d.free_memory(memory, None);
    }
    hits
}

/// Writes `structure` to binding 0 of `set`.
pub unsafe fn write_structure(
    d: &ash::Device,
    set: vk::DescriptorSet,
    structure: vk::AccelerationStructureKHR,
) {
    let structures = [structure];
    let mut as_write = vk::WriteDescriptorSetAccelerationStructureKHR::default()
        .acceleration_structures(&structures);
    let mut w = vk::WriteDescriptorSet::default()
        .dst_set(set)
        .dst_binding(0)
        .descriptor_type(vk::DescriptorType::ACCELERATION_STRUCTURE_KHR)
        .push_next(&mut as_write);
    w.descriptor_count = 1;
    d.update_descriptor_sets(&[w], &[]);
}

/// The compute shader's descriptors as an update template reads them.
#[repr(C)]
struct Descriptors {
    tlas: vk::AccelerationStructureKHR,
    out: vk::DescriptorBufferInfo,
    spheres: vk::DescriptorBufferInfo,
}

impl Descriptors {
    fn new(tlas: vk::AccelerationStructureKHR, out: vk::Buffer, spheres: vk::Buffer) -> Self {
        let whole = |b| {
            vk::DescriptorBufferInfo::default()
                .buffer(b)
                .range(vk::WHOLE_SIZE)
        };
        Self {
            tlas,
            out: whole(out),
            spheres: whole(spheres),
        }
    }

    /// The template entries that read it.
    fn entries() -> [vk::DescriptorUpdateTemplateEntry; 3] {
        let entry = |binding: u32, ty: vk::DescriptorType, offset: usize| {
            vk::DescriptorUpdateTemplateEntry {
                dst_binding: binding,
                dst_array_element: 0,
                descriptor_count: 1,
                descriptor_type: ty,
                offset,
                stride: 0,
            }
        };
        [
            entry(
                0,
                vk::DescriptorType::ACCELERATION_STRUCTURE_KHR,
                std::mem::offset_of!(Descriptors, tlas),
            ),
            entry(
                1,
                vk::DescriptorType::STORAGE_BUFFER,
                std::mem::offset_of!(Descriptors, out),
            ),
            entry(
                2,
                vk::DescriptorType::STORAGE_BUFFER,
                std::mem::offset_of!(Descriptors, spheres),
            ),
        ]
    }
}

/// A template that pushes [`Descriptors`] into set 0 of `layout` at the compute bind point.
unsafe fn push_template(g: &Gpu, layout: vk::PipelineLayout) -> vk::DescriptorUpdateTemplate {
    let entries = Descriptors::entries();
    g.device
        .create_descriptor_update_template(
            &vk::DescriptorUpdateTemplateCreateInfo::default()
                .descriptor_update_entries(&entries)
                .template_type(vk::DescriptorUpdateTemplateType::PUSH_DESCRIPTORS_KHR)
                .pipeline_bind_point(vk::PipelineBindPoint::COMPUTE)
                .pipeline_layout(layout)
                .set(0),
            None,
        )
        .unwrap()
}

/// Writes `set` (the structure, the output and the spheres) through a descriptor update
/// template, as an application that caches its descriptor layouts does.
unsafe fn rewrite_with_template(
    g: &Gpu,
    set: vk::DescriptorSet,
    set_layout: vk::DescriptorSetLayout,
    tlas: vk::AccelerationStructureKHR,
    out: vk::Buffer,
    spheres: vk::Buffer,
) {
    let entries = Descriptors::entries();
    let template = g
        .device
        .create_descriptor_update_template(
            &vk::DescriptorUpdateTemplateCreateInfo::default()
                .descriptor_update_entries(&entries)
                .template_type(vk::DescriptorUpdateTemplateType::DESCRIPTOR_SET)
                .descriptor_set_layout(set_layout),
            None,
        )
        .unwrap();
    let data = Descriptors::new(tlas, out, spheres);
    g.device.update_descriptor_set_with_template(
        set,
        template,
        (&data as *const Descriptors).cast(),
    );
    g.device.destroy_descriptor_update_template(template, None);
}

/// Reads the compacted sizes the first frame queried (from the pool and from the buffer it
/// copied them to: the same), creates structures of those sizes and copies `originals` into
/// them (`COMPACT`); returns the copies and their buffers.
#[allow(clippy::too_many_arguments)]
unsafe fn compact(
    g: &mut Gpu,
    cb: vk::CommandBuffer,
    fence: vk::Fence,
    pool: vk::QueryPool,
    b_sizes: usize,
    originals: &[vk::AccelerationStructureKHR],
    original_bytes: &[u64],
) -> Vec<(vk::AccelerationStructureKHR, usize)> {
    let d = g.device.clone();
    let mut sizes = [0u64; 2];
    d.get_query_pool_results(
        pool,
        0,
        &mut sizes,
        vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
    )
    .unwrap();
    let copied = *g.bufs[b_sizes].map.cast::<[u64; 2]>();
    assert_eq!(
        sizes, copied,
        "vkGetQueryPoolResults and vkCmdCopyQueryPoolResults disagree"
    );
    for (size, original) in sizes.iter().zip(original_bytes) {
        assert!(
            *size > 0 && size <= original,
            "compacted size {size} of a structure of {original} bytes"
        );
    }
    let mut out = Vec::new();
    d.begin_command_buffer(cb, &vk::CommandBufferBeginInfo::default())
        .unwrap();
    for (&size, &original) in sizes.iter().zip(originals) {
        let storage = g.buffer(
            size,
            vk::BufferUsageFlags::ACCELERATION_STRUCTURE_STORAGE_KHR
                | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS,
        );
        let create = vk::AccelerationStructureCreateInfoKHR::default()
            .buffer(g.bufs[storage].buffer)
            .size(size)
            .ty(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL);
        let c = g
            .accel
            .create_acceleration_structure(&create, None)
            .unwrap();
        g.accel.cmd_copy_acceleration_structure(
            cb,
            &vk::CopyAccelerationStructureInfoKHR::default()
                .src(original)
                .dst(c)
                .mode(vk::CopyAccelerationStructureModeKHR::COMPACT),
        );
        out.push((c, storage));
    }
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
    out
}

/// A bottom level's geometries and ranges over the buffers `b`.
struct Level {
    geometries: Vec<vk::AccelerationStructureGeometryKHR<'static>>,
    ranges: Vec<vk::AccelerationStructureBuildRangeInfoKHR>,
}

unsafe fn run_unsafe(
    validation: Validation,
    api: u32,
    sync2: bool,
    pushed: bool,
    update_into: bool,
) -> Result<Vec<Vec<Hit>>, vk::Result> {
    let (_entry, mut g) = setup_with(validation, api, sync2)?;
    let d = g.device.clone();

    // Inputs.
    let (grid_v, grid_i) = grid(0.0);
    let (fan_v, fan_i) = fan();
    let soup_v = soup();
    let sph = spheres();
    let boxes: Vec<[f32; 6]> = sph
        .iter()
        .map(|s| {
            [
                s[0] - s[3],
                s[1] - s[3],
                s[2] - s[3],
                s[0] + s[3],
                s[1] + s[3],
                s[2] + s[3],
            ]
        })
        .collect();
    let b_grid_v = g.buffer(4 * 3 * grid_v.len() as u64, INPUT);
    let b_grid_i = g.buffer(4 * grid_i.len() as u64, INPUT);
    let b_fan_v = g.buffer(8 * fan_v.len() as u64, INPUT);
    let b_fan_i = g.buffer(2 * fan_i.len() as u64 + 8, INPUT);
    let b_soup = g.buffer(4 * 3 * soup_v.len() as u64, INPUT);
    let b_transform = g.buffer(48, INPUT);
    g.write(b_transform, &SOUP_TRANSFORM);
    let b_boxes = g.buffer(24 * boxes.len() as u64, INPUT);
    let b_spheres = g.buffer(16 * sph.len() as u64, vk::BufferUsageFlags::STORAGE_BUFFER);
    g.write(b_grid_v, &grid_v);
    g.write(b_grid_i, &grid_i);
    let fan_half: Vec<[u16; 4]> = fan_v
        .iter()
        .map(|p| [half(p[0]), half(p[1]), half(p[2]), 0])
        .collect();
    g.write(b_fan_v, &fan_half);
    g.write(b_fan_i, &fan_i);
    g.write(b_soup, &soup_v);
    g.write(b_boxes, &boxes);
    g.write(b_spheres, &sph);

    let tri = |(vb, format, stride): (usize, vk::Format, u64),
               n_vertices: u32,
               ib: Option<(usize, vk::IndexType)>,
               xf: Option<usize>,
               opaque: bool| {
        let data = vk::AccelerationStructureGeometryTrianglesDataKHR::default()
            .vertex_format(format)
            .vertex_data(vk::DeviceOrHostAddressConstKHR {
                device_address: g.bufs[vb].address,
            })
            .vertex_stride(stride)
            .max_vertex(n_vertices - 1)
            .index_type(ib.map_or(vk::IndexType::NONE_KHR, |i| i.1))
            .index_data(vk::DeviceOrHostAddressConstKHR {
                device_address: ib.map_or(0, |i| g.bufs[i.0].address),
            })
            .transform_data(vk::DeviceOrHostAddressConstKHR {
                device_address: xf.map_or(0, |b| g.bufs[b].address),
            });
        vk::AccelerationStructureGeometryKHR::default()
            .geometry_type(vk::GeometryTypeKHR::TRIANGLES)
            .geometry(vk::AccelerationStructureGeometryDataKHR { triangles: data })
            .flags(match opaque {
                true => vk::GeometryFlagsKHR::OPAQUE,
                false => vk::GeometryFlagsKHR::empty(),
            })
    };
    let range = |n: u32| vk::AccelerationStructureBuildRangeInfoKHR::default().primitive_count(n);
    let levels = [
        Level {
            geometries: vec![tri(
                (b_grid_v, F32X3, 12),
                grid_v.len() as u32,
                Some((b_grid_i, vk::IndexType::UINT32)),
                None,
                true,
            )],
            ranges: vec![range(grid_i.len() as u32 / 3)],
        },
        Level {
            geometries: vec![
                tri(
                    (b_fan_v, vk::Format::R16G16B16A16_SFLOAT, 8),
                    fan_v.len() as u32,
                    Some((b_fan_i, vk::IndexType::UINT16)),
                    None,
                    false,
                ),
                tri(
                    (b_soup, F32X3, 12),
                    soup_v.len() as u32,
                    None,
                    Some(b_transform),
                    true,
                ),
            ],
            ranges: vec![
                range(fan_i.len() as u32 / 3),
                range(soup_v.len() as u32 / 3),
            ],
        },
        Level {
            geometries: vec![vk::AccelerationStructureGeometryKHR::default()
                .geometry_type(vk::GeometryTypeKHR::AABBS)
                .geometry(vk::AccelerationStructureGeometryDataKHR {
                    aabbs: vk::AccelerationStructureGeometryAabbsDataKHR::default()
                        .data(vk::DeviceOrHostAddressConstKHR {
                            device_address: g.bufs[b_boxes].address,
                        })
                        .stride(24),
                })],
            ranges: vec![range(boxes.len() as u32)],
        },
    ];

    // Bottom levels: sizes, storage, scratch.
    let update_flags = vk::BuildAccelerationStructureFlagsKHR::ALLOW_UPDATE
        | vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_BUILD;
    // The second and third levels are compacted after the first frame.
    let level_flags = [
        update_flags,
        vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE
            | vk::BuildAccelerationStructureFlagsKHR::ALLOW_COMPACTION,
        vk::BuildAccelerationStructureFlagsKHR::ALLOW_COMPACTION,
    ];
    let mut blas = Vec::new();
    let mut blas_bytes = Vec::new();
    let mut blas_scratch = Vec::new();
    for (l, f) in levels.iter().zip(level_flags) {
        let info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
            .ty(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL)
            .flags(f)
            .geometries(&l.geometries);
        let counts: Vec<u32> = l.ranges.iter().map(|r| r.primitive_count).collect();
        let mut sizes = vk::AccelerationStructureBuildSizesInfoKHR::default();
        g.accel.get_acceleration_structure_build_sizes(
            vk::AccelerationStructureBuildTypeKHR::DEVICE,
            &info,
            &counts,
            &mut sizes,
        );
        let storage = g.buffer(
            sizes.acceleration_structure_size,
            vk::BufferUsageFlags::ACCELERATION_STRUCTURE_STORAGE_KHR
                | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS,
        );
        let scratch_bytes = sizes.build_scratch_size.max(sizes.update_scratch_size);
        let scratch = g.buffer(
            scratch_bytes,
            vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS,
        );
        let create = vk::AccelerationStructureCreateInfoKHR::default()
            .buffer(g.bufs[storage].buffer)
            .size(sizes.acceleration_structure_size)
            .ty(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL);
        blas.push(
            g.accel
                .create_acceleration_structure(&create, None)
                .unwrap(),
        );
        blas_scratch.push(scratch);
        blas_bytes.push(sizes.acceleration_structure_size);
    }
    // The structure the grid's first update goes into, where `update_into` says so.
    let grid_into = update_into.then(|| {
        let storage = g.buffer(
            blas_bytes[0],
            vk::BufferUsageFlags::ACCELERATION_STRUCTURE_STORAGE_KHR
                | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS,
        );
        let create = vk::AccelerationStructureCreateInfoKHR::default()
            .buffer(g.bufs[storage].buffer)
            .size(blas_bytes[0])
            .ty(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL);
        g.accel
            .create_acceleration_structure(&create, None)
            .unwrap()
    });
    // The grid's structure before its update went elsewhere, destroyed at teardown.
    let mut retired = Vec::new();
    let mut references: Vec<u64> = blas
        .iter()
        .map(|&a| {
            g.accel.get_acceleration_structure_device_address(
                &vk::AccelerationStructureDeviceAddressInfoKHR::default().acceleration_structure(a),
            )
        })
        .collect();

    // The top level.
    let placements = instances(0);
    let n_instances = placements.len() as u32;
    // The records lie in reverse order, named in order by an array of pointers.
    let b_instances = g.buffer(64 * u64::from(n_instances), INPUT);
    let b_pointers = g.buffer(8 * u64::from(n_instances), INPUT);
    let pointers: Vec<u64> = (0..u64::from(n_instances))
        .map(|k| g.bufs[b_instances].address + 64 * (u64::from(n_instances) - 1 - k))
        .collect();
    g.write(b_pointers, &pointers);
    let inst_geometry = vk::AccelerationStructureGeometryKHR::default()
        .geometry_type(vk::GeometryTypeKHR::INSTANCES)
        .geometry(vk::AccelerationStructureGeometryDataKHR {
            instances: vk::AccelerationStructureGeometryInstancesDataKHR::default()
                .array_of_pointers(true)
                .data(vk::DeviceOrHostAddressConstKHR {
                    device_address: g.bufs[b_pointers].address,
                }),
        });
    let top_geometries = [inst_geometry];
    let top_info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
        .ty(vk::AccelerationStructureTypeKHR::TOP_LEVEL)
        .flags(vk::BuildAccelerationStructureFlagsKHR::ALLOW_UPDATE)
        .geometries(&top_geometries);
    let mut top_sizes = vk::AccelerationStructureBuildSizesInfoKHR::default();
    g.accel.get_acceleration_structure_build_sizes(
        vk::AccelerationStructureBuildTypeKHR::DEVICE,
        &top_info,
        &[n_instances],
        &mut top_sizes,
    );
    let top_storage = g.buffer(
        top_sizes.acceleration_structure_size,
        vk::BufferUsageFlags::ACCELERATION_STRUCTURE_STORAGE_KHR
            | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS,
    );
    let top_scratch = g.buffer(
        top_sizes
            .build_scratch_size
            .max(top_sizes.update_scratch_size),
        vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS,
    );
    let mut tlas = g
        .accel
        .create_acceleration_structure(
            &vk::AccelerationStructureCreateInfoKHR::default()
                .buffer(g.bufs[top_storage].buffer)
                .size(top_sizes.acceleration_structure_size)
                .ty(vk::AccelerationStructureTypeKHR::TOP_LEVEL),
            None,
        )
        .unwrap();
    // The top level the first update goes into, where `update_into` says so.
    let tlas_into = update_into.then(|| {
        let storage = g.buffer(
            top_sizes.acceleration_structure_size,
            vk::BufferUsageFlags::ACCELERATION_STRUCTURE_STORAGE_KHR
                | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS,
        );
        g.accel
            .create_acceleration_structure(
                &vk::AccelerationStructureCreateInfoKHR::default()
                    .buffer(g.bufs[storage].buffer)
                    .size(top_sizes.acceleration_structure_size)
                    .ty(vk::AccelerationStructureTypeKHR::TOP_LEVEL),
                None,
            )
            .unwrap()
    });

    // The pipeline.
    let rays = WIDTH * WIDTH;
    let b_out = g.buffer(32 * u64::from(rays), vk::BufferUsageFlags::STORAGE_BUFFER);
    let code = compile(&compute_shader());
    let module = d
        .create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&code), None)
        .unwrap();
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
        vk::DescriptorSetLayoutBinding::default()
            .binding(2)
            .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
            .descriptor_count(1)
            .stage_flags(vk::ShaderStageFlags::COMPUTE),
    ];
    let set_flags = match pushed {
        true => vk::DescriptorSetLayoutCreateFlags::PUSH_DESCRIPTOR_KHR,
        false => vk::DescriptorSetLayoutCreateFlags::empty(),
    };
    let set_layout = d
        .create_descriptor_set_layout(
            &vk::DescriptorSetLayoutCreateInfo::default()
                .flags(set_flags)
                .bindings(&bindings),
            None,
        )
        .unwrap();
    let push_range = [vk::PushConstantRange::default()
        .stage_flags(vk::ShaderStageFlags::COMPUTE)
        .size(16)];
    let set_layouts = [set_layout];
    let layout = d
        .create_pipeline_layout(
            &vk::PipelineLayoutCreateInfo::default()
                .set_layouts(&set_layouts)
                .push_constant_ranges(&push_range),
            None,
        )
        .unwrap();
    let stage = vk::PipelineShaderStageCreateInfo::default()
        .stage(vk::ShaderStageFlags::COMPUTE)
        .module(module)
        .name(c"main");
    let pipeline = d
        .create_compute_pipelines(
            vk::PipelineCache::null(),
            &[vk::ComputePipelineCreateInfo::default()
                .stage(stage)
                .layout(layout)],
            None,
        )
        .unwrap()[0];
    let pool_sizes = [
        vk::DescriptorPoolSize {
            ty: vk::DescriptorType::ACCELERATION_STRUCTURE_KHR,
            descriptor_count: 1,
        },
        vk::DescriptorPoolSize {
            ty: vk::DescriptorType::STORAGE_BUFFER,
            descriptor_count: 2,
        },
    ];
    let pool = d
        .create_descriptor_pool(
            &vk::DescriptorPoolCreateInfo::default()
                .max_sets(1)
                .pool_sizes(&pool_sizes),
            None,
        )
        .unwrap();
    let set = match pushed {
        true => vk::DescriptorSet::null(),
        false => d
            .allocate_descriptor_sets(
                &vk::DescriptorSetAllocateInfo::default()
                    .descriptor_pool(pool)
                    .set_layouts(&set_layouts),
            )
            .unwrap()[0],
    };
    let template = pushed.then(|| push_template(&g, layout));
    let tlases = [tlas];
    let mut as_write =
        vk::WriteDescriptorSetAccelerationStructureKHR::default().acceleration_structures(&tlases);
    let out_info = [vk::DescriptorBufferInfo::default()
        .buffer(g.bufs[b_out].buffer)
        .range(vk::WHOLE_SIZE)];
    let sph_info = [vk::DescriptorBufferInfo::default()
        .buffer(g.bufs[b_spheres].buffer)
        .range(vk::WHOLE_SIZE)];
    let mut w0 = vk::WriteDescriptorSet::default()
        .dst_set(set)
        .dst_binding(0)
        .descriptor_type(vk::DescriptorType::ACCELERATION_STRUCTURE_KHR)
        .push_next(&mut as_write);
    w0.descriptor_count = 1;
    let writes = [
        w0,
        vk::WriteDescriptorSet::default()
            .dst_set(set)
            .dst_binding(1)
            .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
            .buffer_info(&out_info),
        vk::WriteDescriptorSet::default()
            .dst_set(set)
            .dst_binding(2)
            .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
            .buffer_info(&sph_info),
    ];
    if !pushed {
        d.update_descriptor_sets(&writes, &[]);
    }

    let cmd_pool = d
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
                .command_pool(cmd_pool)
                .command_buffer_count(1),
        )
        .unwrap()[0];
    let fence = d
        .create_fence(&vk::FenceCreateInfo::default(), None)
        .unwrap();

    // Compacted sizes of the second and third levels, read back and copied to a buffer.
    let query_pool = d
        .create_query_pool(
            &vk::QueryPoolCreateInfo::default()
                .query_type(vk::QueryType::ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR)
                .query_count(2),
            None,
        )
        .unwrap();
    let b_sizes = g.buffer(16, vk::BufferUsageFlags::TRANSFER_DST);
    let mut compacted = Vec::new();

    let mut frames = Vec::new();
    for frame in 0..3u32 {
        let mode = match frame {
            0 => vk::BuildAccelerationStructureModeKHR::BUILD,
            _ => vk::BuildAccelerationStructureModeKHR::UPDATE,
        };
        // Frame 1 moves the grid's vertices and the instances; frame 2 updates again with
        // frame 1's scene, as a renderer updates every frame whether or not it moved.
        let scene = frame.min(1);
        // The grid's first update goes from its structure into the other one, which the
        // instances name from then on.
        let grid_src = match (frame, grid_into) {
            (1, Some(into)) => {
                retired.push(blas[0]);
                blas[0] = into;
                references[0] = g.accel.get_acceleration_structure_device_address(
                    &vk::AccelerationStructureDeviceAddressInfoKHR::default()
                        .acceleration_structure(into),
                );
                retired[0]
            }
            _ => blas[0],
        };
        // So does the top level's; the descriptor names the new one from then on (the
        // first frame's work has completed).
        let top_src = match (frame, tlas_into) {
            (0, _) => vk::AccelerationStructureKHR::null(),
            (1, Some(into)) => {
                let old = tlas;
                retired.push(old);
                tlas = into;
                if !pushed {
                    write_structure(&d, set, tlas);
                }
                old
            }
            _ => tlas,
        };
        let (moved, _) = grid(0.25 * scene as f32);
        g.write(b_grid_v, &moved);
        let records: Vec<[u32; 16]> = instances(scene)
            .iter()
            .rev()
            .map(|p| instance_record(p, references[p.level]))
            .collect();
        g.write(b_instances, &records);

        d.begin_command_buffer(cb, &vk::CommandBufferBeginInfo::default())
            .unwrap();
        // What earlier submissions wrote (the compaction's copies) before this frame reads.
        let earlier = vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::MEMORY_WRITE)
            .dst_access_mask(vk::AccessFlags::MEMORY_READ | vk::AccessFlags::MEMORY_WRITE);
        barrier(
            &d,
            cb,
            sync2,
            vk::PipelineStageFlags::ALL_COMMANDS,
            vk::PipelineStageFlags::ALL_COMMANDS,
            earlier,
        );
        // The application binds first; the builds come between its binds and its dispatch.
        d.cmd_bind_pipeline(cb, vk::PipelineBindPoint::COMPUTE, pipeline);
        match template {
            Some(template) => {
                let data = Descriptors::new(tlas, g.bufs[b_out].buffer, g.bufs[b_spheres].buffer);
                g.push.cmd_push_descriptor_set_with_template(
                    cb,
                    template,
                    layout,
                    0,
                    (&data as *const Descriptors).cast(),
                );
            }
            None => d.cmd_bind_descriptor_sets(
                cb,
                vk::PipelineBindPoint::COMPUTE,
                layout,
                0,
                &[set],
                &[],
            ),
        }
        let push = [rays, WIDTH, 5.0f32.to_bits(), CULL_MASK];
        d.cmd_push_constants(cb, layout, vk::ShaderStageFlags::COMPUTE, 0, bytes(&push));

        // Bottom levels: frame 0 builds all, later frames update the grid only.
        let mut infos = Vec::new();
        let mut range_ptrs = Vec::new();
        for (k, l) in levels.iter().enumerate() {
            if frame > 0 && k != 0 {
                continue;
            }
            let src = match (frame, k) {
                (0, _) => vk::AccelerationStructureKHR::null(),
                (_, 0) => grid_src,
                _ => blas[k],
            };
            infos.push(
                vk::AccelerationStructureBuildGeometryInfoKHR::default()
                    .ty(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL)
                    .flags(level_flags[k])
                    .mode(mode)
                    .src_acceleration_structure(src)
                    .dst_acceleration_structure(blas[k])
                    .geometries(&l.geometries)
                    .scratch_data(vk::DeviceOrHostAddressKHR {
                        device_address: g.bufs[blas_scratch[k]].address,
                    }),
            );
            range_ptrs.push(l.ranges.as_slice());
        }
        g.accel
            .cmd_build_acceleration_structures(cb, &infos, &range_ptrs);
        let to_top = vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::ACCELERATION_STRUCTURE_WRITE_KHR)
            .dst_access_mask(
                vk::AccessFlags::ACCELERATION_STRUCTURE_READ_KHR
                    | vk::AccessFlags::ACCELERATION_STRUCTURE_WRITE_KHR,
            );
        barrier(
            &d,
            cb,
            sync2,
            vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR,
            vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR,
            to_top,
        );
        if frame == 0 {
            d.cmd_reset_query_pool(cb, query_pool, 0, 2);
            g.accel.cmd_write_acceleration_structures_properties(
                cb,
                &[blas[1], blas[2]],
                vk::QueryType::ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR,
                query_pool,
                0,
            );
            d.cmd_copy_query_pool_results(
                cb,
                query_pool,
                0,
                2,
                g.bufs[b_sizes].buffer,
                0,
                8,
                vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
            );
        }
        let top = top_info
            .mode(mode)
            .src_acceleration_structure(top_src)
            .dst_acceleration_structure(tlas)
            .scratch_data(vk::DeviceOrHostAddressKHR {
                device_address: g.bufs[top_scratch].address,
            });
        let top_range = [range(n_instances)];
        g.accel
            .cmd_build_acceleration_structures(cb, &[top], &[&top_range]);
        let to_trace = vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::ACCELERATION_STRUCTURE_WRITE_KHR)
            .dst_access_mask(vk::AccessFlags::ACCELERATION_STRUCTURE_READ_KHR);
        barrier(
            &d,
            cb,
            sync2,
            vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR,
            vk::PipelineStageFlags::COMPUTE_SHADER,
            to_trace,
        );
        // No rebind: the state bound before the builds.
        d.cmd_dispatch(cb, rays.div_ceil(64), 1, 1);
        let to_host = vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(vk::AccessFlags::HOST_READ);
        barrier(
            &d,
            cb,
            sync2,
            vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER,
            vk::PipelineStageFlags::HOST,
            to_host,
        );
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
        let raw = std::slice::from_raw_parts(g.bufs[b_out].map.cast::<[u32; 8]>(), rays as usize);
        frames.push(
            raw.iter()
                .map(|h| Hit {
                    t: f32::from_bits(h[0]),
                    kind: h[1],
                    custom: h[2],
                    instance: h[3],
                    geometry: h[4],
                    primitive: h[5],
                    u: f32::from_bits(h[6]),
                    v: f32::from_bits(h[7]),
                })
                .collect(),
        );
        if frame == 0 && !pushed {
            // The set written again, through an update template this time.
            rewrite_with_template(
                &g,
                set,
                set_layout,
                tlas,
                g.bufs[b_out].buffer,
                g.bufs[b_spheres].buffer,
            );
        }
        if frame == 0 {
            compacted = compact(
                &mut g,
                cb,
                fence,
                query_pool,
                b_sizes,
                &blas[1..],
                &blas_bytes[1..],
            );
            // The originals go: frame 1 traces the compacted copies.
            for (k, &(c, _)) in compacted.iter().enumerate() {
                g.accel.destroy_acceleration_structure(blas[1 + k], None);
                blas[1 + k] = c;
                references[1 + k] = g.accel.get_acceleration_structure_device_address(
                    &vk::AccelerationStructureDeviceAddressInfoKHR::default()
                        .acceleration_structure(c),
                );
            }
        }
    }

    // The last state traced again from a fragment shader.
    frames.push(fragment_pass(&mut g, cmd_pool, fence, tlas, b_spheres));

    // Teardown, in the application's order.
    d.device_wait_idle().unwrap();
    d.destroy_fence(fence, None);
    d.free_command_buffers(cmd_pool, &[cb]);
    d.destroy_command_pool(cmd_pool, None);
    d.destroy_descriptor_pool(pool, None);
    if let Some(t) = template {
        d.destroy_descriptor_update_template(t, None);
    }
    d.destroy_query_pool(query_pool, None);
    debug_assert_eq!(compacted.len(), 2);
    d.destroy_pipeline(pipeline, None);
    d.destroy_pipeline_layout(layout, None);
    d.destroy_descriptor_set_layout(set_layout, None);
    d.destroy_shader_module(module, None);
    g.accel.destroy_acceleration_structure(tlas, None);
    for a in blas.into_iter().chain(retired) {
        g.accel.destroy_acceleration_structure(a, None);
    }
    for b in g.bufs.drain(..) {
        d.destroy_buffer(b.buffer, None);
        d.free_memory(b.memory, None);
    }
    d.destroy_device(None);
    if let Some((utils, m)) = g.messenger.take() {
        utils.destroy_debug_utils_messenger(m, None);
    }
    g.instance.destroy_instance(None);
    Ok(frames)
}

pub fn bytes<T: Copy>(v: &[T]) -> &[u8] {
    unsafe { std::slice::from_raw_parts(v.as_ptr().cast(), std::mem::size_of_val(v)) }
}
