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
//! Each family keeps its builder, buffers and scratch in its own files (`kdtree/device.rs`,
//! `bvh/device.rs`, `driver/storage.rs`; `host.rs` uploads trees built on the host); this
//! module dispatches to them. Downloading a
//! structure ([`AccelStructure::download`]) is for tests and tools only.

use crate::accel::bvh::compact::BvhSlots;
use crate::accel::bvh::device::{BvhFamily, BvhScratch, BvhSettings, BvhStorage};
use crate::accel::bvh::lbvh::MortonBits;
use crate::accel::bvh::ploc::PlocParams;
use crate::accel::bvh::wide::WideNode;
use crate::accel::bvh::{BvhNode, BvhParams, Threading};
pub use crate::accel::device_input::BuildFlags;
pub use crate::accel::device_primitives::DevicePrimitives;
use crate::accel::driver::storage::{self as driver, DriverStorage};
use crate::accel::driver::Prefer;
pub use crate::accel::kdtree::device::KdBuilt;
use crate::accel::kdtree::device::{KdFamily, KdStorage};
use crate::accel::kdtree::gpu::BuildScratch;
use crate::accel::kdtree::SahParams;
use crate::accel::primitives::{SceneInfo, TraceGeometry};
pub use crate::accel::sizes::{AccelSizes, RecordedBuild};
pub use crate::accel::walk::{AccelChoice, AccelKind};
use crate::accel::walk::{AccelTraversal, Traversal};
use crate::gpu::{
    require_ray_query, Buffer, BufferArg, Context, GpuError, Readback, Recorder, Result,
};

/// A structure in device memory: what the traversal binds as `nodes`, `prim_refs` and
/// the scene constants.
pub struct AccelStructure {
    kind: AccelKind,
    storage: Storage,
    /// The scene constants (root box, primitive counts, walk) the traversal binds.
    pub(crate) info: Buffer<SceneInfo>,
    /// What it was created with (`allow_update`, the driver's preference, wide nodes, the
    /// kd-tree's budget), fixed for its life.
    flags: BuildFlags,
    /// The parameters of the builder that created it, which every builder recording into it
    /// must have; `None` for a structure uploaded from the host.
    params: Option<BuilderParams>,
    /// Its builds write its handle although it lies in the caller's memory
    /// (`GpuGeometry::enable_references`).
    pub(crate) references_enabled: bool,
}

/// A structure's buffers, by family. One per structure, never in an array: the variants'
/// sizes (a BVH's buffers are more) cost nothing worth a box.
#[allow(clippy::large_enum_variant)]
pub(crate) enum Storage {
    KdTree(KdStorage),
    Bvh(BvhStorage),
    Driver(DriverStorage),
}

impl AccelStructure {
    /// The scene constants (root box, primitive counts, walk) the traversal binds.
    pub fn scene_info(&self) -> &Buffer<SceneInfo> {
        &self.info
    }

    /// A structure of `kind` over `storage`.
    pub(crate) fn from_parts(kind: AccelKind, storage: Storage, info: Buffer<SceneInfo>) -> Self {
        Self {
            kind,
            storage,
            info,
            flags: BuildFlags::default(),
            params: None,
            references_enabled: false,
        }
    }

    /// A structure of the same kind, flags and builder parameters as this one over
    /// `storage` (a compacted copy's).
    pub(crate) fn like(&self, storage: Storage, info: Buffer<SceneInfo>) -> Self {
        Self {
            kind: self.kind,
            storage,
            info,
            flags: self.flags,
            params: self.params,
            // (a copy in the caller's memory: referenced once it says its memory allows)
            references_enabled: false,
        }
    }

    /// The flags it was created with.
    pub fn flags(&self) -> BuildFlags {
        self.flags
    }

    pub(crate) fn storage(&self) -> &Storage {
        &self.storage
    }

    pub(crate) fn storage_mut(&mut self) -> &mut Storage {
        &mut self.storage
    }

    /// Takes `from`'s build state for a byte copy of its arrays (GPU BVHs; a kd-tree or the
    /// driver's structure is refused).
    pub(crate) fn adopt_build_state(&mut self, from: &AccelStructure) -> Result<()> {
        let usage = |reason: &str| GpuError::Usage {
            call: "GpuGeometry::record_built_by_copy",
            reason: reason.into(),
        };
        if self.kind != from.kind || self.flags != from.flags {
            return Err(usage("the source is of another kind or flags"));
        }
        match (&mut self.storage, &from.storage) {
            (Storage::Bvh(d), Storage::Bvh(s)) => d.adopt_build_state(s),
            _ => Err(usage("only a BVH's copy can take its source's build state")),
        }
    }

    /// The kind of structure this is.
    pub fn kind(&self) -> AccelKind {
        self.kind
    }

    /// Bytes of the driver's structure (all its levels), once its build is recorded; `None`
    /// for vkrt's structures (their size is that of the downloaded tree).
    pub fn driver_bytes(&self) -> Option<u64> {
        match &self.storage {
            Storage::Driver(d) => d.levels.as_ref().map(|a| a.structure_bytes()),
            _ => None,
        }
    }

    /// Whether the structure has wide nodes ([`BuildFlags::wide`]): the wide walk, and no
    /// other, serves it.
    pub fn is_wide(&self) -> bool {
        matches!(&self.storage, Storage::Bvh(b) if b.is_wide())
    }

    /// The device's binary and wide node slots of a BVH walked wide (tests and tools: the
    /// wide nodes against their CPU twin, [`crate::accel::bvh::wide::widen`] of the binary
    /// slots); `None` for other structures.
    pub fn download_wide(&self) -> Result<Option<(Vec<BvhNode>, Vec<WideNode>)>> {
        match &self.storage {
            Storage::Bvh(b) => b.download_wide(),
            _ => Ok(None),
        }
    }

    /// A BVH's node slots, parent links and references as they lie on the device, the slots
    /// its leaf collapse freed included, with its live-node count (tests and tools: the
    /// compaction against its CPU twin, [`crate::accel::bvh::compact::renumber`]); `None` for
    /// other structures.
    pub fn download_slots(&self) -> Result<Option<BvhSlots>> {
        match &self.storage {
            Storage::Bvh(b) => b.download_slots().map(Some),
            _ => Ok(None),
        }
    }

    /// The `nodes` and `prim_refs` bindings of `traverse.glsl` (a BVH walked wide: its wide
    /// nodes).
    pub fn node_bindings(&self) -> [&dyn BufferArg; 2] {
        match &self.storage {
            Storage::KdTree(k) => k.node_bindings(),
            Storage::Bvh(b) => b.node_bindings(),
            Storage::Driver(d) => d.node_bindings(),
        }
    }

    /// Records the copy of a kd-tree build's report to the host (16 bytes), read with
    /// [`AccelStructure::kd_built`] after the work has executed; `None` for other kinds.
    pub fn record_read_built(&self, rec: &mut Recorder) -> Result<Option<Readback<u32>>> {
        match &self.storage {
            Storage::KdTree(k) => k.record_read_built(rec).map(Some),
            Storage::Bvh(_) | Storage::Driver(_) => Ok(None),
        }
    }

    /// Records the copy of a kd-tree build's report (16 bytes, [`AccelStructure::kd_built`]
    /// decodes it) into the start of `dst`, a range of the caller's buffer, as the driver
    /// writes a query's result into the caller's buffer with `vkCmdCopyQueryPoolResults`:
    /// read in the renderer's own read-back, with no staging of vkrt's. True where recorded;
    /// false for kinds without a report. Synchronized as [`Recorder::copy_into`].
    pub fn record_copy_built_into(
        &self,
        rec: &mut Recorder,
        dst: &dyn crate::gpu::BufferArg,
    ) -> Result<bool> {
        match &self.storage {
            Storage::KdTree(k) => {
                k.record_copy_built_into(rec, dst);
                rec.check().map(|()| true)
            }
            Storage::Bvh(_) | Storage::Driver(_) => Ok(false),
        }
    }

    /// Decodes a kd-tree build's report.
    pub fn kd_built(words: &[u32]) -> KdBuilt {
        KdBuilt::decode(words)
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

/// Scratch of a build ([`AccelBuilder::create`]).
pub struct AccelScratch(pub(crate) Scratch);

/// A build's scratch, by family.
pub(crate) enum Scratch {
    KdTree(Box<BuildScratch>),
    Bvh(BvhScratch),
    /// The caller's, for the driver's levels placed in its memory; `None`: the levels keep
    /// their own.
    Driver(Option<Buffer<u8>>),
}

/// The builder of one family of structures: the contract every family keeps (sizes,
/// buffers, scratch, a recorded build and refit) as one enum, matched here only.
enum Family {
    KdTree(KdFamily),
    Bvh(BvhFamily),
    Driver,
}

/// A builder's parameters besides its kind, frozen into every structure it creates and
/// checked at every record call into one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct BuilderParams {
    kd: SahParams,
    bvh: BvhParams,
    threading: Threading,
    kd_refs_per_level: Option<usize>,
    morton: Option<MortonBits>,
    ploc: Option<PlocParams>,
}

/// Builds one kind of structure; compiled once, used for any number of builds. Its
/// parameters are set when it is made (`with_*`) and frozen into each structure it creates
/// (with the [`BuildFlags`] given then): a builder with other parameters cannot record into
/// it.
#[must_use]
pub struct AccelBuilder {
    kind: AccelKind,
    family: Family,
    /// The kd-tree build's SAH costs and termination rules.
    kd_params: SahParams,
    /// The BVH kinds' SAH costs and leaf size: the SAH builder's, and the GPU builders'
    /// leaf collapse.
    bvh_params: BvhParams,
    /// How the SAH BVH's host build uses threads (default: the node queue on every core).
    threading: Threading,
    /// The flags of the structures [`AccelBuilder::create`] makes (the calls over the
    /// caller's memory take theirs: [`AccelBuilder::create_in`]).
    flags: BuildFlags,
    /// The tree of a top level over instances' boxes
    /// ([`crate::accel::instances::TopLevelBuilder`]): walked as one
    /// (`SceneInfo::WALK_INSTANCES`).
    pub(crate) top_level: bool,
    /// The kd-tree's first reference budget per level; `None`: 4 per primitive
    /// ([`BuildCapacity::for_primitives`](crate::accel::kdtree::gpu::BuildCapacity::for_primitives)).
    kd_refs_per_level: Option<usize>,
}

impl AccelBuilder {
    /// The builder of `kind`; the driver's needs its ray tracing (else the error naming the
    /// extensions).
    pub fn new(ctx: &Context, kind: AccelKind) -> Result<Self> {
        let family = match kind {
            AccelKind::KdTree => Family::KdTree(KdFamily::new(ctx)?),
            AccelKind::SahBvh => Family::Bvh(BvhFamily::sah(ctx)?),
            AccelKind::Lbvh => Family::Bvh(BvhFamily::lbvh(ctx, MortonBits::default())?),
            AccelKind::Ploc => Family::Bvh(BvhFamily::ploc(ctx, PlocParams::default())?),
            AccelKind::Driver => {
                require_ray_query(ctx)?;
                Family::Driver
            }
        };
        Ok(Self::with_family(kind, family))
    }

    fn with_family(kind: AccelKind, family: Family) -> Self {
        Self {
            kind,
            family,
            top_level: false,
            flags: BuildFlags::default(),
            kd_params: SahParams::default(),
            bvh_params: BvhParams::default(),
            threading: Threading::all_cores(),
            kd_refs_per_level: None,
        }
    }

    /// The kind of structure this builds.
    pub fn kind(&self) -> AccelKind {
        self.kind
    }

    /// The builder of `choice`'s structure, whose [`AccelBuilder::create`] makes them with
    /// [`BuildFlags::for_choice`] (its driver preference, wide nodes for the wide walk).
    pub fn for_choice(ctx: &Context, choice: AccelChoice) -> Result<Self> {
        Ok(Self::new(ctx, choice.kind)?.with_flags(BuildFlags::for_choice(choice)))
    }

    /// With the kd-tree build's SAH costs and termination rules.
    pub fn with_kd_params(mut self, params: SahParams) -> Self {
        self.kd_params = params;
        self
    }

    /// With the BVH kinds' SAH costs and leaf size (the SAH builder's, and the GPU builders'
    /// leaf collapse).
    pub fn with_bvh_params(mut self, params: BvhParams) -> Self {
        self.bvh_params = params;
        self
    }

    /// With the SAH BVH's host build using threads as `threading` says (default: the node
    /// queue on every core).
    pub fn with_threading(mut self, threading: Threading) -> Self {
        self.threading = threading;
        self
    }

    /// With the kd-tree's first reference budget per level (`None`: 4 per primitive); tests
    /// set it tiny to exercise running out.
    pub fn with_kd_refs_per_level(mut self, refs: Option<usize>) -> Self {
        self.kd_refs_per_level = refs;
        self
    }

    /// With the flags [`AccelBuilder::create`] and [`AccelBuilder::sizes`] make structures
    /// with (wide nodes only for BVH kinds).
    pub fn with_flags(mut self, flags: BuildFlags) -> Self {
        self.set_flags(flags);
        self
    }

    /// Sets the flags of the structures [`AccelBuilder::create`] makes from now on; those
    /// it made before keep theirs.
    pub fn set_flags(&mut self, flags: BuildFlags) {
        self.flags = BuildFlags {
            wide: flags.wide && matches!(self.family, Family::Bvh(_)),
            ..flags
        };
    }

    /// [`AccelBuilder::with_flags`] with `allow_update` set: BVHs built to be updated
    /// (`VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_UPDATE_BIT_KHR`) record the refit's schedule
    /// with the structure, and refit one dispatch per depth (`bvh::refit_gpu`).
    pub fn with_allow_update(self, allow_update: bool) -> Self {
        let flags = BuildFlags {
            allow_update,
            ..self.flags
        };
        self.with_flags(flags)
    }

    /// [`AccelBuilder::with_flags`] with `wide` set: BVHs with 4-wide nodes too.
    pub fn with_wide(self, wide: bool) -> Self {
        let flags = BuildFlags { wide, ..self.flags };
        self.with_flags(flags)
    }

    /// [`AccelBuilder::with_flags`] with the driver's preference set.
    pub fn with_driver_prefer(self, prefer: Prefer) -> Self {
        let flags = BuildFlags {
            prefer,
            ..self.flags
        };
        self.with_flags(flags)
    }

    /// The flags [`AccelBuilder::create`] makes structures with.
    pub fn flags(&self) -> BuildFlags {
        self.flags
    }

    /// The kd-tree build's parameters.
    pub fn kd_params(&self) -> SahParams {
        self.kd_params
    }

    /// The BVH kinds' parameters.
    pub fn bvh_params(&self) -> BvhParams {
        self.bvh_params
    }

    /// How the SAH BVH's host build uses threads.
    pub fn threading(&self) -> Threading {
        self.threading
    }

    /// What is frozen into each structure this builder creates.
    pub(crate) fn params(&self) -> BuilderParams {
        BuilderParams {
            kd: self.kd_params,
            bvh: self.bvh_params,
            threading: self.threading,
            kd_refs_per_level: self.kd_refs_per_level,
            morton: match &self.family {
                Family::Bvh(b) => b.morton_bits(),
                _ => None,
            },
            ploc: self.ploc_params(),
        }
    }

    /// `Err` unless `out` was created by a builder of this kind with these parameters.
    pub(crate) fn check_frozen(&self, call: &'static str, out: &AccelStructure) -> Result<()> {
        if out.kind != self.kind {
            return Err(GpuError::KindMismatch {
                call,
                built: out.kind.name().into(),
                expected: format!("{} builder", self.kind.name()),
            });
        }
        match out.params {
            Some(frozen) if frozen != self.params() => Err(GpuError::FrozenSetting {
                call,
                frozen: format!("{frozen:?}"),
                given: format!("{:?}", self.params()),
            }),
            _ => Ok(()),
        }
    }

    /// An LBVH builder with `bits`-bit Morton codes ([`AccelBuilder::new`] takes the
    /// default, 63).
    pub fn lbvh(ctx: &Context, bits: MortonBits) -> Result<Self> {
        let family = Family::Bvh(BvhFamily::lbvh(ctx, bits)?);
        Ok(Self::with_family(AccelKind::Lbvh, family))
    }

    /// A PLOC builder with `params` ([`AccelBuilder::new`] takes the defaults).
    pub fn ploc(ctx: &Context, params: PlocParams) -> Result<Self> {
        let family = Family::Bvh(BvhFamily::ploc(ctx, params)?);
        Ok(Self::with_family(AccelKind::Ploc, family))
    }

    /// The Morton code width of an LBVH or PLOC builder (the default for other kinds).
    pub fn lbvh_bits(&self) -> MortonBits {
        match &self.family {
            Family::Bvh(b) => b.morton_bits().unwrap_or_default(),
            _ => MortonBits::default(),
        }
    }

    /// The knobs of a PLOC builder.
    pub fn ploc_params(&self) -> Option<PlocParams> {
        match &self.family {
            Family::Bvh(b) => b.ploc_params(),
            _ => None,
        }
    }

    fn bvh_settings(&self, flags: &BuildFlags) -> BvhSettings<'_> {
        BvhSettings {
            params: &self.bvh_params,
            threading: self.threading,
            allow_update: flags.allow_update,
            wide: flags.wide,
            walk: AccelTraversal::Bvh(bvh_traversal(flags.wide)).scene_walk(),
        }
    }

    /// Bytes of the structure and scratch for `n` primitives, with this builder's
    /// [`AccelBuilder::flags`] and `grow`: how many times the kd-tree's reference budget is
    /// doubled after a build ran out of it (0 at first).
    pub fn sizes(&self, ctx: &Context, n: usize, grow: u32) -> Result<AccelSizes> {
        match &self.family {
            Family::KdTree(k) => Ok(k.sizes(ctx, n, grow, self.kd_refs_per_level)),
            Family::Bvh(b) => Ok(b.sizes(n, &self.bvh_settings(&self.flags))),
            Family::Driver => driver::sizes(ctx, n, self.flags.prefer),
        }
    }

    /// The structure's buffers and the build scratch for `n` primitives, at
    /// [`AccelBuilder::sizes`], with this builder's [`AccelBuilder::flags`].
    pub fn create(
        &self,
        ctx: &Context,
        n: usize,
        grow: u32,
    ) -> Result<(AccelStructure, AccelScratch)> {
        let flags = BuildFlags {
            kd_capacity_doublings: grow,
            ..self.flags
        };
        let structure = self.create_structure(ctx, n, &flags, 1)?;
        let scratch = self.create_scratch(ctx, n, grow, flags.allow_update)?;
        Ok((structure, scratch))
    }

    /// The structure's buffers for `n` primitives built with `flags` (`info_len` elements of
    /// scene constants: 1, and more where a geometry table follows them).
    pub(crate) fn create_structure(
        &self,
        ctx: &Context,
        n: usize,
        flags: &BuildFlags,
        info_len: usize,
    ) -> Result<AccelStructure> {
        // (and one more element: the structure's handle, GpuGeometry::reference)
        let info = Buffer::new(ctx, "accel.info", info_len + 1)?;
        let grow = flags.kd_capacity_doublings;
        // Wide nodes are a BVH's only.
        let wide = flags.wide && matches!(self.family, Family::Bvh(_));
        let storage = match &self.family {
            Family::KdTree(k) => {
                Storage::KdTree(k.create_storage(ctx, n, grow, self.kd_refs_per_level)?)
            }
            Family::Bvh(b) => Storage::Bvh(b.create_storage(ctx, n, flags.allow_update, wide)?),
            Family::Driver => Storage::Driver(DriverStorage::new(ctx)?),
        };
        Ok(AccelStructure {
            flags: BuildFlags { wide, ..*flags },
            params: Some(self.params()),
            ..AccelStructure::from_parts(self.kind, storage, info)
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
        Ok(AccelScratch(match &self.family {
            Family::KdTree(k) => {
                Scratch::KdTree(k.create_scratch(ctx, n, grow, self.kd_refs_per_level)?)
            }
            Family::Bvh(b) => {
                Scratch::Bvh(b.create_scratch(ctx, n, &self.bvh_params, allow_update)?)
            }
            Family::Driver => Scratch::Driver(None),
        }))
    }

    /// Records the build of `out` over `prims` into `rec`, ending with the barrier of
    /// [`crate::accel::sync::RecordSync::build`] so kernels recorded next may trace it.
    /// `host` is the host's copy of the same geometry, read by host builders only (the SAH
    /// BVH); the kd-tree reads `prims.boxes`.
    pub fn record_build(
        &self,
        rec: &mut Recorder,
        out: &mut AccelStructure,
        prims: &DevicePrimitives,
        host: &TraceGeometry,
        scratch: &AccelScratch,
    ) -> Result<RecordedBuild> {
        let built = self.record_build_inner(rec, prims, Some(host), scratch, out)?;
        rec.end_of_build();
        Ok(built)
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
        let call = "AccelBuilder::record_build";
        self.check_frozen(call, out)?;
        let built = self.record_build_kind(call, rec, prims, host, scratch, out)?;
        // The structure's handle after its constants (a kd-tree's build clears them), where
        // a top level's instances reference it.
        if let Some(record) = handle_record(rec.context(), prims, out)? {
            rec.compute_to_transfer();
            rec.update(&out.info, out.info.len() - 1, &[record])?;
        }
        Ok(built)
    }

    fn record_build_kind(
        &self,
        call: &'static str,
        rec: &mut Recorder,
        prims: &DevicePrimitives,
        host: Option<&TraceGeometry>,
        scratch: &AccelScratch,
        out: &mut AccelStructure,
    ) -> Result<RecordedBuild> {
        let flags = out.flags;
        let info = &out.info;
        match (&self.family, &mut out.storage, &scratch.0) {
            (Family::KdTree(k), Storage::KdTree(s), Scratch::KdTree(sc)) => {
                let p = &self.kd_params;
                k.record_build(rec, prims, host.is_some(), p, sc, s, info)?;
                Ok(RecordedBuild::default())
            }
            (Family::Bvh(b), Storage::Bvh(s), Scratch::Bvh(sc)) if b.takes(sc) => {
                let settings = self.bvh_settings(&flags);
                b.record_build(rec, prims, host, &settings, sc, s, info)
            }
            (Family::Driver, Storage::Driver(s), sc) => {
                let given = match sc {
                    Scratch::Driver(given) => given.as_ref(),
                    _ => None,
                };
                let (prefer, update) = (flags.prefer, flags.allow_update);
                s.record_build(rec, prims, host, prefer, update, given, info)?;
                Ok(RecordedBuild::default())
            }
            _ => Err(GpuError::Usage {
                call,
                reason: format!(
                    "the scratch was made for another kind than {}",
                    self.kind.name()
                ),
            }),
        }
    }

    /// Scratch of [`AccelBuilder::record_refit`] for `n` primitives (`update_scratch_bytes`
    /// of [`AccelBuilder::sizes`]); `None` for kinds that cannot be refit.
    pub fn update_scratch(&self, ctx: &Context, n: usize) -> Result<Option<Buffer<u32>>> {
        match &self.family {
            Family::KdTree(_) => Ok(None),
            Family::Bvh(b) => b.update_scratch(ctx, n).map(Some),
            // The driver's update scratch lives with its structure.
            Family::Driver => Buffer::new(ctx, "accel.refit_visits", 1).map(Some),
        }
    }

    /// [`AccelBuilder::record_refit`] of a structure and its primitives held apart (the
    /// renderer's frames).
    pub(crate) fn record_refit_parts(
        &self,
        rec: &mut Recorder,
        out: &mut AccelStructure,
        prims: &DevicePrimitives,
        scratch: &Buffer<u32>,
    ) -> Result<()> {
        self.check_frozen("AccelBuilder::record_refit", out)?;
        self.record_refit_inner(rec, prims, out, scratch)?;
        rec.end_of_build();
        Ok(())
    }

    fn record_refit_inner(
        &self,
        rec: &mut Recorder,
        prims: &DevicePrimitives,
        out: &AccelStructure,
        scratch: &Buffer<u32>,
    ) -> Result<()> {
        match (&self.family, &out.storage) {
            (_, Storage::Driver(d)) => d.record_update(rec),
            (Family::Bvh(b), Storage::Bvh(s)) => b.record_refit(rec, prims, s, &out.info, scratch),
            _ => Err(GpuError::Usage {
                call: "AccelBuilder::record_refit",
                reason: format!("a {} cannot be refit; rebuild it", out.kind.name()),
            }),
        }
    }

    /// How kernels walk the structures this builder makes with `flags`.
    pub(crate) fn traversal(&self, flags: &BuildFlags) -> AccelTraversal {
        self.kind.walked(bvh_traversal(flags.wide))
    }

    /// The scene constants the gather writes for a structure this builder makes with
    /// `flags` over `n` primitives: how the shader library walks it, and where a BVH's
    /// parent links start.
    pub(crate) fn scene_header(&self, flags: &BuildFlags, n: usize) -> (u32, u32) {
        let walk = match self.traversal(flags) {
            AccelTraversal::Bvh(_) if self.top_level => SceneInfo::WALK_INSTANCES,
            t => t.scene_walk(),
        };
        let parents_at = match self.kind() {
            AccelKind::Lbvh | AccelKind::Ploc => n as u32,
            _ => 0,
        };
        (walk, parents_at)
    }
}

/// How kernels walk a BVH: wide where it has wide nodes.
fn bvh_traversal(wide: bool) -> Traversal {
    match wide {
        true => Traversal::Wide,
        false => Traversal::Stack,
    }
}

/// The seven bindings of `prims` and `accel` in `traverse.glsl`'s order.
pub(crate) fn bindings<'a>(
    prims: &'a DevicePrimitives,
    accel: &'a AccelStructure,
) -> [&'a dyn BufferArg; 7] {
    let [nodes, refs] = accel.node_bindings();
    let p = prims;
    [
        nodes,
        refs,
        &p.tri_verts,
        &p.spheres,
        &p.prim_motion,
        &p.motions,
        &accel.info,
    ]
}

pub(crate) fn address_handle(
    ctx: &Context,
    prims: &DevicePrimitives,
    accel: &AccelStructure,
) -> Result<[u64; 7]> {
    let mut out = [0u64; 7];
    for (o, b) in out.iter_mut().zip(bindings(prims, accel)) {
        *o = crate::gpu::address_of(ctx, b)?;
    }
    Ok(out)
}

/// Whether a structure's builds write its handle: in vkrt's own memory (which has device
/// addresses), or in the caller's where it says so.
pub(crate) fn referenceable(accel: &AccelStructure) -> bool {
    accel.references_enabled || accel.info.buffer_size().is_some()
}

/// The handle a structure keeps in the last element of its scene constants' buffer (what
/// [`GpuGeometry::reference`](crate::accel::gpu_geometry::GpuGeometry::reference) addresses: a top level reads a bottom level through it), as
/// the element's bytes; `None` where the context has no device addresses or the structure
/// keeps no handle.
pub(crate) fn handle_record(
    ctx: &Context,
    prims: &DevicePrimitives,
    accel: &AccelStructure,
) -> Result<Option<SceneInfo>> {
    let f = &ctx.info().features;
    let addresses = f.buffer_device_address || f.ray_query;
    if !addresses || accel.info.len() < 2 || !referenceable(accel) {
        return Ok(None);
    }
    let mut words = [0u64; 8];
    words[..7].copy_from_slice(&address_handle(ctx, prims, accel)?);
    Ok(Some(bytemuck::cast(words)))
}
