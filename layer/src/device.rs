//! The device: its creation (the layer's extensions stripped, what vkrt's walk needs
//! enabled), the dispatch of its functions, and its teardown.

use std::ffi::{c_char, CStr};
use std::sync::{Arc, LazyLock, Mutex, RwLock};

use ash::vk;
use ash::vk::Handle;

use crate::instance::{self, LayerInstance, PROVIDED};
use crate::loader::{self, LayerDeviceCreateInfo};
use crate::{
    accel, commands, debug, deferred, descriptors, guard, log, memory, pfn, queries, shaders, sync,
    HandleMap,
};

/// Logged once per device whose driver ends all of an invocation's loops after a budget of
/// iterations in all (llvmpipe before Mesa 25): an app's own loops can be cut short.
const LOOP_BUDGET_WARNING: &str = "warning: the driver ends all of an \
    invocation's loops once they have run a budget of iterations in all (llvmpipe before \
    Mesa 25): ray queries walk with a flat loop, about one iteration per node visit, pop and \
    primitive, so a shader that traces thousands of rays per invocation can still have its \
    own loops cut short, silently, and a query it cuts ends early";

/// What the layer keeps of a device.
pub struct LayerDevice {
    pub next_gdpa: vk::PFN_vkGetDeviceProcAddr,
    /// The next layer's device functions.
    pub fns: ash::Device,
    /// `None` where the layer does not serve the device: its functions are the next
    /// layer's, none intercepted.
    pub served: Option<Arc<Served>>,
}

/// A device the layer serves.
pub struct Served {
    pub fns: ash::Device,
    /// vkrt over the application's device.
    pub ctx: vkrt::Context,
    pub buffers: Mutex<memory::Buffers>,
    pub commands: Mutex<commands::CommandBuffers>,
    pub accel: accel::Builders,
    /// The thread compiling vkrt's builders since the device was created.
    pub warming: Mutex<Option<std::thread::JoinHandle<()>>>,
    /// The synchronization-2 entry points the layer translates.
    pub sync2: sync::Sync2Fns,
    /// The descriptor entry points the layer translates that a device may lack.
    pub descriptor_fns: descriptors::DescriptorFns,
    /// The descriptor sets and texel views of vkrt's kernels over the application's
    /// buffers, where the device has no push descriptors (with them, the build kernels push
    /// their ranges and the cache stays empty): made by the first build over a range and
    /// bound by every later one; a buffer's are freed when the application destroys it
    /// (`memory`).
    pub bindings: vkrt::gpu::BindingCache,
}

impl Served {
    /// Waits, once, for the thread compiling vkrt's kernels since the device was created,
    /// so that a recording binds kernels that exist rather than compiling its own beside
    /// that thread's (objects created while the application records).
    pub fn kernels_ready(&self) {
        let warming = self.warming.lock().ok().and_then(|mut w| w.take());
        if let Some(t) = warming {
            let _ = t.join();
        }
    }
}

static DEVICES: LazyLock<RwLock<HandleMap<usize, Arc<LayerDevice>>>> =
    LazyLock::new(Default::default);

/// The layer's state of the device of `handle` (a device, queue or command buffer).
pub fn lookup<H: Handle>(handle: H) -> Option<Arc<LayerDevice>> {
    let raw = handle.as_raw();
    if raw == 0 {
        return None;
    }
    // SAFETY: a live dispatchable handle (the loader's contract for every call).
    let key = unsafe { loader::dispatch_key(raw) };
    DEVICES.read().ok()?.get(&key).cloned()
}

/// The served device of `handle`, where the layer serves it.
pub fn served<H: Handle>(handle: H) -> Option<Arc<Served>> {
    lookup(handle)?.served.clone()
}

/// The layer's device functions, by name.
pub fn intercepted(name: &CStr) -> vk::PFN_vkVoidFunction {
    let n = name.to_bytes();
    match n {
        b"vkDestroyDevice" => pfn!(destroy_device, vk::PFN_vkDestroyDevice),
        _ => memory::function(n)
            .or_else(|| accel::function(n))
            .or_else(|| deferred::function(n))
            .or_else(|| commands::function(n))
            .or_else(|| descriptors::function(n))
            .or_else(|| shaders::function(n))
            .or_else(|| sync::function(n))
            .or_else(|| queries::function(n))
            .or_else(|| debug::function(n)),
    }
}

/// The layer's `vkGetDeviceProcAddr`.
///
/// # Safety
/// `device` is live.
pub unsafe fn get_device_proc_addr(device: vk::Device, name: &CStr) -> vk::PFN_vkVoidFunction {
    if name.to_bytes() == b"vkGetDeviceProcAddr" {
        return pfn!(crate::vkGetDeviceProcAddr, vk::PFN_vkGetDeviceProcAddr);
    }
    let layer = lookup(device)?;
    if layer.served.is_some() {
        if let Some(f) = intercepted(name) {
            return Some(f);
        }
    }
    // SAFETY: the next layer's entry point, with the caller's arguments.
    unsafe { (layer.next_gdpa)(device, name.as_ptr()) }
}

pub(crate) unsafe extern "system" fn create_device(
    pd: vk::PhysicalDevice,
    info: *const vk::DeviceCreateInfo<'_>,
    allocator: *const vk::AllocationCallbacks<'_>,
    out: *mut vk::Device,
) -> vk::Result {
    guard(vk::Result::ERROR_INITIALIZATION_FAILED, || {
        // SAFETY: the loader's contract: valid arguments whose chain holds its link.
        unsafe { create(pd, info, allocator, out) }
    })
}

unsafe fn create(
    pd: vk::PhysicalDevice,
    info: *const vk::DeviceCreateInfo<'_>,
    allocator: *const vk::AllocationCallbacks<'_>,
    out: *mut vk::Device,
) -> vk::Result {
    // SAFETY: the caller's contract.
    let info_ref = unsafe { &*info };
    // SAFETY: a valid chain.
    let link: *mut LayerDeviceCreateInfo = unsafe {
        loader::find_link(
            info_ref.p_next.cast(),
            vk::StructureType::LOADER_DEVICE_CREATE_INFO,
        )
    };
    // SAFETY: the loader's link, valid for this call.
    let Some(link) = (unsafe { link.as_mut() }) else {
        return vk::Result::ERROR_INITIALIZATION_FAILED;
    };
    // SAFETY: as above.
    let layer_info = unsafe { &*link.layer_info };
    let next_gipa = layer_info.next_get_instance_proc_addr;
    let next_gdpa = layer_info.next_get_device_proc_addr;
    link.layer_info = layer_info.next;
    let Some(inst) = instance::lookup(pd) else {
        return vk::Result::ERROR_INITIALIZATION_FAILED;
    };
    // SAFETY: the next layer's instance entry point.
    let Some(next_create) = (unsafe { next_gipa(inst.handle, c"vkCreateDevice".as_ptr()) }) else {
        return vk::Result::ERROR_INITIALIZATION_FAILED;
    };
    // SAFETY: the loader's pointer is vkCreateDevice's.
    let next_create: vk::PFN_vkCreateDevice = unsafe { std::mem::transmute(next_create) };

    // SAFETY: the application's extension names.
    let names: Vec<&CStr> = unsafe { enabled_names(info_ref) };
    let wants = names.iter().any(|n| PROVIDED.iter().any(|(p, _)| p == n));
    if !inst.serves(pd) || !wants {
        // SAFETY: the application's arguments, passed on.
        let r = unsafe { next_create(pd, info, allocator, out) };
        if r == vk::Result::SUCCESS {
            // SAFETY: created above.
            register(unsafe { *out }, &inst, next_gdpa, None);
        }
        return r;
    }
    if let Err(missing) = check_requirements(&inst, pd) {
        log(&format!(
            "the device cannot serve VK_KHR_acceleration_structure and VK_KHR_ray_query through \
             vkrt: it lacks {missing}"
        ));
        return vk::Result::ERROR_FEATURE_NOT_PRESENT;
    }
    let supported = supported_features(&inst, pd);

    // The driver's create info: the layer's extensions and feature structs taken out,
    // bufferDeviceAddress and shaderInt64 enabled (the lowered shaders need both), and
    // push descriptors where the device has them (vkrt's builds then bind no set).
    let mut kept: Vec<*const c_char> = names
        .iter()
        .filter(|n| !PROVIDED.iter().any(|(p, _)| p == *n))
        .map(|n| n.as_ptr())
        .collect();
    let push = ash::khr::push_descriptor::NAME;
    if supported.push_descriptor && !names.contains(&push) {
        kept.push(push.as_ptr());
    }
    let mut driver_info = *info_ref;
    driver_info.enabled_extension_count = kept.len() as u32;
    driver_info.pp_enabled_extension_names = kept.as_ptr();
    let mut edits = FeatureEdits::default();
    let mut base = vk::PhysicalDeviceFeatures::default();
    let mut bda =
        vk::PhysicalDeviceBufferDeviceAddressFeatures::default().buffer_device_address(true);
    // SAFETY: the application's chain, restored below before returning.
    let unlinked = unsafe {
        instance::unlink(
            (&mut driver_info as *mut vk::DeviceCreateInfo<'_>).cast(),
            &[
                vk::StructureType::PHYSICAL_DEVICE_ACCELERATION_STRUCTURE_FEATURES_KHR,
                vk::StructureType::PHYSICAL_DEVICE_RAY_QUERY_FEATURES_KHR,
            ],
        )
    };
    // SAFETY: as above.
    unsafe { edits.enable(&mut driver_info, &mut base, &mut bda, &supported) };
    // SAFETY: the edited create info: the application's, less the layer's parts.
    let r = unsafe { next_create(pd, &driver_info, allocator, out) };
    let api = inst.api_version.min(device_api(&inst, pd));
    // SAFETY: the edited create info is valid.
    let enabled = unsafe { vkrt::gpu::DeviceFeatures::from_device_create_info(&driver_info, api) };
    let queue_family = queue_family(&inst, pd, info_ref);
    edits.restore();
    unlinked.relink();
    if r != vk::Result::SUCCESS {
        return r;
    }
    // SAFETY: created above.
    let device = unsafe { *out };
    let mut fp = inst.fns.fp_v1_0().clone();
    fp.get_device_proc_addr = next_gdpa;
    // SAFETY: a live device, its functions through the next layer.
    let fns = unsafe { ash::Device::load(&fp, device) };
    // SAFETY: a queue the application asked for.
    let queue = unsafe { fns.get_device_queue(queue_family, 0) };
    // vkrt loads device extensions (push descriptors) through the instance's
    // vkGetDeviceProcAddr: the next layer's, as the device's own functions are.
    let instance = ash::Instance::from_parts_1_3(
        inst.fns.handle(),
        fp,
        inst.fns.fp_v1_1().clone(),
        inst.fns.fp_v1_3().clone(),
    );
    let parts = vkrt::gpu::RawParts {
        entry: inst.entry.clone(),
        instance,
        physical_device: pd,
        device: fns.clone(),
        queue_family,
        queue,
        enabled_features: enabled,
        debug_utils: false,
        allocator: None,
        pipeline_cache_dir: None,
    };
    // SAFETY: the application's live handles, which outlive the context: it is dropped in
    // vkDestroyDevice before the device goes.
    let ctx = match unsafe { vkrt::Context::from_raw(parts) } {
        Ok(c) => c,
        Err(e) => {
            log(&format!("the device cannot run vkrt: {e}"));
            // SAFETY: created above, unused.
            unsafe { fns.destroy_device(allocator.as_ref()) };
            return vk::Result::ERROR_FEATURE_NOT_PRESENT;
        }
    };
    if let Some(budget) = ctx.info().loop_budget {
        log(&format!(
            "{LOOP_BUDGET_WARNING} ({}: {budget} iterations)",
            ctx.info().device
        ));
    }
    let bindings = vkrt::gpu::BindingCache::new(&ctx);
    let served = Served {
        fns: fns.clone(),
        ctx,
        buffers: Mutex::default(),
        commands: Mutex::default(),
        accel: accel::Builders::default(),
        warming: Mutex::new(None),
        // SAFETY: the next layer's, for a live device.
        sync2: unsafe { sync::Sync2Fns::load(next_gdpa, device) },
        // SAFETY: as above.
        descriptor_fns: unsafe { descriptors::DescriptorFns::load(next_gdpa, device) },
        bindings,
    };
    let served = Arc::new(served);
    let warm = served.clone();
    let thread = std::thread::Builder::new()
        .name("vkrt-layer-kernels".into())
        .spawn(move || guard((), || warm.accel.warm(&warm.ctx)));
    match thread {
        Ok(t) => *served.warming.lock().unwrap_or_else(|e| e.into_inner()) = Some(t),
        Err(e) => log(&format!(
            "no thread to compile vkrt's kernels ahead ({e}): the first build will"
        )),
    }
    register(device, &inst, next_gdpa, Some(served));
    vk::Result::SUCCESS
}

fn register(
    device: vk::Device,
    inst: &LayerInstance,
    next_gdpa: vk::PFN_vkGetDeviceProcAddr,
    served: Option<Arc<Served>>,
) {
    let mut fp = inst.fns.fp_v1_0().clone();
    fp.get_device_proc_addr = next_gdpa;
    // SAFETY: a live device, its functions through the next layer.
    let fns = unsafe { ash::Device::load(&fp, device) };
    // SAFETY: a live dispatchable handle.
    let key = unsafe { loader::dispatch_key(device.as_raw()) };
    if let Ok(mut m) = DEVICES.write() {
        m.insert(
            key,
            Arc::new(LayerDevice {
                next_gdpa,
                fns,
                served,
            }),
        );
    }
}

/// # Safety
/// `info`'s names are valid.
unsafe fn enabled_names<'a>(info: &'a vk::DeviceCreateInfo<'_>) -> Vec<&'a CStr> {
    if info.pp_enabled_extension_names.is_null() {
        return Vec::new();
    }
    // SAFETY: the caller's contract.
    unsafe {
        std::slice::from_raw_parts(
            info.pp_enabled_extension_names,
            info.enabled_extension_count as usize,
        )
    }
    .iter()
    // SAFETY: the caller's contract.
    .map(|&p| unsafe { CStr::from_ptr(p) })
    .collect()
}

fn device_api(inst: &LayerInstance, pd: vk::PhysicalDevice) -> u32 {
    // SAFETY: a physical device of the instance.
    unsafe { inst.fns.get_physical_device_properties(pd) }.api_version
}

/// What the device supports of the features the layer enables.
#[derive(Clone, Copy, Default)]
struct Supported {
    int64_atomics: bool,
    /// `VK_KHR_push_descriptor`: vkrt's build kernels push their buffers, so recording a
    /// build creates no descriptor set.
    push_descriptor: bool,
}

fn supported_features(inst: &LayerInstance, pd: vk::PhysicalDevice) -> Supported {
    let mut v12 = vk::PhysicalDeviceVulkan12Features::default();
    let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut v12);
    // SAFETY: a physical device of the instance; the chain is ours.
    unsafe { (inst.fns.fp_v1_1().get_physical_device_features2)(pd, &mut f2) };
    // SAFETY: as above.
    let extensions =
        unsafe { inst.fns.enumerate_device_extension_properties(pd) }.unwrap_or_default();
    Supported {
        int64_atomics: v12.shader_buffer_int64_atomics == vk::TRUE,
        push_descriptor: extensions
            .iter()
            .any(|e| e.extension_name_as_c_str() == Ok(ash::khr::push_descriptor::NAME)),
    }
}

/// Why the device cannot be served, naming what it lacks.
fn check_requirements(inst: &LayerInstance, pd: vk::PhysicalDevice) -> Result<(), String> {
    let mut missing = Vec::new();
    if inst.api_version < vk::API_VERSION_1_2 {
        missing.push("an instance of Vulkan 1.2 (the application asked for less)".to_string());
    }
    let api = device_api(inst, pd);
    if api < vk::API_VERSION_1_2 {
        missing.push(format!(
            "Vulkan 1.2 (it speaks {}.{})",
            vk::api_version_major(api),
            vk::api_version_minor(api)
        ));
    } else {
        let mut v12 = vk::PhysicalDeviceVulkan12Features::default();
        let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut v12);
        // SAFETY: a physical device of the instance; the chain is ours.
        unsafe { (inst.fns.fp_v1_1().get_physical_device_features2)(pd, &mut f2) };
        if f2.features.shader_int64 != vk::TRUE {
            missing.push("shaderInt64".into());
        }
        if v12.buffer_device_address != vk::TRUE {
            missing.push("bufferDeviceAddress".into());
        }
    }
    match missing.is_empty() {
        true => Ok(()),
        false => Err(missing.join(", ")),
    }
}

/// The queue family vkrt's context is given: the first the application asked for with
/// compute (the layer records into the application's command buffers and submits nothing).
fn queue_family(
    inst: &LayerInstance,
    pd: vk::PhysicalDevice,
    info: &vk::DeviceCreateInfo<'_>,
) -> u32 {
    // SAFETY: a physical device of the instance.
    let families = unsafe { inst.fns.get_physical_device_queue_family_properties(pd) };
    let asked: &[vk::DeviceQueueCreateInfo<'_>] = match info.p_queue_create_infos.is_null() {
        true => &[],
        // SAFETY: the application's valid array.
        false => unsafe {
            std::slice::from_raw_parts(
                info.p_queue_create_infos,
                info.queue_create_info_count as usize,
            )
        },
    };
    asked
        .iter()
        .map(|q| q.queue_family_index)
        .find(|&f| {
            families
                .get(f as usize)
                .is_some_and(|p| p.queue_flags.contains(vk::QueueFlags::COMPUTE))
        })
        .or_else(|| asked.first().map(|q| q.queue_family_index))
        .unwrap_or(0)
}

/// The application's feature flags the layer turned on for the driver's create info, to
/// turn back.
#[derive(Default)]
struct FeatureEdits(Vec<(*mut vk::Bool32, vk::Bool32)>);

impl FeatureEdits {
    fn set(&mut self, flag: &mut vk::Bool32) {
        self.0.push((flag as *mut _, *flag));
        *flag = vk::TRUE;
    }

    /// Enables shaderInt64 and bufferDeviceAddress (and 64-bit atomics where the device has
    /// them: vkrt's single-pass scan) in `info`, in the application's structs where it gave
    /// them, else in `base` and `bda`, which `info` then points to.
    ///
    /// # Safety
    /// `info`'s chain is valid; `base` and `bda` outlive its use.
    unsafe fn enable<'a>(
        &mut self,
        info: &mut vk::DeviceCreateInfo<'a>,
        base: &'a mut vk::PhysicalDeviceFeatures,
        bda: &'a mut vk::PhysicalDeviceBufferDeviceAddressFeatures<'a>,
        supported: &Supported,
    ) {
        let (mut features2, mut v12, mut bda_struct) = (None, None, None);
        let mut next = info.p_next as *mut vk::BaseOutStructure<'_>;
        // SAFETY: a valid chain.
        while let Some(n) = unsafe { next.as_mut() } {
            match n.s_type {
                vk::StructureType::PHYSICAL_DEVICE_FEATURES_2 => features2 = Some(next),
                vk::StructureType::PHYSICAL_DEVICE_VULKAN_1_2_FEATURES => v12 = Some(next),
                vk::StructureType::PHYSICAL_DEVICE_BUFFER_DEVICE_ADDRESS_FEATURES => {
                    bda_struct = Some(next)
                }
                _ => {}
            }
            next = n.p_next;
        }
        match features2 {
            // SAFETY: the sType says which struct it is.
            Some(f) => self.set(unsafe {
                &mut (*f.cast::<vk::PhysicalDeviceFeatures2<'_>>())
                    .features
                    .shader_int64
            }),
            None => {
                // SAFETY: null or the application's struct.
                if let Some(app) = unsafe { info.p_enabled_features.as_ref() } {
                    *base = *app;
                }
                base.shader_int64 = vk::TRUE;
                info.p_enabled_features = base;
            }
        }
        match (v12, bda_struct) {
            (Some(v), _) => {
                // SAFETY: the sType says which struct it is.
                let v = unsafe { &mut *v.cast::<vk::PhysicalDeviceVulkan12Features<'_>>() };
                self.set(&mut v.buffer_device_address);
                if supported.int64_atomics {
                    self.set(&mut v.shader_buffer_int64_atomics);
                }
            }
            (None, Some(b)) => {
                // SAFETY: the sType says which struct it is.
                let b =
                    unsafe { &mut *b.cast::<vk::PhysicalDeviceBufferDeviceAddressFeatures<'_>>() };
                self.set(&mut b.buffer_device_address);
            }
            (None, None) => {
                bda.p_next = info.p_next as *mut _;
                info.p_next =
                    (bda as *const vk::PhysicalDeviceBufferDeviceAddressFeatures<'_>).cast();
            }
        }
    }

    fn restore(self) {
        for (flag, old) in self.0.into_iter().rev() {
            // SAFETY: the application's struct, alive for the call that set it.
            unsafe { *flag = old };
        }
    }
}

unsafe extern "system" fn destroy_device(
    device: vk::Device,
    allocator: *const vk::AllocationCallbacks<'_>,
) {
    guard((), || {
        if device == vk::Device::null() {
            return;
        }
        // SAFETY: a live dispatchable handle.
        let key = unsafe { loader::dispatch_key(device.as_raw()) };
        let Some(layer) = DEVICES.write().ok().and_then(|mut m| m.remove(&key)) else {
            return;
        };
        if let Some(served) = &layer.served {
            // The kernels' thread uses the device: it ends first.
            served.kernels_ready();
            // The device is idle (the specification's rule for vkDestroyDevice): what
            // its command buffers used, and the structures the application left, go first.
            served.commands.lock().map(|mut c| c.clear()).ok();
            served.accel.clear(&served.fns);
        }
        let fns = layer.fns.clone();
        drop(layer);
        // SAFETY: the application's call, passed on, after vkrt's objects are gone.
        unsafe { (fns.fp_v1_0().destroy_device)(device, allocator) };
    })
}
