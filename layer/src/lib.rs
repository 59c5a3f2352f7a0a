//! `VK_LAYER_VKRT_ray_query`: a Vulkan layer that gives an unmodified application
//! `VK_KHR_acceleration_structure`, `VK_KHR_ray_query` and `VK_KHR_deferred_host_operations`
//! on a device whose driver has no ray query, through vkrt's builders and walk.
//!
//! Where the driver has `VK_KHR_ray_query` the layer is inert: it intercepts nothing on
//! that device (`VKRT_LAYER_FORCE=1` turns it on anyway and hides the driver's own
//! ray-tracing extensions, for tests). On the devices it serves:
//!
//! - the physical-device queries report the three extensions, their features and
//!   properties (`instance`);
//! - device creation strips them from the driver's create info and enables what vkrt's
//!   walk needs (`bufferDeviceAddress`, `shaderInt64`), or fails with
//!   `VK_ERROR_FEATURE_NOT_PRESENT` naming what the device lacks (`device`);
//! - acceleration structures live in the application's buffers and are built by vkrt's
//!   builders into its command buffers (`accel`), whose compute state is restored after
//!   (`commands`);
//! - shader modules go through `vkrt::spirv::lower_ray_queries` (`shaders`), and
//!   acceleration-structure descriptors become the uniform texel buffers the lowered
//!   shaders read (`descriptors`);
//! - debug names of the layer's own handles stop at the layer (`debug`).
//!
//! Every entry point catches panics (`guard`): none crosses into the loader.

mod accel;
mod commands;
mod debug;
mod deferred;
mod descriptors;
mod device;
mod instance;
pub mod loader;
mod memory;
mod queries;
mod shaders;
mod sync;

use std::ffi::{c_char, CStr};
use std::panic::{catch_unwind, AssertUnwindSafe};

use ash::vk;

/// The layer's name, as its manifest and `ppEnabledLayerNames` spell it.
pub const LAYER_NAME: &CStr = c"VK_LAYER_VKRT_ray_query";

/// The environment variable that turns the layer on where the driver has ray query.
pub const FORCE_VARIABLE: &str = "VKRT_LAYER_FORCE";

/// The environment variable that makes the layer say, after each command it records for
/// vkrt, how many Vulkan objects vkrt created while recording it (`1`).
pub const STATS_VARIABLE: &str = "VKRT_LAYER_STATS";

/// Logs (where [`STATS_VARIABLE`] is `1`) the objects `ctx` created since `before` while
/// `call` was recorded.
pub(crate) fn stats(call: &str, ctx: &vkrt::Context, before: vkrt::gpu::Traffic) {
    static ON: std::sync::LazyLock<bool> =
        std::sync::LazyLock::new(|| std::env::var(STATS_VARIABLE).is_ok_and(|v| v.trim() == "1"));
    if *ON {
        let created = (ctx.traffic() - before).objects_created;
        log(&format!(
            "stats: {call}: {created} objects created while recording"
        ));
    }
}

/// Runs `f`, turning a panic into `fallback` and a log line: no panic unwinds into the
/// loader or the application.
pub(crate) fn guard<R>(fallback: R, f: impl FnOnce() -> R) -> R {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(r) => r,
        Err(e) => {
            let what = e
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| e.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            log(&format!(
                "internal error (caught at the layer's boundary): {what}"
            ));
            fallback
        }
    }
}

/// A map keyed by handles and dispatch keys: pointers or driver-chosen integers, hashed by
/// one multiplication (the maps sit on the path of every intercepted command).
pub(crate) type HandleMap<K, V> =
    std::collections::HashMap<K, V, std::hash::BuildHasherDefault<HandleHasher>>;

/// Fibonacci hashing of a single integer key.
#[derive(Default)]
pub(crate) struct HandleHasher(u64);

impl std::hash::Hasher for HandleHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(8) ^ u64::from(b)).wrapping_mul(0x9e37_79b9_7f4a_7c15);
        }
    }

    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0 ^ v).wrapping_mul(0x9e37_79b9_7f4a_7c15);
    }

    fn write_usize(&mut self, v: usize) {
        self.write_u64(v as u64);
    }
}

/// One line on standard error, as the loader's and Mesa's messages go.
pub(crate) fn log(message: &str) {
    eprintln!("vkrt layer: {message}");
}

/// A function pointer as the loader's tables hold it.
macro_rules! pfn {
    ($f:expr, $t:ty) => {{
        let f: $t = $f;
        // SAFETY: a function pointer cast to the untyped pointer the loader casts back.
        Some(unsafe { std::mem::transmute::<$t, unsafe extern "system" fn()>(f) })
    }};
}
pub(crate) use pfn;

/// Loader interface negotiation: version 2, with `vk_layerGetPhysicalDeviceProcAddr`.
///
/// # Safety
/// Called by the loader with a valid struct.
#[no_mangle]
pub unsafe extern "system" fn vkNegotiateLoaderLayerInterfaceVersion(
    p: *mut loader::NegotiateLayerInterface,
) -> vk::Result {
    guard(vk::Result::ERROR_INITIALIZATION_FAILED, || {
        // SAFETY: the loader's contract: a valid struct, or null.
        let Some(p) = (unsafe { p.as_mut() }) else {
            return vk::Result::ERROR_INITIALIZATION_FAILED;
        };
        if p.s_type != loader::LAYER_NEGOTIATE_INTERFACE_STRUCT
            || p.loader_layer_interface_version < 2
        {
            return vk::Result::ERROR_INITIALIZATION_FAILED;
        }
        p.loader_layer_interface_version = 2;
        p.get_instance_proc_addr = Some(vkGetInstanceProcAddr);
        p.get_device_proc_addr = Some(vkGetDeviceProcAddr);
        p.get_physical_device_proc_addr = Some(vk_layerGetPhysicalDeviceProcAddr);
        vk::Result::SUCCESS
    })
}

/// The layer's `vkGetInstanceProcAddr`.
///
/// # Safety
/// As `vkGetInstanceProcAddr`.
#[no_mangle]
pub unsafe extern "system" fn vkGetInstanceProcAddr(
    instance: vk::Instance,
    name: *const c_char,
) -> vk::PFN_vkVoidFunction {
    guard(None, || {
        // SAFETY: the loader's contract: a NUL-terminated name.
        let name = unsafe { CStr::from_ptr(name) };
        // SAFETY: the handle is null or a live instance.
        unsafe { instance::get_instance_proc_addr(instance, name) }
    })
}

/// The layer's `vkGetDeviceProcAddr`.
///
/// # Safety
/// As `vkGetDeviceProcAddr`.
#[no_mangle]
pub unsafe extern "system" fn vkGetDeviceProcAddr(
    device: vk::Device,
    name: *const c_char,
) -> vk::PFN_vkVoidFunction {
    guard(None, || {
        // SAFETY: the loader's contract: a NUL-terminated name.
        let name = unsafe { CStr::from_ptr(name) };
        // SAFETY: a live device.
        unsafe { device::get_device_proc_addr(device, name) }
    })
}

/// The layer's `vk_layerGetPhysicalDeviceProcAddr`: physical-device functions the loader
/// does not know; the layer adds none, so this passes the next layer's.
///
/// # Safety
/// As the loader's interface says.
#[no_mangle]
pub unsafe extern "system" fn vk_layerGetPhysicalDeviceProcAddr(
    instance: vk::Instance,
    name: *const c_char,
) -> vk::PFN_vkVoidFunction {
    guard(None, || {
        let layer = instance::lookup(instance)?;
        // SAFETY: the next layer's own entry point, with the caller's arguments.
        layer.next_gpdpa.and_then(|f| unsafe { f(instance, name) })
    })
}
