//! `Context`: the instance, device and queue vkrt works on — created headless here, or
//! adopted from an embedding renderer that owns them (`Context::from_raw`).
//!
//! A `Context` is a cheap clone of an `Arc`; buffers and recorders hold one, so the device
//! outlives every object made from it. An adopted device is never destroyed by vkrt.

use std::collections::HashMap;
use std::ffi::{c_char, CStr};
use std::mem::ManuallyDrop;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};

use super::error::{vk_err, GpuError, Result};
use super::hook::ScopeHook;
use super::info::{self, CalibratedTimestamps, DeviceFeatures, DeviceInfo};
use super::kernel::{Kernel, KernelKey};
use super::pipeline_cache;
use super::timeline::{Calibration, Calibrator};
use super::validation::{self, MessageSink, Validation, ValidationMessage};

/// How to create a headless context.
#[derive(Clone, Debug, Default)]
pub struct ContextOptions {
    /// Whether to enable the Khronos validation layer (with synchronization validation).
    pub validation: Validation,
    /// Substring of the device name; `None` reads `VKRT_DEVICE`, else the best device type
    /// wins (discrete > integrated > virtual > cpu).
    pub device_name: Option<String>,
    /// What the caller's own shaders on this device need beyond vkrt's features.
    pub extra: ExtraFeatures,
}

/// Features and extensions a context vkrt creates enables besides its own, for the caller's
/// shaders that run on it ([`crate::gpu::ForeignKernel`], a renderer's pipelines on the
/// adopted-by-vkrt device): `scalarBlockLayout`, say. One the device lacks fails
/// [`Context::new`] with [`GpuError::MissingCapability`] naming it.
#[derive(Clone, Debug, Default)]
pub struct ExtraFeatures {
    /// Vulkan 1.2 features to enable (every `VK_TRUE` member), beside vkrt's.
    pub v12: vk::PhysicalDeviceVulkan12Features<'static>,
    /// Device extensions to enable (ones without a feature struct of their own).
    /// `VK_KHR_push_descriptor` among them also has vkrt's kernels without texel bindings
    /// push their buffers rather than bind descriptor sets ([`DeviceFeatures::push_descriptor`]).
    pub extensions: Vec<std::ffi::CString>,
}

// SAFETY: `v12`'s `p_next` is never followed: only its feature members are read (and a
// caller's non-null chain is refused by `Context::new`).
unsafe impl Send for ExtraFeatures {}
// SAFETY: as above.
unsafe impl Sync for ExtraFeatures {}

/// Where the feature members of a `VkPhysicalDeviceVulkan12Features` lie: the byte offset
/// of the first, and how many.
fn v12_span() -> (usize, usize) {
    type F = vk::PhysicalDeviceVulkan12Features<'static>;
    let first = std::mem::offset_of!(F, sampler_mirror_clamp_to_edge);
    let last = std::mem::offset_of!(F, subgroup_broadcast_dynamic_id);
    (
        first,
        (last - first) / std::mem::size_of::<vk::Bool32>() + 1,
    )
}

/// The feature members of a `VkPhysicalDeviceVulkan12Features`, in order.
fn v12_members<'a>(f: &'a vk::PhysicalDeviceVulkan12Features<'_>) -> &'a [vk::Bool32] {
    let (first, n) = v12_span();
    // SAFETY: the struct is repr(C) and its members from the first feature to the last are
    // `Bool32`s, contiguous (4-byte members, 4-byte aligned: no padding between them).
    unsafe { std::slice::from_raw_parts((f as *const _ as *const u8).add(first).cast(), n) }
}

/// `f`'s feature members, writable.
fn v12_members_mut<'a>(f: &'a mut vk::PhysicalDeviceVulkan12Features<'_>) -> &'a mut [vk::Bool32] {
    let (first, n) = v12_span();
    // SAFETY: as in `v12_members`, through the unique borrow.
    unsafe { std::slice::from_raw_parts_mut((f as *mut _ as *mut u8).add(first).cast(), n) }
}

/// `Err` naming what of `extra` `pd` does not support.
fn check_extra(
    instance: &ash::Instance,
    pd: vk::PhysicalDevice,
    extra: &ExtraFeatures,
) -> Result<()> {
    let device = || {
        // SAFETY: a physical device of this instance.
        let p = unsafe { instance.get_physical_device_properties(pd) };
        p.device_name_as_c_str()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    if !extra.v12.p_next.is_null() {
        return Err(GpuError::Usage {
            call: "Context::new",
            reason: "ExtraFeatures::v12 carries a p_next chain, which vkrt does not follow".into(),
        });
    }
    let mut supported = vk::PhysicalDeviceVulkan12Features::default();
    let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut supported);
    // SAFETY: a physical device of this instance; the chain outlives the call.
    unsafe { instance.get_physical_device_features2(pd, &mut f2) };
    let missing = v12_members(&extra.v12)
        .iter()
        .zip(v12_members(&supported))
        .any(|(&want, &have)| want != 0 && have == 0);
    if missing {
        let mut only = vk::PhysicalDeviceVulkan12Features::default();
        for ((o, &w), &h) in v12_members_mut(&mut only)
            .iter_mut()
            .zip(v12_members(&extra.v12))
            .zip(v12_members(&supported))
        {
            *o = (w != 0 && h == 0) as vk::Bool32;
        }
        let names: Vec<String> = format!("{only:?}")
            .split(", ")
            .filter(|kv| kv.ends_with(": 1"))
            .map(|kv| {
                kv.trim_end_matches(": 1")
                    .trim_start_matches("PhysicalDeviceVulkan12Features { ")
                    .to_string()
            })
            .collect();
        return Err(GpuError::MissingCapability {
            device: device(),
            what: format!(
                "Vulkan 1.2 features asked for in ContextOptions::extra: {}",
                names.join(", ")
            ),
        });
    }
    // SAFETY: a physical device of this instance.
    let available = unsafe { instance.enumerate_device_extension_properties(pd) }
        .map_err(vk_err("vkEnumerateDeviceExtensionProperties"))?;
    for want in &extra.extensions {
        if !available.iter().any(|e| {
            e.extension_name_as_c_str()
                .is_ok_and(|n| n == want.as_c_str())
        }) {
            return Err(GpuError::MissingCapability {
                device: device(),
                what: format!(
                    "the extension {} asked for in ContextOptions::extra",
                    want.to_string_lossy()
                ),
            });
        }
    }
    Ok(())
}

impl ContextOptions {
    /// The options tests use: validation with synchronization validation whenever the layer
    /// is installed and `VKRT_VALIDATION` is not `0`.
    pub fn for_tests() -> Self {
        Self {
            validation: Validation::FromEnv,
            ..Self::default()
        }
    }
}

/// Handles an embedding renderer already owns, for [`Context::from_raw`].
pub struct RawParts {
    /// The loaded Vulkan entry points the instance was created from.
    pub entry: ash::Entry,
    /// The renderer's instance.
    pub instance: ash::Instance,
    /// The physical device `device` was created on.
    pub physical_device: vk::PhysicalDevice,
    /// The renderer's logical device; vkrt never destroys it.
    pub device: ash::Device,
    /// A queue family with compute support, and a queue of it.
    pub queue_family: u32,
    /// A queue of `queue_family`, which vkrt submits its work to.
    pub queue: vk::Queue,
    /// Features the caller enabled at device creation (vkrt cannot query them):
    /// [`DeviceFeatures::from_device_create_info`] reads them from the create info. Its
    /// `calibrated_timestamps`, where set, calibrates vkrt's profiles through that extension
    /// (else they are aligned by a timestamp written at a submission).
    pub enabled_features: DeviceFeatures,
    /// Whether the instance has `VK_EXT_debug_utils` enabled (for pass labels).
    pub debug_utils: bool,
    /// The renderer's own allocator, to share memory blocks; `None` creates one for vkrt.
    pub allocator: Option<Arc<Mutex<Allocator>>>,
    /// A directory for vkrt's on-disk pipeline cache. `None` (the default for an adopted
    /// device): vkrt writes nothing to disk; a context vkrt creates itself uses
    /// `$VKRT_PIPELINE_CACHE`, `$XDG_CACHE_HOME/vkrt` or `$HOME/.cache/vkrt`.
    pub pipeline_cache_dir: Option<std::path::PathBuf>,
}

/// A shared handle on a Vulkan device and queue, with an allocator and a kernel cache.
#[derive(Clone)]
pub struct Context {
    pub(crate) inner: Arc<Inner>,
}

/// What host–device traffic vkrt caused: see [`Context::traffic`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Traffic {
    /// `vkQueueSubmit` calls (each of vkrt's submissions has one command buffer).
    pub submits: u64,
    /// Bytes copied from device buffers into host memory and read there.
    pub readback_bytes: u64,
    /// Bytes written from host memory into device buffers (staging uploads).
    pub upload_bytes: u64,
    /// Bytes written by `vkCmdUpdateBuffer` (constants carried in the command buffer, as
    /// push constants are: no staging buffer).
    pub inline_bytes: u64,
    /// Device-local buffers vkrt allocated from its own allocator (buffers placed in a
    /// caller's memory are not counted).
    pub device_allocations: u64,
    /// Vulkan objects vkrt created on the device: buffers, buffer views, shader modules,
    /// pipelines and their layouts, descriptor pools and sets, query pools, command pools
    /// and buffers, fences, acceleration structures. Recording a frame after
    /// [`crate::gpu::BindingCache::prepare`] creates none.
    pub objects_created: u64,
}

/// Device memory held through the context's allocator (the caller's too, where a renderer
/// handed in its own): see [`Context::memory`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct MemoryUsage {
    /// Live allocations.
    pub allocations: u64,
    /// Bytes the live allocations use.
    pub allocated_bytes: u64,
    /// Bytes of the memory blocks the allocator holds from the driver (used or not).
    pub capacity_bytes: u64,
    /// Bytes of vkrt's own buffers alive now.
    pub vkrt_bytes: u64,
    /// The most bytes of vkrt's own buffers alive at once since the last
    /// [`Context::reset_memory_peak`] (what a build needed at its peak: primitives,
    /// structure and scratch).
    pub vkrt_peak_bytes: u64,
}

impl std::ops::Sub for Traffic {
    type Output = Traffic;
    fn sub(self, earlier: Traffic) -> Traffic {
        Traffic {
            submits: self.submits - earlier.submits,
            readback_bytes: self.readback_bytes - earlier.readback_bytes,
            upload_bytes: self.upload_bytes - earlier.upload_bytes,
            inline_bytes: self.inline_bytes - earlier.inline_bytes,
            device_allocations: self.device_allocations - earlier.device_allocations,
            objects_created: self.objects_created - earlier.objects_created,
        }
    }
}

impl Inner {
    /// Counts `n` Vulkan objects created ([`Traffic::objects_created`]).
    pub(crate) fn created(&self, n: u64) {
        self.objects_created.fetch_add(n, Ordering::Relaxed);
    }
}

static NEXT_CONTEXT_ID: AtomicU64 = AtomicU64::new(1);

pub(crate) struct Inner {
    /// Unique per context made in this process: what a kernel is checked against.
    pub(crate) id: u64,
    pub(crate) entry: ash::Entry,
    pub(crate) instance: ash::Instance,
    pub(crate) physical_device: vk::PhysicalDevice,
    pub(crate) device: ash::Device,
    pub(crate) queue: Mutex<vk::Queue>,
    pub(crate) queue_family: u32,
    pub(crate) allocator: ManuallyDrop<Arc<Mutex<Allocator>>>,
    pub(crate) info: DeviceInfo,
    pub(crate) debug_utils: Option<ash::ext::debug_utils::Device>,
    /// VK_KHR_acceleration_structure's functions, where `ray_query` is enabled.
    pub(crate) accel_ext: Option<ash::khr::acceleration_structure::Device>,
    /// VK_KHR_push_descriptor's functions, where enabled: kernels without texel bindings
    /// push their buffers ([`super::Kernel`]).
    pub(crate) push_descriptor: Option<ash::khr::push_descriptor::Device>,
    pub(crate) pipeline_cache: vk::PipelineCache,
    /// Where the pipeline cache is saved (`None`: nowhere).
    cache_path: Option<std::path::PathBuf>,
    pub(crate) kernels: Mutex<HashMap<KernelKey, Arc<Kernel>>>,
    /// The binding caches made on this context, told when a vkrt buffer drops.
    pub(crate) caches: super::bindings::CacheRegistry,
    /// vkrt's objects alive that hold the context, by kind ([`Context::holders`]).
    pub(crate) holders: super::teardown::HolderCounts,
    /// Recordings dropped uncompleted on an adopted device, freed by [`Context::retire`].
    pub(crate) retired: Mutex<Vec<super::recorder::Recorder>>,
    /// Queue submissions and bytes read back to the host so far ([`Context::traffic`]).
    pub(crate) submits: AtomicU64,
    pub(crate) readback_bytes: AtomicU64,
    pub(crate) upload_bytes: AtomicU64,
    pub(crate) inline_bytes: AtomicU64,
    pub(crate) device_allocations: AtomicU64,
    /// Every vkCreate*/vkAllocate* vkrt calls on the device ([`Traffic::objects_created`]).
    pub(crate) objects_created: AtomicU64,
    /// Bytes of vkrt's own live allocations and their high-water mark since the last
    /// [`Context::reset_memory_peak`].
    pub(crate) live_bytes: AtomicU64,
    pub(crate) peak_bytes: AtomicU64,
    /// Whether new recorders time every dispatch ([`Context::set_dispatch_timestamps`]).
    pub(crate) dispatch_timestamps: AtomicBool,
    /// Whether new recorders count compute-shader invocations
    /// ([`Context::set_pipeline_statistics`]).
    pub(crate) pipeline_statistics: AtomicBool,
    /// The copy kernel's bandwidth as f64 bits, 0 for none ([`Context::set_copy_baseline`]).
    pub(crate) copy_baseline: AtomicU64,
    /// The hook new recorders tell their scopes ([`Context::set_scope_hook`]).
    pub(crate) scope_hook: Mutex<Option<Arc<dyn ScopeHook>>>,
    /// Device-tick ↔ host-clock samples, where the device was created with calibrated
    /// timestamps (vkrt's own devices that have them).
    pub(crate) calibrator: Option<Calibrator>,
    messenger: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    sink: Box<MessageSink>,
    pub(crate) owns_device: bool,
}

impl Context {
    /// Creates a headless instance and device on the best Vulkan 1.2+ device.
    pub fn new(options: &ContextOptions) -> Result<Self> {
        // SAFETY: loading the system Vulkan loader runs its initialisation code; we trust the
        // installed loader as every Vulkan application must.
        let entry = unsafe { ash::Entry::load() }.map_err(|e| GpuError::Loader(e.to_string()))?;
        let sink = Box::<MessageSink>::default();
        let (instance, validation_on, debug_utils_on) = create_instance(&entry, options, &sink)?;
        let messenger = if validation_on {
            let loader = ash::ext::debug_utils::Instance::new(&entry, &instance);
            let info = validation::messenger_info(&sink);
            // SAFETY: `instance` is valid and has VK_EXT_debug_utils enabled; `sink` is boxed
            // and dropped only after the messenger is destroyed (Inner::drop).
            let raw = unsafe { loader.create_debug_utils_messenger(&info, None) }
                .map_err(vk_err("vkCreateDebugUtilsMessengerEXT"))?;
            Some((loader, raw))
        } else {
            None
        };
        let wanted = options
            .device_name
            .clone()
            .or_else(|| std::env::var("VKRT_DEVICE").ok().filter(|s| !s.is_empty()));
        let picked = pick_device(&instance, wanted.as_deref());
        let built = picked.and_then(|(pd, family)| {
            let mut features = info::supported_features(&instance, pd);
            // Only an extension whose time domains are the device's and the host clock's.
            let calibration = Calibrator::extension(&entry, &instance, pd);
            features.calibrated_timestamps = [CalibratedTimestamps::Khr, CalibratedTimestamps::Ext]
                .into_iter()
                .find(|c| Some(c.name()) == calibration);
            // Pushed descriptors spare the descriptor sets but cost lavapipe more per
            // dispatch (bunny builds: LBVH 2–19 % slower, PLOC 5–13 %: docs/performance.md),
            // so they are the caller's choice: `extra.extensions`.
            features.push_descriptor &= options
                .extra
                .extensions
                .iter()
                .any(|e| e.as_c_str() == ash::khr::push_descriptor::NAME);
            check_extra(&instance, pd, &options.extra)?;
            create_device(&instance, pd, family, &features, &options.extra)
                .map(|d| (pd, family, features, (d, calibration)))
        });
        let (physical_device, queue_family, features, (device, calibration)) = match built {
            Ok(v) => v,
            Err(e) => {
                // SAFETY: nothing else was created from this instance yet.
                unsafe {
                    if let Some((loader, raw)) = &messenger {
                        loader.destroy_debug_utils_messenger(*raw, None);
                    }
                    instance.destroy_instance(None);
                }
                return Err(e);
            }
        };
        // SAFETY: the device was created with one queue of `queue_family`.
        let queue = unsafe { device.get_device_queue(queue_family, 0) };
        let parts = RawParts {
            entry,
            instance,
            physical_device,
            device,
            queue_family,
            queue,
            enabled_features: features,
            debug_utils: debug_utils_on,
            allocator: None,
            pipeline_cache_dir: None,
        };
        Self::assemble(parts, messenger, sink, true, calibration)
    }

    /// Adopts a device that an embedding renderer owns. vkrt never destroys the adopted
    /// instance, device or allocator; it destroys only what it created itself.
    ///
    /// # Safety
    /// - every handle in `parts` is valid and belongs to the same instance and device;
    /// - `queue` is a queue of `queue_family`, which supports compute;
    /// - `enabled_features` and `debug_utils` say truly what the device and instance enable;
    /// - the instance, device (and allocator) outlive this context and every clone of it;
    /// - the caller does not use `queue` from another thread while vkrt submits to it
    ///   (vkrt submits only from `Recorder::submit_and_wait` and buffer up/downloads);
    /// - the last clone of the context is dropped only once the work recorded into the
    ///   caller's command buffers through it has finished executing ([`RecordedWork`]
    ///   completed): vkrt then destroys its pipelines and buffers without waiting for the
    ///   device, whose other queues are the caller's.
    ///
    /// [`RecordedWork`]: super::RecordedWork
    pub unsafe fn from_raw(parts: RawParts) -> Result<Self> {
        let physical = info::query(
            &parts.instance,
            parts.physical_device,
            parts.enabled_features,
        );
        info::check_requirements(&physical)?;
        // The caller's calibrated timestamps, where it enabled them.
        let calibration = parts
            .enabled_features
            .calibrated_timestamps
            .map(|c| c.name());
        Self::assemble(parts, None, Box::default(), false, calibration)
    }

    /// The context over `parts`; `calibration` names the calibrated-timestamps extension
    /// the device was created with, if any.
    fn assemble(
        parts: RawParts,
        messenger: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
        sink: Box<MessageSink>,
        owns_device: bool,
        calibration: Option<&'static CStr>,
    ) -> Result<Self> {
        let mut info = info::query(
            &parts.instance,
            parts.physical_device,
            parts.enabled_features,
        );
        info.timestamps &=
            info::timestamp_bits(&parts.instance, parts.physical_device, parts.queue_family) > 0;
        let allocator = match parts.allocator {
            Some(a) => a,
            None => {
                let desc = AllocatorCreateDesc {
                    instance: parts.instance.clone(),
                    device: parts.device.clone(),
                    physical_device: parts.physical_device,
                    debug_settings: Default::default(),
                    // Acceleration structures and their inputs live at device addresses.
                    buffer_device_address: parts.enabled_features.buffer_device_address
                        || parts.enabled_features.ray_query,
                    allocation_sizes: Default::default(),
                };
                let a = Allocator::new(&desc).map_err(|e| GpuError::Allocation {
                    name: "allocator".into(),
                    bytes: 0,
                    reason: e.to_string(),
                })?;
                Arc::new(Mutex::new(a))
            }
        };
        let debug_utils = parts
            .debug_utils
            .then(|| ash::ext::debug_utils::Device::new(&parts.instance, &parts.device));
        let accel_ext = parts
            .enabled_features
            .ray_query
            .then(|| ash::khr::acceleration_structure::Device::new(&parts.instance, &parts.device));
        let push_descriptor = parts
            .enabled_features
            .push_descriptor
            .then(|| ash::khr::push_descriptor::Device::new(&parts.instance, &parts.device));
        let cache_path = match (&parts.pipeline_cache_dir, owns_device) {
            (Some(dir), _) => Some(pipeline_cache::path_in(dir, &info)),
            (None, true) => pipeline_cache::default_path(&info),
            (None, false) => None,
        };
        let pipeline_cache = pipeline_cache::create(&parts.device, cache_path.as_deref())?;
        let calibrator =
            calibration.and_then(|ext| Calibrator::new(&parts.instance, &parts.device, ext));
        Ok(Self {
            inner: Arc::new(Inner {
                id: NEXT_CONTEXT_ID.fetch_add(1, Ordering::Relaxed),
                entry: parts.entry,
                instance: parts.instance,
                physical_device: parts.physical_device,
                device: parts.device,
                queue: Mutex::new(parts.queue),
                queue_family: parts.queue_family,
                allocator: ManuallyDrop::new(allocator),
                info,
                debug_utils,
                accel_ext,
                push_descriptor,
                pipeline_cache,
                cache_path,
                kernels: Mutex::new(HashMap::new()),
                caches: Default::default(),
                holders: Default::default(),
                retired: Mutex::default(),
                submits: AtomicU64::new(0),
                readback_bytes: AtomicU64::new(0),
                upload_bytes: AtomicU64::new(0),
                inline_bytes: AtomicU64::new(0),
                device_allocations: AtomicU64::new(0),
                objects_created: AtomicU64::new(0),
                live_bytes: AtomicU64::new(0),
                peak_bytes: AtomicU64::new(0),
                dispatch_timestamps: AtomicBool::new(false),
                pipeline_statistics: AtomicBool::new(false),
                copy_baseline: AtomicU64::new(0),
                scope_hook: Mutex::new(None),
                calibrator,
                messenger,
                sink,
                owns_device,
            }),
        })
    }

    /// Whether recorders made from now on ([`Recorder::new`](super::Recorder::new),
    /// [`Recorder::from_raw`](super::Recorder::from_raw)) time every dispatch as a scope
    /// named after its kernel and variant, nested in the pass scopes. Off by default: then a
    /// dispatch writes no timestamp. On, a recording takes two queries per dispatch, so
    /// vkrt's own recorders add query pools as they fill (a caller's `from_raw` recorder
    /// reports the dispatches its capacity left untimed instead).
    pub fn set_dispatch_timestamps(&self, on: bool) {
        self.inner.dispatch_timestamps.store(on, Ordering::Relaxed);
    }

    /// Whether recorders made from now on count the compute-shader invocations of every
    /// dispatch with a pipeline-statistics query and sum them into the scopes around it
    /// ([`super::PassTime::invocations`]): how much work an indirect pass really did. Off by
    /// default. Needs `pipelineStatisticsQuery` ([`DeviceFeatures::pipeline_statistics_query`]);
    /// returns whether counting is on. vkrt's own recorders make a query pool when they are
    /// created and add one whenever it fills; a caller's [`Recorder::from_raw`] makes one of
    /// half its query capacity when it is created, never while recording, and counts the
    /// dispatches past it as uncounted (a warning); [`Recorder::from_raw_with`] counts
    /// nothing (it creates no Vulkan object).
    ///
    /// [`Recorder::from_raw`]: super::Recorder::from_raw
    /// [`Recorder::from_raw_with`]: super::Recorder::from_raw_with
    pub fn set_pipeline_statistics(&self, on: bool) -> bool {
        let on = on && self.inner.info.features.pipeline_statistics_query;
        self.inner.pipeline_statistics.store(on, Ordering::Relaxed);
        on
    }

    /// Records the bandwidth of the best plain copy kernel on this device, measured by the
    /// caller (read plus written GiB per second; `vkrt bench copy` measures it): profiles
    /// read from now on carry it ([`super::ProfiledDevice::copy_gib_per_s`]), so each
    /// pass's bandwidth can be weighed against it. A value that is not finite and positive
    /// clears it.
    pub fn set_copy_baseline(&self, gib_per_s: f64) {
        let bits = match gib_per_s.is_finite() && gib_per_s > 0.0 {
            true => gib_per_s.to_bits(),
            false => 0,
        };
        self.inner.copy_baseline.store(bits, Ordering::Relaxed);
    }

    /// The copy bandwidth [`Context::set_copy_baseline`] recorded, if any.
    pub fn copy_baseline(&self) -> Option<f64> {
        let bits = self.inner.copy_baseline.load(Ordering::Relaxed);
        (bits != 0).then(|| f64::from_bits(bits))
    }

    /// Registers `hook` on the recorders made from now on: each is told every scope and
    /// dispatch as it is recorded, with the timestamp queries it wrote, and their ticks once
    /// the work has completed ([`ScopeHook`]); `None` removes it.
    pub fn set_scope_hook(&self, hook: Option<Arc<dyn ScopeHook>>) {
        *super::error::lock(&self.inner.scope_hook) = hook;
    }

    /// A device tick and the host time it corresponds to, now: through calibrated
    /// timestamps where the context has them, else from a submission of one timestamp
    /// (placed at its submit). `None` where the device has no timestamps. What a GPU
    /// profiler of the caller's starts its clock from (Tracy's `new_gpu_context`).
    pub fn calibrate(&self) -> Result<Option<Calibration>> {
        if let Some(c) = self.inner.calibrator.as_ref().and_then(|c| c.sample()) {
            return Ok(Some(c));
        }
        let mut rec = super::Recorder::new(self)?;
        rec.set_scope_hook(None);
        rec.scope("vkrt.clock", |_| ());
        let profile = rec.submit_and_wait()?;
        Ok(profile.submissions.first().and_then(|s| s.calibration))
    }

    /// Queue submissions vkrt made and bytes it read back to the host through this context
    /// so far; the difference of two readings is what the work between them cost.
    pub fn traffic(&self) -> Traffic {
        Traffic {
            submits: self.inner.submits.load(Ordering::Relaxed),
            readback_bytes: self.inner.readback_bytes.load(Ordering::Relaxed),
            upload_bytes: self.inner.upload_bytes.load(Ordering::Relaxed),
            inline_bytes: self.inner.inline_bytes.load(Ordering::Relaxed),
            device_allocations: self.inner.device_allocations.load(Ordering::Relaxed),
            objects_created: self.inner.objects_created.load(Ordering::Relaxed),
        }
    }

    /// Device memory held through the allocator now: a long-running renderer checks that
    /// it stays flat (`vkrt animate` reports it per frame). Memory placed in the caller's
    /// own allocations is the caller's to count.
    pub fn memory(&self) -> MemoryUsage {
        let allocator = self
            .inner
            .allocator
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let report = allocator.generate_report();
        MemoryUsage {
            allocations: report.allocations.len() as u64,
            allocated_bytes: report.total_allocated_bytes,
            capacity_bytes: report.total_capacity_bytes,
            vkrt_bytes: self.inner.live_bytes.load(Ordering::Relaxed),
            vkrt_peak_bytes: self.inner.peak_bytes.load(Ordering::Relaxed),
        }
    }

    /// Starts a new high-water mark of vkrt's buffers at what is alive now.
    pub fn reset_memory_peak(&self) {
        let live = self.inner.live_bytes.load(Ordering::Relaxed);
        self.inner.peak_bytes.store(live, Ordering::Relaxed);
    }

    /// Counts an allocation of `bytes` made (`+`) or freed (`-`).
    pub(crate) fn count_allocation(&self, bytes: u64, made: bool) {
        if made {
            let live = self.inner.live_bytes.fetch_add(bytes, Ordering::Relaxed) + bytes;
            self.inner.peak_bytes.fetch_max(live, Ordering::Relaxed);
        } else {
            self.inner.live_bytes.fetch_sub(bytes, Ordering::Relaxed);
        }
    }

    /// What the device is and what it can do.
    pub fn info(&self) -> &DeviceInfo {
        &self.inner.info
    }

    /// Whether validation messages are being collected by this context.
    pub fn validation_enabled(&self) -> bool {
        self.inner.messenger.is_some()
    }

    /// Takes the validation messages collected so far.
    pub fn take_validation_messages(&self) -> Vec<ValidationMessage> {
        std::mem::take(&mut *super::error::lock(&self.inner.sink.messages))
    }

    /// The raw ash device, for embedding renderers that mix their own commands in.
    pub fn device(&self) -> &ash::Device {
        &self.inner.device
    }

    /// The queue family vkrt records for.
    pub fn queue_family(&self) -> u32 {
        self.inner.queue_family
    }

    /// Names a Vulkan object for debuggers and validation messages (debug-utils).
    pub(crate) fn set_object_name<H: vk::Handle>(&self, handle: H, name: &str) {
        let Some(du) = &self.inner.debug_utils else {
            return;
        };
        let Ok(name) = std::ffi::CString::new(name) else {
            return;
        };
        let info = vk::DebugUtilsObjectNameInfoEXT::default()
            .object_handle(handle)
            .object_name(&name);
        // SAFETY: `handle` is a live object of this device; naming is best effort.
        let _ = unsafe { du.set_debug_utils_object_name(&info) };
    }

    /// Waits until the device is idle. Refused on a device adopted with
    /// [`Context::from_raw`]: a device-wide wait would also wait for the renderer's other
    /// queues, which it synchronizes itself; wait for its own fence instead.
    pub fn wait_idle(&self) -> Result<()> {
        if !self.inner.owns_device {
            return Err(GpuError::Usage {
                call: "Context::wait_idle",
                reason: "the device is the renderer's (Context::from_raw): wait for the fence \
                         of the submission that carried vkrt's work instead"
                    .into(),
            });
        }
        let _queue = super::error::lock(&self.inner.queue);
        // SAFETY: the device is valid; holding the queue lock keeps our submissions out.
        unsafe { self.inner.device.device_wait_idle() }.map_err(vk_err("vkDeviceWaitIdle"))
    }
}

impl Drop for Inner {
    fn drop(&mut self) {
        // SAFETY: the last clone of the context is going away, so no buffer, recorder or
        // kernel made from it is alive (they all hold a clone). On vkrt's own device (and
        // queue) we wait for it to be idle before destroying what we created; on an adopted
        // one, `from_raw`'s contract says vkrt's work has finished, and waiting for the whole
        // device would need the caller's other queues externally synchronized.
        unsafe {
            if self.owns_device {
                let _ = self.device.device_wait_idle();
            }
            for kernel in self.kernels.get_mut().unwrap().values() {
                kernel.destroy(&self.device);
            }
            pipeline_cache::save_and_destroy(
                &self.device,
                self.pipeline_cache,
                self.cache_path.as_deref(),
            );
            // The allocator must go before the device; an adopted one may live on elsewhere.
            ManuallyDrop::drop(&mut self.allocator);
            if self.owns_device {
                self.device.destroy_device(None);
                if let Some((loader, raw)) = self.messenger.take() {
                    loader.destroy_debug_utils_messenger(raw, None);
                }
                self.instance.destroy_instance(None);
            }
        }
        let _ = &self.entry;
    }
}

fn create_instance(
    entry: &ash::Entry,
    options: &ContextOptions,
    sink: &MessageSink,
) -> Result<(ash::Instance, bool, bool)> {
    // SAFETY: plain enumeration calls on a loaded entry.
    let (layers, extensions) = unsafe {
        (
            entry
                .enumerate_instance_layer_properties()
                .map_err(vk_err("vkEnumerateInstanceLayerProperties"))?,
            entry
                .enumerate_instance_extension_properties(None)
                .map_err(vk_err("vkEnumerateInstanceExtensionProperties"))?,
        )
    };
    let has_layer = layers.iter().any(|l| {
        l.layer_name_as_c_str()
            .is_ok_and(|n| n == validation::LAYER_NAME)
    });
    let validation_on =
        options
            .validation
            .resolve(has_layer)
            .map_err(|what| GpuError::MissingCapability {
                device: "instance".into(),
                what,
            })?;
    let has_ext = |name: &CStr| {
        extensions
            .iter()
            .any(|e| e.extension_name_as_c_str().is_ok_and(|n| n == name))
    };
    let debug_utils_on = has_ext(ash::ext::debug_utils::NAME);
    let mut ext_names: Vec<*const c_char> = Vec::new();
    if debug_utils_on {
        ext_names.push(ash::ext::debug_utils::NAME.as_ptr());
    }
    let mut flags = vk::InstanceCreateFlags::empty();
    if has_ext(ash::khr::portability_enumeration::NAME) {
        ext_names.push(ash::khr::portability_enumeration::NAME.as_ptr());
        flags |= vk::InstanceCreateFlags::ENUMERATE_PORTABILITY_KHR;
    }
    if validation_on && !debug_utils_on {
        return Err(GpuError::MissingCapability {
            device: "instance".into(),
            what: "VK_EXT_debug_utils (needed to collect validation messages)".into(),
        });
    }
    let layer_names = if validation_on {
        vec![validation::LAYER_NAME.as_ptr()]
    } else {
        vec![]
    };
    let app = vk::ApplicationInfo::default()
        .application_name(c"vkrt")
        .engine_name(c"vkrt")
        .api_version(vk::API_VERSION_1_2);
    let (enabled_features, disabled_features) = validation::features();
    let mut validation_features = vk::ValidationFeaturesEXT::default()
        .enabled_validation_features(&enabled_features)
        .disabled_validation_features(&disabled_features);
    let mut messenger_info = validation::messenger_info(sink);
    let mut create = vk::InstanceCreateInfo::default()
        .application_info(&app)
        .enabled_layer_names(&layer_names)
        .enabled_extension_names(&ext_names)
        .flags(flags);
    if validation_on {
        create = create
            .push_next(&mut validation_features)
            .push_next(&mut messenger_info);
    }
    // SAFETY: every pointer in `create` refers to locals that live across the call.
    let instance =
        unsafe { entry.create_instance(&create, None) }.map_err(vk_err("vkCreateInstance"))?;
    Ok((instance, validation_on, debug_utils_on))
}

/// Picks a physical device and its compute queue family.
fn pick_device(
    instance: &ash::Instance,
    wanted: Option<&str>,
) -> Result<(vk::PhysicalDevice, u32)> {
    // SAFETY: enumeration on a valid instance.
    let devices = unsafe { instance.enumerate_physical_devices() }
        .map_err(vk_err("vkEnumeratePhysicalDevices"))?;
    let mut candidates = Vec::new();
    let mut rejected = Vec::new();
    for pd in devices {
        let physical = info::query(instance, pd, info::supported_features(instance, pd));
        if let Some(w) = wanted {
            if !physical.device.to_lowercase().contains(&w.to_lowercase()) {
                rejected.push(format!("{} (name does not contain `{w}`)", physical.device));
                continue;
            }
        }
        if let Err(e) = info::check_requirements(&physical) {
            rejected.push(e.to_string());
            continue;
        }
        match info::compute_queue_family(instance, pd) {
            Some(family) => candidates.push((physical.type_rank, pd, family)),
            None => rejected.push(format!("{}: no compute queue", physical.device)),
        }
    }
    candidates.sort_by_key(|c| c.0);
    match candidates.first() {
        Some(&(_, pd, family)) => Ok((pd, family)),
        None if rejected.len() == 1 && wanted.is_none() => {
            Err(GpuError::NoDevice(rejected.remove(0)))
        }
        None => Err(GpuError::NoDevice(if rejected.is_empty() {
            "the Vulkan loader lists no device (install mesa-vulkan-drivers for lavapipe)".into()
        } else {
            rejected.join("; ")
        })),
    }
}

fn create_device(
    instance: &ash::Instance,
    pd: vk::PhysicalDevice,
    family: u32,
    features: &DeviceFeatures,
    extra: &ExtraFeatures,
) -> Result<ash::Device> {
    let priorities = [1.0];
    let queues = [vk::DeviceQueueCreateInfo::default()
        .queue_family_index(family)
        .queue_priorities(&priorities)];
    // The same structs a renderer gets from `DeviceFeatures::request`.
    let mut r = features.request();
    // The caller's extras beside them (checked as supported).
    for (mine, &theirs) in v12_members_mut(&mut r.v12)
        .iter_mut()
        .zip(v12_members(&extra.v12))
    {
        *mine |= theirs;
    }
    // Among them, calibrated timestamps put the device's ticks on the host's clock
    // (`timeline`).
    let mut ext_names: Vec<_> = r.extensions.iter().map(|n| n.as_ptr()).collect();
    for e in &extra.extensions {
        if !r.extensions.contains(&e.as_c_str()) {
            ext_names.push(e.as_ptr());
        }
    }
    let mut create = vk::DeviceCreateInfo::default()
        .queue_create_infos(&queues)
        .enabled_features(&r.base)
        .push_next(&mut r.v11)
        .push_next(&mut r.v12);
    if let Some(s) = r.size_control.as_mut() {
        create = create.push_next(s);
    }
    if let (Some(a), Some(q)) = (r.acceleration_structure.as_mut(), r.ray_query.as_mut()) {
        create = create.push_next(a).push_next(q);
    }
    create = create.enabled_extension_names(&ext_names);
    // SAFETY: `create` points at locals that outlive the call; only supported features and
    // extensions are requested.
    unsafe { instance.create_device(pd, &create, None) }.map_err(vk_err("vkCreateDevice"))
}
