//! The one error type of the `gpu` layer. Each Vulkan call maps its result where it is made,
//! naming the call, so an error says what failed rather than only a `VkResult`.

use ash::vk;

/// What can go wrong in the GPU layer.
#[derive(Clone, Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GpuError {
    /// The Vulkan loader library could not be loaded; holds the loader's message.
    #[error("cannot load the Vulkan loader (libvulkan.so.1): {0}; install libvulkan1 and a driver (e.g. mesa-vulkan-drivers for lavapipe)")]
    Loader(String),
    /// No physical device passed the requirements (or none was found); holds why the
    /// devices were rejected.
    #[error("no usable Vulkan device: {0}")]
    NoDevice(String),
    /// The device lacks a capability the requested work needs.
    #[error("device `{device}` lacks a required capability: {what}")]
    MissingCapability {
        /// The device's name.
        device: String,
        /// The missing feature, extension or property.
        what: String,
    },
    /// A Vulkan call returned an error not mapped to a more specific variant.
    #[error("{call} failed: {code}")]
    Vulkan {
        /// The Vulkan function that failed.
        call: &'static str,
        /// The `VkResult` it returned.
        code: vk::Result,
    },
    /// A Vulkan call ran out of device or host memory.
    #[error("out of GPU memory during {call}")]
    OutOfMemory {
        /// The Vulkan function that failed.
        call: &'static str,
    },
    /// The device was lost (`VK_ERROR_DEVICE_LOST`), or a wait for submitted work timed out.
    #[error("device lost (last pass recorded before the loss: {last_pass})")]
    DeviceLost {
        /// The last profiler scope recorded before the loss, to locate the failing pass.
        last_pass: String,
    },
    /// gpu-allocator could not create the allocator or allocate a buffer's memory.
    #[error("allocation of buffer `{name}` ({bytes} bytes) failed: {reason}")]
    Allocation {
        /// The buffer's debug name.
        name: String,
        /// The size asked for, in bytes.
        bytes: u64,
        /// The allocator's message.
        reason: String,
    },
    /// A device buffer bound whole would exceed `maxStorageBufferRange`.
    #[error("buffer `{name}` needs {bytes} bytes, above this device's maxStorageBufferRange of {limit} bytes; split the data or use a device with a larger limit")]
    BufferTooLarge {
        /// The buffer's debug name.
        name: String,
        /// The size needed, in bytes (`u64::MAX` where the size overflows).
        bytes: u64,
        /// The device's `maxStorageBufferRange`, in bytes.
        limit: u64,
    },
    /// A kernel cannot be built for this device or configuration, or its work failed
    /// (a build that ran out of capacity, an invalid input).
    #[error("kernel `{kernel}`: {reason}")]
    Kernel {
        /// The kernel or build step, by name (e.g. `prims.scan`, `accel.kdtree`).
        kernel: &'static str,
        /// What went wrong.
        reason: String,
    },
    /// A structure or scratch placed in a caller's buffer that does not fit or is misaligned:
    /// nothing was created or recorded on the range.
    #[error("placement: {what}: {problem}")]
    Placement {
        /// What was being placed (`target N: ...` for one target of a batch).
        what: String,
        /// What is wrong with the range, in numbers.
        problem: PlacementProblem,
    },
    /// A recording through a sealed [`BindingCache`](crate::gpu::BindingCache) needed a
    /// descriptor set the cache was not prepared with (a buffer it has not seen, or one
    /// re-created since): nothing was created; prepare the cache with the new buffers.
    #[error("kernel `{kernel}`: the sealed binding cache has no descriptor set for these buffers; prepare it with them")]
    CacheMiss {
        /// The kernel whose set was missing.
        kernel: &'static str,
    },
    /// A structure used before any build of it was recorded (a trace, an update, a
    /// compaction, a reference): record its build first.
    #[error("{call}: the structure has not been built: record its build first")]
    NotBuilt {
        /// The API function that refused.
        call: &'static str,
    },
    /// A structure handed to a builder or tracer of another kind (or walk).
    #[error("{call}: a {expected} cannot take a {built} structure")]
    KindMismatch {
        /// The API function that refused.
        call: &'static str,
        /// What the structure is (`lbvh`, `kdtree`, `lbvh with wide nodes`, ...).
        built: String,
        /// What the call needs (`ploc builder`, `lbvh (stack) tracer`, ...).
        expected: String,
    },
    /// A builder whose parameters differ from those frozen into the structure when it was
    /// created: record with the builder that created it.
    #[error("{call}: the structure was created with other builder parameters ({frozen}; this builder has {given}): record with the builder that created it")]
    FrozenSetting {
        /// The API function that refused.
        call: &'static str,
        /// The parameters frozen into the structure.
        frozen: String,
        /// The builder's.
        given: String,
    },
    /// One target of a batch ([`crate::accel::device::AccelBuilder::record_builds_from`])
    /// refused with a structured error: which target, and the error.
    #[error("target {index}: {error}")]
    Target {
        /// The target's index in the batch.
        index: usize,
        /// Why it was refused.
        error: Box<GpuError>,
    },
    /// A call the API refuses: wrong sizes, wrong kind, a buffer too small for the work.
    #[error("{call}: {reason}")]
    Usage {
        /// The API function that refused.
        call: &'static str,
        /// Why it refused.
        reason: String,
    },
    /// An output file (a profile, a report, an image) cannot be written: an I/O error, an
    /// unsupported image extension, an encoder's error, or a scene that could not be generated.
    #[error("cannot write {path}: {reason}")]
    Io {
        /// The file, or a label such as `<png>` where there is no path.
        path: String,
        /// What went wrong.
        reason: String,
    },
}

/// Why a range of a caller's buffer cannot take what was placed in it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum PlacementProblem {
    /// The range is too small: grow it to `needed` bytes (what the sizes call returned).
    #[error("needs {needed} bytes; the buffer range given holds {given}")]
    TooSmall {
        /// Bytes the placement needs.
        needed: u64,
        /// Bytes the range holds.
        given: u64,
    },
    /// The range starts at an offset the device cannot bind.
    #[error(
        "offset {offset} is not a multiple of this device's buffer offset alignment ({alignment})"
    )]
    Misaligned {
        /// The range's offset in its buffer.
        offset: u64,
        /// The alignment it needs (`AccelBuilder`'s placement alignment).
        alignment: u64,
    },
    /// The range names no buffer.
    #[error("a null buffer")]
    NullBuffer,
}

/// `std::result::Result` with [`GpuError`] as the default error.
pub type Result<T, E = GpuError> = std::result::Result<T, E>;

/// Maps a failed Vulkan call into a [`GpuError`] that names the call.
pub(crate) fn vk_err(call: &'static str) -> impl Fn(vk::Result) -> GpuError {
    move |code| match code {
        vk::Result::ERROR_OUT_OF_DEVICE_MEMORY | vk::Result::ERROR_OUT_OF_HOST_MEMORY => {
            GpuError::OutOfMemory { call }
        }
        vk::Result::ERROR_DEVICE_LOST => GpuError::DeviceLost {
            last_pass: format!("unknown (during {call})"),
        },
        code => GpuError::Vulkan { call, code },
    }
}

/// Locks `m` even where a thread panicked while holding it: what vkrt keeps behind its
/// locks (the queue handle, the allocator, the kernel cache, validation messages) stays whole
/// across a panic elsewhere, and a second panic would turn one failure into many.
pub(crate) fn lock<T>(m: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Our own misuse of the API: a bug in the caller, not a runtime condition.
#[cold]
#[track_caller]
pub(crate) fn usage_error(msg: &str) -> ! {
    panic!("vkrt gpu usage error: {msg}")
}
