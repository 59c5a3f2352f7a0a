//! Acceleration structures: the SAH kd-tree of Kolodzey (2014) (GPU build, CPU twin of the same
//! algorithm, and the classic full-clipping CPU build as the quality reference), with
//! statistics and a structural validator, and the SAH BVH of Sochora (2013) (multithreaded CPU
//! build). Node layouts are shared byte for byte with GLSL.
#![forbid(unsafe_code)]

pub mod bvh;
pub mod device;
pub mod driver;
pub mod embedded;
pub mod geometry;
pub mod instances;
pub mod kdtree;
pub mod shader_library;
