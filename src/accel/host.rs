//! Structures on the host: a device structure downloaded ([`HostStructure`], for tests and
//! tools), and a tree built on the host uploaded as a device structure ([`HostRef`],
//! [`upload_structure`]): the CPU twins' trees, or a downloaded one. [`host_twin`]: what a
//! kind builds on the device, built on the CPU, bit for bit.

use crate::accel::bvh::collapse::{collapse, collapse_in_place};
use crate::accel::bvh::device::BvhStorage;
use crate::accel::bvh::lbvh::{self, MortonBits};
use crate::accel::bvh::ploc::{self, PlocParams};
use crate::accel::bvh::{self, Bvh, BvhParams, Threading};
use crate::accel::device::{AccelBuilder, AccelKind, AccelStructure, Storage};
use crate::accel::device_primitives::DevicePrimitives;
use crate::accel::kdtree::device::KdStorage;
use crate::accel::kdtree::{breadth_first, KdTree, SahParams};
use crate::accel::primitives::{SceneInfo, TraceGeometry};
use crate::accel::walk::{AccelTraversal, Traversal};
use crate::gpu::{Buffer, Context, GpuError, Result};
use crate::scene::Aabb;
use bytemuck::Zeroable;

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
            Storage::Driver(_) => Err(GpuError::Usage {
                call: "AccelStructure::download",
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
                true => AccelTraversal::Bvh(Traversal::Wide),
                false => AccelTraversal::Bvh(Traversal::Stack),
            }
            .scene_walk();
            let constants = prims.info(&bvh.bounds, bvh.refs.len() as u32).walked(walk);
            let storage = Storage::Bvh(BvhStorage::from_host(ctx, bvh, wide)?);
            (AccelKind::SahBvh, storage, constants)
        }
    };
    // (and the structure's handle after them, written once its buffers have addresses)
    let info = Buffer::from_slice(ctx, "accel.info", &[constants, SceneInfo::zeroed()])?;
    Ok(AccelStructure::from_parts(kind, storage, info))
}

/// The settings a CPU twin builds with: those of the device builder it twins.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TwinParams {
    /// The kd-tree's SAH costs and termination rules.
    pub kd: SahParams,
    /// The BVHs' SAH costs and leaf size (the GPU builders' leaf collapse).
    pub bvh: BvhParams,
    /// The LBVH's Morton code width.
    pub morton_bits: MortonBits,
    /// PLOC's knobs.
    pub ploc: PlocParams,
    /// How the SAH BVH's build uses threads (the tree is the same for every scheme).
    pub threading: Threading,
}

impl Default for TwinParams {
    fn default() -> Self {
        Self {
            kd: SahParams::default(),
            bvh: BvhParams::default(),
            morton_bits: MortonBits::default(),
            ploc: PlocParams::default(),
            threading: Threading::all_cores(),
        }
    }
}

/// What `kind` builds on the device over `g` with `p`, built on the host by its CPU twin,
/// bit for bit: the breadth-first kd-tree, the SAH BVH, and the LBVH's and PLOC's trees with
/// the SAH leaf collapse as the device lays them out. The driver's structure is opaque: the
/// SAH BVH stands in for it.
pub fn host_twin(kind: AccelKind, g: &TraceGeometry, p: &TwinParams) -> Result<HostStructure> {
    let boxes = &g.boxes;
    Ok(match kind {
        AccelKind::KdTree => HostStructure::KdTree(breadth_first::build_boxes(boxes, &p.kd).0),
        AccelKind::SahBvh | AccelKind::Driver => {
            HostStructure::Bvh(bvh::build(boxes, &p.bvh, p.threading).map_err(|e| {
                GpuError::Kernel {
                    kernel: "accel.sah_bvh",
                    reason: e.to_string(),
                }
            })?)
        }
        AccelKind::Lbvh => HostStructure::Bvh(collapse_in_place(
            &lbvh::build(boxes, p.morton_bits),
            &p.bvh,
        )),
        AccelKind::Ploc => HostStructure::Bvh(collapse(&ploc::build(boxes, &p.ploc).0, &p.bvh)),
    })
}

impl AccelBuilder {
    /// The settings of this builder's CPU twin.
    pub fn twin_params(&self) -> TwinParams {
        TwinParams {
            kd: self.kd_params(),
            bvh: self.bvh_params(),
            morton_bits: self.lbvh_bits(),
            ploc: self.ploc_params().unwrap_or_default(),
            threading: self.threading(),
        }
    }

    /// [`host_twin`] of this builder's kind and settings: what it builds over `g`, built on
    /// the CPU.
    pub fn host_twin(&self, g: &TraceGeometry) -> Result<HostStructure> {
        host_twin(self.kind(), g, &self.twin_params())
    }
}
