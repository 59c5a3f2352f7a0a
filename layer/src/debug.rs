//! Debug names and tags (`VK_EXT_debug_utils`, `VK_EXT_debug_marker`). The layer's own
//! handles (acceleration structures, deferred operations) stop here: the layers and driver
//! below would take them for objects of their own (lavapipe dereferences them). Every other
//! object's name passes on.

use std::ffi::CStr;

use ash::vk;

use crate::device::lookup;
use crate::{guard, pfn};

pub fn function(name: &[u8]) -> vk::PFN_vkVoidFunction {
    match name {
        b"vkSetDebugUtilsObjectNameEXT" => {
            pfn!(set_name, vk::PFN_vkSetDebugUtilsObjectNameEXT)
        }
        b"vkSetDebugUtilsObjectTagEXT" => pfn!(set_tag, vk::PFN_vkSetDebugUtilsObjectTagEXT),
        b"vkDebugMarkerSetObjectNameEXT" => {
            pfn!(marker_name, vk::PFN_vkDebugMarkerSetObjectNameEXT)
        }
        b"vkDebugMarkerSetObjectTagEXT" => pfn!(marker_tag, vk::PFN_vkDebugMarkerSetObjectTagEXT),
        _ => None,
    }
}

/// Whether objects of `ty` are the layer's own handles.
fn own(ty: vk::ObjectType) -> bool {
    matches!(
        ty,
        vk::ObjectType::ACCELERATION_STRUCTURE_KHR | vk::ObjectType::DEFERRED_OPERATION_KHR
    )
}

/// Whether debug-report objects of `ty` are the layer's own handles.
fn own_marker(ty: vk::DebugReportObjectTypeEXT) -> bool {
    ty == vk::DebugReportObjectTypeEXT::ACCELERATION_STRUCTURE_KHR
}

/// The next layer's `name` on `device`, as `F`.
///
/// # Safety
/// `device` is live and `F` is the type of `name`'s entry point.
unsafe fn next<F: Copy>(device: vk::Device, name: &CStr) -> Option<F> {
    let layer = lookup(device)?;
    // SAFETY: the next layer's entry point with a live device.
    let f = unsafe { (layer.next_gdpa)(device, name.as_ptr()) }?;
    debug_assert_eq!(size_of::<F>(), size_of::<unsafe extern "system" fn()>());
    // SAFETY: the loader's pointer for `name`, whose type the caller names.
    Some(unsafe { std::mem::transmute_copy::<unsafe extern "system" fn(), F>(&f) })
}

unsafe extern "system" fn set_name(
    device: vk::Device,
    info: *const vk::DebugUtilsObjectNameInfoEXT<'_>,
) -> vk::Result {
    guard(vk::Result::SUCCESS, || {
        // SAFETY: the application's valid struct.
        if own(unsafe { (*info).object_type }) {
            return vk::Result::SUCCESS;
        }
        // SAFETY: the entry point's own type; the caller's arguments.
        match unsafe {
            next::<vk::PFN_vkSetDebugUtilsObjectNameEXT>(device, c"vkSetDebugUtilsObjectNameEXT")
        } {
            // SAFETY: as above.
            Some(f) => unsafe { f(device, info) },
            None => vk::Result::SUCCESS,
        }
    })
}

unsafe extern "system" fn set_tag(
    device: vk::Device,
    info: *const vk::DebugUtilsObjectTagInfoEXT<'_>,
) -> vk::Result {
    guard(vk::Result::SUCCESS, || {
        // SAFETY: the application's valid struct.
        if own(unsafe { (*info).object_type }) {
            return vk::Result::SUCCESS;
        }
        // SAFETY: the entry point's own type; the caller's arguments.
        match unsafe {
            next::<vk::PFN_vkSetDebugUtilsObjectTagEXT>(device, c"vkSetDebugUtilsObjectTagEXT")
        } {
            // SAFETY: as above.
            Some(f) => unsafe { f(device, info) },
            None => vk::Result::SUCCESS,
        }
    })
}

unsafe extern "system" fn marker_name(
    device: vk::Device,
    info: *const vk::DebugMarkerObjectNameInfoEXT<'_>,
) -> vk::Result {
    guard(vk::Result::SUCCESS, || {
        // SAFETY: the application's valid struct.
        if own_marker(unsafe { (*info).object_type }) {
            return vk::Result::SUCCESS;
        }
        // SAFETY: the entry point's own type; the caller's arguments.
        match unsafe {
            next::<vk::PFN_vkDebugMarkerSetObjectNameEXT>(device, c"vkDebugMarkerSetObjectNameEXT")
        } {
            // SAFETY: as above.
            Some(f) => unsafe { f(device, info) },
            None => vk::Result::SUCCESS,
        }
    })
}

unsafe extern "system" fn marker_tag(
    device: vk::Device,
    info: *const vk::DebugMarkerObjectTagInfoEXT<'_>,
) -> vk::Result {
    guard(vk::Result::SUCCESS, || {
        // SAFETY: the application's valid struct.
        if own_marker(unsafe { (*info).object_type }) {
            return vk::Result::SUCCESS;
        }
        // SAFETY: the entry point's own type; the caller's arguments.
        match unsafe {
            next::<vk::PFN_vkDebugMarkerSetObjectTagEXT>(device, c"vkDebugMarkerSetObjectTagEXT")
        } {
            // SAFETY: as above.
            Some(f) => unsafe { f(device, info) },
            None => vk::Result::SUCCESS,
        }
    })
}
