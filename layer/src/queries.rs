//! Acceleration-structure property queries. The driver knows no such query type, so the
//! pool is a real one of a type every device has (occlusion), and its results are kept
//! here: a structure's compacted size is known when the write is recorded (vkrt places its
//! arrays from the counts), so the write stores it, a host read returns it, and a copy to a
//! buffer is recorded as an update of that buffer.

use std::collections::HashMap;
use std::sync::{LazyLock, Mutex};

use ash::vk;

use crate::commands::slice;
use crate::device::served;
use crate::{accel, guard, log, pfn};

/// A pool of the extension's query types: each query's value, once written.
struct Pool {
    ty: vk::QueryType,
    values: Vec<Option<u64>>,
}

static POOLS: LazyLock<Mutex<HashMap<vk::QueryPool, Pool>>> = LazyLock::new(Default::default);

fn is_structure_query(ty: vk::QueryType) -> bool {
    matches!(
        ty,
        vk::QueryType::ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR
            | vk::QueryType::ACCELERATION_STRUCTURE_SERIALIZATION_SIZE_KHR
            | vk::QueryType::ACCELERATION_STRUCTURE_SIZE_KHR
            | vk::QueryType::ACCELERATION_STRUCTURE_SERIALIZATION_BOTTOM_LEVEL_POINTERS_KHR
    )
}

pub fn function(name: &[u8]) -> vk::PFN_vkVoidFunction {
    match name {
        b"vkCreateQueryPool" => pfn!(create_pool, vk::PFN_vkCreateQueryPool),
        b"vkDestroyQueryPool" => pfn!(destroy_pool, vk::PFN_vkDestroyQueryPool),
        b"vkResetQueryPool" | b"vkResetQueryPoolEXT" => pfn!(reset_pool, vk::PFN_vkResetQueryPool),
        b"vkCmdResetQueryPool" => pfn!(cmd_reset_pool, vk::PFN_vkCmdResetQueryPool),
        b"vkGetQueryPoolResults" => pfn!(get_results, vk::PFN_vkGetQueryPoolResults),
        b"vkCmdCopyQueryPoolResults" => pfn!(cmd_copy_results, vk::PFN_vkCmdCopyQueryPoolResults),
        b"vkCmdWriteAccelerationStructuresPropertiesKHR" => pfn!(
            cmd_write_properties,
            vk::PFN_vkCmdWriteAccelerationStructuresPropertiesKHR
        ),
        _ => None,
    }
}

unsafe extern "system" fn create_pool(
    device: vk::Device,
    info: *const vk::QueryPoolCreateInfo<'_>,
    allocator: *const vk::AllocationCallbacks<'_>,
    out: *mut vk::QueryPool,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        let Some(s) = served(device) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        // SAFETY: the application's valid create info.
        let mut ours = unsafe { *info };
        let ty = ours.query_type;
        if !is_structure_query(ty) {
            // SAFETY: the application's call, passed on.
            return unsafe { (s.fns.fp_v1_0().create_query_pool)(device, info, allocator, out) };
        }
        ours.query_type = vk::QueryType::OCCLUSION;
        // SAFETY: a pool of the same size of a type the driver has.
        let r = unsafe { (s.fns.fp_v1_0().create_query_pool)(device, &ours, allocator, out) };
        if r == vk::Result::SUCCESS {
            let pool = Pool {
                ty,
                values: vec![None; ours.query_count as usize],
            };
            // SAFETY: created above.
            POOLS
                .lock()
                .map(|mut p| p.insert(unsafe { *out }, pool))
                .ok();
        }
        r
    })
}

unsafe extern "system" fn destroy_pool(
    device: vk::Device,
    pool: vk::QueryPool,
    allocator: *const vk::AllocationCallbacks<'_>,
) {
    guard((), || {
        let Some(s) = served(device) else { return };
        POOLS.lock().map(|mut p| p.remove(&pool)).ok();
        // SAFETY: the application's call, passed on.
        unsafe { (s.fns.fp_v1_0().destroy_query_pool)(device, pool, allocator) };
    })
}

/// Forgets the values of queries `first..first + count` of `pool`, if it is one of the
/// layer's; whether it is.
fn reset(pool: vk::QueryPool, first: u32, count: u32) -> bool {
    let Ok(mut pools) = POOLS.lock() else {
        return false;
    };
    let Some(p) = pools.get_mut(&pool) else {
        return false;
    };
    for v in p
        .values
        .iter_mut()
        .skip(first as usize)
        .take(count as usize)
    {
        *v = None;
    }
    true
}

unsafe extern "system" fn reset_pool(
    device: vk::Device,
    pool: vk::QueryPool,
    first: u32,
    count: u32,
) {
    guard((), || {
        let Some(s) = served(device) else { return };
        reset(pool, first, count);
        // SAFETY: the application's call, passed on (hostQueryReset, core 1.2).
        unsafe { (s.fns.fp_v1_2().reset_query_pool)(device, pool, first, count) };
    })
}

unsafe extern "system" fn cmd_reset_pool(
    cb: vk::CommandBuffer,
    pool: vk::QueryPool,
    first: u32,
    count: u32,
) {
    guard((), || {
        let Some(s) = served(cb) else { return };
        // Recorded order is the order the values are kept in (see the module's comment).
        reset(pool, first, count);
        // SAFETY: the application's call, passed on.
        unsafe { (s.fns.fp_v1_0().cmd_reset_query_pool)(cb, pool, first, count) };
    })
}

unsafe extern "system" fn cmd_write_properties(
    cb: vk::CommandBuffer,
    count: u32,
    structures: *const vk::AccelerationStructureKHR,
    ty: vk::QueryType,
    pool: vk::QueryPool,
    first: u32,
) {
    guard((), || {
        let Some(s) = served(cb) else { return };
        let call = "vkCmdWriteAccelerationStructuresPropertiesKHR";
        if ty != vk::QueryType::ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR {
            return log(&format!(
                "{call}: {ty:?} is not supported (serialization is not); nothing written"
            ));
        }
        let Ok(mut pools) = POOLS.lock() else { return };
        let Some(p) = pools.get_mut(&pool) else {
            return log(&format!(
                "{call}: the pool is not a compacted-size query pool"
            ));
        };
        // SAFETY: the application's `count` structures.
        for (k, &h) in unsafe { slice(structures, count) }.iter().enumerate() {
            let size = s.accel.object(h).and_then(accel::compacted_size);
            if size.is_none() {
                log(&format!(
                    "{call}: structure {k} was never built; its query stays unavailable"
                ));
            }
            if let Some(v) = p.values.get_mut(first as usize + k) {
                *v = size;
            }
        }
        debug_assert_eq!(p.ty, ty);
    })
}

/// The bytes of queries `first..first + count` as `flags` lay them out, `stride` apart.
fn results(
    p: &Pool,
    first: u32,
    count: u32,
    stride: u64,
    flags: vk::QueryResultFlags,
) -> (Vec<(u64, Vec<u8>)>, bool) {
    let wide = flags.contains(vk::QueryResultFlags::TYPE_64);
    let availability = flags.contains(vk::QueryResultFlags::WITH_AVAILABILITY);
    let partial = flags.contains(vk::QueryResultFlags::PARTIAL);
    let mut all_ready = true;
    let mut out = Vec::new();
    for k in 0..count {
        let value = p.values.get((first + k) as usize).copied().flatten();
        all_ready &= value.is_some();
        let mut bytes = Vec::new();
        let mut put = |x: u64| match wide {
            true => bytes.extend(x.to_le_bytes()),
            false => bytes.extend((x as u32).to_le_bytes()),
        };
        // Unavailable: nothing is written, unless asked for partial or availability.
        match value {
            Some(v) => put(v),
            None if partial || availability => put(0),
            None => {}
        }
        if availability {
            put(u64::from(value.is_some()));
        }
        if !bytes.is_empty() {
            out.push((u64::from(k) * stride, bytes));
        }
    }
    (out, all_ready)
}

#[allow(clippy::too_many_arguments)]
unsafe extern "system" fn get_results(
    device: vk::Device,
    pool: vk::QueryPool,
    first: u32,
    count: u32,
    data_size: usize,
    data: *mut std::ffi::c_void,
    stride: vk::DeviceSize,
    flags: vk::QueryResultFlags,
) -> vk::Result {
    guard(vk::Result::ERROR_DEVICE_LOST, || {
        let Some(s) = served(device) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        let pools = POOLS.lock();
        let Some(p) = pools.as_ref().ok().and_then(|m| m.get(&pool)) else {
            drop(pools);
            // SAFETY: the application's call, passed on.
            return unsafe {
                (s.fns.fp_v1_0().get_query_pool_results)(
                    device, pool, first, count, data_size, data, stride, flags,
                )
            };
        };
        let (items, ready) = results(p, first, count, stride, flags);
        for (at, bytes) in items {
            if at as usize + bytes.len() <= data_size {
                // SAFETY: within the application's `data_size` bytes.
                unsafe {
                    std::ptr::copy_nonoverlapping(
                        bytes.as_ptr(),
                        data.cast::<u8>().add(at as usize),
                        bytes.len(),
                    )
                };
            }
        }
        // A value is kept when its write is recorded: one never written will not come.
        match ready {
            true => vk::Result::SUCCESS,
            false => vk::Result::NOT_READY,
        }
    })
}

#[allow(clippy::too_many_arguments)]
unsafe extern "system" fn cmd_copy_results(
    cb: vk::CommandBuffer,
    pool: vk::QueryPool,
    first: u32,
    count: u32,
    buffer: vk::Buffer,
    offset: vk::DeviceSize,
    stride: vk::DeviceSize,
    flags: vk::QueryResultFlags,
) {
    guard((), || {
        let Some(s) = served(cb) else { return };
        let pools = POOLS.lock();
        let Some(p) = pools.as_ref().ok().and_then(|m| m.get(&pool)) else {
            drop(pools);
            // SAFETY: the application's call, passed on.
            return unsafe {
                (s.fns.fp_v1_0().cmd_copy_query_pool_results)(
                    cb, pool, first, count, buffer, offset, stride, flags,
                )
            };
        };
        let (items, _) = results(p, first, count, stride, flags);
        for (at, bytes) in items {
            // SAFETY: the application's buffer range (its copy's rules: transfer-destination
            // usage, room for every query), outside a render pass.
            unsafe { s.fns.cmd_update_buffer(cb, buffer, offset + at, &bytes) };
        }
    })
}
