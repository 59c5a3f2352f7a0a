//! The host side of the embedding examples: a program that owns its Vulkan instance, device,
//! queue, gpu-allocator `Allocator`, buffers and command buffers, as a renderer does, and
//! hands them to vkrt with `Context::from_raw`. Shared by `embed.rs` and `own_shader.rs`.
#![allow(dead_code, reason = "each example uses a part")]

use std::error::Error;
use std::ffi::{c_char, c_void, CStr};
use std::mem::ManuallyDrop;
use std::sync::{Arc, Mutex};

use ash::vk;
use gpu_allocator::vulkan::{
    Allocation, AllocationCreateDesc, AllocationScheme, Allocator, AllocatorCreateDesc,
};
use gpu_allocator::MemoryLocation;
use vkrt::gpu::{DeviceFeatures, RawParts, Validation};

pub type BoxResult<T> = Result<T, Box<dyn Error>>;

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// A global memory barrier: `src` work and writes before → `dst` work and accesses after.
///
/// # Safety
/// `cmd` is a command buffer of `device` in the recording state, outside a render pass.
pub unsafe fn barrier(
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
pub type Sink = Arc<Mutex<Vec<String>>>;

/// What the host (a renderer) owns. Dropping it destroys the allocator, device, messenger
/// and instance, in that order.
pub struct Host {
    pub entry: ash::Entry,
    pub instance: ash::Instance,
    pub messenger: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    pub sink: Sink,
    pub debug_utils: bool,
    pub physical_device: vk::PhysicalDevice,
    pub device: ash::Device,
    pub family: u32,
    pub queue: vk::Queue,
    pub features: DeviceFeatures,
    pub allocator: ManuallyDrop<Arc<Mutex<Allocator>>>,
}

impl Host {
    pub fn new(validation: Validation) -> BoxResult<Self> {
        Self::new_with(validation, false)
    }

    /// [`Host::new`] on a device that also enables `VK_KHR_push_descriptor` where it has it
    /// (vkrt's kernels without texel bindings then push their buffers, creating no set).
    #[allow(dead_code, reason = "not every example or test pushes descriptors")]
    pub fn with_push_descriptors(validation: Validation) -> BoxResult<Self> {
        Self::new_with(validation, true)
    }

    fn new_with(validation: Validation, push_descriptors: bool) -> BoxResult<Self> {
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
        match Self::with_device(&instance, push_descriptors) {
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
        push_descriptors: bool,
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
        // 8-bit storage, which vkrt's kd-tree builder needs (a Vulkan 1.2 feature).
        let mut supported12 = vk::PhysicalDeviceVulkan12Features::default();
        let mut query = vk::PhysicalDeviceFeatures2::default().push_next(&mut supported12);
        // SAFETY: a plain query of a valid physical device of a Vulkan 1.2 instance.
        unsafe { instance.get_physical_device_features2(physical_device, &mut query) };
        // The driver's own ray tracing where the device has it, as vkrt lists it
        // (`device_requirements().ray_query_extensions` and three features).
        let ray_query_exts = vkrt::gpu::device_requirements().ray_query_extensions;
        // SAFETY: a plain query of a valid physical device.
        let available = unsafe { instance.enumerate_device_extension_properties(physical_device) }?;
        let has_exts = ray_query_exts.iter().all(|&want| {
            available
                .iter()
                .any(|e| e.extension_name_as_c_str() == Ok(want))
        });
        let mut accel_supported = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default();
        let mut query_supported = vk::PhysicalDeviceRayQueryFeaturesKHR::default();
        if has_exts {
            let mut query = vk::PhysicalDeviceFeatures2::default()
                .push_next(&mut accel_supported)
                .push_next(&mut query_supported);
            // SAFETY: as above; the chained structs belong to extensions the device has.
            unsafe { instance.get_physical_device_features2(physical_device, &mut query) };
        }
        let ray_query = has_exts
            && accel_supported.acceleration_structure == vk::TRUE
            && query_supported.ray_query == vk::TRUE
            && supported12.buffer_device_address == vk::TRUE;
        let mut enable12 = vk::PhysicalDeviceVulkan12Features::default()
            .storage_buffer8_bit_access(supported12.storage_buffer8_bit_access == vk::TRUE)
            .buffer_device_address(ray_query);
        let mut enable_accel = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default()
            .acceleration_structure(true);
        let mut enable_query = vk::PhysicalDeviceRayQueryFeaturesKHR::default().ray_query(true);
        let push = ash::khr::push_descriptor::NAME;
        let push_descriptor = push_descriptors
            && available
                .iter()
                .any(|e| e.extension_name_as_c_str() == Ok(push));
        let features = DeviceFeatures {
            shader_int64: base.shader_int64 == vk::TRUE,
            shader_float64: base.shader_float64 == vk::TRUE,
            storage_buffer_8bit: enable12.storage_buffer8_bit_access == vk::TRUE,
            buffer_device_address: ray_query,
            ray_query,
            push_descriptor,
            ..DeviceFeatures::default()
        };
        let mut ext_names: Vec<*const c_char> = match ray_query {
            true => ray_query_exts.iter().map(|e| e.as_ptr()).collect(),
            false => Vec::new(),
        };
        if push_descriptor {
            ext_names.push(push.as_ptr());
        }
        let priorities = [1.0];
        let queues = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(family)
            .queue_priorities(&priorities)];
        let mut create = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queues)
            .enabled_features(&base)
            .enabled_extension_names(&ext_names)
            .push_next(&mut enable12);
        if ray_query {
            create = create
                .push_next(&mut enable_accel)
                .push_next(&mut enable_query);
        }
        // SAFETY: `create` points at locals that outlive the call; only supported features
        // are enabled.
        let device = unsafe { instance.create_device(physical_device, &create, None) }?;
        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: instance.clone(),
            device: device.clone(),
            physical_device,
            debug_settings: Default::default(),
            buffer_device_address: ray_query,
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
    pub fn raw_parts(&self) -> RawParts {
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
            pipeline_cache_dir: None,
        }
    }

    /// A buffer of the host's, from its allocator.
    pub fn buffer(
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
    pub fn command_buffer(&self) -> BoxResult<HostCommands> {
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
    pub fn submit_and_wait(&self, cmd: vk::CommandBuffer) -> BoxResult<()> {
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
pub struct HostBuffer {
    pub device: ash::Device,
    pub allocator: Arc<Mutex<Allocator>>,
    pub raw: vk::Buffer,
    pub allocation: Option<Allocation>,
}

impl HostBuffer {
    pub fn write(&mut self, bytes: &[u8]) {
        let allocation = self.allocation.as_mut().expect("bound");
        let mapped = allocation.mapped_slice_mut().expect("host-visible");
        mapped[..bytes.len()].copy_from_slice(bytes);
    }

    pub fn read(&self) -> Vec<u8> {
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
pub struct HostCommands {
    pub device: ash::Device,
    pub pool: vk::CommandPool,
    pub cmd: vk::CommandBuffer,
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
