//! The BVH family on the device: Sochora's (2013) SAH BVH built on the host's cores and
//! uploaded, as Embree's are, the GPU LBVH (Karras 2012) and PLOC (Meister & Bittner 2018)
//! with their SAH leaf collapse, each refit in place, and the 4-wide nodes (Ylitie, Karras
//! & Laine 2017) made after every build and refit for the wide walk. All share one layout,
//! so a builder added here changes this file and the test lists only.

use std::sync::Arc;

use crate::accel::bvh::collapse::{self, RefLayout};
use crate::accel::bvh::collapse_gpu::{CollapseKernels, CollapseScratch};
use crate::accel::bvh::compact::BvhSlots;
use crate::accel::bvh::compact_gpu::{CompactKernels, TreeArrays};
use crate::accel::bvh::layout::MAX_WALK_LEAF;
use crate::accel::bvh::lbvh::MortonBits;
use crate::accel::bvh::lbvh_gpu::{self, LbvhBuilder};
use crate::accel::bvh::ploc::PlocParams;
use crate::accel::bvh::ploc_gpu::{PlocBuilder, PlocScratch};
use crate::accel::bvh::refit_gpu::{LevelRefit, RefitSchedule, ScheduleScratch};
use crate::accel::bvh::wide::WideNode;
use crate::accel::bvh::wide_gpu::Widen;
use crate::accel::bvh::{self, Bvh, BvhNode, BvhParams, Threading};
use crate::accel::device_primitives::DevicePrimitives;
use crate::accel::primitives::{SceneInfo, TraceGeometry};
use crate::accel::sizes::{AccelSizes, RecordedBuild};
use crate::gpu::placement::{place, Placement};
use crate::gpu::{
    kernels, Buffer, BufferArg, Context, GpuError, Kernel, Memory, RawBuffer, Readback, Recorder,
    Result, Spec,
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

/// Nodes of a BVH over `n` primitives (one for 0 or 1: a root).
fn bvh_nodes(n: usize) -> usize {
    n.saturating_sub(1).max(1)
}

/// Which builder makes the tree; the GPU builders with the SAH leaf collapse of their trees.
enum TreeBuilder {
    /// Sochora's SAH BVH, on the host.
    Sah,
    Lbvh(LbvhBuilder, CollapseKernels),
    Ploc(PlocBuilder, CollapseKernels),
}

/// The BVH family's builder: one tree builder, and the refit and widen every BVH shares.
pub(crate) struct BvhFamily {
    tree: TreeBuilder,
    /// `accel.bvh_refit`.
    refit: Arc<Kernel>,
    /// `accel.bvh_refit_level` and the schedule's kernels.
    level_refit: LevelRefit,
    /// `accel.bvh_widen`.
    widen: Widen,
}

/// How a BVH is built: the settings of [`AccelBuilder`](crate::accel::device::AccelBuilder)
/// that apply to BVHs.
pub(crate) struct BvhSettings<'a> {
    pub params: &'a BvhParams,
    pub threading: Threading,
    /// Built to be updated: the refit's schedule is recorded with the build.
    pub allow_update: bool,
    /// With 4-wide nodes, for the wide walk.
    pub wide: bool,
    /// `SceneInfo::walk` of the scene constants a build over host primitives writes.
    pub walk: u32,
}

/// A BVH in device memory.
pub(crate) struct BvhStorage {
    nodes: Buffer<BvhNode>,
    /// References, then one parent link per node slot; for a structure the GPU builders
    /// build, then the count of live nodes their leaf collapse writes.
    refs: Buffer<u32>,
    /// Node slots and references of the built tree.
    counts: (usize, usize),
    /// Live nodes of the built tree where the host knows them; `None` where a leaf collapse
    /// counted them on the device (the word after the parent links).
    live: Option<usize>,
    /// The kernels of a compacted copy, prepared when it was created.
    compaction: Option<Arc<BvhCompaction>>,
    /// The refit's schedule, for a structure built to be updated.
    schedule: Option<Box<RefitSchedule>>,
    /// The 4-wide nodes, one per binary slot, for a structure walked wide: bound in place
    /// of the binary nodes.
    wide: Option<Buffer<WideNode>>,
}

/// Scratch of a BVH build.
pub(crate) enum BvhScratch {
    /// The SAH builder works in host memory.
    Host,
    Lbvh(Box<LbvhDeviceScratch>),
    Ploc(Box<PlocDeviceScratch>),
}

/// PLOC build scratch, the visit counters (the one-primitive tree's refit, the collapse)
/// and the collapse's.
pub(crate) struct PlocDeviceScratch {
    build: PlocScratch,
    visits: Buffer<u32>,
    collapse: CollapseScratch,
    /// The refit schedule's, for a structure built to be updated.
    schedule: Option<ScheduleScratch>,
}

/// LBVH build scratch: the topology's, the visit counters of the boxes' refit and the
/// collapse, and the collapse's.
pub(crate) struct LbvhDeviceScratch {
    topology: lbvh_gpu::LbvhScratch,
    visits: Buffer<u32>,
    collapse: CollapseScratch,
    /// The refit schedule's, for a structure built to be updated.
    schedule: Option<ScheduleScratch>,
}

impl BvhFamily {
    fn with(ctx: &Context, tree: TreeBuilder) -> Result<Self> {
        Ok(Self {
            tree,
            refit: ctx.kernel(
                bvh::pairs_variant(
                    ctx,
                    &kernels::ACCEL_BVH_REFIT_BOXES64,
                    &kernels::ACCEL_BVH_REFIT_BOXES,
                ),
                &Spec::new().workgroup(refit_workgroup(ctx)),
            )?,
            level_refit: LevelRefit::new(ctx)?,
            widen: Widen::new(ctx)?,
        })
    }

    /// The SAH BVH's.
    pub(crate) fn sah(ctx: &Context) -> Result<Self> {
        Self::with(ctx, TreeBuilder::Sah)
    }

    /// The LBVH's with `bits`-bit Morton codes.
    pub(crate) fn lbvh(ctx: &Context, bits: MortonBits) -> Result<Self> {
        let collapse = CollapseKernels::new(ctx, refit_workgroup(ctx))?;
        Self::with(
            ctx,
            TreeBuilder::Lbvh(LbvhBuilder::new(ctx, bits)?, collapse),
        )
    }

    /// PLOC's with `params`.
    pub(crate) fn ploc(ctx: &Context, params: PlocParams) -> Result<Self> {
        let collapse = CollapseKernels::new(ctx, refit_workgroup(ctx))?;
        Self::with(
            ctx,
            TreeBuilder::Ploc(PlocBuilder::new(ctx, params)?, collapse),
        )
    }

    /// The Morton code width of the LBVH or PLOC builder.
    pub(crate) fn morton_bits(&self) -> Option<MortonBits> {
        match &self.tree {
            TreeBuilder::Lbvh(l, _) => Some(l.bits()),
            TreeBuilder::Ploc(p, _) => Some(p.params().bits),
            TreeBuilder::Sah => None,
        }
    }

    /// The knobs of the PLOC builder.
    pub(crate) fn ploc_params(&self) -> Option<PlocParams> {
        match &self.tree {
            TreeBuilder::Ploc(p, _) => Some(p.params()),
            _ => None,
        }
    }

    /// Whether `scratch` was made by this builder.
    pub(crate) fn takes(&self, scratch: &BvhScratch) -> bool {
        matches!(
            (&self.tree, scratch),
            (TreeBuilder::Sah, BvhScratch::Host)
                | (TreeBuilder::Lbvh(..), BvhScratch::Lbvh(_))
                | (TreeBuilder::Ploc(..), BvhScratch::Ploc(_))
        )
    }

    pub(crate) fn sizes(&self, n: usize, s: &BvhSettings<'_>) -> AccelSizes {
        let info = std::mem::size_of::<SceneInfo>() as u64;
        let nodes = bvh_nodes(n) as u64;
        let build_scratch_bytes = match &self.tree {
            TreeBuilder::Lbvh(l, c) => {
                l.scratch_bytes(n) + nodes * 4 + c.scratch_bytes(n, LBVH_REFS)
            }
            TreeBuilder::Ploc(p, c) => {
                p.scratch_bytes(n) + nodes * 4 + c.scratch_bytes(n, PLOC_REFS)
            }
            TreeBuilder::Sah => 0,
        };
        let (schedule, schedule_scratch) = match s.allow_update {
            true => (
                RefitSchedule::bytes(nodes as usize),
                self.level_refit.scratch_bytes(nodes as usize),
            ),
            false => (0, 0),
        };
        let wide = if s.wide { nodes * 64 } else { 0 };
        AccelSizes {
            structure_bytes: nodes * 64 + wide + (n as u64 + nodes + 1) * 4 + info + schedule,
            build_scratch_bytes: build_scratch_bytes + schedule_scratch,
            update_scratch_bytes: Some(nodes * 4),
        }
    }

    pub(crate) fn create_storage(
        &self,
        ctx: &Context,
        n: usize,
        allow_update: bool,
        wide: bool,
    ) -> Result<BvhStorage> {
        let nodes = bvh_nodes(n);
        Ok(BvhStorage {
            nodes: Buffer::new(ctx, "accel.bvh_nodes", nodes)?,
            // (and the live-node count a leaf collapse writes)
            refs: Buffer::new(ctx, "accel.bvh_refs", n + nodes + 1)?,
            counts: (0, 0),
            live: Some(0),
            compaction: None,
            schedule: match allow_update {
                true => Some(Box::new(RefitSchedule::new(ctx, nodes)?)),
                false => None,
            },
            wide: match wide {
                true => Some(Buffer::new(ctx, "accel.bvh_wide", nodes)?),
                false => None,
            },
        })
    }

    pub(crate) fn create_scratch(
        &self,
        ctx: &Context,
        n: usize,
        params: &BvhParams,
        allow_update: bool,
    ) -> Result<BvhScratch> {
        let nodes = bvh_nodes(n);
        let collapse = |c: &CollapseKernels, layout| -> Result<CollapseScratch> {
            CollapseKernels::check(params)?;
            c.scratch(ctx, n, layout)
        };
        let schedule = match allow_update {
            true => Some(self.level_refit.schedule_scratch(ctx, nodes)?),
            false => None,
        };
        Ok(match &self.tree {
            TreeBuilder::Lbvh(l, c) => BvhScratch::Lbvh(Box::new(LbvhDeviceScratch {
                topology: l.scratch(ctx, n)?,
                visits: Buffer::new(ctx, "accel.lbvh.visits", nodes)?,
                collapse: collapse(c, LBVH_REFS)?,
                schedule,
            })),
            TreeBuilder::Ploc(p, c) => BvhScratch::Ploc(Box::new(PlocDeviceScratch {
                build: p.scratch(ctx, n)?,
                visits: Buffer::new(ctx, "accel.ploc.visits", nodes)?,
                collapse: collapse(c, PLOC_REFS)?,
                schedule,
            })),
            TreeBuilder::Sah => BvhScratch::Host,
        })
    }

    /// Records the build of `out` over `prims` (`host`: the host's copy, which the SAH
    /// builder reads; `None` where a gather wrote the scene constants), then the refit's
    /// schedule and the wide nodes where `out` has them.
    #[allow(clippy::too_many_arguments, reason = "the build's inputs and outputs")]
    pub(crate) fn record_build(
        &self,
        rec: &mut Recorder,
        prims: &DevicePrimitives,
        host: Option<&TraceGeometry>,
        s: &BvhSettings<'_>,
        scratch: &BvhScratch,
        out: &mut BvhStorage,
        info: &Buffer<SceneInfo>,
    ) -> Result<RecordedBuild> {
        let n = prims.count();
        let (nodes, refs) = (&out.nodes, &out.refs);
        let p = s.params;
        let recorded = match (&self.tree, scratch) {
            (TreeBuilder::Sah, _) => {
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
                if p.max_leaf_prims > MAX_WALK_LEAF {
                    return Err(GpuError::Usage {
                        call: "AccelBuilder::record_build",
                        reason: format!(
                            "max_leaf_prims = {}: the GPU walks take leaves of at most \
                             {MAX_WALK_LEAF} primitives",
                            p.max_leaf_prims
                        ),
                    });
                }
                let t = std::time::Instant::now();
                let bvh =
                    bvh::build(&host.boxes, p, s.threading).map_err(|e| GpuError::Kernel {
                        kernel: "accel.sah_bvh",
                        reason: e.to_string(),
                    })?;
                let host_ms = t.elapsed().as_secs_f64() * 1e3;
                crate::gpu::record_host_span("accel.sah_bvh.host_build", t);
                let mut words = bvh.refs.clone();
                words.extend_from_slice(&bvh.parents);
                rec.upload(nodes, &bvh.nodes)?;
                rec.upload(refs, &words)?;
                let constants = prims.info(&bvh.bounds, bvh.refs.len() as u32);
                rec.upload(info, &[constants.walked(s.walk)])?;
                rec.transfer_to_compute();
                out.counts = (bvh.nodes.len(), bvh.refs.len());
                out.live = Some(bvh.nodes.len());
                RecordedBuild {
                    host_ms: Some(host_ms),
                }
            }
            (TreeBuilder::Lbvh(lbvh, collapse), BvhScratch::Lbvh(sc)) => {
                let n_nodes = if n == 0 { 0 } else { bvh_nodes(n) };
                if host.is_some() {
                    upload_gpu_bvh_info(rec, prims, info, s.walk)?;
                }
                // The references go to the collapse's scratch where it collapses.
                let collapsing = collapse::applies(n, p);
                let tree_refs = match collapsing {
                    true => sc.collapse.tree_refs(),
                    false => refs,
                };
                out.counts = (n_nodes, n);
                out.live = out.record_zero_live(rec, collapsing);
                // One climb builds the topology with its boxes (and the collapse's decisions).
                let (visits, cs) = (&sc.visits, &sc.collapse);
                let decide = collapsing.then(|| (cs.costs(), p));
                let boxes = &prims.boxes;
                lbvh.record_build(
                    rec,
                    boxes,
                    n,
                    &sc.topology,
                    nodes,
                    tree_refs,
                    visits,
                    info,
                    decide,
                )?;
                if collapsing {
                    collapse.record(rec, n, visits, cs, p, nodes, refs, true, LBVH_REFS)?;
                }
                RecordedBuild::default()
            }
            (TreeBuilder::Ploc(ploc, collapse), BvhScratch::Ploc(sc)) => {
                let n_nodes = if n == 0 { 0 } else { bvh_nodes(n) };
                if host.is_some() {
                    upload_gpu_bvh_info(rec, prims, info, s.walk)?;
                }
                out.counts = (n_nodes, n);
                out.live = out.record_zero_live(rec, collapse::applies(n, p));
                if collapse::applies(n, p) {
                    // The references go to the collapse's scratch, and are laid out in `refs`.
                    let tree_refs = sc.collapse.tree_refs();
                    ploc.record_build(rec, &prims.boxes, n, &sc.build, nodes, tree_refs, info)?;
                    rec.compute_to_compute();
                    let (visits, cs) = (&sc.visits, &sc.collapse);
                    collapse.record(rec, n, visits, cs, p, nodes, refs, false, PLOC_REFS)?;
                } else if n >= 2 {
                    ploc.record_build(rec, &prims.boxes, n, &sc.build, nodes, refs, info)?;
                } else {
                    let meet = &sc.visits;
                    ploc.record_small(rec, &prims.boxes, n, &sc.build, nodes, refs, meet, info)?;
                }
                rec.compute_to_compute();
                RecordedBuild::default()
            }
            _ => unreachable!("BvhFamily::takes is checked before"),
        };
        if let Some(schedule) = &out.schedule {
            let placed = match scratch {
                BvhScratch::Lbvh(s) => s.schedule.as_ref(),
                BvhScratch::Ploc(s) => s.schedule.as_ref(),
                BvhScratch::Host => None,
            };
            let (n_nodes, n_refs) = out.counts;
            let level = &self.level_refit;
            level.record_schedule(rec, &out.refs, n_nodes, n_refs as u32, schedule, placed)?;
        }
        self.record_widen(rec, out);
        Ok(recorded)
    }

    /// Scratch of a refit over `n` primitives: a visit counter per node.
    pub(crate) fn update_scratch(&self, ctx: &Context, n: usize) -> Result<Buffer<u32>> {
        Buffer::new(ctx, "accel.refit_visits", bvh_nodes(n))
    }

    /// Records a refit of `out` to `prims.boxes` as they are now (see
    /// [`AccelBuilder::record_refit`](crate::accel::device::AccelBuilder::record_refit)).
    pub(crate) fn record_refit(
        &self,
        rec: &mut Recorder,
        prims: &DevicePrimitives,
        out: &BvhStorage,
        info: &Buffer<SceneInfo>,
        scratch: &Buffer<u32>,
    ) -> Result<()> {
        let (n_nodes, n_refs) = out.counts;
        if scratch.len() < n_nodes {
            return Err(GpuError::Usage {
                call: "AccelBuilder::record_refit",
                reason: format!(
                    "the update scratch holds {} counters; this structure needs {n_nodes}",
                    scratch.len()
                ),
            });
        }
        if n_refs != prims.count() {
            return Err(GpuError::Usage {
                call: "AccelBuilder::record_refit",
                reason: format!(
                    "the structure was built over {n_refs} primitives; {} given",
                    prims.count()
                ),
            });
        }
        let (nodes, refs) = (&out.nodes, &out.refs);
        match &out.schedule {
            Some(schedule) if n_nodes > 0 => {
                self.level_refit
                    .record_refit(rec, nodes, refs, &prims.boxes, info, schedule);
            }
            _ => {
                let kernel = &self.refit;
                record_refit_nodes(rec, kernel, prims, nodes, refs, scratch, info, n_nodes)
            }
        }
        self.record_widen(rec, out);
        Ok(())
    }

    /// Records `accel.bvh_widen` over `out`'s binary nodes where it has wide ones (after a
    /// build or refit wrote them).
    fn record_widen(&self, rec: &mut Recorder, out: &BvhStorage) {
        if let Some(wide) = &out.wide {
            self.widen.record(rec, &out.nodes, wide, out.counts.0);
        }
    }
}

impl BvhStorage {
    /// A BVH built on the host (or downloaded), uploaded; with its wide nodes where `wide`.
    pub(crate) fn from_host(ctx: &Context, bvh: &Bvh, wide: bool) -> Result<Self> {
        let largest = bvh.nodes.iter().map(|n| n.a_count.max(n.b_count)).max();
        if let Some(count) = largest.filter(|&c| c > MAX_WALK_LEAF) {
            return Err(GpuError::Usage {
                call: "GpuGeometry::upload_bvh",
                reason: format!(
                    "a leaf of {count} primitives: the GPU walks take leaves of at most \
                     {MAX_WALK_LEAF} (BvhParams::max_leaf_prims)"
                ),
            });
        }
        let mut words = bvh.refs.clone();
        words.extend_from_slice(&bvh.parents);
        Ok(Self {
            nodes: Buffer::from_slice(ctx, "accel.bvh_nodes", &bvh.nodes)?,
            refs: Buffer::from_slice(ctx, "accel.bvh_refs", &words)?,
            counts: (bvh.nodes.len(), bvh.refs.len()),
            live: Some(bvh.nodes.len()),
            compaction: None,
            schedule: None,
            wide: match wide {
                true => Some(Buffer::from_slice(ctx, "accel.bvh_wide", bvh.wide())?),
                false => None,
            },
        })
    }

    /// Whether it has wide nodes.
    pub(crate) fn is_wide(&self) -> bool {
        self.wide.is_some()
    }

    /// The `nodes` and `prim_refs` bindings (walked wide: the wide nodes).
    pub(crate) fn node_bindings(&self) -> [&dyn BufferArg; 2] {
        match &self.wide {
            Some(wide) => [wide, &self.refs],
            None => [&self.nodes, &self.refs],
        }
    }

    /// The binary and wide node slots, where it has wide nodes.
    pub(crate) fn download_wide(&self) -> Result<Option<(Vec<BvhNode>, Vec<WideNode>)>> {
        let Some(wide) = &self.wide else {
            return Ok(None);
        };
        let mut binary = self.nodes.download()?;
        let mut w = wide.download()?;
        binary.truncate(self.counts.0);
        w.truncate(self.counts.0);
        Ok(Some((binary, w)))
    }

    /// Where a leaf collapse counts the live nodes: after the references and parent links.
    fn live_at(&self) -> usize {
        self.nodes.len() + self.counts.1
    }

    /// Zeroes the live-node count where the build records a leaf collapse, which counts
    /// into it; what [`BvhStorage::live`] is then. After a compute → transfer barrier (the
    /// last build's count was a kernel's write), before the builders' first fill, whose
    /// transfer → compute barrier orders it before their kernels.
    /// Takes `from`'s build state (counts, live nodes) for a byte copy of its arrays: both
    /// made for the same geometry and flags, so the arrays have the same shape.
    pub(crate) fn adopt_build_state(&mut self, from: &BvhStorage) -> Result<()> {
        let same = self.nodes.len() == from.nodes.len()
            && self.refs.len() == from.refs.len()
            && self.schedule.is_some() == from.schedule.is_some()
            && self.wide.is_some() == from.wide.is_some()
            && self.compaction.is_none()
            && from.compaction.is_none();
        if !same {
            return Err(GpuError::Usage {
                call: "GpuGeometry::record_built_by_copy",
                reason: "the source's arrays are of another shape".into(),
            });
        }
        self.counts = from.counts;
        self.live = from.live;
        Ok(())
    }

    fn record_zero_live(&self, rec: &mut Recorder, collapsing: bool) -> Option<usize> {
        if !collapsing {
            return Some(self.counts.0);
        }
        rec.compute_to_transfer();
        rec.fill_range(&self.refs, self.live_at(), 1, 0);
        None
    }

    /// Records the read of the built tree's live-node count (where the host does not know
    /// it: a copy of the collapse's count into host memory). The caller orders the build
    /// before (`compute_to_transfer`) and the copy before the host's read
    /// (`transfer_to_host`).
    pub(crate) fn record_live_count(&self, rec: &mut Recorder) -> Result<LiveCount> {
        if let Some(live) = self.live {
            return Ok(LiveCount::Known(live));
        }
        let ctx = rec.context().clone();
        let staging = Buffer::with_memory(&ctx, "staging.readback", 1, Memory::Readback)?;
        rec.copy_range(&self.refs, self.live_at(), &staging, 0, 1);
        Ok(LiveCount::Counted(Readback::from_staging(rec, staging)))
    }

    /// What its compacted copy is made for: node slots, references, schedule, wide nodes.
    pub(crate) fn compact_shape(&self) -> CompactShape {
        CompactShape {
            slots: self.counts.0,
            refs: self.counts.1,
            schedule: self.schedule.is_some(),
            wide: self.wide.is_some(),
        }
    }

    /// The storage of a compacted copy of a tree of `shape` holding `live` nodes, with the
    /// kernels that fill it.
    pub(crate) fn compacted(ctx: &Context, shape: &CompactShape, live: usize) -> Result<Self> {
        let slots = live.max(1);
        Ok(Self {
            nodes: Buffer::new(ctx, "accel.bvh_nodes", slots)?,
            refs: Buffer::new(ctx, "accel.bvh_refs", shape.refs + slots)?,
            counts: (live, shape.refs),
            live: Some(live),
            compaction: Some(Arc::new(BvhCompaction::new(ctx)?)),
            schedule: match shape.schedule {
                true => Some(Box::new(RefitSchedule::new(ctx, slots)?)),
                false => None,
            },
            wide: match shape.wide {
                true => Some(Buffer::new(ctx, "accel.bvh_wide", slots)?),
                false => None,
            },
        })
    }

    /// Records the compaction of this built tree into `dst` ([`BvhStorage::compacted`] with
    /// its live count), with its scratch placed in the caller's range (none for an empty
    /// tree): the live nodes renumbered with their references and parent links, the
    /// schedule renamed, the wide nodes made anew from the compacted ones. Kernels only;
    /// ends with a compute → compute barrier.
    pub(crate) fn record_compact_into(
        &self,
        rec: &mut Recorder,
        dst: &BvhStorage,
        scratch: Option<RawBuffer>,
    ) -> Result<()> {
        let call = "GpuGeometry::record_compact_into";
        let c = dst.compaction.as_ref().ok_or_else(|| GpuError::Usage {
            call,
            reason: "the destination is not a compacted structure (create_compacted_in)".into(),
        })?;
        let (n_nodes, n_refs) = self.counts;
        let live = dst.counts.0;
        let (src_shape, dst_shape) = (self.compact_shape(), dst.compact_shape());
        let same = (src_shape.schedule, src_shape.wide) == (dst_shape.schedule, dst_shape.wide);
        if !same || dst.counts.1 != n_refs || live > n_nodes || (n_nodes > 0) != (live > 0) {
            return Err(GpuError::Usage {
                call,
                reason: format!(
                    "the destination holds {live} nodes over {} references; this tree has \
                     {n_nodes} node slots over {n_refs}",
                    dst.counts.1
                ),
            });
        }
        if n_nodes == 0 {
            return Ok(());
        }
        let scratch = scratch.ok_or_else(|| GpuError::Usage {
            call,
            reason: "a BVH's compaction needs scratch of CompactedSize::scratch_bytes".into(),
        })?;
        let ctx = rec.context().clone();
        let (sc, _) = place(
            &ctx,
            "the compaction's scratch",
            Placement::Into(scratch),
            || c.kernels.scratch(&ctx, n_nodes),
        )?;
        let src = TreeArrays {
            nodes: &self.nodes,
            refs: &self.refs,
            schedule: self.schedule.as_ref().map(|s| s.arrays()),
        };
        let out = TreeArrays {
            nodes: &dst.nodes,
            refs: &dst.refs,
            schedule: dst.schedule.as_ref().map(|s| s.arrays()),
        };
        c.kernels
            .record(rec, &src, &out, n_nodes, n_refs, live, &sc);
        if let Some(wide) = &dst.wide {
            c.widen.record(rec, &dst.nodes, wide, live);
        }
        Ok(())
    }

    /// Bytes of the scratch [`BvhStorage::record_compact_into`] needs for a tree of `shape`.
    pub(crate) fn compact_scratch_bytes(ctx: &Context, shape: &CompactShape) -> Result<u64> {
        if shape.slots == 0 {
            return Ok(0);
        }
        let kernels = CompactKernels::new(ctx)?;
        let (_, bytes) = place(ctx, "the compaction's scratch", Placement::Measure, || {
            kernels.scratch(ctx, shape.slots)
        })?;
        Ok(bytes)
    }

    /// The node slots, parent links and references as they lie (freed slots included),
    /// and the live-node count where the device holds it (tests and tools).
    pub(crate) fn download_slots(&self) -> Result<BvhSlots> {
        let (n_nodes, n_refs) = self.counts;
        let mut nodes = self.nodes.download()?;
        nodes.truncate(n_nodes);
        let words = self.refs.download()?;
        Ok(BvhSlots {
            nodes,
            parents: words[n_refs..n_refs + n_nodes].to_vec(),
            refs: words[..n_refs].to_vec(),
            live: match self.live {
                Some(live) => live,
                None => words[self.live_at()] as usize,
            },
        })
    }

    /// The tree as the host sees it, without the slots a leaf collapse removed; `bounds`
    /// from the scene constants.
    pub(crate) fn download(&self, bounds: Aabb) -> Result<Bvh> {
        let (n_nodes, n_refs) = self.counts;
        let mut nodes = self.nodes.download()?;
        nodes.truncate(n_nodes);
        let all = self.refs.download()?;
        let (nodes, parents) = collapse::drop_removed(nodes, &all[n_refs..n_refs + n_nodes]);
        Ok(Bvh {
            nodes,
            parents,
            refs: all[..n_refs].to_vec(),
            bounds: if n_refs == 0 { Aabb::EMPTY } else { bounds },
            wide: Default::default(),
        })
    }
}

/// The live nodes of a built tree, as [`BvhStorage::record_live_count`] finds them.
pub(crate) enum LiveCount {
    /// Known on the host.
    Known(usize),
    /// The collapse's count, read back once the work has executed.
    Counted(Readback<u32>),
}

impl LiveCount {
    /// The count. Call only after the recording's work has completed.
    pub(crate) fn read(self) -> Result<usize> {
        match self {
            LiveCount::Known(live) => Ok(live),
            LiveCount::Counted(words) => Ok(words.read()?[0] as usize),
        }
    }
}

/// What a BVH's compacted copy is made for ([`BvhStorage::compact_shape`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct CompactShape {
    /// Node slots of the built tree.
    pub slots: usize,
    /// References.
    pub refs: usize,
    /// With a refit schedule (built to be updated).
    pub schedule: bool,
    /// With wide nodes.
    pub wide: bool,
}

/// The kernels of a BVH's compaction, and the widening of its wide nodes.
pub(crate) struct BvhCompaction {
    kernels: CompactKernels,
    widen: Widen,
}

impl BvhCompaction {
    fn new(ctx: &Context) -> Result<Self> {
        Ok(Self {
            kernels: CompactKernels::new(ctx)?,
            widen: Widen::new(ctx)?,
        })
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
