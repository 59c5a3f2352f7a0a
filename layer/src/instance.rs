//! The instance: its creation and the physical-device queries — extensions, features,
//! properties and formats — answered for the devices the layer serves.

use std::collections::HashMap;
use std::ffi::{c_char, c_void, CStr};
use std::sync::{Arc, LazyLock, Mutex, RwLock};

use ash::vk;
use ash::vk::Handle;

use crate::loader::{self, LayerInstanceCreateInfo, PfnGetPhysicalDeviceProcAddr};
use crate::{device, guard, pfn, FORCE_VARIABLE, LAYER_NAME};

/// What the layer keeps of an instance.
pub struct LayerInstance {
    pub handle: vk::Instance,
    pub next_gpdpa: Option<PfnGetPhysicalDeviceProcAddr>,
    pub next_gipa: vk::PFN_vkGetInstanceProcAddr,
    /// The next layer's entry points.
    pub entry: ash::Entry,
    pub fns: ash::Instance,
    /// The application's `apiVersion` (1.0 where it gave none).
    pub api_version: u32,
    /// `VKRT_LAYER_FORCE=1` when the instance was created.
    pub force: bool,
    /// Whether any of its physical devices is served: otherwise its physical-device
    /// queries are the next layer's own, not intercepted.
    pub active: bool,
    served: Mutex<HashMap<vk::PhysicalDevice, bool>>,
}

static INSTANCES: LazyLock<RwLock<HashMap<usize, Arc<LayerInstance>>>> =
    LazyLock::new(Default::default);

/// The layer's state of the instance `handle` (or of a physical device of it: they share
/// the dispatch key).
pub fn lookup<H: Handle>(handle: H) -> Option<Arc<LayerInstance>> {
    let raw = handle.as_raw();
    if raw == 0 {
        return None;
    }
    // SAFETY: a live dispatchable handle (the loader's contract for every call).
    let key = unsafe { loader::dispatch_key(raw) };
    INSTANCES.read().ok()?.get(&key).cloned()
}

/// The extensions the layer adds, with their specification versions.
pub const PROVIDED: [(&CStr, u32); 3] = [
    (ash::khr::acceleration_structure::NAME, 13),
    (ash::khr::ray_query::NAME, 1),
    (ash::khr::deferred_host_operations::NAME, 4),
];

/// The driver's extensions the layer hides on a device it serves: its own versions of
/// those it adds, and those that need a driver's acceleration structures.
const HIDDEN: [&CStr; 8] = [
    ash::khr::acceleration_structure::NAME,
    ash::khr::ray_query::NAME,
    ash::khr::deferred_host_operations::NAME,
    ash::khr::ray_tracing_pipeline::NAME,
    ash::khr::ray_tracing_maintenance1::NAME,
    ash::khr::ray_tracing_position_fetch::NAME,
    ash::ext::opacity_micromap::NAME,
    ash::nv::ray_tracing_motion_blur::NAME,
];

impl LayerInstance {
    /// The driver's device extensions (below the layer).
    pub fn driver_extensions(&self, pd: vk::PhysicalDevice) -> Vec<vk::ExtensionProperties> {
        // SAFETY: a physical device of this instance.
        unsafe { self.fns.enumerate_device_extension_properties(pd) }.unwrap_or_default()
    }

    /// Whether the layer serves `pd`: forced on, or its driver has no ray query.
    pub fn serves(&self, pd: vk::PhysicalDevice) -> bool {
        if let Some(&s) = self
            .served
            .lock()
            .ok()
            .and_then(|m| m.get(&pd).copied())
            .as_ref()
        {
            return s;
        }
        let native = self
            .driver_extensions(pd)
            .iter()
            .any(|e| e.extension_name_as_c_str() == Ok(ash::khr::ray_query::NAME));
        let s = self.force || !native;
        if let Ok(mut m) = self.served.lock() {
            m.insert(pd, s);
        }
        s
    }
}

/// The layer's `vkGetInstanceProcAddr`.
///
/// # Safety
/// `instance` is null or live.
pub unsafe fn get_instance_proc_addr(
    instance: vk::Instance,
    name: &CStr,
) -> vk::PFN_vkVoidFunction {
    match name.to_bytes() {
        b"vkGetInstanceProcAddr" => {
            return pfn!(crate::vkGetInstanceProcAddr, vk::PFN_vkGetInstanceProcAddr)
        }
        b"vkCreateInstance" => return pfn!(create_instance, vk::PFN_vkCreateInstance),
        _ => {}
    }
    let layer = lookup(instance)?;
    match name.to_bytes() {
        b"vkDestroyInstance" => return pfn!(destroy_instance, vk::PFN_vkDestroyInstance),
        b"vkCreateDevice" => return pfn!(device::create_device, vk::PFN_vkCreateDevice),
        b"vkGetDeviceProcAddr" => {
            return pfn!(crate::vkGetDeviceProcAddr, vk::PFN_vkGetDeviceProcAddr)
        }
        _ => {}
    }
    if layer.active {
        if let Some(f) = physical_device_function(name) {
            return Some(f);
        }
        // Device functions asked through the instance: the layer's, which pass through on
        // devices it does not serve.
        if let Some(f) = device::intercepted(name) {
            return Some(f);
        }
    }
    // SAFETY: the next layer's entry point with the caller's arguments.
    unsafe { (layer.next_gipa)(instance, name.as_ptr()) }
}

fn physical_device_function(name: &CStr) -> vk::PFN_vkVoidFunction {
    match name.to_bytes() {
        b"vkEnumerateDeviceExtensionProperties" => pfn!(
            enumerate_device_extension_properties,
            vk::PFN_vkEnumerateDeviceExtensionProperties
        ),
        b"vkGetPhysicalDeviceFeatures2" | b"vkGetPhysicalDeviceFeatures2KHR" => {
            pfn!(get_features2, vk::PFN_vkGetPhysicalDeviceFeatures2)
        }
        b"vkGetPhysicalDeviceProperties2" | b"vkGetPhysicalDeviceProperties2KHR" => {
            pfn!(get_properties2, vk::PFN_vkGetPhysicalDeviceProperties2)
        }
        b"vkGetPhysicalDeviceFormatProperties" => pfn!(
            get_format_properties,
            vk::PFN_vkGetPhysicalDeviceFormatProperties
        ),
        b"vkGetPhysicalDeviceFormatProperties2" | b"vkGetPhysicalDeviceFormatProperties2KHR" => {
            pfn!(
                get_format_properties2,
                vk::PFN_vkGetPhysicalDeviceFormatProperties2
            )
        }
        _ => None,
    }
}

unsafe extern "system" fn create_instance(
    info: *const vk::InstanceCreateInfo<'_>,
    allocator: *const vk::AllocationCallbacks<'_>,
    out: *mut vk::Instance,
) -> vk::Result {
    guard(vk::Result::ERROR_INITIALIZATION_FAILED, || {
        // SAFETY: the loader's contract: a valid create info whose chain holds its link.
        let info_ref = unsafe { &*info };
        // SAFETY: a valid chain.
        let link: *mut LayerInstanceCreateInfo = unsafe {
            loader::find_link(
                info_ref.p_next.cast(),
                vk::StructureType::LOADER_INSTANCE_CREATE_INFO,
            )
        };
        // SAFETY: the loader's link, valid for this call.
        let Some(link) = (unsafe { link.as_mut() }) else {
            return vk::Result::ERROR_INITIALIZATION_FAILED;
        };
        // SAFETY: as above.
        let layer_info = unsafe { &*link.layer_info };
        let next_gipa = layer_info.next_get_instance_proc_addr;
        let next_gpdpa = layer_info.next_get_physical_device_proc_addr;
        // The next layer finds its own link.
        link.layer_info = layer_info.next;
        // SAFETY: the next layer's global entry point.
        let Some(create) =
            (unsafe { next_gipa(vk::Instance::null(), c"vkCreateInstance".as_ptr()) })
        else {
            return vk::Result::ERROR_INITIALIZATION_FAILED;
        };
        // SAFETY: the loader's pointer is vkCreateInstance's.
        let create: vk::PFN_vkCreateInstance = unsafe { std::mem::transmute(create) };
        // SAFETY: the application's arguments, passed on.
        let r = unsafe { create(info, allocator, out) };
        if r != vk::Result::SUCCESS {
            return r;
        }
        // SAFETY: created above.
        let handle = unsafe { *out };
        // The next layer's vkGetInstanceProcAddr loads every instance function. Global
        // functions are not asked for: a layer need not answer them for a null instance
        // (the validation layer faults), and vkrt uses none on an adopted instance.
        let entry = ash::Entry::from_parts_1_1(
            ash::StaticFn {
                get_instance_proc_addr: next_gipa,
            },
            ash::EntryFnV1_0::load(|_| std::ptr::null()),
            ash::EntryFnV1_1::load(|_| std::ptr::null()),
        );
        // SAFETY: a live instance of that entry.
        let fns = unsafe { ash::Instance::load(entry.static_fn(), handle) };
        // SAFETY: pApplicationInfo is null or valid.
        let api_version = unsafe { info_ref.p_application_info.as_ref() }
            .map(|a| a.api_version)
            .filter(|&v| v != 0)
            .unwrap_or(vk::API_VERSION_1_0);
        let force = std::env::var(FORCE_VARIABLE).is_ok_and(|v| v == "1");
        let mut layer = LayerInstance {
            handle,
            next_gpdpa,
            next_gipa,
            entry,
            fns,
            api_version,
            force,
            active: false,
            served: Mutex::new(HashMap::new()),
        };
        // SAFETY: a live instance.
        let devices = unsafe { layer.fns.enumerate_physical_devices() }.unwrap_or_default();
        layer.active = devices.iter().any(|&pd| layer.serves(pd));
        // SAFETY: a live dispatchable handle.
        let key = unsafe { loader::dispatch_key(handle.as_raw()) };
        if let Ok(mut m) = INSTANCES.write() {
            m.insert(key, Arc::new(layer));
        }
        vk::Result::SUCCESS
    })
}

unsafe extern "system" fn destroy_instance(
    instance: vk::Instance,
    allocator: *const vk::AllocationCallbacks<'_>,
) {
    guard((), || {
        if instance == vk::Instance::null() {
            return;
        }
        // SAFETY: a live dispatchable handle.
        let key = unsafe { loader::dispatch_key(instance.as_raw()) };
        let layer = INSTANCES.write().ok().and_then(|mut m| m.remove(&key));
        if let Some(layer) = layer {
            // SAFETY: the application's call, passed on.
            unsafe { (layer.fns.fp_v1_0().destroy_instance)(instance, allocator) };
        }
    })
}

/// Writes `items` to the application's count-and-array pair, as every enumeration does.
///
/// # Safety
/// `count` is valid; `out` is null or holds `*count` elements.
pub unsafe fn write_enumeration<T: Copy>(items: &[T], count: *mut u32, out: *mut T) -> vk::Result {
    // SAFETY: the caller's contract.
    let count = unsafe { &mut *count };
    if out.is_null() {
        *count = items.len() as u32;
        return vk::Result::SUCCESS;
    }
    let n = (*count as usize).min(items.len());
    // SAFETY: `out` holds `*count >= n` elements.
    unsafe { std::ptr::copy_nonoverlapping(items.as_ptr(), out, n) };
    *count = n as u32;
    if n < items.len() {
        vk::Result::INCOMPLETE
    } else {
        vk::Result::SUCCESS
    }
}

fn extension(name: &CStr, version: u32) -> vk::ExtensionProperties {
    let mut e = vk::ExtensionProperties {
        spec_version: version,
        ..Default::default()
    };
    for (d, s) in e.extension_name.iter_mut().zip(name.to_bytes()) {
        *d = *s as c_char;
    }
    e
}

/// The layer's own extensions: what `vkEnumerateDeviceExtensionProperties` lists for it.
pub fn provided_extensions() -> Vec<vk::ExtensionProperties> {
    PROVIDED.iter().map(|(n, v)| extension(n, *v)).collect()
}

unsafe extern "system" fn enumerate_device_extension_properties(
    pd: vk::PhysicalDevice,
    layer_name: *const c_char,
    count: *mut u32,
    out: *mut vk::ExtensionProperties,
) -> vk::Result {
    guard(vk::Result::ERROR_INITIALIZATION_FAILED, || {
        let Some(layer) = lookup(pd) else {
            return vk::Result::ERROR_INITIALIZATION_FAILED;
        };
        // SAFETY: null or a NUL-terminated name.
        let asked = unsafe { layer_name.as_ref() }.map(|_| unsafe { CStr::from_ptr(layer_name) });
        let items = match asked {
            Some(n) if n == LAYER_NAME => provided_extensions(),
            Some(_) => {
                // Another layer's: the next layer answers.
                // SAFETY: the application's arguments, passed on.
                return unsafe {
                    (layer.fns.fp_v1_0().enumerate_device_extension_properties)(
                        pd, layer_name, count, out,
                    )
                };
            }
            None => {
                let mut items = layer.driver_extensions(pd);
                if layer.serves(pd) {
                    items.retain(|e| !HIDDEN.iter().any(|h| e.extension_name_as_c_str() == Ok(*h)));
                    items.extend(provided_extensions());
                }
                items
            }
        };
        // SAFETY: the application's count and array.
        unsafe { write_enumeration(&items, count, out) }
    })
}

/// A struct of a `pNext` chain taken out (its predecessor, itself), to put back.
pub struct Unlinked(
    Vec<(
        *mut vk::BaseOutStructure<'static>,
        *mut vk::BaseOutStructure<'static>,
    )>,
);

/// Takes the structs of `types` out of the chain after `head`, so that the driver never
/// sees an sType of an extension it does not have.
///
/// # Safety
/// `head` starts a valid chain, which stays alive and unmodified until `relink`.
pub unsafe fn unlink(head: *mut c_void, types: &[vk::StructureType]) -> Unlinked {
    let mut removed = Vec::new();
    let mut prev = head.cast::<vk::BaseOutStructure<'static>>();
    // SAFETY: a valid chain.
    while let Some(p) = unsafe { prev.as_mut() } {
        let node = p.p_next;
        // SAFETY: a valid chain.
        let Some(n) = (unsafe { node.as_mut() }) else {
            break;
        };
        if types.contains(&n.s_type) {
            p.p_next = n.p_next;
            removed.push((prev, node));
        } else {
            prev = node;
        }
    }
    Unlinked(removed)
}

impl Unlinked {
    /// Puts the structs back where they were.
    pub fn relink(self) {
        for &(prev, node) in self.0.iter().rev() {
            // SAFETY: `unlink`'s contract: both are still alive.
            unsafe { (*prev).p_next = node };
        }
    }

    /// The structs taken out, to fill.
    pub fn nodes(&self) -> impl Iterator<Item = *mut vk::BaseOutStructure<'static>> + '_ {
        self.0.iter().map(|&(_, n)| n)
    }
}

const FEATURE_TYPES: [vk::StructureType; 2] = [
    vk::StructureType::PHYSICAL_DEVICE_ACCELERATION_STRUCTURE_FEATURES_KHR,
    vk::StructureType::PHYSICAL_DEVICE_RAY_QUERY_FEATURES_KHR,
];

unsafe extern "system" fn get_features2(
    pd: vk::PhysicalDevice,
    features: *mut vk::PhysicalDeviceFeatures2<'_>,
) {
    guard((), || {
        let Some(layer) = lookup(pd) else { return };
        let next = layer.fns.fp_v1_1().get_physical_device_features2;
        if !layer.serves(pd) {
            // SAFETY: the application's arguments, passed on.
            return unsafe { next(pd, features) };
        }
        // SAFETY: the application's valid chain, restored before returning.
        let ours = unsafe { unlink(features.cast(), &FEATURE_TYPES) };
        // SAFETY: the application's arguments, less the layer's structs.
        unsafe { next(pd, features) };
        for node in ours.nodes() {
            // SAFETY: a struct of the sType it says.
            unsafe { fill_feature(node) };
        }
        ours.relink();
    })
}

/// What the layer supports of its extensions' features.
unsafe fn fill_feature(node: *mut vk::BaseOutStructure<'static>) {
    // SAFETY: the caller's contract.
    match unsafe { (*node).s_type } {
        vk::StructureType::PHYSICAL_DEVICE_ACCELERATION_STRUCTURE_FEATURES_KHR => {
            // SAFETY: the sType says which struct it is.
            let f = unsafe {
                &mut *node.cast::<vk::PhysicalDeviceAccelerationStructureFeaturesKHR<'_>>()
            };
            f.acceleration_structure = vk::TRUE;
            // Handles are minted by the layer: no replay at an address.
            f.acceleration_structure_capture_replay = vk::FALSE;
            // Builds take the counts at record time (sizes are placed from them).
            f.acceleration_structure_indirect_build = vk::FALSE;
            // vkrt builds on the device only.
            f.acceleration_structure_host_commands = vk::FALSE;
            f.descriptor_binding_acceleration_structure_update_after_bind = vk::FALSE;
        }
        vk::StructureType::PHYSICAL_DEVICE_RAY_QUERY_FEATURES_KHR => {
            // SAFETY: the sType says which struct it is.
            let f = unsafe { &mut *node.cast::<vk::PhysicalDeviceRayQueryFeaturesKHR<'_>>() };
            f.ray_query = vk::TRUE;
        }
        _ => {}
    }
}

unsafe extern "system" fn get_properties2(
    pd: vk::PhysicalDevice,
    properties: *mut vk::PhysicalDeviceProperties2<'_>,
) {
    guard((), || {
        let Some(layer) = lookup(pd) else { return };
        let next = layer.fns.fp_v1_1().get_physical_device_properties2;
        if !layer.serves(pd) {
            // SAFETY: the application's arguments, passed on.
            return unsafe { next(pd, properties) };
        }
        let types = [vk::StructureType::PHYSICAL_DEVICE_ACCELERATION_STRUCTURE_PROPERTIES_KHR];
        // SAFETY: the application's valid chain, restored before returning.
        let ours = unsafe { unlink(properties.cast(), &types) };
        // SAFETY: the application's arguments, less the layer's structs.
        unsafe { next(pd, properties) };
        // SAFETY: filled by the driver above.
        let limits = unsafe { (*properties).properties.limits };
        for node in ours.nodes() {
            // SAFETY: the only sType unlinked.
            let p = unsafe {
                &mut *node.cast::<vk::PhysicalDeviceAccelerationStructurePropertiesKHR<'_>>()
            };
            fill_properties(p, &limits);
        }
        ours.relink();
    })
}

/// The specification's required limits: apps ask for them (wgpu's ray-query examples
/// refuse less). vkrt's builders place primitives in storage buffers, so a build past
/// what `maxStorageBufferRange` holds fails at its sizes (docs/layer.md).
fn fill_properties(
    p: &mut vk::PhysicalDeviceAccelerationStructurePropertiesKHR<'_>,
    limits: &vk::PhysicalDeviceLimits,
) {
    p.max_geometry_count = 1 << 24;
    p.max_instance_count = 1 << 24;
    p.max_primitive_count = 1 << 29;
    // A structure is a uniform texel buffer to the lowered shaders.
    let per_stage = limits.max_per_stage_descriptor_sampled_images;
    let per_set = limits.max_descriptor_set_sampled_images;
    p.max_per_stage_descriptor_acceleration_structures = per_stage;
    p.max_per_stage_descriptor_update_after_bind_acceleration_structures = per_stage;
    p.max_descriptor_set_acceleration_structures = per_set;
    p.max_descriptor_set_update_after_bind_acceleration_structures = per_set;
    p.min_acceleration_structure_scratch_offset_alignment = 256;
}

/// The vertex formats vkrt's builders read: the six the extension requires.
fn is_vertex_format(format: vk::Format) -> bool {
    vkrt::VertexFormat::from_vk(format).is_some()
}

unsafe extern "system" fn get_format_properties(
    pd: vk::PhysicalDevice,
    format: vk::Format,
    out: *mut vk::FormatProperties,
) {
    guard((), || {
        let Some(layer) = lookup(pd) else { return };
        // SAFETY: the application's arguments, passed on.
        unsafe { (layer.fns.fp_v1_0().get_physical_device_format_properties)(pd, format, out) };
        if layer.serves(pd) && is_vertex_format(format) {
            // SAFETY: filled above.
            unsafe {
                (*out).buffer_features |=
                    vk::FormatFeatureFlags::ACCELERATION_STRUCTURE_VERTEX_BUFFER_KHR
            };
        }
    })
}

unsafe extern "system" fn get_format_properties2(
    pd: vk::PhysicalDevice,
    format: vk::Format,
    out: *mut vk::FormatProperties2<'_>,
) {
    guard((), || {
        let Some(layer) = lookup(pd) else { return };
        // SAFETY: the application's arguments, passed on.
        unsafe { (layer.fns.fp_v1_1().get_physical_device_format_properties2)(pd, format, out) };
        if !(layer.serves(pd) && is_vertex_format(format)) {
            return;
        }
        // SAFETY: filled above; its chain is the application's.
        let out = unsafe { &mut *out };
        out.format_properties.buffer_features |=
            vk::FormatFeatureFlags::ACCELERATION_STRUCTURE_VERTEX_BUFFER_KHR;
        let mut next = out.p_next.cast::<vk::BaseOutStructure<'_>>();
        // SAFETY: a valid chain.
        while let Some(n) = unsafe { next.as_mut() } {
            if n.s_type == vk::StructureType::FORMAT_PROPERTIES_3 {
                // SAFETY: the sType says which struct it is.
                let p3 = unsafe { &mut *next.cast::<vk::FormatProperties3<'_>>() };
                p3.buffer_features |=
                    vk::FormatFeatureFlags2::ACCELERATION_STRUCTURE_VERTEX_BUFFER_KHR;
            }
            next = n.p_next;
        }
    })
}
