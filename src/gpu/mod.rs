//! Everything that touches Vulkan, and the only place with `unsafe` code.
//!
//! - [`Context`]: instance, device and queue — headless, or adopted from an embedding
//!   renderer with [`Context::from_raw`];
//! - [`Buffer`]: typed storage buffers on gpu-allocator;
//! - [`Kernel`]: compute pipelines from the SPIR-V that `build.rs` embeds ([`kernels`]);
//! - [`BindingCache`]: descriptor sets and texel views prepared once for every frame;
//! - [`Recorder`]: dispatches, copies, fills, barrier helpers named by what they order, and
//!   profiler scopes — into its own command buffer or the caller's;
//! - [`Profile`]: per-pass GPU milliseconds and a Chrome-trace/Perfetto export, on one time
//!   axis with the host's spans ([`timeline`]);
//! - [`AccelerationStructure`]: the driver's own structures (`VK_KHR_acceleration_structure`),
//!   where the device has ray query;
//! - [`ScopeHook`]: every scope and dispatch with its queries as it is recorded, and their
//!   ticks once done, for a renderer's own profiler (`tracy::TracyScopes` with the `tracy`
//!   feature);
//! - [`ForeignKernel`]: a pipeline over a renderer's own SPIR-V and the layout it states;
//! - [`Validation`]: the Khronos layer with synchronization validation, for tests.
//!
//! Rules: every `unsafe` block states the contract it relies on; Vulkan errors are mapped
//! where the call is made into [`GpuError`] naming the call; misuse of this API by our own
//! code panics through one cold helper.

mod accel_ext;
mod bindings;
mod buffer;
pub(crate) mod teardown;
pub(crate) use buffer::BufferId;
pub use teardown::Busy;
mod capture;
mod context;
mod error;
mod foreign;
mod hook;
mod info;
mod kernel;
mod pipeline;
mod pipeline_cache;
mod profiler;
mod recorder;
mod shader;
mod stats;
pub mod timeline;
#[cfg(feature = "tracy")]
pub mod tracy;
mod validation;

pub use accel_ext::{
    accel_build_sizes, accel_scratch, require_ray_query, AccelGeometry, AccelInstance,
    AccelerationStructure, DriverBuildSizes,
};
pub use ash::vk;
pub use bindings::BindingCache;
pub use buffer::{
    address_of, placement, Buffer, BufferArg, CopiedStructure, DeviceRange, Memory, RawBuffer,
    TexelView,
};
pub use context::{Context, ContextOptions, ExtraFeatures, MemoryUsage, RawParts, Traffic};
pub use error::{GpuError, PlacementProblem, Result};
pub use foreign::{ForeignBinding, ForeignKernel};
pub use hook::{CompletedScope, QuerySlot, RecordedScope, ScopeHook};
pub use info::{
    device_requirements, mesa_version, traversal_steps_within, CalibratedTimestamps,
    DeviceFeatureRequest, DeviceFeatures, DeviceInfo, DeviceRequirements, LLVMPIPE_LOOP_BUDGET,
};
pub use kernel::{Kernel, Spec, PUSH_CONSTANT_BYTES};
pub use profiler::{
    capture as capture_profiles, write_atomically, PassBytes, PassTime, Profile, ProfiledDevice,
    ScopeKind, Spread, Submission, DEFAULT_QUERY_CAPACITY,
};
pub use recorder::{Readback, RecordCounts, RecordedWork, Recorder};
pub use shader::{find as find_kernel, kernels, ShaderBlob};
pub use timeline::{host_span, record_host_span, Calibration, HostSpan};
pub use validation::{Validation, ValidationMessage};
