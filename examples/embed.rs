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

use std::error::Error;
use std::ffi::{c_char, c_void, CStr};
use std::mem::ManuallyDrop;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use ash::vk;
use glam::Vec3;
use gpu_allocator::vulkan::{
    Allocation, AllocationCreateDesc, AllocationScheme, Allocator, AllocatorCreateDesc,
};
use gpu_allocator::MemoryLocation;
use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::gpu::{
    Buffer, BufferArg, Context, DeviceFeatures, Profile, RawParts, Recorder, Validation,
    DEFAULT_QUERY_CAPACITY,
};
use vkrt::trace::gpu::{GpuGeometry, Tracer};
use vkrt::trace::{Hit, Ray, TraceGeometry, TraceOptions};

type BoxResult<T> = Result<T, Box<dyn Error>>;

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

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
    });

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
    let work = rec.finish();
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

/// A global memory barrier: `src` work and writes before → `dst` work and accesses after.
///
/// # Safety
/// `cmd` is a command buffer of `device` in the recording state, outside a render pass.
unsafe fn barrier(
    device: &ash::Device,
    cmd: vk::CommandBuffer,
    src: (vk::PipelineStageFlags, vk::AccessFlags),
    dst: (vk::PipelineStageFlags, vk::AccessFlags),
) {
    let memory = vk::MemoryBarrier::default()
        .src_access_mask(src.1)
        .dst_access_mask(dst.1);
    // SAFETY: the caller's contract.
    unsafe {
        device.cmd_pipeline_barrier(
            cmd,
            src.0,
            dst.0,
            vk::DependencyFlags::empty(),
            &[memory],
            &[],
            &[],
        )
    };
}

/// Validation messages, filled by the debug messenger's callback.
type Sink = Arc<Mutex<Vec<String>>>;

/// What the host (a renderer) owns. Dropping it destroys the allocator, device, messenger
/// and instance, in that order.
struct Host {
    entry: ash::Entry,
    instance: ash::Instance,
    messenger: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    sink: Sink,
    debug_utils: bool,
    physical_device: vk::PhysicalDevice,
    device: ash::Device,
    family: u32,
    queue: vk::Queue,
    features: DeviceFeatures,
    allocator: ManuallyDrop<Arc<Mutex<Allocator>>>,
}

impl Host {
    fn new(validation: Validation) -> BoxResult<Self> {
        // SAFETY: loading the system's Vulkan loader runs its initialisation code; every
        // Vulkan program trusts the installed loader.
        let entry = unsafe { ash::Entry::load() }?;
        // SAFETY: plain enumeration calls on a loaded entry.
        let (layers, extensions) = unsafe {
            (
                entry.enumerate_instance_layer_properties()?,
                entry.enumerate_instance_extension_properties(None)?,
            )
        };
        let layer_installed = layers
            .iter()
            .any(|l| l.layer_name_as_c_str() == Ok(VALIDATION_LAYER));
        let validate = match validation {
            Validation::Off => false,
            Validation::On if !layer_installed => {
                return Err("VK_LAYER_KHRONOS_validation is not installed \
                            (Debian: vulkan-validationlayers)"
                    .into())
            }
            Validation::On => true,
            Validation::FromEnv => {
                layer_installed && !std::env::var("VKRT_VALIDATION").is_ok_and(|v| v == "0")
            }
        };
        let debug_utils = extensions
            .iter()
            .any(|e| e.extension_name_as_c_str() == Ok(ash::ext::debug_utils::NAME));
        if validate && !debug_utils {
            return Err("validation needs VK_EXT_debug_utils to report messages".into());
        }
        let sink: Sink = Arc::default();
        let layer_names: Vec<*const c_char> = if validate {
            vec![VALIDATION_LAYER.as_ptr()]
        } else {
            Vec::new()
        };
        let extension_names: Vec<*const c_char> = if debug_utils {
            vec![ash::ext::debug_utils::NAME.as_ptr()]
        } else {
            Vec::new()
        };
        let app = vk::ApplicationInfo::default()
            .application_name(c"vkrt-embed-example")
            .api_version(vk::API_VERSION_1_2);
        let enables = [vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION];
        let mut features =
            vk::ValidationFeaturesEXT::default().enabled_validation_features(&enables);
        // Chained into the instance's creation, this also reports vkCreateInstance and
        // vkDestroyInstance.
        let mut chained_messenger = messenger_info(&sink);
        let mut create = vk::InstanceCreateInfo::default()
            .application_info(&app)
            .enabled_layer_names(&layer_names)
            .enabled_extension_names(&extension_names);
        if validate {
            create = create
                .push_next(&mut features)
                .push_next(&mut chained_messenger);
        }
        // SAFETY: every pointer in `create` refers to locals that live across the call; the
        // chained messenger's user data is `sink`, which outlives the instance (`run`
        // holds a clone until after the host is dropped).
        let instance = unsafe { entry.create_instance(&create, None) }?;
        let messenger = if validate {
            let loader = ash::ext::debug_utils::Instance::new(&entry, &instance);
            // SAFETY: the instance has VK_EXT_debug_utils; `sink` outlives the messenger.
            match unsafe { loader.create_debug_utils_messenger(&messenger_info(&sink), None) } {
                Ok(m) => Some((loader, m)),
                Err(e) => {
                    // SAFETY: nothing else was created from the instance.
                    unsafe { instance.destroy_instance(None) };
                    return Err(e.into());
                }
            }
        } else {
            None
        };
        match Self::with_device(&instance) {
            Ok((physical_device, family, device, features, allocator)) => {
                // SAFETY: the device was created with one queue of `family`.
                let queue = unsafe { device.get_device_queue(family, 0) };
                Ok(Self {
                    entry,
                    instance,
                    messenger,
                    sink,
                    debug_utils,
                    physical_device,
                    device,
                    family,
                    queue,
                    features,
                    allocator: ManuallyDrop::new(allocator),
                })
            }
            Err(e) => {
                // SAFETY: `with_device` destroyed what it created; only these remain.
                unsafe {
                    if let Some((loader, m)) = messenger {
                        loader.destroy_debug_utils_messenger(m, None);
                    }
                    instance.destroy_instance(None);
                }
                Err(e)
            }
        }
    }

    /// Picks a device (`VKRT_DEVICE`: a substring of its name; else discrete first), creates
    /// it with the optional features the host wants (64-bit integers and doubles, which
    /// vkrt's exact triangle test uses), and its allocator.
    #[allow(clippy::type_complexity, reason = "a private constructor step")]
    fn with_device(
        instance: &ash::Instance,
    ) -> BoxResult<(
        vk::PhysicalDevice,
        u32,
        ash::Device,
        DeviceFeatures,
        Arc<Mutex<Allocator>>,
    )> {
        let wanted = std::env::var("VKRT_DEVICE")
            .unwrap_or_default()
            .to_lowercase();
        // SAFETY: plain queries on a valid instance and its physical devices.
        let mut candidates: Vec<(u32, vk::PhysicalDevice, u32)> = unsafe {
            instance
                .enumerate_physical_devices()?
                .into_iter()
                .filter_map(|pd| {
                    let props = instance.get_physical_device_properties(pd);
                    let name = props.device_name_as_c_str().ok()?.to_string_lossy();
                    if !name.to_lowercase().contains(&wanted) {
                        return None;
                    }
                    let family = instance
                        .get_physical_device_queue_family_properties(pd)
                        .iter()
                        .position(|f| f.queue_flags.contains(vk::QueueFlags::COMPUTE))?;
                    let rank = match props.device_type {
                        vk::PhysicalDeviceType::DISCRETE_GPU => 0,
                        vk::PhysicalDeviceType::INTEGRATED_GPU => 1,
                        vk::PhysicalDeviceType::VIRTUAL_GPU => 2,
                        _ => 3,
                    };
                    Some((rank, pd, family as u32))
                })
                .collect()
        };
        candidates.sort_by_key(|c| c.0);
        let &(_, physical_device, family) = candidates
            .first()
            .ok_or("no Vulkan device with a compute queue (install mesa-vulkan-drivers)")?;
        // SAFETY: a plain query of a valid physical device.
        let supported = unsafe { instance.get_physical_device_features(physical_device) };
        let base = vk::PhysicalDeviceFeatures::default()
            .shader_int64(supported.shader_int64 == vk::TRUE)
            .shader_float64(supported.shader_float64 == vk::TRUE);
        let features = DeviceFeatures {
            shader_int64: base.shader_int64 == vk::TRUE,
            shader_float64: base.shader_float64 == vk::TRUE,
            ..DeviceFeatures::default()
        };
        let priorities = [1.0];
        let queues = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(family)
            .queue_priorities(&priorities)];
        let create = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queues)
            .enabled_features(&base);
        // SAFETY: `create` points at locals that outlive the call; only supported features
        // are enabled.
        let device = unsafe { instance.create_device(physical_device, &create, None) }?;
        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: instance.clone(),
            device: device.clone(),
            physical_device,
            debug_settings: Default::default(),
            buffer_device_address: false,
            allocation_sizes: Default::default(),
        });
        match allocator {
            Ok(a) => Ok((
                physical_device,
                family,
                device,
                features,
                Arc::new(Mutex::new(a)),
            )),
            Err(e) => {
                // SAFETY: nothing was created on the device.
                unsafe { device.destroy_device(None) };
                Err(e.into())
            }
        }
    }

    /// The handles vkrt adopts (clones of ash's function tables; the objects stay ours).
    fn raw_parts(&self) -> RawParts {
        RawParts {
            entry: self.entry.clone(),
            instance: self.instance.clone(),
            physical_device: self.physical_device,
            device: self.device.clone(),
            queue_family: self.family,
            queue: self.queue,
            enabled_features: self.features,
            debug_utils: self.debug_utils,
            allocator: Some(Arc::clone(&self.allocator)),
        }
    }

    /// A buffer of the host's, from its allocator.
    fn buffer(
        &self,
        name: &str,
        bytes: u64,
        location: MemoryLocation,
        usage: vk::BufferUsageFlags,
    ) -> BoxResult<HostBuffer> {
        let create = vk::BufferCreateInfo::default().size(bytes).usage(usage);
        // SAFETY: a valid device and create-info.
        let raw = unsafe { self.device.create_buffer(&create, None) }?;
        let mut buffer = HostBuffer {
            device: self.device.clone(),
            allocator: Arc::clone(&self.allocator),
            raw,
            allocation: None,
        };
        // SAFETY: `raw` was just created on this device.
        let requirements = unsafe { self.device.get_buffer_memory_requirements(raw) };
        let allocation = self
            .allocator
            .lock()
            .unwrap()
            .allocate(&AllocationCreateDesc {
                name,
                requirements,
                location,
                linear: true,
                allocation_scheme: AllocationScheme::GpuAllocatorManaged,
            })?;
        // SAFETY: the allocation satisfies `requirements` and is bound to nothing else.
        let bound = unsafe {
            self.device
                .bind_buffer_memory(raw, allocation.memory(), allocation.offset())
        };
        buffer.allocation = Some(allocation);
        bound?;
        Ok(buffer)
    }

    /// The host's command pool and a primary command buffer of it, recording.
    fn command_buffer(&self) -> BoxResult<HostCommands> {
        let info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(self.family)
            .flags(vk::CommandPoolCreateFlags::TRANSIENT);
        // SAFETY: a valid device and create-info.
        let pool = unsafe { self.device.create_command_pool(&info, None) }?;
        let mut commands = HostCommands {
            device: self.device.clone(),
            pool,
            cmd: vk::CommandBuffer::null(),
        };
        let alloc = vk::CommandBufferAllocateInfo::default()
            .command_pool(pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(1);
        // SAFETY: the pool is ours and used by this thread only.
        commands.cmd = unsafe { self.device.allocate_command_buffers(&alloc) }?[0];
        let begin = vk::CommandBufferBeginInfo::default()
            .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
        // SAFETY: a fresh command buffer, begun once.
        unsafe { self.device.begin_command_buffer(commands.cmd, &begin) }?;
        Ok(commands)
    }

    /// Ends `cmd`, submits it to the host's queue and waits for it.
    fn submit_and_wait(&self, cmd: vk::CommandBuffer) -> BoxResult<()> {
        // SAFETY: `cmd` is recording (begun by `command_buffer`), and this thread is the
        // only user of the queue; the fence is waited for (or the device idled) before it is
        // destroyed.
        unsafe {
            self.device.end_command_buffer(cmd)?;
            let fence = self
                .device
                .create_fence(&vk::FenceCreateInfo::default(), None)?;
            let cmds = [cmd];
            let submit = [vk::SubmitInfo::default().command_buffers(&cmds)];
            let result = self
                .device
                .queue_submit(self.queue, &submit, fence)
                .and_then(|()| self.device.wait_for_fences(&[fence], true, u64::MAX));
            if result.is_err() {
                let _ = self.device.device_wait_idle();
            }
            self.device.destroy_fence(fence, None);
            Ok(result?)
        }
    }
}

impl Drop for Host {
    fn drop(&mut self) {
        // SAFETY: `run` drops the host last: vkrt's context (and every clone of it) and the
        // host's buffers and command pool are gone, so the allocator below is the last one
        // and the device has no pending work after the wait.
        unsafe {
            let _ = self.device.device_wait_idle();
            let allocator = ManuallyDrop::take(&mut self.allocator);
            if Arc::strong_count(&allocator) != 1 {
                // Freeing its memory after vkDestroyDevice would be an error: leak instead.
                eprintln!("embed: the allocator is still shared; leaking the device");
                std::mem::forget(allocator);
                return;
            }
            drop(allocator);
            self.device.destroy_device(None);
            if let Some((loader, m)) = self.messenger.take() {
                loader.destroy_debug_utils_messenger(m, None);
            }
            self.instance.destroy_instance(None);
        }
    }
}

/// A buffer the host owns, destroyed and freed when dropped.
struct HostBuffer {
    device: ash::Device,
    allocator: Arc<Mutex<Allocator>>,
    raw: vk::Buffer,
    allocation: Option<Allocation>,
}

impl HostBuffer {
    fn write(&mut self, bytes: &[u8]) {
        let allocation = self.allocation.as_mut().expect("bound");
        let mapped = allocation.mapped_slice_mut().expect("host-visible");
        mapped[..bytes.len()].copy_from_slice(bytes);
    }

    fn read(&self) -> Vec<u8> {
        let allocation = self.allocation.as_ref().expect("bound");
        allocation.mapped_slice().expect("host-visible").to_vec()
    }
}

impl Drop for HostBuffer {
    fn drop(&mut self) {
        // SAFETY: no pending GPU work uses the buffer: the host waits for its submission
        // before anything is dropped (or never submitted).
        unsafe { self.device.destroy_buffer(self.raw, None) };
        if let Some(a) = self.allocation.take() {
            let _ = self.allocator.lock().unwrap().free(a);
        }
    }
}

/// The host's command pool and its one command buffer.
struct HostCommands {
    device: ash::Device,
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
}

impl Drop for HostCommands {
    fn drop(&mut self) {
        // SAFETY: the command buffer has executed (fence waited) or was never submitted.
        unsafe {
            if self.cmd != vk::CommandBuffer::null() {
                self.device.free_command_buffers(self.pool, &[self.cmd]);
            }
            self.device.destroy_command_pool(self.pool, None);
        }
    }
}

fn messenger_info(sink: &Sink) -> vk::DebugUtilsMessengerCreateInfoEXT<'_> {
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
        .user_data(Arc::as_ptr(sink) as *mut c_void)
}

unsafe extern "system" fn on_message(
    _severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user_data: *mut c_void,
) -> vk::Bool32 {
    // SAFETY: the loader passes valid callback data for the duration of the call, and
    // `user_data` is the sink's mutex, alive while any messenger is (see `Host::new`).
    let (data, sink) = unsafe { (&*data, &*(user_data as *const Mutex<Vec<String>>)) };
    let text = if data.p_message.is_null() {
        String::new()
    } else {
        // SAFETY: a non-null message is a NUL-terminated string valid during the call.
        unsafe { CStr::from_ptr(data.p_message) }
            .to_string_lossy()
            .into_owned()
    };
    eprintln!("validation: {text}");
    if let Ok(mut messages) = sink.lock() {
        messages.push(text);
    }
    vk::FALSE
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
