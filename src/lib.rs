//! vkrt: a Vulkan-native ray-tracing engine whose acceleration structures are built on the
//! GPU with raw Vulkan compute, meant to be read, embedded and profiled.
//!
//! Build a structure on the GPU and trace rays against it:
//!
//! ```
//! use vkrt::glam::Vec3;
//! use vkrt::{AccelBuilder, AccelKind, Context, ContextOptions, GpuGeometry, Ray, Recorder};
//! use vkrt::{TraceGeometry, TraceOptions, Tracer};
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! # /*
//! let ctx = Context::new(&ContextOptions::default())?;
//! # */
//! # let ctx = Context::new(&ContextOptions::for_tests())?; // validation as the tests run it
//! let triangle = [Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, -1.0, 0.0), Vec3::Y];
//! let geometry = TraceGeometry::from_triangles(&[triangle]);
//!
//! // Karras's LBVH, built by GPU kernels in one submission.
//! let builder = AccelBuilder::new(&ctx, AccelKind::Lbvh)?;
//! let mut rec = Recorder::new(&ctx)?;
//! let (structure, _) = GpuGeometry::record_build(&mut rec, &builder, &geometry, 0)?;
//! rec.submit_and_wait()?;
//!
//! let walk = AccelKind::Lbvh.walked(Default::default());
//! let tracer = Tracer::for_accel(&ctx, &TraceOptions::default(), walk)?;
//! let ray = Ray::new(Vec3::new(0.0, 0.0, 2.0), -Vec3::Z, 0.0, f32::INFINITY);
//! let batch = tracer.trace(&ctx, &structure, &[ray], 0.0)?;
//! assert!(batch.hits[0].is_hit());
//! assert_eq!(batch.hits[0].t, 2.0);
//! # let messages = ctx.take_validation_messages();
//! # assert!(messages.is_empty(), "validation: {messages:?}");
//! # Ok(())
//! # }
//! ```
//!
//! A renderer embeds vkrt on its own terms ([`Context::from_raw`] adopts its device,
//! [`accel::geometry`] describes its vertex and index buffers, [`AccelBuilder::create_in`]
//! places a structure in its memory, `vkrt/ray_query.glsl` traces from its own shaders):
//! the guide is [`guide::embedding`]. Cargo features, thread safety (which types are `Send`
//! and `Sync`), versioning and the minimum Rust version: [`guide::versioning`].
//!
//! Layers (calls go downward only): [`gpu`] (all Vulkan, all `unsafe`), [`prims`] (scans,
//! reductions, sorts), [`scene`] (the host-side model), [`accel`] (the builders), [`trace`]
//! (the walks) and [`render`]; [`verify`] checks them all on a device. The scene loaders, the
//! renderer and the checks are the features `scene-files`, `render` and `verify`
//! ([`guide::versioning`]).

#![deny(unsafe_code)]
#![warn(unsafe_op_in_unsafe_fn, clippy::undocumented_unsafe_blocks)]
// Every public item says what it is: CI builds with `-D warnings`.
#![warn(missing_docs)]

#[allow(
    unsafe_code,
    reason = "the gpu layer is the one place that talks to Vulkan"
)]
pub mod gpu;

pub mod accel;
pub mod guide;
pub mod host;
pub mod prims;
#[cfg(feature = "render")]
pub mod render;
pub mod scene;
// A renderer's GL_EXT_ray_query shaders run over a scene through vkrt and the driver
// (`vkrt shader-check`).
#[cfg(feature = "scene-files")]
pub mod shader_check;
pub mod spirv;
pub mod trace;
#[cfg(feature = "verify")]
pub mod verify;

pub use glam;

pub use accel::batch::BuildTarget;
pub use accel::compact::CompactedSize;
pub use accel::device::{AccelBuilder, AccelChoice, AccelKind, AccelSizes, AccelStructure};
pub use accel::embedded::{
    BuildFlags, BuildStatus, DRIVER_BUFFER_USAGE, GEOMETRY_BUFFER_USAGE,
    REFERENCEABLE_BUFFER_USAGE, REFERENCEABLE_MEMORY_FLAGS, REQUIRED_BUFFER_USAGE,
};
pub use accel::geometry::{
    Aabbs, Geometry, IndexType, Indices, Spheres, Transform, Triangles, VertexFormat,
};
pub use accel::geometry_shape::GeometryShape;
pub use accel::gpu_geometry::GpuGeometry;
pub use accel::instance::Instance;
pub use accel::instances::{TopLevel, TopLevelBuilder};
pub use accel::primitives::TraceGeometry;
pub use accel::sync::{RecordSync, StageAccess};
pub use gpu::{
    BindingCache, Buffer, Context, ContextOptions, DeviceFeatures, DeviceInfo, GpuError, Memory,
    PlacementProblem, RawBuffer, RawParts, RecordedWork, Recorder, Validation,
};
pub use scene::Scene;
pub use trace::gpu::Tracer;
pub use trace::{Hit, Intersector, Query, Ray, TraceOptions};
