//! Bounding volume hierarchies: the binary two-boxes-per-node layout the traversal reads
//! ([`layout`]), Sochora's (2013) multithreaded CPU SAH builder ([`sah`]), the refit that follows
//! moved primitives ([`refit`](mod@refit), CPU twin of the GPU kernel), and a structural validator
//! with the SAH cost of a built tree ([`validate`]); the GPU builders' LBVH ([`lbvh`]) and
//! PLOC ([`ploc`]) with the SAH leaf collapse of their trees ([`collapse`]) and the compaction
//! that renumbers a collapsed tree densely ([`compact`]); and the 4-wide quantized layout
//! every BVH can be walked in ([`wide`]).

pub mod collapse;
pub mod collapse_gpu;
pub mod compact;
pub mod compact_gpu;
pub(crate) mod device;
pub mod layout;
pub mod lbvh;
pub mod lbvh_gpu;
pub mod ploc;
pub mod ploc_gpu;
pub mod refit;
pub mod refit_gpu;
pub mod sah;
pub mod validate;
pub mod wide;
pub mod wide_gpu;

pub use layout::{Bvh, BvhNode, Child, NO_NODE};

/// The GPU profiler scopes of the GPU BVH builds (LBVH: bounds, Morton codes, sort,
/// topology, boxes; PLOC: the same sort, then its clusters and rounds; both: the SAH leaf
/// collapse).
pub const GPU_BUILD_PASSES: [&str; 8] = [
    "lbvh.bounds",
    "lbvh.morton",
    "lbvh.sort",
    "lbvh.climb",
    "refit",
    "ploc.init",
    "ploc.rounds",
    "collapse",
];
pub use refit::refit;
pub use sah::{build, build_timed, BvhError, BvhParams, Threading};

/// The variant of a kernel that moves whole BVH nodes, boxes or codes: `pairs64` (64-bit
/// pairs, `PAIRS64`) where the device has `shaderInt64`, else `words`. On lavapipe every
/// load or store at a lane-varying address loops over lanes and components, so a 64-bit
/// component moves two words in one trip.
pub(crate) fn pairs_variant(
    ctx: &crate::gpu::Context,
    pairs64: &'static crate::gpu::ShaderBlob,
    words: &'static crate::gpu::ShaderBlob,
) -> &'static crate::gpu::ShaderBlob {
    if ctx.info().features.shader_int64 {
        pairs64
    } else {
        words
    }
}
