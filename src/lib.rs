//! vkrt: a Vulkan-native ray-tracing engine whose acceleration structures are built on the
//! GPU with raw Vulkan compute, meant to be read, embedded and profiled.
//!
//! Layers (calls go downward only): [`gpu`] (all Vulkan, all `unsafe`), then the host-side
//! [`scene`] model. See `README.md` for the architecture.

#![deny(unsafe_code)]
#![warn(unsafe_op_in_unsafe_fn, clippy::undocumented_unsafe_blocks)]

#[allow(
    unsafe_code,
    reason = "the gpu layer is the one place that talks to Vulkan"
)]
pub mod gpu;

pub mod accel;
#[cfg(feature = "cli")]
pub mod accuracy;
#[cfg(feature = "cli")]
pub mod bench;
pub mod prims;
pub mod render;
pub mod scene;
pub mod trace;
pub mod verify;
