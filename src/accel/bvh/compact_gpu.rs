//! Compaction of a collapsed BVH on the device (CPU twin: [`super::compact`]): the live
//! flags of the node slots (`accel.bvh_compact_flags`), their exclusive scan (each live
//! node's rank, [`Scan`]), then every live node moved to its rank with its children and
//! parent renamed, and the references copied (`accel.bvh_compact_scatter`); for a structure
//! built to be updated, its refit schedule's ids renamed and its per-depth words copied
//! (`accel.bvh_compact_rename`).

use std::sync::Arc;

use super::BvhNode;
use crate::gpu::{kernels, Buffer, BufferArg, Context, Kernel, Recorder, Result, Spec};
use crate::prims::scan::{Scan, ScanInput, ScanOp, ScanScratch};
use crate::prims::PrimConfig;

const WORKGROUP: u32 = 64;

/// The kernels, compiled once.
pub struct CompactKernels {
    flags: Arc<Kernel>,
    scatter: Arc<Kernel>,
    rename: Arc<Kernel>,
    scan: Scan,
}

/// Scratch of one compaction of up to `max_nodes` node slots: the ranks and their scan's.
pub struct CompactScratch {
    rank: Buffer<u32>,
    scan: ScanScratch,
}

/// A built tree's arrays as compaction reads or writes them.
pub struct TreeArrays<'a> {
    /// The node slots.
    pub nodes: &'a Buffer<BvhNode>,
    /// The references, then a parent link per node slot.
    pub refs: &'a Buffer<u32>,
    /// The refit schedule (its node ids, and its per-depth words), where it has one.
    pub schedule: Option<(&'a Buffer<u32>, &'a Buffer<u32>)>,
}

impl CompactKernels {
    /// Compiles the kernels and the scan.
    pub fn new(ctx: &Context) -> Result<Self> {
        let spec = Spec::new().workgroup(WORKGROUP);
        Ok(Self {
            flags: ctx.kernel(&kernels::ACCEL_BVH_COMPACT_FLAGS, &spec)?,
            scatter: ctx.kernel(&kernels::ACCEL_BVH_COMPACT_SCATTER, &spec)?,
            rename: ctx.kernel(&kernels::ACCEL_BVH_COMPACT_RENAME, &spec)?,
            scan: Scan::new(ctx, PrimConfig::default_for(ctx), ScanInput::U32)?,
        })
    }

    /// The scratch of compactions of trees of up to `max_nodes` node slots (placed where a
    /// [`crate::gpu::placement::place`] is active).
    pub fn scratch(&self, ctx: &Context, max_nodes: usize) -> Result<CompactScratch> {
        let n = max_nodes.max(1);
        Ok(CompactScratch {
            rank: Buffer::new(ctx, "accel.compact.rank", n)?,
            scan: self.scan.scratch(ctx, n)?,
        })
    }

    /// Records the compaction of the `n_nodes` node slots and `n_refs` references of `src`
    /// into `dst`, which holds the `live` nodes among them (and the schedule's first `live`
    /// ids). The caller orders the accesses of `src`, `dst` and `scratch` before; ends with
    /// a barrier to kernels and indirect dispatches. Kernels only: no fill, no copy.
    #[allow(
        clippy::too_many_arguments,
        reason = "both trees' arrays and the counts"
    )]
    pub fn record(
        &self,
        rec: &mut Recorder,
        src: &TreeArrays<'_>,
        dst: &TreeArrays<'_>,
        n_nodes: usize,
        n_refs: usize,
        live: usize,
        scratch: &CompactScratch,
    ) {
        if n_nodes == 0 {
            return;
        }
        let (nodes32, refs32) = (n_nodes as u32, n_refs as u32);
        rec.scope("compact.rank", |rec| {
            let groups = rec.groups_1d(n_nodes as u64, WORKGROUP);
            let b: [&dyn BufferArg; 2] = [src.refs, &scratch.rank];
            rec.dispatch(&self.flags, groups, &b, &[nodes32, refs32]);
            rec.compute_to_compute();
            let (rank, op) = (&scratch.rank, ScanOp::Exclusive);
            self.scan
                .record(rec, rank, rank, n_nodes, op, &scratch.scan);
        });
        rec.compute_to_compute();
        rec.scope("compact.scatter", |rec| {
            let groups = rec.groups_1d(n_nodes.max(n_refs) as u64, WORKGROUP);
            let b: [&dyn BufferArg; 5] = [src.nodes, src.refs, &scratch.rank, dst.nodes, dst.refs];
            rec.dispatch(&self.scatter, groups, &b, &[nodes32, refs32]);
            if let (Some((order, levels)), Some((out_order, out_levels))) =
                (src.schedule, dst.schedule)
            {
                let words = levels.len().min(out_levels.len());
                let groups = rec.groups_1d(live.max(words) as u64, WORKGROUP);
                let b: [&dyn BufferArg; 5] = [order, &scratch.rank, out_order, levels, out_levels];
                rec.dispatch(&self.rename, groups, &b, &[live as u32, words as u32]);
            }
        });
        rec.compute_to_indirect();
    }
}
