//! Typed storage buffers on gpu-allocator.
//!
//! `Buffer<T>` is device-local storage usable by kernels, copies, fills and indirect
//! dispatch. Uploads and downloads go through a host-visible staging buffer and a one-off
//! submission; that is correct on every device (on lavapipe all memory is host memory,
//! but we do not depend on it).

use std::marker::PhantomData;

use ash::vk;
use bytemuck::Pod;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use gpu_allocator::MemoryLocation;

use super::context::Context;
use super::error::{vk_err, GpuError, Result};
use super::recorder::Recorder;

pub(crate) use sealed::BufferId;

/// The key a range's descriptor sets and views are cached under ([`BufferArg`] is sealed by
/// it): public in a private module, so nothing outside vkrt can name or implement it.
pub(crate) mod sealed {
    use ash::vk;

    /// Which buffer a range lies in, as bindings are keyed: a vkrt [`Buffer`](super::Buffer)'s
    /// own id, never reused (its cached sets and views go when it drops), or a caller's
    /// handle, which a driver may reuse once the buffer is destroyed (hence
    /// [`BindingCache::forget`](crate::gpu::BindingCache::forget)).
    #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
    pub enum BufferId {
        /// A vkrt buffer (or a range taken from one).
        Vkrt(u64),
        /// A caller's buffer.
        Caller(vk::Buffer),
    }

    pub trait Identity {
        fn id(&self) -> BufferId;
    }
}

/// The next vkrt buffer's id (0 is never given).
static NEXT_BUFFER_ID: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

/// Anything a kernel can bind or a command can read or write: a whole [`Buffer`] or a
/// caller-owned range ([`RawBuffer`]).
///
/// Sealed: only vkrt's types implement it, so a safe call cannot be handed a raw handle
/// ([`RawBuffer::new`] is where one enters, `unsafe`).
pub trait BufferArg: sealed::Identity {
    /// The Vulkan buffer the range lies in.
    fn raw(&self) -> vk::Buffer;
    /// Byte offset of the range's start in that buffer.
    fn offset(&self) -> u64;
    /// Size in bytes of the bound range (at least 4, as Vulkan wants non-empty ranges).
    fn range(&self) -> u64;
    /// Size in bytes of the whole Vulkan buffer where it is known (vkrt's own buffers), for
    /// the check that the range lies within it.
    fn buffer_size(&self) -> Option<u64> {
        None
    }
}

/// The device address of `b`'s first byte: an error where the context has no
/// `bufferDeviceAddress` (the buffer must have `SHADER_DEVICE_ADDRESS` usage, as vkrt's own
/// buffers and ranges of them do there).
pub fn address_of(ctx: &Context, b: &dyn BufferArg) -> Result<u64> {
    let f = &ctx.info().features;
    if !(f.buffer_device_address || f.ray_query) {
        return Err(GpuError::MissingCapability {
            device: ctx.info().device.clone(),
            what: "bufferDeviceAddress (device addresses of buffers)".into(),
        });
    }
    let info = vk::BufferDeviceAddressInfo::default().buffer(b.raw());
    // SAFETY: bufferDeviceAddress is enabled (checked above); `b` is a live buffer of this
    // device with SHADER_DEVICE_ADDRESS usage (the caller's contract, stated above).
    Ok(unsafe { ctx.inner.device.get_buffer_device_address(&info) } + b.offset())
}

/// An RGBA32UI view of a buffer range, for a uniform texel buffer binding (the structure
/// read through texel buffers: `VKRT_TEXEL_BUFFERS` of `vkrt/ray_query.glsl`); destroyed
/// when dropped. Keep it, and the buffer, until the work that reads it has executed.
pub struct TexelView {
    ctx: super::teardown::Held,
    view: vk::BufferView,
}

impl TexelView {
    /// A view of `b`'s range: an error unless the offset is a multiple of the device's
    /// `minTexelBufferOffsetAlignment` and the range whole 16-byte texels, at most
    /// `maxTexelBufferElements` of them (vkrt's own buffers and ranges are whole texels).
    pub fn new(ctx: &Context, b: &dyn BufferArg) -> Result<Self> {
        Ok(Self {
            ctx: super::teardown::Held::new(ctx, super::teardown::Holder::TexelView),
            view: create_texel_view(ctx, b)?,
        })
    }

    /// The Vulkan buffer view, to write into a descriptor.
    pub fn raw(&self) -> vk::BufferView {
        self.view
    }
}

impl Drop for TexelView {
    fn drop(&mut self) {
        // SAFETY: the view was made on this device, and its owner keeps it until the work
        // that reads it has executed (the type's contract).
        unsafe { self.ctx.inner.device.destroy_buffer_view(self.view, None) };
    }
}

/// An RGBA32UI view of `b`'s range, checked against the device's limits; the caller
/// destroys it.
pub(crate) fn create_texel_view(ctx: &Context, b: &dyn BufferArg) -> Result<vk::BufferView> {
    let info = ctx.info();
    let align = info.min_texel_buffer_offset_alignment.max(1);
    let range = b.range();
    if b.offset() % align != 0
        || range == 0
        || range % 16 != 0
        || range / 16 > u64::from(info.max_texel_buffer_elements)
    {
        return Err(GpuError::Usage {
            call: "texel buffer view",
            reason: format!(
                "a texel buffer of {range} bytes at offset {} (offsets a multiple of {align}, \
                 whole texels of 16 bytes, at most {} of them)",
                b.offset(),
                info.max_texel_buffer_elements
            ),
        });
    }
    let create = vk::BufferViewCreateInfo::default()
        .buffer(b.raw())
        .format(vk::Format::R32G32B32A32_UINT)
        .offset(b.offset())
        .range(range);
    // SAFETY: valid device; the buffer has UNIFORM_TEXEL_BUFFER usage (vkrt's buffers and
    // REQUIRED_BUFFER_USAGE have it); offset, range and texel count were checked against the
    // device's limits above.
    let view = unsafe { ctx.inner.device.create_buffer_view(&create, None) }
        .map_err(vk_err("vkCreateBufferView"))?;
    ctx.inner.created(1);
    Ok(view)
}

/// A range of a buffer that the embedding renderer owns; vkrt never frees it.
///
/// Made only by [`RawBuffer::new`] (or [`Buffer::as_raw`]), whose contract is what makes the
/// safe calls taking one sound: vkrt records reads and writes of the range and cannot check
/// the handle behind it.
///
/// ```compile_fail
/// // Not in safe code: the fields are private.
/// let r = vkrt::gpu::RawBuffer { raw: vkrt::gpu::vk::Buffer::null(), offset: 0, size: 4 };
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RawBuffer {
    pub(crate) raw: vk::Buffer,
    pub(crate) offset: u64,
    pub(crate) size: u64,
    /// What its bindings are cached under: the caller's handle, or the vkrt buffer the range
    /// was taken from ([`Buffer::as_raw`]).
    pub(crate) id: BufferId,
}

impl RawBuffer {
    /// The `size` bytes of `raw` from byte `offset`.
    ///
    /// # Safety
    /// Until every command recorded with this range (or a range taken from it) has finished
    /// executing:
    /// - `raw` is a live buffer of the context's device, bound to memory, and
    ///   `offset + size` is within it;
    /// - it was created with the usages the call taking the range documents (for a
    ///   structure or scratch, [`REQUIRED_BUFFER_USAGE`](crate::REQUIRED_BUFFER_USAGE));
    /// - nothing else writes the range while vkrt's commands use it, except as the call's
    ///   synchronization contract says.
    /// - before `raw` is destroyed, every [`BindingCache`](crate::gpu::BindingCache) that
    ///   bound a range of it has been told with
    ///   [`forget`](crate::gpu::BindingCache::forget) (a driver may give a new buffer the same
    ///   handle, and a cached descriptor set would then point at freed memory).
    pub unsafe fn new(raw: vk::Buffer, offset: u64, size: u64) -> Self {
        Self {
            raw,
            offset,
            size,
            id: BufferId::Caller(raw),
        }
    }

    /// The Vulkan buffer.
    pub fn buffer(&self) -> vk::Buffer {
        self.raw
    }

    /// Byte offset of the range's start in the buffer.
    pub fn offset(&self) -> u64 {
        self.offset
    }

    /// Size of the range in bytes.
    pub fn size(&self) -> u64 {
        self.size
    }

    /// `size` bytes from `offset` into this range, or `None` past its end: a part of a
    /// range inherits its contract.
    pub fn slice(&self, offset: u64, size: u64) -> Option<RawBuffer> {
        let end = offset.checked_add(size)?;
        (end <= self.size).then_some(RawBuffer {
            raw: self.raw,
            offset: self.offset + offset,
            size,
            id: self.id,
        })
    }
}

/// `size` bytes at a device address (`VkDeviceOrHostAddressConstKHR`): geometry or a
/// transform a build reads with `GL_EXT_buffer_reference`. Made only by the `unsafe`
/// [`DeviceRange::new`]: vkrt cannot check an address.
///
/// ```compile_fail
/// // Not in safe code: any u64 would reach the GPU.
/// let d = vkrt::gpu::DeviceRange { address: 64, size: 12 };
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DeviceRange {
    address: u64,
    size: u64,
}

/// The caller's word that a structure's placed bytes are a copy of a built structure's, by
/// the time recorded work reads them
/// ([`GpuGeometry::record_built_by_copy`](crate::accel::gpu_geometry::GpuGeometry::record_built_by_copy)):
/// what an API layer's clone of a structure records. Made only by the `unsafe`
/// [`CopiedStructure::new`]: vkrt cannot see what a copy brought.
#[derive(Clone, Copy, Debug)]
pub struct CopiedStructure(());

impl CopiedStructure {
    /// The word for one structure.
    ///
    /// # Safety
    /// Before any recorded work that reads or updates the structure this is given for
    /// executes, the structure's placed range holds a byte copy of a structure built by the
    /// same builder, over geometry of the same description, with the same build flags.
    pub unsafe fn new() -> Self {
        Self(())
    }
}

impl DeviceRange {
    /// The `size` bytes from device address `address`.
    ///
    /// # Safety
    /// Until every command recorded with this range has finished executing, the bytes lie
    /// in one live buffer of the context's device, created with `SHADER_DEVICE_ADDRESS`
    /// usage and bound to memory allocated with the device-address flag, and nothing writes
    /// them while a build reads them.
    pub unsafe fn new(address: u64, size: u64) -> Self {
        Self { address, size }
    }

    /// The device address of the first byte.
    pub fn address(&self) -> u64 {
        self.address
    }

    /// Bytes from there.
    pub fn size(&self) -> u64 {
        self.size
    }
}

impl sealed::Identity for RawBuffer {
    fn id(&self) -> BufferId {
        self.id
    }
}

impl BufferArg for RawBuffer {
    fn raw(&self) -> vk::Buffer {
        self.raw
    }
    fn offset(&self) -> u64 {
        self.offset
    }
    fn range(&self) -> u64 {
        self.size
    }
}

/// Where a buffer lives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Memory {
    /// Device-local: what kernels read and write.
    Device,
    /// Host-visible, for uploads (staging).
    Upload,
    /// Host-visible and cached, for downloads (read-back).
    Readback,
}

/// A typed buffer of `len` elements of `T`.
pub struct Buffer<T: Pod> {
    ctx: super::teardown::Held,
    pub(crate) raw: vk::Buffer,
    allocation: Option<Allocation>,
    len: usize,
    bytes: u64,
    /// Where the range starts in `raw` (non-zero for a buffer placed in a caller's memory).
    offset: u64,
    /// Whether `raw` is ours to destroy (false for a range of a caller's buffer).
    owned: bool,
    /// What its cached bindings are keyed by: an id unique in the process for a buffer of
    /// its own, the caller's buffer's for a range placed in it (whose sets stay valid as
    /// long as the caller's buffer, and go when it does).
    id: BufferId,
    name: String,
    memory: Memory,
    // The elements live in device memory, not in the handle: it crosses threads whatever `T`.
    _marker: PhantomData<fn() -> T>,
}

impl<T: Pod> sealed::Identity for Buffer<T> {
    fn id(&self) -> BufferId {
        self.id
    }
}

impl<T: Pod> BufferArg for Buffer<T> {
    fn raw(&self) -> vk::Buffer {
        self.raw
    }
    fn offset(&self) -> u64 {
        self.offset
    }
    fn range(&self) -> u64 {
        self.bytes
    }
    fn buffer_size(&self) -> Option<u64> {
        // A range of a caller's buffer (placed): the caller's buffer's size is not known.
        self.owned.then_some(self.bytes)
    }
}

impl<T: Pod> std::fmt::Debug for Buffer<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Buffer<{}>(`{}`, {} elements, {:?})",
            std::any::type_name::<T>(),
            self.name,
            self.len,
            self.memory
        )
    }
}

impl<T: Pod> Buffer<T> {
    /// A device-local buffer of `len` elements with undefined contents.
    pub fn new(ctx: &Context, name: &str, len: usize) -> Result<Self> {
        Self::with_memory(ctx, name, len, Memory::Device)
    }

    /// A device-local buffer of `len` elements to place structures and scratch in
    /// ([`placement::Placement::Into`]): as a renderer's own buffer, its size is not bound
    /// by `maxStorageBufferRange` (only each range placed in it is); it is never bound whole.
    pub fn arena(ctx: &Context, name: &str, len: usize) -> Result<Self> {
        Self::create(ctx, name, len, Memory::Device, false)
    }

    /// A buffer of `len` elements in the given memory.
    pub fn with_memory(ctx: &Context, name: &str, len: usize, memory: Memory) -> Result<Self> {
        Self::create(ctx, name, len, memory, true)
    }

    fn create(
        ctx: &Context,
        name: &str,
        len: usize,
        memory: Memory,
        bound_whole: bool,
    ) -> Result<Self> {
        let elem = std::mem::size_of::<T>() as u64;
        let wanted = (len as u64)
            .checked_mul(elem)
            .ok_or_else(|| GpuError::BufferTooLarge {
                name: name.into(),
                bytes: u64::MAX,
                limit: ctx.info().max_storage_buffer_range,
            })?;
        let limit = ctx.info().max_storage_buffer_range;
        if memory == Memory::Device && bound_whole && wanted > limit {
            return Err(GpuError::BufferTooLarge {
                name: name.into(),
                bytes: wanted,
                limit,
            });
        }
        // Vulkan forbids empty buffers; an empty one gets 16 bytes and len 0. Whole 16-byte
        // texels (where the binding limit allows), so that any buffer can be viewed as an
        // RGBA32UI texel buffer in full.
        let bytes = match wanted.max(16).next_multiple_of(16) {
            b if b <= limit || memory != Memory::Device => b,
            _ => wanted.next_multiple_of(4),
        };
        if memory == Memory::Device && bound_whole {
            if let Some(range) = placement::take(name, bytes) {
                let range = range?;
                return Ok(Self {
                    ctx: super::teardown::Held::new(ctx, super::teardown::Holder::Buffer),
                    raw: range.raw,
                    allocation: None,
                    len,
                    bytes,
                    offset: range.offset,
                    owned: false,
                    id: range.id,
                    name: name.into(),
                    memory,
                    _marker: PhantomData,
                });
            }
            ctx.inner
                .device_allocations
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
        let f = &ctx.info().features;
        let usage = vk::BufferUsageFlags::STORAGE_BUFFER
            | vk::BufferUsageFlags::TRANSFER_SRC
            | vk::BufferUsageFlags::TRANSFER_DST
            | vk::BufferUsageFlags::INDIRECT_BUFFER
            // Traversal data may be read through texel-buffer views.
            | vk::BufferUsageFlags::UNIFORM_TEXEL_BUFFER
            | if f.buffer_device_address || f.ray_query {
                // Geometry may be read at device addresses; the allocator then allocates
                // every block with VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT.
                vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS
            } else {
                vk::BufferUsageFlags::empty()
            }
            | if f.ray_query {
                // The driver's acceleration structures live in buffers and read their inputs
                // (vertices, instances, scratch) at device addresses.
                vk::BufferUsageFlags::ACCELERATION_STRUCTURE_STORAGE_KHR
                    | vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR
            } else {
                vk::BufferUsageFlags::empty()
            };
        let device = &ctx.inner.device;
        let create = vk::BufferCreateInfo::default()
            .size(bytes)
            .usage(usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        // SAFETY: valid device and create-info; the buffer is destroyed on every error path.
        let raw =
            unsafe { device.create_buffer(&create, None) }.map_err(vk_err("vkCreateBuffer"))?;
        ctx.inner.created(1);
        // SAFETY: `raw` was just created on this device.
        let requirements = unsafe { device.get_buffer_memory_requirements(raw) };
        let location = match memory {
            Memory::Device => MemoryLocation::GpuOnly,
            Memory::Upload => MemoryLocation::CpuToGpu,
            Memory::Readback => MemoryLocation::GpuToCpu,
        };
        let allocation = super::error::lock(&ctx.inner.allocator).allocate(&AllocationCreateDesc {
            name,
            requirements,
            location,
            linear: true,
            allocation_scheme: AllocationScheme::GpuAllocatorManaged,
        });
        let allocation = match allocation {
            Ok(a) => a,
            Err(e) => {
                // SAFETY: `raw` is unused.
                unsafe { device.destroy_buffer(raw, None) };
                return Err(GpuError::Allocation {
                    name: name.into(),
                    bytes,
                    reason: e.to_string(),
                });
            }
        };
        // SAFETY: the allocation satisfies `requirements` and is not bound to anything else.
        let bound =
            unsafe { device.bind_buffer_memory(raw, allocation.memory(), allocation.offset()) };
        if let Err(e) = bound {
            // SAFETY: `raw` is unused; the allocation goes back to the allocator.
            unsafe { device.destroy_buffer(raw, None) };
            let _ = super::error::lock(&ctx.inner.allocator).free(allocation);
            return Err(vk_err("vkBindBufferMemory")(e));
        }
        ctx.set_object_name(raw, name);
        ctx.count_allocation(allocation.size(), true);
        Ok(Self {
            ctx: super::teardown::Held::new(ctx, super::teardown::Holder::Buffer),
            raw,
            allocation: Some(allocation),
            len,
            bytes,
            offset: 0,
            owned: true,
            id: BufferId::Vkrt(NEXT_BUFFER_ID.fetch_add(1, std::sync::atomic::Ordering::Relaxed)),
            name: name.into(),
            memory,
            _marker: PhantomData,
        })
    }

    /// A device-local buffer holding `data`.
    pub fn from_slice(ctx: &Context, name: &str, data: &[T]) -> Result<Self> {
        let buffer = Self::new(ctx, name, data.len())?;
        buffer.upload(data)?;
        Ok(buffer)
    }

    /// A device-local buffer of `len` zeroed elements.
    pub fn zeroed(ctx: &Context, name: &str, len: usize) -> Result<Self> {
        let buffer = Self::new(ctx, name, len)?;
        let mut rec = Recorder::new(ctx)?;
        rec.fill(&buffer, 0);
        rec.transfer_to_host();
        rec.submit_and_wait()?;
        Ok(buffer)
    }

    /// Number of elements of type `T`.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the buffer holds no elements.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The context it was created in.
    pub fn context(&self) -> &Context {
        &self.ctx
    }

    /// The debug name it was created with.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Size of the contents in bytes.
    pub fn byte_len(&self) -> u64 {
        (self.len * std::mem::size_of::<T>()) as u64
    }

    /// [`Buffer::device_address`] where the feature is known to be on: vkrt's structures that
    /// read addresses refuse to be made without it.
    pub(crate) fn address(&self) -> u64 {
        self.device_address()
            .expect("bufferDeviceAddress, checked when the structure was made")
    }

    /// The buffer's device address (for acceleration-structure builds, ray queries and
    /// geometry read at addresses). [`GpuError::MissingCapability`] unless
    /// `bufferDeviceAddress` is enabled ([`super::DeviceFeatures::buffer_device_address`], or
    /// `ray_query`, which needs it).
    pub fn device_address(&self) -> Result<u64> {
        let f = &self.ctx.info().features;
        if !(f.buffer_device_address || f.ray_query) {
            return Err(GpuError::MissingCapability {
                device: self.ctx.info().device.clone(),
                what: "bufferDeviceAddress (a buffer's device address)".into(),
            });
        }
        let info = vk::BufferDeviceAddressInfo::default().buffer(self.raw);
        // SAFETY: bufferDeviceAddress is enabled (checked above) and the buffer
        // was created with SHADER_DEVICE_ADDRESS usage and bound to memory allocated with the
        // device-address flag (the allocator is created with buffer_device_address then).
        Ok(unsafe { self.ctx.inner.device.get_buffer_device_address(&info) } + self.offset)
    }

    /// The range this buffer covers, for vkrt's own recordings, which keep the buffer alive
    /// until their work has executed.
    pub(crate) fn own_range(&self) -> RawBuffer {
        RawBuffer {
            raw: self.raw,
            offset: self.offset,
            size: self.bytes,
            id: self.id,
        }
    }

    /// The range this buffer covers, as a [`RawBuffer`].
    ///
    /// # Safety
    /// This buffer outlives every command recorded with the range (a [`RawBuffer`] does not
    /// keep it alive), as [`RawBuffer::new`] requires.
    pub unsafe fn as_raw(&self) -> RawBuffer {
        self.own_range()
    }

    /// Writes `data` at the start of the buffer (through staging for device memory).
    pub fn upload(&self, data: &[T]) -> Result<()> {
        super::timeline::host_span("vkrt.upload", || self.upload_now(data))
    }

    fn upload_now(&self, data: &[T]) -> Result<()> {
        if data.len() > self.len {
            return Err(GpuError::Usage {
                call: "Buffer::upload",
                reason: format!(
                    "{} elements into `{}` of {}",
                    data.len(),
                    self.name,
                    self.len
                ),
            });
        }
        if data.is_empty() {
            return Ok(());
        }
        if self.memory != Memory::Device {
            self.write_mapped(bytemuck::cast_slice(data));
            return Ok(());
        }
        let staging =
            Buffer::<T>::with_memory(&self.ctx, "staging.upload", data.len(), Memory::Upload)?;
        staging.write_mapped(bytemuck::cast_slice(data));
        self.ctx.inner.upload_bytes.fetch_add(
            std::mem::size_of_val(data) as u64,
            std::sync::atomic::Ordering::Relaxed,
        );
        let mut rec = Recorder::new(&self.ctx)?;
        rec.copy(&staging, self, data.len());
        rec.transfer_to_host();
        rec.submit_and_wait().map(drop)
    }

    /// Reads the whole buffer back.
    pub fn download(&self) -> Result<Vec<T>> {
        super::timeline::host_span("vkrt.read_back", || self.download_now())
    }

    fn download_now(&self) -> Result<Vec<T>> {
        if self.len == 0 {
            return Ok(Vec::new());
        }
        if self.memory != Memory::Device {
            let bytes = &self.mapped_bytes()[..self.byte_len() as usize];
            if self.memory == Memory::Readback {
                self.ctx
                    .inner
                    .readback_bytes
                    .fetch_add(self.byte_len(), std::sync::atomic::Ordering::Relaxed);
            }
            return Ok(bytemuck::pod_collect_to_vec(bytes));
        }
        let staging =
            Buffer::<T>::with_memory(&self.ctx, "staging.readback", self.len, Memory::Readback)?;
        let mut rec = Recorder::new(&self.ctx)?;
        rec.compute_to_transfer();
        rec.copy(self, &staging, self.len);
        rec.transfer_to_host();
        rec.submit_and_wait()?;
        staging.download_now()
    }

    fn mapped_bytes(&self) -> &[u8] {
        let allocation = self.allocation.as_ref().expect("buffer is alive");
        allocation
            .mapped_slice()
            .unwrap_or_else(|| super::error::usage_error("host access to device memory"))
    }

    pub(crate) fn write_mapped(&self, bytes: &[u8]) {
        let allocation = self.allocation.as_ref().expect("buffer is alive");
        let ptr = allocation
            .mapped_ptr()
            .unwrap_or_else(|| super::error::usage_error("host access to device memory"))
            .cast::<u8>();
        assert!(bytes.len() as u64 <= allocation.size());
        // SAFETY: the mapping covers `allocation.size()` bytes (checked above) for the
        // buffer's lifetime, and `bytes` is host memory that cannot overlap it. vkrt waits for
        // its submissions, so no GPU access to this staging buffer is pending.
        unsafe { std::ptr::copy_nonoverlapping(bytes.as_ptr(), ptr.as_ptr(), bytes.len()) };
    }
}

impl<T: Pod> Drop for Buffer<T> {
    fn drop(&mut self) {
        if !self.owned {
            // A range of a caller's buffer (or a measured placeholder): the caller frees it,
            // and its cached sets go then (they are keyed by the caller's buffer, so a range
            // placed anew each recording, as a build's scratch is, binds the same sets).
            return;
        }
        // SAFETY: no pending work uses the buffer (the contract below), so none binds the
        // cached sets and views of its ranges, which go with it.
        unsafe { self.ctx.inner.caches.evict(self.id) };
        // SAFETY: vkrt waits for every submission it makes before returning, so the buffer is
        // not in use by a pending command buffer of ours; buffers bound into a caller-owned
        // command buffer must outlive it (documented on `Recorder::from_raw`).
        unsafe { self.ctx.inner.device.destroy_buffer(self.raw, None) };
        if let Some(a) = self.allocation.take() {
            self.ctx.count_allocation(a.size(), false);
            let _ = super::error::lock(&self.ctx.inner.allocator).free(a);
        }
    }
}

/// Placing device buffers in memory the caller owns, the way `VK_KHR_acceleration_structure`
/// lets an application place a structure and its scratch.
///
/// While [`place`](placement::place) runs its closure on this thread, every device-local
/// [`Buffer`] the closure creates is a range of the caller's buffer (carved in creation
/// order, each aligned to `minStorageBufferOffsetAlignment` and `minTexelBufferOffsetAlignment`), or, with
/// [`Placement::Measure`](placement::Placement::Measure), a placeholder that only counts
/// bytes. Because sizing and placing run the same code, a size query is exact
/// for the input it was asked about.
pub mod placement {
    use std::cell::RefCell;

    use super::{Context, RawBuffer};
    use crate::gpu::error::{GpuError, PlacementProblem, Result};
    use ash::vk;

    /// Where [`place`] puts the device buffers its closure creates.
    #[derive(Clone, Copy, Debug)]
    pub enum Placement {
        /// Nowhere: count the bytes (the buffers are placeholders that must not be used).
        Measure,
        /// In this range of a caller's buffer, which needs `STORAGE_BUFFER`,
        /// `TRANSFER_SRC`, `TRANSFER_DST`, `INDIRECT_BUFFER` and `UNIFORM_TEXEL_BUFFER`
        /// usage (and
        /// `SHADER_DEVICE_ADDRESS` for the driver's structure).
        Into(RawBuffer),
    }

    struct Arena {
        target: Option<RawBuffer>,
        used: u64,
        align: u64,
    }

    thread_local! {
        static ARENAS: RefCell<Vec<Arena>> = const { RefCell::new(Vec::new()) };
    }

    /// Runs `f` with device buffers placed per `placement`; returns its result and the bytes
    /// it placed. With [`Placement::Into`], a range too small for what `f` creates is an
    /// error naming both sizes (and `f`'s result is dropped: nothing it recorded may run).
    pub fn place<R>(
        ctx: &Context,
        what: &str,
        placement: Placement,
        f: impl FnOnce() -> Result<R>,
    ) -> Result<(R, u64)> {
        let align = alignment(ctx);
        let target = match placement {
            Placement::Measure => None,
            Placement::Into(r) => {
                if r.raw == vk::Buffer::null() {
                    return Err(GpuError::Placement {
                        what: what.into(),
                        problem: PlacementProblem::NullBuffer,
                    });
                }
                if r.offset % align != 0 {
                    return Err(GpuError::Placement {
                        what: what.into(),
                        problem: PlacementProblem::Misaligned {
                            offset: r.offset,
                            alignment: align,
                        },
                    });
                }
                Some(r)
            }
        };
        ARENAS.with(|a| {
            a.borrow_mut().push(Arena {
                target,
                used: 0,
                align,
            })
        });
        let result = f();
        let arena = ARENAS
            .with(|a| a.borrow_mut().pop())
            .expect("the arena pushed above");
        let value = result?;
        if let Some(t) = arena.target {
            if arena.used > t.size {
                return Err(GpuError::Placement {
                    what: what.into(),
                    problem: PlacementProblem::TooSmall {
                        needed: arena.used,
                        given: t.size,
                    },
                });
            }
        }
        Ok((value, arena.used))
    }

    /// The alignment of a placement's offset, and of each buffer within it: every placed
    /// buffer may be bound as a storage buffer or viewed as a texel buffer.
    pub fn alignment(ctx: &Context) -> u64 {
        let info = ctx.info();
        info.min_storage_buffer_offset_alignment
            .max(info.min_texel_buffer_offset_alignment)
            .clamp(4, 256)
    }

    /// Whether buffers created now are placeholders ([`Placement::Measure`]): code that
    /// would hand a buffer to the driver (an acceleration structure on it) only counts then.
    pub fn measuring() -> bool {
        ARENAS.with(|a| {
            a.borrow()
                .last()
                .is_some_and(|arena| arena.target.is_none())
        })
    }

    /// The range for a new device buffer `name` of `bytes`, when a [`place`] is active: an
    /// error once the caller's range is too small, before anything is created on it.
    pub(super) fn take(name: &str, bytes: u64) -> Option<Result<RawBuffer>> {
        ARENAS.with(|a| {
            let mut arenas = a.borrow_mut();
            let arena = arenas.last_mut()?;
            let start = arena.used.next_multiple_of(arena.align);
            arena.used = start + bytes;
            Some(match arena.target {
                Some(t) if arena.used > t.size => Err(GpuError::Placement {
                    what: format!("`{name}`"),
                    problem: PlacementProblem::TooSmall {
                        needed: arena.used,
                        given: t.size,
                    },
                }),
                Some(t) => Ok(RawBuffer {
                    raw: t.raw,
                    offset: t.offset + start,
                    size: bytes,
                    id: t.id,
                }),
                None => Ok(RawBuffer {
                    raw: vk::Buffer::null(),
                    offset: start,
                    size: bytes,
                    id: super::BufferId::Caller(vk::Buffer::null()),
                }),
            })
        })
    }
}
