//! What a structure over the caller's device geometry is created for: the geometries' layout
//! and shape and the build flags, which every build and update into it must match.

use crate::accel::geometry::GeometryLayout;
use crate::accel::geometry_shape::{GeometryDescription, GeometryShape};
use crate::accel::walk::{AccelChoice, AccelKind, Prefer, Traversal};
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
    /// BVH kinds: also make the 4-wide nodes ([`crate::accel::bvh::wide`]) after every build
    /// and update, for the wide walk (`Traversal::Wide`), in place of the binary ones the
    /// shaders bind. A top level's own nodes stay binary (the instance walk reads those).
    pub wide: bool,
}

impl BuildFlags {
    /// The flags of `choice`: its driver preference, and wide nodes for the wide walk.
    pub fn for_choice(choice: AccelChoice) -> Self {
        Self {
            prefer: choice.prefer,
            wide: choice.walk == Traversal::Wide
                && matches!(
                    choice.kind,
                    AccelKind::SahBvh | AccelKind::Lbvh | AccelKind::Ploc
                ),
            ..Self::default()
        }
    }
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
    /// A compacted copy ([`crate::accel::compact`]) of the structure whose scene constants
    /// lie there: it holds that tree's bytes only, and is never built or updated into.
    pub(crate) compacted: Option<(crate::gpu::vk::Buffer, u64)>,
}

impl DeviceInput {
    pub(crate) fn new<G: GeometryDescription>(
        ctx: &Context,
        geometries: &[G],
        flags: BuildFlags,
    ) -> Result<Self> {
        Ok(Self {
            layout: GeometryLayout::of_described(ctx, geometries)?,
            shape: shape(geometries),
            flags,
            built: false,
            compacted: None,
        })
    }
}

pub(crate) fn shape<G: GeometryDescription>(geometries: &[G]) -> Vec<(bool, u32)> {
    geometries
        .iter()
        .map(|g| {
            let s = g.shape();
            (
                matches!(s, GeometryShape::Triangles { .. }),
                s.primitive_count(),
            )
        })
        .collect()
}
