//! What a structure over the caller's device geometry is created for: the geometries' layout
//! and shape and the build flags, which every build and update into it must match.

use crate::accel::driver::Prefer;
use crate::accel::geometry::{Geometry, GeometryLayout};
use crate::gpu::{Context, Result};

/// How a structure is built (`VkBuildAccelerationStructureFlagsKHR`, and the kd-tree's
/// capacity).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BuildFlags {
    /// What the driver's builder optimises for (vkrt's own builders have one way each).
    pub prefer: Prefer,
    /// The structure will be updated
    /// ([`AccelBuilder::record_update_from`](crate::accel::device::AccelBuilder::record_update_from)).
    pub allow_update: bool,
    /// The kd-tree's reference budget per level doubled this many times (0 at first; one
    /// more after [`BuildStatus::kd_overflow`](crate::accel::embedded::BuildStatus::kd_overflow)).
    pub kd_capacity_doublings: u32,
}

/// What a structure over the caller's geometry was created for.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct DeviceInput {
    pub(crate) layout: GeometryLayout,
    /// Per geometry: a triangle geometry (else spheres), and its primitive count.
    pub(crate) shape: Vec<(bool, u32)>,
    pub(crate) flags: BuildFlags,
    /// A build has been recorded (tracing or updating before one is an error).
    pub(crate) built: bool,
}

impl DeviceInput {
    pub(crate) fn new(ctx: &Context, geometries: &[Geometry], flags: BuildFlags) -> Result<Self> {
        Ok(Self {
            layout: GeometryLayout::of(ctx, geometries)?,
            shape: shape(geometries),
            flags,
            built: false,
        })
    }
}

pub(crate) fn shape(geometries: &[Geometry]) -> Vec<(bool, u32)> {
    geometries
        .iter()
        .map(|g| (matches!(g, Geometry::Triangles(_)), g.primitive_count()))
        .collect()
}
