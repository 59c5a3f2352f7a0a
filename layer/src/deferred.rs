//! `VK_KHR_deferred_host_operations`, which `VK_KHR_acceleration_structure` requires: the
//! layer defers nothing (it has no host commands), so an operation is complete from its
//! creation.

use ash::vk;

use crate::{guard, pfn};

pub fn function(name: &[u8]) -> vk::PFN_vkVoidFunction {
    match name {
        b"vkCreateDeferredOperationKHR" => pfn!(create, vk::PFN_vkCreateDeferredOperationKHR),
        b"vkDestroyDeferredOperationKHR" => pfn!(destroy, vk::PFN_vkDestroyDeferredOperationKHR),
        b"vkGetDeferredOperationMaxConcurrencyKHR" => pfn!(
            max_concurrency,
            vk::PFN_vkGetDeferredOperationMaxConcurrencyKHR
        ),
        b"vkGetDeferredOperationResultKHR" => pfn!(result, vk::PFN_vkGetDeferredOperationResultKHR),
        b"vkDeferredOperationJoinKHR" => pfn!(join, vk::PFN_vkDeferredOperationJoinKHR),
        _ => None,
    }
}

unsafe extern "system" fn create(
    _device: vk::Device,
    _allocator: *const vk::AllocationCallbacks<'_>,
    out: *mut vk::DeferredOperationKHR,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        // A non-zero-sized cell: a distinct address per operation.
        let raw = Box::into_raw(Box::new([0u8; 1])) as usize as u64;
        // SAFETY: the application's out pointer.
        unsafe { *out = vk::Handle::from_raw(raw) };
        vk::Result::SUCCESS
    })
}

unsafe extern "system" fn destroy(
    _device: vk::Device,
    op: vk::DeferredOperationKHR,
    _allocator: *const vk::AllocationCallbacks<'_>,
) {
    guard((), || {
        let raw = vk::Handle::as_raw(op);
        if raw != 0 {
            // SAFETY: made by `create`, destroyed once (the extension's rule).
            drop(unsafe { Box::from_raw(raw as usize as *mut [u8; 1]) });
        }
    })
}

unsafe extern "system" fn max_concurrency(
    _device: vk::Device,
    _op: vk::DeferredOperationKHR,
) -> u32 {
    1
}

unsafe extern "system" fn result(_device: vk::Device, _op: vk::DeferredOperationKHR) -> vk::Result {
    vk::Result::SUCCESS
}

unsafe extern "system" fn join(_device: vk::Device, _op: vk::DeferredOperationKHR) -> vk::Result {
    vk::Result::SUCCESS
}
