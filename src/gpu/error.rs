//! The one error type of the `gpu` layer. Each Vulkan call maps its result where it is made,
//! naming the call, so an error says what failed rather than only a `VkResult`.

use ash::vk;

/// What can go wrong in the GPU layer.
#[derive(Clone, Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GpuError {
    #[error("cannot load the Vulkan loader (libvulkan.so.1): {0}; install libvulkan1 and a driver (e.g. mesa-vulkan-drivers for lavapipe)")]
    Loader(String),
    #[error("no usable Vulkan device: {0}")]
    NoDevice(String),
    #[error("device `{device}` lacks a required capability: {what}")]
    MissingCapability { device: String, what: String },
    #[error("{call} failed: {code}")]
    Vulkan {
        call: &'static str,
        code: vk::Result,
    },
    #[error("out of GPU memory during {call}")]
    OutOfMemory { call: &'static str },
    #[error("device lost (last pass recorded before the loss: {last_pass})")]
    DeviceLost { last_pass: String },
    #[error("allocation of buffer `{name}` ({bytes} bytes) failed: {reason}")]
    Allocation {
        name: String,
        bytes: u64,
        reason: String,
    },
    #[error("buffer `{name}` needs {bytes} bytes, above this device's maxStorageBufferRange of {limit} bytes; split the data or use a device with a larger limit")]
    BufferTooLarge {
        name: String,
        bytes: u64,
        limit: u64,
    },
    #[error("kernel `{kernel}`: {reason}")]
    Kernel {
        kernel: &'static str,
        reason: String,
    },
    /// A structure or scratch placed in a caller's buffer that does not fit or is misaligned.
    #[error("placement: {0}")]
    Placement(String),
    /// A call the API refuses: wrong sizes, wrong kind, a buffer too small for the work.
    #[error("{call}: {reason}")]
    Usage { call: &'static str, reason: String },
    #[error("cannot write {path}: {reason}")]
    Io { path: String, reason: String },
}

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

/// Our own misuse of the API: a bug in the caller, not a runtime condition.
#[cold]
#[track_caller]
pub(crate) fn usage_error(msg: &str) -> ! {
    panic!("vkrt gpu usage error: {msg}")
}
