//! Structures on the host: a device structure downloaded ([`HostStructure`], for tests and
//! tools), and a tree built on the host uploaded as a device structure ([`HostRef`],
//! [`upload_structure`]): the CPU twins' trees, or a downloaded one.

use crate::accel::bvh::device::BvhStorage;
use crate::accel::bvh::Bvh;
use crate::accel::device::{AccelKind, AccelStructure, Storage};
use crate::accel::device_primitives::DevicePrimitives;
use crate::accel::kdtree::device::KdStorage;
use crate::accel::kdtree::KdTree;
use crate::accel::primitives::SceneInfo;
use crate::gpu::{Buffer, Context, GpuError, Result};
use crate::scene::Aabb;

/// A structure downloaded to the host (tests and tools).
#[derive(Clone, Debug, PartialEq)]
pub enum HostStructure {
    /// A kd-tree's nodes and references.
    KdTree(KdTree),
    /// A BVH, without the slots a leaf collapse removed (the rest renumbered).
    Bvh(Bvh),
}

/// A host structure to upload, borrowed ([`upload_structure`]).
#[derive(Clone, Copy, Debug)]
pub enum HostRef<'a> {
    /// A kd-tree, walked as one.
    KdTree(&'a KdTree),
    /// A BVH walked by its binary nodes.
    Bvh(&'a Bvh),
    /// A BVH walked wide: its binary nodes and its wide ones ([`Bvh::wide`]).
    WideBvh(&'a Bvh),
}

impl AccelStructure {
    /// The structure as the host sees it (for tests and tools: it reads the whole
    /// structure back).
    pub fn download(&self) -> Result<HostStructure> {
        let info = self.info.download()?[0];
        let bounds = Aabb {
            min: glam::Vec3::from_slice(&info.bounds_min[..3]),
            max: glam::Vec3::from_slice(&info.bounds_max[..3]),
        };
        match self.storage() {
            Storage::KdTree(k) => k.download(&info, bounds).map(HostStructure::KdTree),
            Storage::Bvh(b) => b.download(bounds).map(HostStructure::Bvh),
            Storage::Driver(_) => Err(GpuError::Kernel {
                kernel: "accel.driver",
                reason: "the driver's structure is opaque: it cannot be downloaded".into(),
            }),
        }
    }
}

/// A structure built from a host structure (for tools and tests that built one on the
/// host: the CPU twins' trees, or a downloaded one).
pub fn upload_structure(
    ctx: &Context,
    prims: &DevicePrimitives,
    host: HostRef<'_>,
) -> Result<AccelStructure> {
    let (kind, storage, constants) = match host {
        HostRef::KdTree(tree) => (
            AccelKind::KdTree,
            Storage::KdTree(KdStorage::from_host(ctx, tree)?),
            prims.info(&tree.bounds, 0),
        ),
        HostRef::Bvh(bvh) | HostRef::WideBvh(bvh) => {
            let wide = matches!(host, HostRef::WideBvh(_));
            let walk = match wide {
                true => SceneInfo::WALK_BVH_WIDE,
                false => SceneInfo::WALK_BVH,
            };
            let constants = prims.info(&bvh.bounds, bvh.refs.len() as u32).walked(walk);
            let storage = Storage::Bvh(BvhStorage::from_host(ctx, bvh, wide)?);
            (AccelKind::SahBvh, storage, constants)
        }
    };
    let info = Buffer::from_slice(ctx, "accel.info", &[constants])?;
    Ok(AccelStructure::from_parts(kind, storage, info, false))
}
