//! The refit of a BVH built to be updated (`BuildFlags::allow_update`, as
//! `VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_UPDATE_BIT_KHR`): the build also records a
//! schedule — the nodes sorted by depth (`accel.bvh_schedule`, a stable radix sort, so the
//! schedule is the same on every run), and where each depth starts with its indirect
//! dispatch (`accel.bvh_schedule_scan`) — kept with the structure; each refit is then one
//! dispatch per depth, deepest first (`accel.bvh_refit_level`): no atomics, no waiting, no
//! idle lanes, where the climbing refit (`accel.bvh_refit`) keeps a subgroup going while any
//! of its lanes climbs. The boxes are the climbing refit's and the CPU twin's, bit for bit.

use std::sync::Arc;

use super::layout::MAX_TRAVERSAL_DEPTH;
use super::BvhNode;
use crate::accel::primitives::SceneInfo;
use crate::gpu::{kernels, Buffer, BufferArg, Context, Kernel, Recorder, Result, Spec};
use crate::prims::radix_sort::{RadixScratch, RadixSort};
use crate::prims::PrimConfig;

const WORKGROUP: u32 = 64;
/// Words of the levels buffer: counts, starts and dispatches of every depth.
const LEVEL_WORDS: usize = 5 * MAX_TRAVERSAL_DEPTH as usize;

/// The kernels, compiled once.
pub struct LevelRefit {
    schedule: Arc<Kernel>,
    scan: Arc<Kernel>,
    level: Arc<Kernel>,
    sort: RadixSort,
}

/// What a structure built to be updated keeps: its nodes sorted by depth, and per depth the
/// count, the start and the indirect dispatch.
pub struct RefitSchedule {
    order: Buffer<u32>,
    levels: Buffer<u32>,
}

impl RefitSchedule {
    /// Bytes of the schedule of `n_nodes` nodes.
    pub fn bytes(n_nodes: usize) -> u64 {
        4 * (n_nodes.max(1) + LEVEL_WORDS) as u64
    }

    /// Allocates the schedule of a tree of `n_nodes` nodes.
    pub fn new(ctx: &Context, n_nodes: usize) -> Result<Self> {
        Ok(Self {
            order: Buffer::new(ctx, "accel.refit.order", n_nodes)?,
            levels: Buffer::new(ctx, "accel.refit.levels", LEVEL_WORDS)?,
        })
    }

    /// The node ids sorted by depth, and the per-depth words (counts, starts, dispatches).
    pub(crate) fn arrays(&self) -> (&Buffer<u32>, &Buffer<u32>) {
        (&self.order, &self.levels)
    }
}

/// Transient scratch of the schedule's build: the depth keys and the sort's.
/// Scratch of [`LevelRefit::record_schedule`].
pub struct ScheduleScratch {
    keys: Buffer<u32>,
    sort: RadixScratch,
}

impl LevelRefit {
    /// Compiles the schedule, scan and per-depth refit kernels and the depth sort.
    pub fn new(ctx: &Context) -> Result<Self> {
        let spec = Spec::new().workgroup(WORKGROUP);
        Ok(Self {
            schedule: ctx.kernel(&kernels::ACCEL_BVH_SCHEDULE, &spec)?,
            scan: ctx.kernel(&kernels::ACCEL_BVH_SCHEDULE_SCAN, &Spec::new())?,
            level: ctx.kernel(
                super::pairs_variant(
                    ctx,
                    &kernels::ACCEL_BVH_REFIT_LEVEL_PAIRS64,
                    &kernels::ACCEL_BVH_REFIT_LEVEL_WORDS,
                ),
                &spec,
            )?,
            sort: RadixSort::new(ctx, PrimConfig::default_for(ctx), 8)?,
        })
    }

    /// Bytes of the transient scratch of [`LevelRefit::record_schedule`].
    pub fn scratch_bytes(&self, n_nodes: usize) -> u64 {
        4 * n_nodes.max(1) as u64 + self.sort.scratch_bytes(n_nodes.max(1))
    }

    /// Records the schedule of the first `n_nodes` nodes of a built tree whose parent links
    /// are in `refs` from `parents_at` on. Ends with a barrier that lets refits (kernels and
    /// indirect dispatches) read it.
    pub fn record_schedule(
        &self,
        rec: &mut Recorder,
        refs: &Buffer<u32>,
        n_nodes: usize,
        parents_at: u32,
        schedule: &RefitSchedule,
        scratch: Option<&ScheduleScratch>,
    ) -> Result<()> {
        if n_nodes == 0 {
            return Ok(());
        }
        let ctx = rec.context().clone();
        let own = match scratch {
            Some(_) => None,
            None => Some(self.schedule_scratch(&ctx, n_nodes)?),
        };
        let Some(scratch) = scratch.or(own.as_ref()) else {
            unreachable!("one of the two is set")
        };
        rec.scope("refit.schedule", |rec| {
            rec.fill(&schedule.levels, 0);
            rec.transfer_to_compute();
            let groups = rec.groups_1d(n_nodes as u64, WORKGROUP);
            let b: [&dyn BufferArg; 4] = [refs, &scratch.keys, &schedule.order, &schedule.levels];
            rec.dispatch(&self.schedule, groups, &b, &[n_nodes as u32, parents_at]);
            rec.compute_to_compute();
            // Depths fit 7 bits (MAX_TRAVERSAL_DEPTH = 128), and the key of a slot the
            // leaf collapse freed, 128, the eighth.
            self.sort.record(
                rec,
                &scratch.keys,
                &schedule.order,
                n_nodes,
                8,
                &scratch.sort,
            );
            rec.compute_to_compute();
            rec.dispatch(&self.scan, [1, 1, 1], &[&schedule.levels], &WORKGROUP);
        });
        rec.compute_to_indirect();
        if let Some(own) = own {
            // Freed when this returns, before the work runs: kept with the recorder.
            rec.keep_alive(own);
        }
        Ok(())
    }

    /// The scratch of a schedule over `n_nodes` nodes (its bytes: [`Self::scratch_bytes`]).
    pub fn schedule_scratch(&self, ctx: &Context, n_nodes: usize) -> Result<ScheduleScratch> {
        Ok(ScheduleScratch {
            keys: Buffer::new(ctx, "accel.refit.depths", n_nodes.max(1))?,
            sort: self.sort.scratch(ctx, n_nodes.max(1))?,
        })
    }

    /// Records a refit of every node in `schedule`, deepest first, from `boxes` (six floats
    /// per primitive) as they are now; the root box goes to `info`. Ends with a compute →
    /// compute barrier.
    #[allow(clippy::too_many_arguments, reason = "the structure's buffers")]
    pub fn record_refit(
        &self,
        rec: &mut Recorder,
        nodes: &Buffer<BvhNode>,
        refs: &Buffer<u32>,
        boxes: &Buffer<f32>,
        info: &Buffer<SceneInfo>,
        schedule: &RefitSchedule,
    ) {
        rec.scope("refit", |rec| {
            for depth in (0..MAX_TRAVERSAL_DEPTH).rev() {
                let args = 4 * u64::from(2 * MAX_TRAVERSAL_DEPTH + 3 * depth);
                let b: [&dyn BufferArg; 6] =
                    [nodes, refs, boxes, &schedule.order, &schedule.levels, info];
                rec.dispatch_indirect(&self.level, &schedule.levels, args, &b, &depth);
                rec.compute_to_compute();
            }
        });
    }
}
