//! The loader's layer interface (`vk_layer.h`), written out: what the loader hands a layer
//! at instance and device creation, and the interface negotiation of version 2.

use std::ffi::{c_char, c_void};

use ash::vk;

/// `PFN_GetPhysicalDeviceProcAddr`.
pub type PfnGetPhysicalDeviceProcAddr =
    unsafe extern "system" fn(vk::Instance, *const c_char) -> vk::PFN_vkVoidFunction;

/// `VkLayerFunction`: what a loader create info in the chain carries.
pub const LAYER_LINK_INFO: u32 = 0;

/// `VkLayerInstanceLink`: the next layer's entry points.
#[repr(C)]
pub struct LayerInstanceLink {
    pub next: *mut LayerInstanceLink,
    pub next_get_instance_proc_addr: vk::PFN_vkGetInstanceProcAddr,
    pub next_get_physical_device_proc_addr: Option<PfnGetPhysicalDeviceProcAddr>,
}

/// `VkLayerInstanceCreateInfo` (`VK_STRUCTURE_TYPE_LOADER_INSTANCE_CREATE_INFO`). Its union
/// is two pointers wide (`layerDevice`); only `pLayerInfo` is read.
#[repr(C)]
pub struct LayerInstanceCreateInfo {
    pub s_type: vk::StructureType,
    pub p_next: *const c_void,
    pub function: u32,
    pub layer_info: *mut LayerInstanceLink,
    _union_rest: *mut c_void,
}

/// `VkLayerDeviceLink`.
#[repr(C)]
pub struct LayerDeviceLink {
    pub next: *mut LayerDeviceLink,
    pub next_get_instance_proc_addr: vk::PFN_vkGetInstanceProcAddr,
    pub next_get_device_proc_addr: vk::PFN_vkGetDeviceProcAddr,
}

/// `VkLayerDeviceCreateInfo` (`VK_STRUCTURE_TYPE_LOADER_DEVICE_CREATE_INFO`).
#[repr(C)]
pub struct LayerDeviceCreateInfo {
    pub s_type: vk::StructureType,
    pub p_next: *const c_void,
    pub function: u32,
    pub layer_info: *mut LayerDeviceLink,
}

/// `VkNegotiateLayerInterface`.
#[repr(C)]
pub struct NegotiateLayerInterface {
    /// `LAYER_NEGOTIATE_INTERFACE_STRUCT` (1).
    pub s_type: u32,
    pub p_next: *mut c_void,
    pub loader_layer_interface_version: u32,
    pub get_instance_proc_addr: Option<vk::PFN_vkGetInstanceProcAddr>,
    pub get_device_proc_addr: Option<vk::PFN_vkGetDeviceProcAddr>,
    pub get_physical_device_proc_addr: Option<PfnGetPhysicalDeviceProcAddr>,
}

/// The negotiation struct's type tag.
pub const LAYER_NEGOTIATE_INTERFACE_STRUCT: u32 = 1;

/// The link entry of the loader's create info in `p_next` whose sType is `s_type`.
///
/// # Safety
/// `p_next` is a valid chain of Vulkan structs.
pub unsafe fn find_link<T>(mut p_next: *const c_void, s_type: vk::StructureType) -> *mut T {
    while !p_next.is_null() {
        // SAFETY: every struct in a valid chain starts with sType and pNext.
        let base = unsafe { &*p_next.cast::<vk::BaseInStructure<'_>>() };
        if base.s_type == s_type {
            // SAFETY: the loader's create infos share this prefix: sType, pNext, function.
            let function = unsafe { *p_next.cast::<u8>().add(16).cast::<u32>() };
            if function == LAYER_LINK_INFO {
                return p_next as *mut T;
            }
        }
        p_next = base.p_next.cast();
    }
    std::ptr::null_mut()
}

/// The dispatch key of a dispatchable handle: the loader's table pointer at its start,
/// shared by an instance and its physical devices, and by a device, its queues and its
/// command buffers.
///
/// # Safety
/// `raw` is a live dispatchable handle.
pub unsafe fn dispatch_key(raw: u64) -> usize {
    // SAFETY: the caller's contract: a dispatchable handle points at its dispatch table.
    unsafe { *(raw as usize as *const usize) }
}
