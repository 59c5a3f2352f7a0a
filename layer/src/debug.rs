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

/// An entry point of the four: a device and one info struct.
type Entry<T> = unsafe extern "system" fn(vk::Device, *const T) -> vk::Result;

/// Passes the call `name` on to the next layer unless `ours` (the object is the layer's
/// own): what each of the four entry points does.
///
/// # Safety
/// `device` is live, `info` the application's valid struct, and `Entry<T>` the type of
/// `name`'s entry point.
unsafe fn pass_on<T>(device: vk::Device, info: *const T, ours: bool, name: &CStr) -> vk::Result {
    guard(vk::Result::SUCCESS, || {
        if ours {
            return vk::Result::SUCCESS;
        }
        let Some(layer) = lookup(device) else {
            return vk::Result::SUCCESS;
        };
        // SAFETY: the next layer's entry point with a live device.
        let Some(f) = (unsafe { (layer.next_gdpa)(device, name.as_ptr()) }) else {
            return vk::Result::SUCCESS;
        };
        // SAFETY: the loader's pointer for `name`, of the type the caller names.
        let f = unsafe { std::mem::transmute::<unsafe extern "system" fn(), Entry<T>>(f) };
        // SAFETY: the application's arguments, passed on.
        unsafe { f(device, info) }
    })
}

unsafe extern "system" fn set_name(
    device: vk::Device,
    info: *const vk::DebugUtilsObjectNameInfoEXT<'_>,
) -> vk::Result {
    // SAFETY: the application's valid struct; the entry point's own type.
    unsafe {
        let ours = own((*info).object_type);
        pass_on(device, info, ours, c"vkSetDebugUtilsObjectNameEXT")
    }
}

unsafe extern "system" fn set_tag(
    device: vk::Device,
    info: *const vk::DebugUtilsObjectTagInfoEXT<'_>,
) -> vk::Result {
    // SAFETY: as above.
    unsafe {
        let ours = own((*info).object_type);
        pass_on(device, info, ours, c"vkSetDebugUtilsObjectTagEXT")
    }
}

unsafe extern "system" fn marker_name(
    device: vk::Device,
    info: *const vk::DebugMarkerObjectNameInfoEXT<'_>,
) -> vk::Result {
    // SAFETY: as above.
    unsafe {
        let ours = own_marker((*info).object_type);
        pass_on(device, info, ours, c"vkDebugMarkerSetObjectNameEXT")
    }
}

unsafe extern "system" fn marker_tag(
    device: vk::Device,
    info: *const vk::DebugMarkerObjectTagInfoEXT<'_>,
) -> vk::Result {
    // SAFETY: as above.
    unsafe {
        let ours = own_marker((*info).object_type);
        pass_on(device, info, ours, c"vkDebugMarkerSetObjectTagEXT")
    }
}
