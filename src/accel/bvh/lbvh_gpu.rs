//! The LBVH built on the GPU (Karras 2012), recorded into the caller's recorder with no
//! read-back: centroid bounds (`accel.lbvh_bounds`), Morton codes (`accel.lbvh_morton`), a
//! stable key-value radix sort of the codes (`prims`; 63-bit codes sort the high words, then
//! every run of equal high words by its low words, `accel.lbvh_ties`, with the whole sort by
//! both words recorded behind a GPU-side gate for runs too long for that), the codes
//! gathered into sorted (high, low) pairs, then the whole tree in one bottom-up climb after
//! Apetrei (2014) (`accel.lbvh_climb`): topology, boxes and, with the SAH collapse, its
//! decisions, every node in the slot Karras's topology pass gives it. Its references end in
//! depth-first order, so the collapse leaves them in place
//! ([`super::collapse::RefLayout::InPlace`]). CPU twin: [`super::lbvh`] (Karras's
//! construction, then [`super::refit()`]).

use std::sync::Arc;

use super::collapse_gpu::MAX_COLLAPSE_LEAF;
use super::lbvh::MortonBits;
use super::sah::BvhParams;
use super::{BvhNode, NO_NODE};
use crate::gpu::{kernels, Buffer, BufferArg, Context, GpuError, Kernel, Recorder, Result, Spec};
use crate::prims::radix_sort::{RadixScratch, RadixSort, SortGate};
use crate::prims::PrimConfig;

const WORKGROUP: u32 = 64;

/// Longest run of equal high words that `accel.lbvh_ties` sorts in place; a longer one runs
/// the whole two-word sort (the cluster of a small detailed object in a large scene).
const MAX_TIE_RUN: u32 = 32;

/// The gate's words (indices): the indirect grids of the fallback's gathers, of its sorts'
/// tile kernels and of their copy, three each, then the length of their count tables' scans.
const GATE_GATHER: usize = 0;
const GATE_TILES: usize = 3;
const GATE_COPY: usize = 6;
const GATE_TABLE: usize = 9;
const GATE_WORDS: usize = 10;

/// The LBVH's kernels, compiled once.
pub struct LbvhBuilder {
    bounds: Arc<Kernel>,
    morton: Arc<Kernel>,
    gather1: Arc<Kernel>,
    gather2: Arc<Kernel>,
    ties: Arc<Kernel>,
    /// The bottom-up build (`accel.lbvh_climb`): `boxes`, and `costs` deciding the collapse.
    climb: [Arc<Kernel>; 2],
    sort: RadixSort,
    bits: MortonBits,
}

/// Device scratch of one build.
pub struct LbvhScratch {
    max_n: usize,
    /// Keys of the centroid box's minima, then inverted keys of its maxima.
    bounds: Buffer<u32>,
    code_hi: Buffer<u32>,
    code_lo: Buffer<u32>,
    sort_keys: Buffer<u32>,
    /// The codes in sorted order, (high, low) words.
    sorted: Buffer<[u32; 2]>,
    /// Indirect arguments of the whole two-word sort: zeros unless a run of equal high words
    /// is too long for `accel.lbvh_ties`.
    gate: Buffer<u32>,
    sort: RadixScratch,
}

impl LbvhBuilder {
    /// Compiles the kernels and the radix sort for Morton codes of `bits`.
    pub fn new(ctx: &Context, bits: MortonBits) -> Result<Self> {
        let spec = Spec::new().workgroup(WORKGROUP);
        let climb = Spec::new().workgroup(ctx.info().subgroup_size.max(1));
        let pairs = |pairs64, words| super::pairs_variant(ctx, pairs64, words);
        Ok(Self {
            bounds: ctx.kernel(&kernels::ACCEL_BVH_LBVH_BOUNDS, &spec)?,
            morton: ctx.kernel(
                &kernels::ACCEL_BVH_LBVH_MORTON,
                &spec.clone().u32(1, bits.per_axis()),
            )?,
            gather1: ctx.kernel(&kernels::ACCEL_BVH_LBVH_GATHER_ONE, &spec)?,
            ties: ctx.kernel(
                &kernels::ACCEL_BVH_LBVH_TIES,
                &spec.clone().u32(1, MAX_TIE_RUN),
            )?,
            gather2: ctx.kernel(
                pairs(
                    &kernels::ACCEL_BVH_LBVH_GATHER_CODES64,
                    &kernels::ACCEL_BVH_LBVH_GATHER_CODES,
                ),
                &spec,
            )?,
            // Workgroups of one subgroup, as the climbing refit's (accel/bvh/refit.comp).
            climb: [
                ctx.kernel(
                    pairs(
                        &kernels::ACCEL_BVH_LBVH_CLIMB_BOXES64,
                        &kernels::ACCEL_BVH_LBVH_CLIMB_BOXES,
                    ),
                    &climb,
                )?,
                ctx.kernel(
                    pairs(
                        &kernels::ACCEL_BVH_LBVH_CLIMB_COSTS64,
                        &kernels::ACCEL_BVH_LBVH_CLIMB_COSTS,
                    ),
                    &climb,
                )?,
            ],
            sort: RadixSort::new(ctx, PrimConfig::default_for(ctx), 8)?,
            bits,
        })
    }

    /// The Morton code width the builder sorts by.
    pub fn bits(&self) -> MortonBits {
        self.bits
    }

    /// Bytes of [`LbvhBuilder::scratch`] for `n` primitives.
    pub fn scratch_bytes(&self, n: usize) -> u64 {
        4 * (6 + GATE_WORDS + 5 * n.max(1)) as u64 + self.sort.scratch_bytes(n.max(1))
    }

    /// Allocates the scratch of builds of up to `n` primitives.
    pub fn scratch(&self, ctx: &Context, n: usize) -> Result<LbvhScratch> {
        Ok(LbvhScratch {
            max_n: n,
            bounds: Buffer::new(ctx, "accel.lbvh.bounds", 6)?,
            code_hi: Buffer::new(ctx, "accel.lbvh.code_hi", n)?,
            code_lo: Buffer::new(ctx, "accel.lbvh.code_lo", n)?,
            sort_keys: Buffer::new(ctx, "accel.lbvh.sort_keys", n)?,
            sorted: Buffer::new(ctx, "accel.lbvh.sorted", n)?,
            gate: Buffer::new(ctx, "accel.lbvh.gate", GATE_WORDS)?,
            sort: self.sort.scratch(ctx, n.max(1))?,
        })
    }

    /// Records the whole LBVH over the `n` primitive boxes `boxes` (six floats each) in one
    /// bottom-up climb after the sort (Apetrei 2014, `accel.lbvh_climb`): the sorted ids
    /// into `refs[..n]`, parent links into `refs[n..]`, every node with its boxes, the root
    /// box into `info`; with `decide`, every node's SAH collapse decision into its costs
    /// buffer too (the work of the collapse's cost pass). Karras's (2012) tree, bit for bit,
    /// without his topology pass's binary searches. `meet` holds a word per node (`n - 1`, at
    /// least one), filled here. Ends with a compute → compute barrier.
    #[allow(
        clippy::too_many_arguments,
        reason = "the tree's buffers and the knobs"
    )]
    pub fn record_build(
        &self,
        rec: &mut Recorder,
        boxes: &Buffer<f32>,
        n: usize,
        scratch: &LbvhScratch,
        nodes: &Buffer<BvhNode>,
        refs: &Buffer<u32>,
        meet: &Buffer<u32>,
        info: &dyn BufferArg,
        decide: Option<(&Buffer<u32>, &BvhParams)>,
    ) -> Result<()> {
        if n == 0 {
            return Ok(());
        }
        let splits = n.saturating_sub(1).max(1);
        if meet.len() < splits {
            return Err(GpuError::Usage {
                call: "LbvhBuilder::record_build",
                reason: format!("{} meeting words for {n} primitives", meet.len()),
            });
        }
        self.record_sort(rec, boxes, n, scratch, refs)?;
        let s = scratch;
        let n32 = n as u32;
        rec.scope("lbvh.climb", |rec| {
            rec.fill_first(meet, splits, NO_NODE);
            let groups = rec.groups_1d(n as u64, WORKGROUP);
            let b: [&dyn BufferArg; 4] = [refs, &s.code_hi, &s.code_lo, &s.sorted];
            rec.dispatch(&self.gather2, groups, &b, &n32);
            rec.compute_to_compute();
            rec.transfer_to_compute();
            let kernel = &self.climb[usize::from(decide.is_some())];
            let groups = rec.groups_1d(n as u64, kernel.invocations());
            let b: [&dyn BufferArg; 6] = [nodes, refs, boxes, &s.sorted, meet, info];
            match decide {
                Some((costs, p)) => {
                    let push = [
                        n32,
                        p.max_leaf_prims.min(MAX_COLLAPSE_LEAF),
                        p.traversal_cost.to_bits(),
                        p.intersection_cost.to_bits(),
                    ];
                    let b = [b[0], b[1], b[2], b[3], b[4], b[5], costs];
                    rec.dispatch(kernel, groups, &b, &push);
                }
                None => rec.dispatch(kernel, groups, &b, &n32),
            }
        });
        rec.compute_to_compute();
        Ok(())
    }

    /// Records the primitive ids sorted by the Morton codes of their centroids into
    /// `refs[..n]` (stable: equal codes keep the primitive order). Ends with a compute →
    /// compute barrier.
    pub fn record_sort(
        &self,
        rec: &mut Recorder,
        boxes: &Buffer<f32>,
        n: usize,
        scratch: &LbvhScratch,
        refs: &Buffer<u32>,
    ) -> Result<()> {
        if n > scratch.max_n {
            return Err(GpuError::Usage {
                call: "LbvhBuilder::record_sort",
                reason: format!("LBVH of {n} primitives, scratch for {}", scratch.max_n),
            });
        }
        if n == 0 {
            return Ok(());
        }
        let s = scratch;
        let groups = rec.groups_1d(n as u64, WORKGROUP);
        let n32 = n as u32;
        rec.scope("lbvh.bounds", |rec| {
            rec.fill(&s.bounds, u32::MAX);
            if self.bits == MortonBits::Bits63 {
                rec.fill(&s.gate, 0); // shut until accel.lbvh_ties finds a long run
            }
            rec.transfer_to_compute();
            rec.dispatch(&self.bounds, groups, &[boxes, &s.bounds], &n32);
        });
        rec.compute_to_compute();
        rec.scope("lbvh.morton", |rec| {
            let b: [&dyn BufferArg; 6] =
                [boxes, &s.bounds, &s.code_hi, &s.code_lo, &s.sort_keys, refs];
            rec.dispatch(&self.morton, groups, &b, &n32);
        });
        rec.compute_to_compute();
        rec.scope("lbvh.sort", |rec| match self.bits {
            MortonBits::Bits30 => {
                self.sort.record(rec, &s.sort_keys, refs, n, 30, &s.sort);
            }
            MortonBits::Bits63 => self.record_sort63(rec, n, s, refs),
        });
        rec.compute_to_compute();
        Ok(())
    }

    /// The sort of 63-bit codes: the high words (the morton pass wrote them as the keys),
    /// then the runs of equal high words by their low words (`accel.lbvh_ties`); where a run
    /// is too long for that kernel, it opens the gate of the whole stable sort, low words then
    /// high words, from the order it left (equal codes still in primitive order). The
    /// result is a stable sort by the whole codes either way.
    fn record_sort63(&self, rec: &mut Recorder, n: usize, s: &LbvhScratch, refs: &Buffer<u32>) {
        let n32 = n as u32;
        let groups = rec.groups_1d(n as u64, WORKGROUP);
        self.sort.record(rec, &s.sort_keys, refs, n, 31, &s.sort);
        rec.compute_to_compute();
        // What the tie pass writes into the gate when it opens it (after `n`).
        let [tiles, copy] = self.sort.grids(rec, n);
        let mut push = [0u32; 1 + GATE_WORDS];
        push[0] = n32;
        let open = &mut push[1..];
        for (at, grid) in [
            (GATE_GATHER, groups),
            (GATE_TILES, tiles),
            (GATE_COPY, copy),
        ] {
            open[at..at + 3].copy_from_slice(&grid);
        }
        open[GATE_TABLE] = self.sort.table_len(n) as u32;
        rec.scope("lbvh.ties", |rec| {
            let b: [&dyn BufferArg; 4] = [refs, &s.sort_keys, &s.code_lo, &s.gate];
            rec.dispatch(&self.ties, groups, &b, &push);
        });
        rec.compute_to_indirect();
        let gate = SortGate {
            args: &s.gate,
            tiles: 4 * GATE_TILES as u64,
            copy: 4 * GATE_COPY as u64,
            table: GATE_TABLE as u32,
        };
        rec.scope("lbvh.whole_codes", |rec| {
            for (words, bits) in [(&s.code_lo, 32), (&s.code_hi, 31)] {
                let b: [&dyn BufferArg; 3] = [refs, words, &s.sort_keys];
                let at = 4 * GATE_GATHER as u64;
                rec.dispatch_indirect(&self.gather1, &s.gate, at, &b, &n32);
                rec.compute_to_compute();
                self.sort
                    .record_gated(rec, &s.sort_keys, refs, n, bits, &s.sort, &gate);
                rec.compute_to_compute();
            }
        });
    }
}
