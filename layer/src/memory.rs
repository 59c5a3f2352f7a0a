//! Buffers and memory: acceleration-structure usages become what vkrt's structures are
//! (storage, device address, texel, transfer, indirect), every allocation gets a device
//! address, and bound buffers are kept by address, since the extension names scratch and
//! instance arrays by address only while vkrt's builders bind buffers.

use std::collections::{BTreeMap, HashMap};

use ash::vk;

use crate::device::served;
use crate::{guard, pfn};

/// The usages that mark a buffer vkrt may place a structure, its inputs or its scratch in.
const ACCEL_USAGES: vk::BufferUsageFlags = vk::BufferUsageFlags::from_raw(
    vk::BufferUsageFlags::ACCELERATION_STRUCTURE_STORAGE_KHR.as_raw()
        | vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR.as_raw(),
);

/// The application's bound buffers with device addresses.
#[derive(Default)]
pub struct Buffers {
    /// (address, buffer) → size.
    by_address: BTreeMap<(u64, u64), u64>,
    /// buffer → (address, size), once bound.
    bound: HashMap<vk::Buffer, (u64, u64)>,
    /// buffer → size, for those with device addresses.
    created: HashMap<vk::Buffer, u64>,
}

impl Buffers {
    /// The buffer range of `len` bytes at `address`.
    pub fn resolve(&self, address: u64, len: u64) -> Option<vkrt::gpu::RawBuffer> {
        let end = address.checked_add(len)?;
        self.by_address
            .range(..=(address, u64::MAX))
            .rev()
            .find(|(&(start, _), &size)| end <= start + size)
            .map(|(&(start, raw), _)| {
                // SAFETY (of the handle only): a buffer the application created.
                let raw = <vk::Buffer as vk::Handle>::from_raw(raw);
                // SAFETY: the range lies in a buffer the app bound to memory; the
                // specification requires it alive and bound while the commands that read
                // it through this address execute.
                unsafe { vkrt::gpu::RawBuffer::new(raw, address - start, len) }
            })
    }
}

/// The usages of a buffer the application created with `usage`.
pub fn translate_usage(usage: vk::BufferUsageFlags) -> vk::BufferUsageFlags {
    if usage.intersects(ACCEL_USAGES | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS) {
        (usage & !ACCEL_USAGES)
            | vkrt::REQUIRED_BUFFER_USAGE
            | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS
    } else {
        usage
    }
}

pub fn function(name: &[u8]) -> vk::PFN_vkVoidFunction {
    match name {
        b"vkCreateBuffer" => pfn!(create_buffer, vk::PFN_vkCreateBuffer),
        b"vkDestroyBuffer" => pfn!(destroy_buffer, vk::PFN_vkDestroyBuffer),
        b"vkBindBufferMemory" => pfn!(bind_buffer_memory, vk::PFN_vkBindBufferMemory),
        b"vkBindBufferMemory2" | b"vkBindBufferMemory2KHR" => {
            pfn!(bind_buffer_memory2, vk::PFN_vkBindBufferMemory2)
        }
        b"vkAllocateMemory" => pfn!(allocate_memory, vk::PFN_vkAllocateMemory),
        b"vkGetDeviceBufferMemoryRequirements" | b"vkGetDeviceBufferMemoryRequirementsKHR" => pfn!(
            get_device_buffer_memory_requirements,
            vk::PFN_vkGetDeviceBufferMemoryRequirements
        ),
        _ => None,
    }
}

unsafe extern "system" fn create_buffer(
    device: vk::Device,
    info: *const vk::BufferCreateInfo<'_>,
    allocator: *const vk::AllocationCallbacks<'_>,
    out: *mut vk::Buffer,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        let Some(s) = served(device) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        // SAFETY: the application's valid create info.
        let mut ours = unsafe { *info };
        ours.usage = translate_usage(ours.usage);
        // SAFETY: the application's arguments, the usage translated.
        let r = unsafe { (s.fns.fp_v1_0().create_buffer)(device, &ours, allocator, out) };
        if r == vk::Result::SUCCESS
            && ours
                .usage
                .contains(vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS)
        {
            if let Ok(mut b) = s.buffers.lock() {
                // SAFETY: created above.
                b.created.insert(unsafe { *out }, ours.size);
            }
        }
        r
    })
}

unsafe extern "system" fn destroy_buffer(
    device: vk::Device,
    buffer: vk::Buffer,
    allocator: *const vk::AllocationCallbacks<'_>,
) {
    guard((), || {
        let Some(s) = served(device) else { return };
        // SAFETY: the application may destroy `buffer` only once no pending work uses it,
        // vkrt's builds over it included.
        unsafe { s.bindings.forget(buffer) };
        if let Ok(mut b) = s.buffers.lock() {
            b.created.remove(&buffer);
            if let Some((address, _)) = b.bound.remove(&buffer) {
                b.by_address.remove(&(address, vk::Handle::as_raw(buffer)));
            }
        }
        // SAFETY: the application's call, passed on.
        unsafe { (s.fns.fp_v1_0().destroy_buffer)(device, buffer, allocator) };
    })
}

/// Keeps `buffer`'s address once it is bound.
fn note_bound(s: &crate::device::Served, buffer: vk::Buffer) {
    let Ok(mut b) = s.buffers.lock() else { return };
    let Some(&size) = b.created.get(&buffer) else {
        return;
    };
    let info = vk::BufferDeviceAddressInfo::default().buffer(buffer);
    // SAFETY: a bound buffer with SHADER_DEVICE_ADDRESS usage.
    let address = unsafe { s.fns.get_buffer_device_address(&info) };
    b.bound.insert(buffer, (address, size));
    b.by_address
        .insert((address, vk::Handle::as_raw(buffer)), size);
}

unsafe extern "system" fn bind_buffer_memory(
    device: vk::Device,
    buffer: vk::Buffer,
    memory: vk::DeviceMemory,
    offset: vk::DeviceSize,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        let Some(s) = served(device) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        // SAFETY: the application's call, passed on.
        let r = unsafe { (s.fns.fp_v1_0().bind_buffer_memory)(device, buffer, memory, offset) };
        if r == vk::Result::SUCCESS {
            note_bound(&s, buffer);
        }
        r
    })
}

unsafe extern "system" fn bind_buffer_memory2(
    device: vk::Device,
    count: u32,
    infos: *const vk::BindBufferMemoryInfo<'_>,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        let Some(s) = served(device) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        // SAFETY: the application's call, passed on.
        let r = unsafe { (s.fns.fp_v1_1().bind_buffer_memory2)(device, count, infos) };
        if r == vk::Result::SUCCESS {
            // SAFETY: the application's array of `count`.
            for i in unsafe { std::slice::from_raw_parts(infos, count as usize) } {
                note_bound(&s, i.buffer);
            }
        }
        r
    })
}

unsafe extern "system" fn allocate_memory(
    device: vk::Device,
    info: *const vk::MemoryAllocateInfo<'_>,
    allocator: *const vk::AllocationCallbacks<'_>,
    out: *mut vk::DeviceMemory,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        let Some(s) = served(device) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        // Applications never ask for addresses of structure memory: every allocation gets
        // them, in the application's flags struct where it gave one.
        // SAFETY: the application's valid create info.
        let mut ours = unsafe { *info };
        let mut flags =
            vk::MemoryAllocateFlagsInfo::default().flags(vk::MemoryAllocateFlags::DEVICE_ADDRESS);
        let mut next = ours.p_next as *mut vk::BaseOutStructure<'_>;
        let mut theirs: Option<(*mut vk::MemoryAllocateFlags, vk::MemoryAllocateFlags)> = None;
        // SAFETY: a valid chain.
        while let Some(n) = unsafe { next.as_mut() } {
            if n.s_type == vk::StructureType::MEMORY_ALLOCATE_FLAGS_INFO {
                // SAFETY: the sType says which struct it is.
                let f = unsafe { &mut *next.cast::<vk::MemoryAllocateFlagsInfo<'_>>() };
                theirs = Some((&mut f.flags, f.flags));
                f.flags |= vk::MemoryAllocateFlags::DEVICE_ADDRESS;
            }
            next = n.p_next;
        }
        if theirs.is_none() {
            flags.p_next = ours.p_next;
            ours.p_next = (&flags as *const vk::MemoryAllocateFlagsInfo<'_>).cast();
        }
        // SAFETY: the application's arguments, with device addresses.
        let r = unsafe { (s.fns.fp_v1_0().allocate_memory)(device, &ours, allocator, out) };
        if let Some((at, old)) = theirs {
            // SAFETY: the application's struct, alive for this call.
            unsafe { *at = old };
        }
        r
    })
}

unsafe extern "system" fn get_device_buffer_memory_requirements(
    device: vk::Device,
    info: *const vk::DeviceBufferMemoryRequirements<'_>,
    out: *mut vk::MemoryRequirements2<'_>,
) {
    guard((), || {
        let Some(s) = served(device) else { return };
        // SAFETY: the application's valid struct and its create info.
        let mut ours = unsafe { *info };
        // SAFETY: as above.
        let mut create = unsafe { *ours.p_create_info };
        create.usage = translate_usage(create.usage);
        ours.p_create_info = &create;
        // SAFETY: the application's arguments, the usage translated.
        unsafe { (s.fns.fp_v1_3().get_device_buffer_memory_requirements)(device, &ours, out) };
    })
}
