//! Acceleration structures and what they are built over.
//!
//! - [`primitives`]: the scene flattened into triangles and spheres (with motion), the input
//!   every builder reads; [`geometry`]: the same described as the caller's own device buffers;
//!   [`geometry_shape`]: described by their counts alone, for sizes.
//! - [`kdtree`]: the SAH kd-tree built breadth-first on the GPU with exact SAH at every level
//!   and split-axis clipping (after Wu, Zhao & Liu 2011), its CPU twin, and the classic
//!   full-clipping CPU build as the quality reference.
//! - [`bvh`]: the CPU SAH BVH (sweep and binned builders and their threading schemes), the GPU
//!   LBVH (Karras 2012) and PLOC (Meister & Bittner 2018) with SAH collapse and refit, and the
//!   4-wide quantized nodes (Ylitie, Karras & Laine 2017).
//! - [`device`]: one builder over every kind, sized, created in the caller's memory and
//!   recorded into its command buffer; [`gpu_geometry`] pairs a structure with its primitives;
//!   [`embedded`] builds over the caller's buffers, [`batch`] several such structures at
//!   once, [`compact`] copies a built kd-tree into the bytes it uses; [`driver`] maps the
//!   same scene to the driver's own acceleration structures.
//! - [`sync`]: the stages and accesses each record call touches first and leaves last.
//! - [`instances`]: two levels, a top level over instances of bottom-level structures.
//! - [`walk`]: which walk a kernel runs over a structure; [`shader_library`]: what a
//!   renderer's own shader binds to walk it.
//!
//! Node layouts are shared byte for byte with GLSL.
#![forbid(unsafe_code)]

pub mod batch;
pub mod bvh;
pub mod compact;
pub mod device;
pub mod device_input;
pub mod device_primitives;
pub mod driver;
pub(crate) mod driver_levels;
pub mod embedded;
pub mod geometry;
pub mod geometry_shape;
pub mod gpu_geometry;
pub mod host;
pub mod instance;
pub mod instances;
pub mod kdtree;
pub mod primitives;
pub mod shader_library;
pub mod sizes;
pub mod sync;
pub mod two_levels;
pub mod walk;
