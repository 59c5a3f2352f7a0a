//! Acceleration structures that live on the device, behind one interface shaped like
//! `VK_KHR_acceleration_structure`:
//!
//! 1. [`AccelBuilder::sizes`]: the bytes of the structure, of the build's scratch and of an
//!    update's scratch for a primitive count — asked first, so a caller can allocate;
//! 2. [`AccelBuilder::create`]: the structure's buffers and the scratch at those sizes;
//! 3. [`AccelBuilder::record_build`]: the build recorded into the caller's [`Recorder`], with
//!    no submission and no read-back of its own; the structure's buffers are then bound
//!    where they lie by every kernel that traces (`glsl/include/vkrt/traverse.glsl`, whose walk is
//!    chosen by the `ACCEL_KIND` specialization constant of [`AccelTraversal`]).
//!
//! The GPU kd-tree (Kolodzey 2014) is built by kernels and finished on the device
//! (`accel.kdtree_finish` writes the scene constants, and an empty root if the build ran
//! out of capacity). The SAH BVH (Sochora 2013) is a host builder, as Embree's are: it reads the
//! host's copy of the primitive boxes and records the upload of its nodes. Downloading a
//! structure ([`AccelStructure::download`]) is for tests and tools only.

use crate::accel::bvh::collapse::{self, RefLayout};
use crate::accel::bvh::collapse_gpu::{CollapseKernels, CollapseScratch};
use crate::accel::bvh::lbvh::MortonBits;
use crate::accel::bvh::lbvh_gpu::LbvhBuilder;
use crate::accel::bvh::ploc::PlocParams;
use crate::accel::bvh::ploc_gpu::{PlocBuilder, PlocScratch};
use crate::accel::bvh::refit_gpu::{LevelRefit, RefitSchedule, ScheduleScratch};
use crate::accel::bvh::wide::{WideNode, MAX_WIDE_LEAF};
use crate::accel::bvh::wide_gpu::Widen;
use crate::accel::bvh::{self, Bvh, BvhNode, BvhParams, Threading};
use crate::accel::driver::{DriverAccel, DriverInput, Prefer};
use crate::accel::kdtree::gpu::{BuildCapacity, BuildOutput, BuildScratch, KdTreeBuilder};
use crate::accel::kdtree::{KdNode, KdTree, SahParams};
use std::sync::Arc;

pub use crate::accel::device_primitives::DevicePrimitives;
use crate::accel::primitives::{SceneInfo, TraceGeometry};
pub use crate::accel::sizes::AccelSizes;
use crate::accel::walk::AccelTraversal;
use crate::accel::walk::Traversal;
use crate::gpu::{
    kernels, require_ray_query, AccelGeometry, Buffer, BufferArg, Context, GpuError, Kernel,
    Readback, Recorder, Result, Spec,
};
use crate::scene::Aabb;

/// Where the LBVH's collapse puts the references: its references lie in Morton order, depth
/// first, so the collapse leaves them in place.
const LBVH_REFS: RefLayout = RefLayout::InPlace;
/// PLOC's references are in no such order: its collapse lays them out in node order.
const PLOC_REFS: RefLayout = RefLayout::NodeOrder;

/// The refit's workgroups are one subgroup each (`accel.bvh_refit` explains why).
fn refit_workgroup(ctx: &Context) -> u32 {
    ctx.info().subgroup_size.max(1)
}

/// The structures vkrt builds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum AccelKind {
    /// Kolodzey's (2014) SAH kd-tree, built on the GPU.
    #[default]
    KdTree,
    /// Sochora's (2013) SAH BVH, built on the host's cores and uploaded.
    SahBvh,
    /// Karras's LBVH (2012), built on the GPU.
    Lbvh,
    /// PLOC (Meister & Bittner 2018), built on the GPU.
    Ploc,
    /// The driver's own (`VK_KHR_acceleration_structure`), queried with `VK_KHR_ray_query`:
    /// the peer vkrt's structures are measured against, where the device has it.
    Driver,
}

impl AccelKind {
    /// The structures vkrt itself builds (every device runs them).
    pub const ALL: [AccelKind; 4] = [
        AccelKind::KdTree,
        AccelKind::SahBvh,
        AccelKind::Lbvh,
        AccelKind::Ploc,
    ];

    /// The CLI name (`--accel`).
    pub fn name(self) -> &'static str {
        match self {
            AccelKind::KdTree => "kdtree",
            AccelKind::SahBvh => "sah-bvh",
            AccelKind::Lbvh => "lbvh",
            AccelKind::Ploc => "ploc",
            AccelKind::Driver => "driver",
        }
    }

    /// How kernels walk this kind (`traversal` applies to vkrt's BVHs).
    pub fn walked(self, traversal: Traversal) -> AccelTraversal {
        match self {
            AccelKind::KdTree => AccelTraversal::KdTree,
            AccelKind::SahBvh | AccelKind::Lbvh | AccelKind::Ploc => AccelTraversal::Bvh(traversal),
            AccelKind::Driver => AccelTraversal::RayQuery,
        }
    }

    /// [`AccelKind::ALL`], and the driver's where `ctx`'s device has ray query.
    pub fn available(ctx: &Context) -> Vec<AccelKind> {
        let mut kinds = Self::ALL.to_vec();
        if ctx.info().features.ray_query {
            kinds.push(AccelKind::Driver);
        }
        kinds
    }

    /// Whether one walk serves it (no `--traversal` choice).
    fn single_walk(self) -> bool {
        matches!(self, AccelKind::KdTree | AccelKind::Driver)
    }
}

/// What `--accel` and `--traversal` choose: a structure and how kernels walk it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize)]
pub struct AccelChoice {
    /// The structure built.
    pub kind: AccelKind,
    /// How a BVH is walked (ignored for a kd-tree and the driver's structure).
    pub walk: Traversal,
    /// What the driver's builder optimises for (the driver's structure only).
    pub prefer: Prefer,
}

impl AccelChoice {
    /// `kind` walked by `walk` (the default walk for kinds with one walk: the kd-tree and
    /// the driver's), with the driver's default preference.
    pub fn new(kind: AccelKind, walk: Traversal) -> Self {
        let walk = if kind.single_walk() {
            Traversal::default()
        } else {
            walk
        };
        Self {
            kind,
            walk,
            prefer: Prefer::default(),
        }
    }

    /// The driver's structure built with `prefer`.
    pub fn driver(prefer: Prefer) -> Self {
        Self {
            prefer,
            ..Self::new(AccelKind::Driver, Traversal::default())
        }
    }

    /// The walk the kernels compile in (`ACCEL_KIND`).
    pub fn traversal(self) -> AccelTraversal {
        self.kind.walked(self.walk)
    }

    /// Every structure vkrt builds with every walk, for suites and benchmarks.
    pub fn all() -> Vec<Self> {
        Self::every(AccelKind::ALL.to_vec())
    }

    /// [`AccelChoice::all`], and the driver's structure where `ctx`'s device has it.
    pub fn all_on(ctx: &Context) -> Vec<Self> {
        Self::every(AccelKind::available(ctx))
    }

    fn every(kinds: Vec<AccelKind>) -> Vec<Self> {
        kinds
            .into_iter()
            .flat_map(|kind| {
                let walks: &[Traversal] = if kind.single_walk() {
                    &[Traversal::Stack]
                } else {
                    &Traversal::ALL
                };
                walks.iter().map(move |&w| Self::new(kind, w))
            })
            .collect()
    }

    /// `kdtree`, `sah-bvh/stack`, `lbvh/bitstack`, ...
    pub fn label(self) -> String {
        match (self.kind, self.prefer) {
            (AccelKind::Driver, Prefer::FastBuild) => format!("driver/{}", self.prefer.name()),
            (AccelKind::KdTree | AccelKind::Driver, _) => self.kind.name().to_string(),
            _ => format!("{}/{}", self.kind.name(), self.walk.name()),
        }
    }
}

/// A structure in device memory: what the traversal binds as `nodes`, `prim_refs` and
/// the scene constants.
pub struct AccelStructure {
    kind: AccelKind,
    storage: Storage,
    /// The scene constants (root box, primitive counts, walk) the traversal binds.
    pub info: Buffer<SceneInfo>,
    /// Built to be updated (`ALLOW_UPDATE`).
    allow_update: bool,
}

enum Storage {
    KdTree {
        out: Box<BuildOutput>,
        /// Written by `accel.kdtree_finish`: nodes, references, overflow flag, references
        /// the overflowing level needed.
        built: Buffer<u32>,
    },
    Bvh {
        nodes: Buffer<BvhNode>,
        /// References, then one parent link per node.
        refs: Buffer<u32>,
        /// Nodes and references of the built tree.
        counts: (usize, usize),
        /// The refit's schedule, for a structure built to be updated.
        schedule: Option<Box<RefitSchedule>>,
        /// The 4-wide nodes, one per binary slot, for a structure walked wide: bound in
        /// place of the binary nodes.
        wide: Option<Buffer<WideNode>>,
    },
    Driver {
        /// Recorded by the build.
        accel: Option<Box<DriverAccel>>,
        /// The TLAS's device address: the `nodes` binding of the `query` kernels.
        address: Buffer<u64>,
        /// The `prim_refs` binding: the first primitive id of each instance.
        bases: Buffer<u32>,
    },
}

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

/// What a kd-tree build recorded on the device reports once it has executed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct KdBuilt {
    /// Nodes written (1, the empty root, when the build overflowed or had no primitives).
    pub nodes: u32,
    /// Primitive references written (0 when the build overflowed or had no primitives).
    pub refs: u32,
    /// The build ran out of capacity: the structure is an empty leaf (every ray misses).
    pub overflow: bool,
    /// References the level that overflowed needed (what to grow the budget to).
    pub needed_refs: u32,
}

impl AccelStructure {
    /// The driver's two levels over `instances` of `levels` (their primitives uploaded
    /// before, into `rec` or earlier), recorded into `rec`: a structure the `query` kernels
    /// trace with level `bound`'s primitives bound (see [`DriverAccel::record_instanced`]).
    pub(crate) fn record_driver_instanced(
        rec: &mut Recorder,
        levels: &[&DevicePrimitives],
        instances: &[crate::accel::instance::Instance],
        bound: usize,
        prefer: Prefer,
    ) -> Result<(Self, crate::accel::driver::InstancedIds)> {
        let ctx = rec.context().clone();
        let (accel, ids) = DriverAccel::record_instanced(rec, levels, instances, bound, prefer)?;
        let info = Buffer::new(&ctx, "accel.info", 1)?;
        let address = Buffer::new(&ctx, "accel.driver.address", 1)?;
        let bases = Buffer::new(&ctx, "accel.driver.bases", ids.bases.len())?;
        let constants = match levels.get(bound) {
            Some(p) => p.info(&Aabb::EMPTY, 0),
            None => SceneInfo::new(&Aabb::EMPTY, [0, 0, 0], false, 0),
        };
        rec.update(&info, 0, &[constants.walked(SceneInfo::WALK_RAY_QUERY)])?;
        rec.update(&address, 0, &[accel.tlas_address()])?;
        for (k, chunk) in ids.bases.chunks(8192).enumerate() {
            rec.update(&bases, 8192 * k, chunk)?;
        }
        rec.transfer_to_compute();
        let out = AccelStructure {
            kind: AccelKind::Driver,
            storage: Storage::Driver {
                accel: Some(Box::new(accel)),
                address,
                bases,
            },
            info,
            allow_update: false,
        };
        Ok((out, ids))
    }

    /// The kind of structure this is.
    pub fn kind(&self) -> AccelKind {
        self.kind
    }

    /// Bytes of the driver's structure (all its levels), once its build is recorded; `None`
    /// for vkrt's structures (their size is that of the downloaded tree).
    pub fn driver_bytes(&self) -> Option<u64> {
        match &self.storage {
            Storage::Driver { accel, .. } => accel.as_ref().map(|a| a.structure_bytes()),
            _ => None,
        }
    }

    /// The driver's levels, where this is the driver's structure and they exist.
    pub(crate) fn driver_levels(&mut self) -> Option<&mut Option<Box<DriverAccel>>> {
        match &mut self.storage {
            Storage::Driver { accel, .. } => Some(accel),
            _ => None,
        }
    }

    pub(crate) fn driver_levels_ref(&self) -> Option<Option<&DriverAccel>> {
        match &self.storage {
            Storage::Driver { accel, .. } => Some(accel.as_deref()),
            _ => None,
        }
    }

    /// Whether the structure has wide nodes ([`AccelBuilder::wide`]): the wide walk, and no
    /// other, serves it.
    pub fn is_wide(&self) -> bool {
        matches!(&self.storage, Storage::Bvh { wide: Some(_), .. })
    }

    /// The device's binary and wide node slots of a BVH walked wide (tests and tools: the
    /// wide nodes against their CPU twin, [`crate::accel::bvh::wide::widen`] of the binary
    /// slots); `None` for other structures.
    pub fn download_wide(&self) -> Result<Option<(Vec<BvhNode>, Vec<WideNode>)>> {
        match &self.storage {
            Storage::Bvh {
                nodes,
                wide: Some(wide),
                counts,
                ..
            } => {
                let mut binary = nodes.download()?;
                let mut w = wide.download()?;
                binary.truncate(counts.0);
                w.truncate(counts.0);
                Ok(Some((binary, w)))
            }
            _ => Ok(None),
        }
    }

    /// The `nodes` and `prim_refs` bindings of `traverse.glsl` (a BVH walked wide: its wide
    /// nodes).
    pub fn node_bindings(&self) -> [&dyn BufferArg; 2] {
        match &self.storage {
            Storage::KdTree { out, .. } => [&out.nodes[0], &out.prim_refs],
            Storage::Bvh {
                wide: Some(wide),
                refs,
                ..
            } => [wide, refs],
            Storage::Bvh { nodes, refs, .. } => [nodes, refs],
            Storage::Driver { address, bases, .. } => [address, bases],
        }
    }

    /// Records the copy of a kd-tree build's report to the host (16 bytes), read with
    /// [`AccelStructure::kd_built`] after the work has executed; `None` for other kinds.
    pub fn record_read_built(&self, rec: &mut Recorder) -> Result<Option<Readback<u32>>> {
        match &self.storage {
            Storage::KdTree { built, .. } => rec.read_back(built).map(Some),
            Storage::Bvh { .. } | Storage::Driver { .. } => Ok(None),
        }
    }

    /// Decodes a kd-tree build's report.
    pub fn kd_built(words: &[u32]) -> KdBuilt {
        KdBuilt {
            nodes: words[0],
            refs: words[1],
            overflow: words[2] != 0,
            needed_refs: words[3],
        }
    }

    /// The structure as the host sees it (for tests and tools: it reads the whole
    /// structure back).
    pub fn download(&self) -> Result<HostStructure> {
        let info = self.info.download()?[0];
        let bounds = |empty: bool| {
            if empty {
                Aabb::EMPTY
            } else {
                Aabb {
                    min: glam::Vec3::from_slice(&info.bounds_min[..3]),
                    max: glam::Vec3::from_slice(&info.bounds_max[..3]),
                }
            }
        };
        match &self.storage {
            Storage::KdTree { out, built } => {
                let b = Self::kd_built(&built.download()?);
                if b.overflow {
                    return Err(GpuError::Kernel {
                        kernel: "accel.kdtree",
                        reason: format!(
                            "the build ran out of capacity (a level needed {} references)",
                            b.needed_refs
                        ),
                    });
                }
                let primitives = info.n_tris + info.n_spheres + info.n_aabbs;
                let nodes: Vec<KdNode> = out.download_nodes(b.nodes.max(1) as usize)?;
                let mut prim_refs = out.prim_refs.download()?;
                prim_refs.truncate(b.refs as usize);
                Ok(HostStructure::KdTree(KdTree {
                    nodes,
                    prim_refs,
                    bounds: bounds(primitives == 0),
                    primitives,
                }))
            }
            Storage::Bvh {
                nodes,
                refs,
                counts: (n_nodes, n_refs),
                ..
            } => {
                let mut nodes = nodes.download()?;
                nodes.truncate(*n_nodes);
                let all = refs.download()?;
                // Without the slots a leaf collapse removed.
                let (nodes, parents) =
                    collapse::drop_removed(nodes, &all[*n_refs..*n_refs + *n_nodes]);
                Ok(HostStructure::Bvh(Bvh {
                    nodes,
                    parents,
                    refs: all[..*n_refs].to_vec(),
                    bounds: bounds(*n_refs == 0),
                    wide: Default::default(),
                }))
            }
            Storage::Driver { .. } => Err(GpuError::Kernel {
                kernel: "accel.driver",
                reason: "the driver's structure is opaque: it cannot be downloaded".into(),
            }),
        }
    }
}

/// Scratch of a build.
pub enum AccelScratch {
    /// The GPU kd-tree build's.
    KdTree(Box<BuildScratch>),
    /// The LBVH build's (and its collapse's).
    Lbvh(Box<LbvhScratch>),
    /// The PLOC build's (and its collapse's).
    Ploc(Box<PlocDeviceScratch>),
    /// The driver's builds and updates, for levels placed in a caller's memory.
    Driver(Buffer<u8>),
    /// The builder works in host memory (or the driver's levels keep their own scratch).
    None,
}

/// Builds one kind of structure; compiled once, used for any number of builds.
#[must_use]
pub struct AccelBuilder {
    kind: AccelKind,
    kd: Option<KdTreeBuilder>,
    lbvh: Option<LbvhBuilder>,
    ploc: Option<PlocBuilder>,
    /// `accel.bvh_refit` (BVH kinds).
    refit: Option<Arc<Kernel>>,
    /// The SAH leaf collapse of the GPU builders' trees (LBVH, PLOC), with `bvh_params`'
    /// costs and leaf size (`max_leaf_prims = 1` keeps one primitive per leaf).
    collapse: Option<CollapseKernels>,
    /// The kd-tree build's SAH costs and termination rules.
    pub kd_params: SahParams,
    /// The BVH kinds' SAH costs and leaf size: the SAH builder's, and the GPU builders'
    /// leaf collapse.
    pub bvh_params: BvhParams,
    /// How the SAH BVH's host build uses threads (default: the node queue on every core).
    pub threading: Threading,
    /// What the driver's builder optimises for (the driver's structure).
    pub driver_prefer: Prefer,
    /// Build BVHs to be updated (`VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_UPDATE_BIT_KHR`):
    /// the build also records the refit's schedule, kept with the structure, and refits run
    /// one dispatch per depth (`bvh::refit_gpu`) instead of climbing. Off by default.
    pub allow_update: bool,
    /// `accel.bvh_refit_level` and the schedule's kernels (BVH kinds).
    level_refit: Option<LevelRefit>,
    /// Also make the 4-wide nodes ([`crate::accel::bvh::wide`]) after every build and
    /// refit, for the wide walk (`Traversal::Wide`); BVH kinds only. Set by
    /// [`AccelBuilder::for_choice`] from the choice's walk.
    pub wide: bool,
    /// `accel.bvh_widen` (BVH kinds).
    widen: Option<Widen>,
    /// The tree of a top level over instances' boxes
    /// ([`crate::accel::instances::TopLevelBuilder`]): walked as one
    /// (`SceneInfo::WALK_INSTANCES`).
    pub(crate) top_level: bool,
    /// The kd-tree's first reference budget per level; `None`: 4 per primitive
    /// ([`BuildCapacity::for_primitives`]). Tests set it tiny to exercise running out.
    pub kd_refs_per_level: Option<usize>,
}

/// What [`AccelBuilder::record_build`] knows when it returns.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct RecordedBuild {
    /// Host milliseconds spent building (a host builder; `None` for a device builder,
    /// whose GPU passes are in the recorder's profile).
    pub host_ms: Option<f64>,
}

impl RecordedBuild {
    /// The build's milliseconds: the host builder's, or the GPU passes in `profile` (the
    /// executed recorder's, whose scope `build` holds the build).
    pub fn ms(&self, profile: &crate::gpu::Profile) -> f64 {
        self.host_ms
            .unwrap_or_else(|| profile.ms("build").unwrap_or(0.0))
    }
}

impl AccelBuilder {
    /// The builder of `kind`; the driver's needs its ray tracing (else the error naming the
    /// extensions).
    pub fn new(ctx: &Context, kind: AccelKind) -> Result<Self> {
        if kind == AccelKind::Driver {
            require_ray_query(ctx)?;
        }
        Ok(Self {
            kind,
            kd: match kind {
                AccelKind::KdTree => Some(KdTreeBuilder::new(ctx)?),
                _ => None,
            },
            lbvh: match kind {
                AccelKind::Lbvh => Some(LbvhBuilder::new(ctx, MortonBits::default())?),
                _ => None,
            },
            ploc: match kind {
                AccelKind::Ploc => Some(PlocBuilder::new(ctx, PlocParams::default())?),
                _ => None,
            },
            refit: match kind {
                AccelKind::KdTree | AccelKind::Driver => None,
                AccelKind::SahBvh | AccelKind::Lbvh | AccelKind::Ploc => Some(ctx.kernel(
                    crate::accel::bvh::pairs_variant(
                        ctx,
                        &kernels::ACCEL_BVH_REFIT_BOXES64,
                        &kernels::ACCEL_BVH_REFIT_BOXES,
                    ),
                    &Spec::new().workgroup(refit_workgroup(ctx)),
                )?),
            },
            level_refit: match kind {
                AccelKind::KdTree | AccelKind::Driver => None,
                _ => Some(LevelRefit::new(ctx)?),
            },
            collapse: match kind {
                AccelKind::Lbvh | AccelKind::Ploc => {
                    Some(CollapseKernels::new(ctx, refit_workgroup(ctx))?)
                }
                _ => None,
            },
            widen: match kind {
                AccelKind::SahBvh | AccelKind::Lbvh | AccelKind::Ploc => Some(Widen::new(ctx)?),
                _ => None,
            },
            wide: false,
            top_level: false,
            allow_update: false,
            kd_params: SahParams::default(),
            bvh_params: BvhParams::default(),
            threading: Threading::all_cores(),
            driver_prefer: Prefer::default(),
            kd_refs_per_level: None,
        })
    }

    /// The kind of structure this builds.
    pub fn kind(&self) -> AccelKind {
        self.kind
    }

    /// The builder of `choice`'s structure (its driver preference included).
    pub fn for_choice(ctx: &Context, choice: AccelChoice) -> Result<Self> {
        let mut b = Self::new(ctx, choice.kind)?;
        b.driver_prefer = choice.prefer;
        b.wide = choice.walk == Traversal::Wide && b.widen.is_some();
        Ok(b)
    }

    /// An LBVH builder with `bits`-bit Morton codes ([`AccelBuilder::new`] takes the
    /// default, 63).
    pub fn lbvh(ctx: &Context, bits: MortonBits) -> Result<Self> {
        let mut b = Self::new(ctx, AccelKind::Lbvh)?;
        b.lbvh = Some(LbvhBuilder::new(ctx, bits)?);
        Ok(b)
    }

    /// A PLOC builder with `params` ([`AccelBuilder::new`] takes the defaults).
    pub fn ploc(ctx: &Context, params: PlocParams) -> Result<Self> {
        let mut b = Self::new(ctx, AccelKind::Ploc)?;
        b.ploc = Some(PlocBuilder::new(ctx, params)?);
        Ok(b)
    }

    /// The Morton code width of an LBVH or PLOC builder (the default for other kinds).
    pub fn lbvh_bits(&self) -> MortonBits {
        match (&self.lbvh, &self.ploc) {
            (Some(l), _) => l.bits(),
            (_, Some(p)) => p.params().bits,
            _ => MortonBits::default(),
        }
    }

    /// The knobs of a PLOC builder.
    pub fn ploc_params(&self) -> Option<PlocParams> {
        self.ploc.as_ref().map(|p| p.params())
    }

    /// The kd-tree build's capacity for `n` primitives: the default, doubled `grow` times,
    /// fitted to the device with all nodes in the one buffer the traversal binds.
    fn kd_capacity(&self, ctx: &Context, n: usize, grow: u32) -> Result<BuildCapacity> {
        let kd = self.kd_builder()?;
        let first = self
            .kd_refs_per_level
            .unwrap_or(BuildCapacity::for_primitives(n).refs_per_level);
        let c = BuildCapacity::with_refs(n, first << grow.min(8));
        let c = kd.fit_capacity(ctx, c);
        Ok(BuildCapacity {
            nodes: c
                .nodes
                .min((ctx.info().max_storage_buffer_range / 16) as usize),
            ..c
        })
    }

    /// Bytes of the structure and scratch for `n` primitives (`grow`: how many times the
    /// kd-tree's reference budget is doubled after a build ran out of it; 0 at first).
    pub fn sizes(&self, ctx: &Context, n: usize, grow: u32) -> Result<AccelSizes> {
        let info = std::mem::size_of::<SceneInfo>() as u64;
        Ok(match self.kind {
            AccelKind::KdTree => {
                let kd = self.kd_builder()?;
                let c = self.kd_capacity(ctx, n, grow)?;
                let s = kd.build_sizes(n, &c);
                AccelSizes {
                    structure_bytes: s.tree_bytes + info + 16,
                    build_scratch_bytes: s.scratch_bytes,
                    update_scratch_bytes: None,
                }
            }
            AccelKind::SahBvh | AccelKind::Lbvh | AccelKind::Ploc => {
                let nodes = bvh_nodes(n) as u64;
                let collapse = |layout| {
                    self.collapse
                        .as_ref()
                        .map_or(0, |c| c.scratch_bytes(n, layout))
                };
                let build_scratch_bytes = match (&self.lbvh, &self.ploc) {
                    (Some(l), _) => l.scratch_bytes(n) + nodes * 4 + collapse(LBVH_REFS),
                    (_, Some(p)) => p.scratch_bytes(n) + nodes * 4 + collapse(PLOC_REFS),
                    _ => 0,
                };
                let (schedule, schedule_scratch) = match (&self.level_refit, self.allow_update) {
                    (Some(l), true) => (
                        RefitSchedule::bytes(nodes as usize),
                        l.scratch_bytes(nodes as usize),
                    ),
                    _ => (0, 0),
                };
                let wide = if self.wide { nodes * 64 } else { 0 };
                AccelSizes {
                    structure_bytes: nodes * 64 + wide + (n as u64 + nodes) * 4 + info + schedule,
                    build_scratch_bytes: build_scratch_bytes + schedule_scratch,
                    update_scratch_bytes: Some(nodes * 4),
                }
            }
            AccelKind::Driver => {
                // The driver's sizes depend on the geometry (DriverAccel::sizes has them
                // exactly); for a count alone, `n` triangles.
                let tris = [AccelGeometry::Triangles {
                    vertices: 0,
                    count: n as u32,
                }];
                let flags = self.driver_prefer.flags(false);
                let s = crate::gpu::accel_build_sizes(ctx, &tris, flags)?;
                AccelSizes {
                    structure_bytes: s.structure + info + 8,
                    build_scratch_bytes: s.scratch,
                    update_scratch_bytes: None,
                }
            }
        })
    }

    /// The structure's buffers and the build scratch for `n` primitives, at
    /// [`AccelBuilder::sizes`].
    pub fn create(
        &self,
        ctx: &Context,
        n: usize,
        grow: u32,
    ) -> Result<(AccelStructure, AccelScratch)> {
        let structure = self.create_structure(ctx, n, grow, self.allow_update, 1)?;
        let scratch = self.create_scratch(ctx, n, grow, self.allow_update)?;
        Ok((structure, scratch))
    }

    /// The structure's buffers for `n` primitives (`info_len` elements of scene constants:
    /// 1, and more where a geometry table follows them).
    pub(crate) fn create_structure(
        &self,
        ctx: &Context,
        n: usize,
        grow: u32,
        allow_update: bool,
        info_len: usize,
    ) -> Result<AccelStructure> {
        let info = Buffer::new(ctx, "accel.info", info_len)?;
        let storage = match self.kind {
            AccelKind::KdTree => {
                let kd = self.kd_builder()?;
                let c = self.kd_capacity(ctx, n, grow)?;
                Storage::KdTree {
                    out: Box::new(kd.output(ctx, &c)?),
                    built: Buffer::new(ctx, "accel.kdtree_built", 4)?,
                }
            }
            AccelKind::SahBvh | AccelKind::Lbvh | AccelKind::Ploc => {
                let nodes = bvh_nodes(n);
                Storage::Bvh {
                    nodes: Buffer::new(ctx, "accel.bvh_nodes", nodes)?,
                    refs: Buffer::new(ctx, "accel.bvh_refs", n + nodes)?,
                    counts: (0, 0),
                    schedule: if allow_update {
                        Some(Box::new(RefitSchedule::new(ctx, nodes)?))
                    } else {
                        None
                    },
                    wide: if self.wide {
                        Some(Buffer::new(ctx, "accel.bvh_wide", nodes)?)
                    } else {
                        None
                    },
                }
            }
            AccelKind::Driver => Storage::Driver {
                accel: None,
                address: Buffer::new(ctx, "accel.driver.address", 1)?,
                // Triangles and boxes at most (DriverAccel::geometries).
                bases: Buffer::new(ctx, "accel.driver.bases", 2)?,
            },
        };
        Ok(AccelStructure {
            kind: self.kind,
            storage,
            info,
            allow_update,
        })
    }

    /// The build scratch for `n` primitives.
    pub(crate) fn create_scratch(
        &self,
        ctx: &Context,
        n: usize,
        grow: u32,
        allow_update: bool,
    ) -> Result<AccelScratch> {
        match self.kind {
            AccelKind::KdTree => {
                let kd = self.kd_builder()?;
                let c = self.kd_capacity(ctx, n, grow)?;
                Ok(AccelScratch::KdTree(Box::new(kd.scratch(
                    ctx,
                    n.max(1),
                    c,
                )?)))
            }
            AccelKind::SahBvh | AccelKind::Lbvh | AccelKind::Ploc => {
                let nodes = bvh_nodes(n);
                let collapse = |layout| -> Result<CollapseScratch> {
                    CollapseKernels::check(&self.bvh_params)?;
                    self.collapse
                        .as_ref()
                        .ok_or_else(missing("the collapse kernels"))?
                        .scratch(ctx, n, layout)
                };
                let schedule = match (&self.level_refit, allow_update) {
                    (Some(l), true) => Some(l.schedule_scratch(ctx, nodes)?),
                    _ => None,
                };
                Ok(match (&self.lbvh, &self.ploc) {
                    (Some(l), _) => AccelScratch::Lbvh(Box::new(LbvhScratch {
                        topology: l.scratch(ctx, n)?,
                        visits: Buffer::new(ctx, "accel.lbvh.visits", nodes)?,
                        collapse: collapse(LBVH_REFS)?,
                        schedule,
                    })),
                    (_, Some(p)) => AccelScratch::Ploc(Box::new(PlocDeviceScratch {
                        build: p.scratch(ctx, n)?,
                        visits: Buffer::new(ctx, "accel.ploc.visits", nodes)?,
                        collapse: collapse(PLOC_REFS)?,
                        schedule,
                    })),
                    _ => AccelScratch::None,
                })
            }
            AccelKind::Driver => Ok(AccelScratch::None),
        }
    }

    fn kd_builder(&self) -> Result<&KdTreeBuilder> {
        self.kd.as_ref().ok_or_else(missing("a kd-tree builder"))
    }

    /// Records the build of `out` over `prims` into `rec`, ending with a compute → compute
    /// barrier so kernels recorded next may trace it. `host` is the host's copy of the same
    /// geometry, read by host builders only (the SAH BVH); the kd-tree reads `prims.boxes`.
    pub fn record_build(
        &self,
        rec: &mut Recorder,
        prims: &DevicePrimitives,
        host: &TraceGeometry,
        scratch: &AccelScratch,
        out: &mut AccelStructure,
    ) -> Result<RecordedBuild> {
        self.record_build_inner(rec, prims, Some(host), scratch, out)
    }

    /// [`AccelBuilder::record_build`]; `host: None` when the geometry came from the caller's
    /// device buffers (`accel.geometry_gather` has then written the scene constants and the
    /// geometry table, and a host builder has nothing to read).
    pub(crate) fn record_build_inner(
        &self,
        rec: &mut Recorder,
        prims: &DevicePrimitives,
        host: Option<&TraceGeometry>,
        scratch: &AccelScratch,
        out: &mut AccelStructure,
    ) -> Result<RecordedBuild> {
        let n = prims.count();
        if out.kind != self.kind {
            return Err(GpuError::Usage {
                call: "AccelBuilder::record_build",
                reason: format!(
                    "a {} builder cannot build into a {} structure",
                    self.kind.name(),
                    out.kind.name()
                ),
            });
        }
        let recorded = match (&mut out.storage, scratch) {
            (
                Storage::Driver {
                    accel,
                    address,
                    bases,
                },
                _,
            ) => {
                if let Some(host) = host {
                    let mut bounds = Aabb::EMPTY;
                    host.boxes.iter().for_each(|b| bounds.union(b));
                    rec.upload(
                        &out.info,
                        &[prims.info(&bounds, 0).walked(SceneInfo::WALK_RAY_QUERY)],
                    )?;
                }
                let input = DriverInput::of(prims);
                // The caller's scratch where its levels were placed in its memory
                // (`create_in`); else the levels are made now, in vkrt's memory, with a
                // scratch of their own.
                let given = match scratch {
                    AccelScratch::Driver(b) => Some(b),
                    _ => None,
                };
                if given.is_none() || accel.is_none() {
                    let ctx = rec.context().clone();
                    let (prefer, update) = (self.driver_prefer, out.allow_update);
                    *accel = DriverAccel::create(&ctx, &input, prefer, update, given.is_none())?
                        .map(Box::new);
                }
                let built = accel.as_ref().ok_or_else(missing("the driver's levels"))?;
                rec.update(bases, 0, &DriverAccel::instance_bases(&input)?)?;
                rec.update(address, 0, &[built.tlas_address()])?;
                built.record_build(rec, given)?;
                rec.transfer_to_compute();
                Ok(RecordedBuild::default())
            }
            (Storage::KdTree { out: o, built }, AccelScratch::KdTree(s)) => {
                let kd = self.kd.as_ref().ok_or_else(missing("a kd-tree builder"))?;
                if host.is_some() {
                    // The finish writes the constants the walk needs; the rest (the shader
                    // library's walk, no geometry table) are zeros.
                    rec.fill(&out.info, 0);
                    rec.transfer_to_compute();
                }
                if n > 0 {
                    kd.record_build_boxes(rec, &prims.boxes, n, &self.kd_params, s, o)?;
                    rec.compute_to_compute();
                }
                kd.record_finish(
                    rec,
                    s,
                    &o.nodes[0],
                    &out.info,
                    built,
                    [
                        n as u32,
                        prims.n_tris as u32,
                        prims.n_spheres as u32,
                        prims.has_motion as u32,
                        prims.n_aabbs as u32,
                    ],
                );
                rec.compute_to_compute();
                Ok(RecordedBuild::default())
            }
            (
                Storage::Bvh {
                    nodes,
                    refs,
                    counts,
                    ..
                },
                AccelScratch::None,
            ) => {
                let host = host.ok_or_else(|| GpuError::Usage {
                    call: "AccelBuilder::record_build",
                    reason: "the SAH BVH is a host builder: it builds from host slices \
                             (record_build with a TraceGeometry), not from device buffers"
                        .into(),
                })?;
                if host.primitive_count() != n {
                    return Err(GpuError::Usage {
                        call: "AccelBuilder::record_build",
                        reason: format!(
                            "the host geometry has {} primitives, the device's {n}",
                            host.primitive_count()
                        ),
                    });
                }
                if self.wide && self.bvh_params.max_leaf_prims > MAX_WIDE_LEAF {
                    return Err(GpuError::Usage {
                        call: "AccelBuilder::record_build",
                        reason: format!(
                            "max_leaf_prims = {}: wide nodes name leaves of at most \
                             {MAX_WIDE_LEAF} primitives",
                            self.bvh_params.max_leaf_prims
                        ),
                    });
                }
                let t = std::time::Instant::now();
                let bvh =
                    bvh::build(&host.boxes, &self.bvh_params, self.threading).map_err(|e| {
                        GpuError::Kernel {
                            kernel: "accel.sah_bvh",
                            reason: e.to_string(),
                        }
                    })?;
                let host_ms = t.elapsed().as_secs_f64() * 1e3;
                let mut words = bvh.refs.clone();
                words.extend_from_slice(&bvh.parents);
                rec.upload(nodes, &bvh.nodes)?;
                rec.upload(refs, &words)?;
                rec.upload(
                    &out.info,
                    &[prims
                        .info(&bvh.bounds, bvh.refs.len() as u32)
                        .walked(self.bvh_walk())],
                )?;
                rec.transfer_to_compute();
                *counts = (bvh.nodes.len(), bvh.refs.len());
                Ok(RecordedBuild {
                    host_ms: Some(host_ms),
                })
            }
            (
                Storage::Bvh {
                    nodes,
                    refs,
                    counts,
                    ..
                },
                AccelScratch::Lbvh(s),
            ) => {
                let lbvh = self.lbvh.as_ref().ok_or_else(missing("an LBVH builder"))?;
                let n_nodes = if n == 0 { 0 } else { bvh_nodes(n) };
                if host.is_some() {
                    upload_gpu_bvh_info(rec, prims, &out.info, self.bvh_walk())?;
                }
                // The references go to the collapse's scratch where it collapses.
                let collapsing = collapse::applies(n, &self.bvh_params);
                let tree_refs = match collapsing {
                    true => s.collapse.tree_refs(),
                    false => &*refs,
                };
                *counts = (n_nodes, n);
                // One climb builds the topology with its boxes (and the collapse's decisions).
                let (p, visits, cs) = (&self.bvh_params, &s.visits, &s.collapse);
                let decide = collapsing.then(|| (cs.costs(), p));
                let (boxes, info) = (&prims.boxes, &out.info);
                lbvh.record_build(
                    rec,
                    boxes,
                    n,
                    &s.topology,
                    nodes,
                    tree_refs,
                    visits,
                    info,
                    decide,
                )?;
                if collapsing {
                    let collapse = self
                        .collapse
                        .as_ref()
                        .ok_or_else(missing("the collapse kernels"))?;
                    collapse.record(rec, n, visits, cs, p, nodes, refs, true, LBVH_REFS)?;
                }
                Ok(RecordedBuild::default())
            }
            (
                Storage::Bvh {
                    nodes,
                    refs,
                    counts,
                    ..
                },
                AccelScratch::Ploc(s),
            ) => {
                let ploc = self.ploc.as_ref().ok_or_else(missing("a PLOC builder"))?;
                let n_nodes = if n == 0 { 0 } else { bvh_nodes(n) };
                if host.is_some() {
                    upload_gpu_bvh_info(rec, prims, &out.info, self.bvh_walk())?;
                }
                *counts = (n_nodes, n);
                if collapse::applies(n, &self.bvh_params) {
                    // The references go to the collapse's scratch, and are laid out in `refs`.
                    let tree_refs = s.collapse.tree_refs();
                    let info = &out.info;
                    ploc.record_build(rec, &prims.boxes, n, &s.build, nodes, tree_refs, info)?;
                    rec.compute_to_compute();
                    let collapse = self
                        .collapse
                        .as_ref()
                        .ok_or_else(missing("the collapse kernels"))?;
                    let p = &self.bvh_params;
                    let layout = PLOC_REFS;
                    collapse.record(
                        rec,
                        n,
                        &s.visits,
                        &s.collapse,
                        p,
                        nodes,
                        refs,
                        false,
                        layout,
                    )?;
                } else if n >= 2 {
                    ploc.record_build(rec, &prims.boxes, n, &s.build, nodes, refs, &out.info)?;
                } else {
                    let (meet, info) = (&s.visits, &out.info);
                    ploc.record_small(rec, &prims.boxes, n, &s.build, nodes, refs, meet, info)?;
                }
                rec.compute_to_compute();
                Ok(RecordedBuild::default())
            }
            _ => Err(GpuError::Usage {
                call: "AccelBuilder::record_build",
                reason: format!(
                    "the scratch was made for another kind than {}",
                    self.kind.name()
                ),
            }),
        }?;
        if let Storage::Bvh {
            refs,
            counts,
            schedule: Some(schedule),
            ..
        } = &out.storage
        {
            let level = self
                .level_refit
                .as_ref()
                .ok_or_else(missing("the level refit"))?;
            let placed = match scratch {
                AccelScratch::Lbvh(s) => s.schedule.as_ref(),
                AccelScratch::Ploc(s) => s.schedule.as_ref(),
                _ => None,
            };
            level.record_schedule(rec, refs, counts.0, counts.1 as u32, schedule, placed)?;
        }
        self.record_widen(rec, out)?;
        Ok(recorded)
    }
}

impl AccelBuilder {
    /// Scratch of [`AccelBuilder::record_refit`] for `n` primitives (`update_scratch_bytes`
    /// of [`AccelBuilder::sizes`]); `None` for kinds that cannot be refit.
    pub fn update_scratch(&self, ctx: &Context, n: usize) -> Result<Option<Buffer<u32>>> {
        match self.kind {
            AccelKind::KdTree => Ok(None),
            // The driver's update scratch lives with its structure.
            AccelKind::Driver => Buffer::new(ctx, "accel.refit_visits", 1).map(Some),
            AccelKind::SahBvh | AccelKind::Lbvh | AccelKind::Ploc => {
                Buffer::new(ctx, "accel.refit_visits", bvh_nodes(n)).map(Some)
            }
        }
    }

    /// Records a refit of `out` (a BVH this builder built over the same primitives) to
    /// `prims.boxes` as they are now: every box recomputed bottom-up, the topology kept, the
    /// root box rewritten. The caller orders the writes of the moved geometry before; the
    /// recording ends with a compute → compute barrier. A kd-tree cannot be refit (its
    /// split planes are fixed): that is an error.
    pub fn record_refit(
        &self,
        rec: &mut Recorder,
        prims: &DevicePrimitives,
        out: &AccelStructure,
        scratch: &Buffer<u32>,
    ) -> Result<()> {
        if let Storage::Driver { accel, .. } = &out.storage {
            let accel = accel.as_ref().ok_or_else(|| GpuError::Usage {
                call: "AccelBuilder::record_refit",
                reason: "the driver's structure has not been built yet".into(),
            })?;
            return accel.record_update(rec, None);
        }
        let (
            Storage::Bvh {
                nodes,
                refs,
                counts,
                schedule,
                ..
            },
            Some(kernel),
        ) = (&out.storage, &self.refit)
        else {
            return Err(GpuError::Kernel {
                kernel: "accel.refit",
                reason: format!("a {} cannot be refit; rebuild it", out.kind.name()),
            });
        };
        let n_nodes = counts.0;
        if scratch.len() < n_nodes {
            return Err(GpuError::Usage {
                call: "AccelBuilder::record_refit",
                reason: format!(
                    "the update scratch holds {} counters; this structure needs {n_nodes}",
                    scratch.len()
                ),
            });
        }
        if counts.1 != prims.count() {
            return Err(GpuError::Usage {
                call: "AccelBuilder::record_refit",
                reason: format!(
                    "the structure was built over {} primitives; {} given",
                    counts.1,
                    prims.count()
                ),
            });
        }
        match (schedule, &self.level_refit) {
            (Some(schedule), Some(level)) if n_nodes > 0 => {
                level.record_refit(rec, nodes, refs, &prims.boxes, &out.info, schedule);
            }
            _ => record_refit_nodes(rec, kernel, prims, nodes, refs, scratch, &out.info, n_nodes),
        }
        self.record_widen(rec, out)
    }

    /// How the shader library walks the BVHs this builder makes (`SceneInfo::walk`).
    pub(crate) fn bvh_walk(&self) -> u32 {
        if self.wide {
            SceneInfo::WALK_BVH_WIDE
        } else {
            SceneInfo::WALK_BVH
        }
    }

    /// Records `accel.bvh_widen` over `out`'s binary nodes where it has wide ones (after a
    /// build or refit wrote them).
    fn record_widen(&self, rec: &mut Recorder, out: &AccelStructure) -> Result<()> {
        let Storage::Bvh {
            nodes,
            wide: Some(wide),
            counts,
            ..
        } = &out.storage
        else {
            return Ok(());
        };
        let widen = self
            .widen
            .as_ref()
            .ok_or_else(missing("the widen kernel"))?;
        widen.record(rec, nodes, wide, counts.0);
        Ok(())
    }
}

/// The scene constants of a GPU-built BVH (LBVH, PLOC) over host-uploaded primitives: the
/// root box is written by the build, the parent links follow the `n` references.
fn upload_gpu_bvh_info(
    rec: &mut Recorder,
    prims: &DevicePrimitives,
    info: &Buffer<SceneInfo>,
    walk: u32,
) -> Result<()> {
    let n = prims.count() as u32;
    rec.upload(info, &[prims.info(&Aabb::EMPTY, n).walked(walk)])?;
    rec.transfer_to_compute();
    Ok(())
}

/// The error for a builder part that `AccelBuilder::new` made for another kind.
fn missing(what: &'static str) -> impl Fn() -> GpuError {
    move || GpuError::Usage {
        call: "AccelBuilder",
        reason: format!("{what} is missing: the builder was made for another kind"),
    }
}

/// Nodes of a BVH over `n` primitives (one for 0 or 1: a root).
fn bvh_nodes(n: usize) -> usize {
    n.saturating_sub(1).max(1)
}

/// PLOC build scratch, the visit counters (the one-primitive tree's refit, the collapse)
/// and the collapse's.
pub struct PlocDeviceScratch {
    build: PlocScratch,
    visits: Buffer<u32>,
    collapse: CollapseScratch,
    /// The refit schedule's, for a structure built to be updated.
    schedule: Option<ScheduleScratch>,
}

/// LBVH build scratch: the topology's, the visit counters of the boxes' refit and the
/// collapse, and the collapse's.
pub struct LbvhScratch {
    topology: crate::accel::bvh::lbvh_gpu::LbvhScratch,
    visits: Buffer<u32>,
    collapse: CollapseScratch,
    /// The refit schedule's, for a structure built to be updated.
    schedule: Option<ScheduleScratch>,
}

/// Records `accel.bvh_refit` over the first `n_nodes` nodes (nothing for 0), in a scope
/// `refit`, ending with a compute → compute barrier.
#[allow(clippy::too_many_arguments, reason = "the refit kernel's bindings")]
fn record_refit_nodes(
    rec: &mut Recorder,
    kernel: &Kernel,
    prims: &DevicePrimitives,
    nodes: &Buffer<BvhNode>,
    refs: &Buffer<u32>,
    visits: &Buffer<u32>,
    info: &Buffer<SceneInfo>,
    n_nodes: usize,
) {
    if n_nodes == 0 {
        return;
    }
    rec.scope("refit", |rec| {
        rec.fill_first(visits, n_nodes, 0);
        rec.transfer_to_compute();
        let groups = rec.groups_1d(n_nodes as u64, refit_workgroup(rec.context()));
        let b: [&dyn BufferArg; 5] = [nodes, refs, &prims.boxes, visits, info];
        rec.dispatch(kernel, groups, &b, &(n_nodes as u32));
    });
    rec.compute_to_compute();
}

/// A structure built from a host structure (for tools and tests that built one on the
/// host: the CPU twins' trees, or a downloaded one).
pub fn upload_structure(
    ctx: &Context,
    prims: &DevicePrimitives,
    host: HostRef<'_>,
) -> Result<AccelStructure> {
    match host {
        HostRef::KdTree(tree) => {
            let nodes: &[KdNode] = if tree.nodes.is_empty() {
                &[KdNode::leaf(0, 0)]
            } else {
                &tree.nodes
            };
            let out = BuildOutput {
                nodes: [
                    Buffer::from_slice(ctx, "accel.kdtree_nodes", nodes)?,
                    Buffer::new(ctx, "accel.kdtree_nodes1", 1)?,
                ],
                prim_refs: Buffer::from_slice(ctx, "accel.kdtree_refs", &tree.prim_refs)?,
            };
            let built = [nodes.len() as u32, tree.prim_refs.len() as u32, 0, 0];
            Ok(AccelStructure {
                kind: AccelKind::KdTree,
                storage: Storage::KdTree {
                    out: Box::new(out),
                    built: Buffer::from_slice(ctx, "accel.kdtree_built", &built)?,
                },
                info: Buffer::from_slice(ctx, "accel.info", &[prims.info(&tree.bounds, 0)])?,
                allow_update: false,
            })
        }
        HostRef::Bvh(bvh) | HostRef::WideBvh(bvh) => {
            let wide = matches!(host, HostRef::WideBvh(_));
            let mut words = bvh.refs.clone();
            words.extend_from_slice(&bvh.parents);
            Ok(AccelStructure {
                kind: AccelKind::SahBvh,
                storage: Storage::Bvh {
                    nodes: Buffer::from_slice(ctx, "accel.bvh_nodes", &bvh.nodes)?,
                    refs: Buffer::from_slice(ctx, "accel.bvh_refs", &words)?,
                    counts: (bvh.nodes.len(), bvh.refs.len()),
                    schedule: None,
                    wide: match wide {
                        true => Some(Buffer::from_slice(ctx, "accel.bvh_wide", bvh.wide())?),
                        false => None,
                    },
                },
                info: Buffer::from_slice(
                    ctx,
                    "accel.info",
                    &[prims
                        .info(&bvh.bounds, bvh.refs.len() as u32)
                        .walked(match wide {
                            true => SceneInfo::WALK_BVH_WIDE,
                            false => SceneInfo::WALK_BVH,
                        })],
                )?,
                allow_update: false,
            })
        }
    }
}

impl AccelTraversal {
    /// Whether this walk serves `s`: its kind's family, and the wide walk exactly the
    /// structures built with wide nodes (they bind those in place of the binary ones).
    pub fn walks(self, s: &AccelStructure) -> bool {
        s.kind().walked(Traversal::default()).family() == self.family()
            && (self == AccelTraversal::Bvh(Traversal::Wide)) == s.is_wide()
    }
}
