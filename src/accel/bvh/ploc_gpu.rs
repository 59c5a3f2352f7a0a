//! PLOC built on the GPU (Meister & Bittner 2018), recorded into the caller's recorder with
//! no read-back: the LBVH's Morton sort ([`LbvhBuilder::record_sort`]), one cluster per
//! primitive (`accel.ploc_init`), then rounds of nearest neighbours (`accel.ploc_nearest`),
//! merge flags with workgroup sums (`accel.ploc_flags`), their scan and the next round's
//! indirect dispatch (`accel.ploc_sums`, one invocation), and the merge and compaction
//! (`accel.ploc_merge`), which writes the nodes in the traversal's layout with their final
//! boxes. The cluster count lives on the device: every round's kernels are dispatched
//! indirectly from it, so the rounds after the last merge are empty dispatches and the host
//! never waits between rounds. CPU twin: [`super::ploc`].

use std::sync::Arc;

use super::lbvh_gpu::{LbvhBuilder, LbvhScratch};
use super::ploc::{PlocParams, PAIRING_ROUNDS};
use super::BvhNode;
use crate::accel::primitives::SceneInfo;
use crate::gpu::{kernels, Buffer, BufferArg, Context, GpuError, Kernel, Recorder, Result, Spec};

/// Words of the round state (`ST_*` in `glsl/accel/bvh/ploc_common.glsl`).
const STATE_WORDS: usize = 16;
/// Word offset of the even rounds' indirect dispatch (`ST_ARGS`).
const ST_ARGS: u64 = 8;

/// PLOC's kernels, compiled once.
pub struct PlocBuilder {
    sort: LbvhBuilder,
    init: Arc<Kernel>,
    nearest: Arc<Kernel>,
    pairing: Arc<Kernel>,
    flags: Arc<Kernel>,
    sums: Arc<Kernel>,
    sums_pairing: Arc<Kernel>,
    merge: Arc<Kernel>,
    params: PlocParams,
    workgroup: u32,
}

/// Device scratch of one build.
pub struct PlocScratch {
    sort: LbvhScratch,
    clusters: [Buffer<[u32; 8]>; 2],
    nearest: Buffer<u32>,
    flags: Buffer<[u32; 2]>,
    group_sums: Buffer<[u32; 2]>,
    /// The rounds' state; after the build: rounds that merged, and pairing rounds.
    pub state: Buffer<u32>,
}

impl PlocBuilder {
    /// Compiles the kernels (the LBVH's Morton sort included) for `params`, in workgroups
    /// of whole subgroups.
    pub fn new(ctx: &Context, params: PlocParams) -> Result<Self> {
        let radius = params.radius;
        // Workgroups of whole subgroups (ploc_merge's ranks are subgroup-major).
        let sg = ctx.info().subgroup_size.max(1);
        let workgroup = (64 / sg).max(1) * sg;
        let spec = Spec::new().workgroup(workgroup);
        let k = |blob, s: &Spec| ctx.kernel(blob, s);
        Ok(Self {
            sort: LbvhBuilder::new(ctx, params.bits)?,
            init: k(&kernels::ACCEL_BVH_PLOC_INIT, &spec)?,
            nearest: k(
                &kernels::ACCEL_BVH_PLOC_NEAREST,
                &spec.clone().u32(1, radius).u32(2, 0),
            )?,
            pairing: k(
                &kernels::ACCEL_BVH_PLOC_NEAREST,
                &spec.clone().u32(1, radius).u32(2, 1),
            )?,
            flags: k(&kernels::ACCEL_BVH_PLOC_FLAGS, &spec)?,
            sums: k(&kernels::ACCEL_BVH_PLOC_SUMS, &Spec::new().u32(1, 0))?,
            sums_pairing: k(&kernels::ACCEL_BVH_PLOC_SUMS, &Spec::new().u32(1, 1))?,
            merge: k(&kernels::ACCEL_BVH_PLOC_MERGE, &spec)?,
            params,
            workgroup,
        })
    }

    /// The parameters the kernels were compiled for.
    pub fn params(&self) -> PlocParams {
        self.params
    }

    /// Bytes of [`PlocBuilder::scratch`] for `n` primitives.
    pub fn scratch_bytes(&self, n: usize) -> u64 {
        let n1 = n.max(1) as u64;
        let groups = n.div_ceil(self.workgroup as usize).max(1) as u64;
        self.sort.scratch_bytes(n)
            + 2 * 32 * n1
            + 4 * n1
            + 8 * n1
            + 8 * groups
            + 4 * STATE_WORDS as u64
    }

    /// Allocates the scratch of builds of up to `n` primitives.
    pub fn scratch(&self, ctx: &Context, n: usize) -> Result<PlocScratch> {
        let groups = n.div_ceil(self.workgroup as usize).max(1);
        Ok(PlocScratch {
            sort: self.sort.scratch(ctx, n)?,
            clusters: [
                Buffer::new(ctx, "accel.ploc.clusters0", n)?,
                Buffer::new(ctx, "accel.ploc.clusters1", n)?,
            ],
            nearest: Buffer::new(ctx, "accel.ploc.nearest", n)?,
            flags: Buffer::new(ctx, "accel.ploc.flags", n)?,
            group_sums: Buffer::new(ctx, "accel.ploc.group_sums", groups)?,
            state: Buffer::new(ctx, "accel.ploc.state", STATE_WORDS)?,
        })
    }

    /// Records the tree of `n <= 1` primitives (the single-leaf root with its box, the
    /// root box into `info`; nothing for 0): PLOC has nothing to merge. `meet`: a word of
    /// scratch.
    #[allow(
        clippy::too_many_arguments,
        reason = "the tree's buffers and the knobs"
    )]
    pub fn record_small(
        &self,
        rec: &mut Recorder,
        boxes: &Buffer<f32>,
        n: usize,
        s: &PlocScratch,
        nodes: &Buffer<BvhNode>,
        refs: &Buffer<u32>,
        meet: &Buffer<u32>,
        info: &dyn BufferArg,
    ) -> Result<()> {
        if n > 1 {
            return Err(GpuError::Usage {
                call: "PlocBuilder::record_small",
                reason: format!("{n} primitives: record_build takes two or more"),
            });
        }
        self.sort
            .record_build(rec, boxes, n, &s.sort, nodes, refs, meet, info, None)
    }

    /// Records the PLOC tree over the `n >= 2` primitive boxes `boxes`: the sorted ids into
    /// `refs[..n]`, parent links into `refs[n..]`, every node with its boxes, the root box
    /// into `info`. Ends with a compute → compute barrier.
    #[allow(clippy::too_many_arguments, reason = "the structure's buffers")]
    pub fn record_build(
        &self,
        rec: &mut Recorder,
        boxes: &Buffer<f32>,
        n: usize,
        s: &PlocScratch,
        nodes: &Buffer<BvhNode>,
        refs: &Buffer<u32>,
        info: &Buffer<SceneInfo>,
    ) -> Result<()> {
        if n < 2 {
            return Err(GpuError::Usage {
                call: "PlocBuilder::record_build",
                reason: format!(
                    "{n} primitives: PLOC records trees of two or more (record_small takes fewer)"
                ),
            });
        }
        self.sort.record_sort(rec, boxes, n, &s.sort, refs)?;
        let wg = self.workgroup;
        rec.scope("ploc.init", |rec| {
            let groups = rec.groups_1d(n as u64, wg);
            let b: [&dyn BufferArg; 4] = [boxes, refs, &s.clusters[0], &s.state];
            rec.dispatch(&self.init, groups, &b, &[n as u32, wg]);
        });
        rec.compute_to_indirect();
        let searching = self.params.rounds(n);
        let rounds = searching + PAIRING_ROUNDS;
        rec.scope("ploc.rounds", |rec| {
            for round in 0..rounds {
                let parity = round % 2;
                let pairing = round >= searching;
                let (src, dst) = (
                    &s.clusters[parity as usize],
                    &s.clusters[1 - parity as usize],
                );
                let args = 4 * (ST_ARGS + 3 * u64::from(parity));
                let nearest = if pairing {
                    &self.pairing
                } else {
                    &self.nearest
                };
                let b: [&dyn BufferArg; 3] = [src, &s.nearest, &s.state];
                rec.dispatch_indirect(nearest, &s.state, args, &b, &parity);
                rec.compute_to_compute();
                let b: [&dyn BufferArg; 4] = [&s.nearest, &s.flags, &s.group_sums, &s.state];
                rec.dispatch_indirect(&self.flags, &s.state, args, &b, &parity);
                rec.compute_to_compute();
                let sums = if pairing {
                    &self.sums_pairing
                } else {
                    &self.sums
                };
                let b: [&dyn BufferArg; 2] = [&s.group_sums, &s.state];
                rec.dispatch(sums, [1, 1, 1], &b, &[parity, wg]);
                // The merge's dispatch reads the state buffer that this kernel wrote.
                rec.compute_to_indirect();
                let b: [&dyn BufferArg; 9] = [
                    src,
                    dst,
                    &s.nearest,
                    &s.flags,
                    &s.group_sums,
                    nodes,
                    refs,
                    &s.state,
                    info,
                ];
                rec.dispatch_indirect(&self.merge, &s.state, args, &b, &[parity, n as u32]);
                rec.compute_to_indirect();
            }
        });
        Ok(())
    }
}
