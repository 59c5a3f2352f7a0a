//! Segmented argmin: the best (cost, index) of every segment of a flat cost array — the
//! kd-tree builder's "best split of every node of a level" (Kolodzey 2014, §2.8).
//!
//! Segment s is `costs[offsets[s]..offsets[s + 1]]`; the segment count lives in a GPU buffer
//! (the previous level's compaction wrote it), with a host-side capacity `max_segments` for
//! sizing, so a whole build level records without reading anything back. Output: `out[s]` =
//! (best cost, global index of it), lowest cost then lowest index, -0.0 == +0.0 (the order of
//! [`super::reduce`]); [`CostIndex::NONE`] = (+inf, `u32::MAX`) for an empty segment.
//!
//! Two paths, as in Kolodzey (2014):
//!
//! - **workgroup per segment** (`segmented_segments.comp`): workgroup s loops over segment
//!   s. Ideal with many segments; with a few huge ones (the first kd-tree levels) a few
//!   workgroups do all the work while the rest of the device idles.
//! - **device-wide, tiled** (`segmented_tiles.comp`): fixed tiles of `cfg.tile()` elements
//!   over the flat array; one workgroup per (long segment, tile) pair reduces the part of
//!   the segment inside the tile into a (tile, segment) slot, and the per-segment kernel
//!   then combines a long segment's slots instead of reading its elements. Every workgroup
//!   gets at most a tile of work whatever the segment sizes.
//! - **packed** (`segmented_packed.comp`), for levels of many short segments (the deep
//!   kd-tree levels: tens of thousands of nodes of a few dozen events), where launching a
//!   workgroup per segment costs far more than reducing it: an invocation per segment, 64
//!   per workgroup. A segment of at most 32 elements its invocation reduces alone; every
//!   longer one the whole subgroup then takes in turn, and those of at least
//!   [`SegmentedArgmin::packed_cut`] take the tiles first. These are the size classes of
//!   CUB's segmented reduction and sort (a thread, a warp or a block per segment).
//!
//! **Hybrid, decided on the GPU, per segment.** A one-workgroup plan kernel
//! (`segmented_plan.comp`) reads the count, decides which segments are *long*, lists them
//! with the prefix sum of the tiles each touches, and writes the indirect workgroup counts
//! of both paths (the tiles get none when no segment is long). The host records plan →
//! `compute_to_indirect` → tiles → `compute_to_indirect` → segments (→ packed) without
//! knowing the count. The hybrid also packs a level once it has 64 × `threshold` segments
//! (enough workgroups for every thread or compute unit): the plan then gives the
//! per-segment kernel no workgroups and the packed one a workgroup per 64 segments.
//! `Hybrid { threshold }` is Kolodzey's node-count switch made per segment: a
//! segment is long when it holds more than 1/`threshold` of all the segments' elements (and
//! at least a tile). On a balanced level k (2^k equal segments) that is exactly "tiles while
//! 2^k < threshold"; on the skewed levels of real scenes it also splits the one node that
//! would otherwise keep a single workgroup busy while the rest of the level is done.
//! `threshold` is, in effect, how many workgroups the device runs at once.
//!
//! The three [`SegmentedMode`]s are the same kernels: workgroup-per-segment has no share
//! rule and never packs, device-wide makes every segment of at least a tile long (shorter
//! ones cannot be split anyway) and never packs. In every mode a segment longer than a
//! segment workgroup may loop over ([`SegmentedArgmin::loop_capacity`], llvmpipe's loop
//! budget) is long.
//!
//! **Threshold, measured** on lavapipe (Mesa 22.3, 2 cores shared with other jobs: load
//! average about 3.5; subgroup 8) with [`SegmentedArgmin::recommended`] (tiles 256 × 256,
//! one-subgroup segment workgroups); level k = 2^k equal segments; GPU ms, best of 3,
//! modes interleaved; `cargo test --release --test prims_bench -- --ignored
//! --nocapture threshold` (`hybrid_tT` is `Hybrid { threshold: T }`):
//!
//! | n = 2^22, level | segment | per segment | device-wide | t2 | t4 | t16 | t64 | t256 |
//! |---|---|---|---|---|---|---|---|---|
//! | 0 | 4M | 4.31 | 5.05 | 5.18 | 5.09 | 5.25 | 5.25 | 5.20 |
//! | 1 | 2M | 4.35 | 5.27 | 4.40 | 5.31 | 5.13 | 5.36 | 5.15 |
//! | 2 | 1M | 4.53 | 5.15 | 4.46 | 4.40 | 5.25 | 5.20 | 5.37 |
//! | 4 | 256K | 4.44 | 5.25 | 4.46 | 4.38 | 4.42 | 5.26 | 5.22 |
//! | 6 | 64K | 4.46 | 5.40 | 4.38 | 4.54 | 4.39 | 4.38 | 5.36 |
//! | 8 | 16K | 4.57 | 4.69 | 4.64 | 4.59 | 4.46 | 4.54 | 4.54 |
//! | 10 | 4K | 5.73 | 4.99 | 5.24 | 4.99 | 4.99 | 4.95 | 5.05 |
//! | 12 | 1K | 6.42 | 6.56 | 6.45 | 6.37 | 6.27 | 6.38 | 6.78 |
//! | 14 | 256 | 12.2 | 12.2 | 12.5 | 12.1 | 12.4 | 12.2 | 12.4 |
//! | 16 | 64 | 63.2 | 62.3 | 62.6 | 63.0 | 62.2 | 63.3 | 62.3 |
//!
//! At n = 2^24 levels 0–1 (16M, 8M) take the tiles in every mode (longer than a
//! one-subgroup workgroup's loop capacity): about 19.9 ms each. Level 2 (4M): per segment
//! 16.8, device-wide 20.2, t2 16.8, t16 20.2; level 4: 16.8 / 20.5 / 16.8 / t16 17.0 / t64
//! 20.3; from level 8 on all about 17.3 but device-wide 20.9.
//!
//! Reading: where the tiles are used they cost about a fifth more than one workgroup per
//! segment, as soon as there are at least as many segments as lavapipe has threads (2): a
//! tile workgroup of 256 invocations costs more per element than a one-subgroup one, and
//! with the segments alone keeping both threads busy, splitting them buys nothing. With
//! fewer segments than threads the tiles win when the machine is quiet (level 0, n = 2^22,
//! `pass_breakdown`: tiles 7.8 ms on one lavapipe thread, about 4 ms on two; one workgroup
//! 6.0 ms), and lose under load, as in the table. So the best threshold is the number of
//! workgroups the device runs at once: lavapipe's thread count, which
//! [`SegmentedMode::hybrid_for`] picks; a GPU's is in the hundreds
//! ([`DEFAULT_HYBRID_THRESHOLD`]). The segment workgroup matters far more at the deep
//! levels: with 256 invocations instead of one subgroup, the per-segment column reads 17.7
//! ms at level 10, 55 ms at 12 and 1,606 ms at 16 (each invocation llvmpipe launches
//! costs about as much as reading a few hundred elements).
//!
//! **Packing, measured** on Mesa 25.0.7's lavapipe (2 threads, subgroup 8, quiet machine),
//! the same table with 32-invocation segment workgroups (the kd-tree builder's), GPU ms,
//! n = 2^22 (`BENCH_SEG_WG=32 … threshold`; the hybrids pack from 64 × `threshold`
//! segments):
//!
//! | level | segment | per segment | device-wide | t2 | t4 | t16 | t64 | t256 |
//! |---|---|---|---|---|---|---|---|---|
//! | 4 | 256K | 1.95 | 2.54 | 2.07 | 2.06 | 2.01 | 2.57 | 2.69 |
//! | 8 | 16K | 3.39 | 2.24 | 4.04 | 2.32 | 2.22 | 2.67 | 2.84 |
//! | 10 | 4K | 2.55 | 2.77 | 2.59 | 2.57 | 2.37 | 2.66 | 2.61 |
//! | 12 | 1K | 4.63 | 4.55 | 2.45 | 2.50 | 2.45 | 2.48 | 4.65 |
//! | 14 | 256 | 13.4 | 13.4 | 3.02 | 3.12 | 2.93 | 3.00 | 2.94 |
//! | 16 | 64 | 86.0 | 87.1 | 5.64 | 5.23 | 5.64 | 5.65 | 6.14 |
//!
//! Packed levels cost what the elements cost (2.5–5.6 ms at every depth) where one
//! workgroup per segment grows with the segment count (15× at level 16). On the bunny's
//! kd-tree (up to 65 K nodes a level) the best-split phase fell from 375 ms to 31–38 ms,
//! on Mesa 22.3 from 940 to 91 ms; a packed invocation's own loop of up to 16, 32, 64 or
//! 128 elements measured alike (31–43 ms, within the run-to-run spread).
//!
//! Scratch: [`SegmentedArgmin::scratch_len`] words — the 16-word plan record, the list of
//! long segments, then two words per (tile, segment) slot.
//!
//! Barriers: `record` orders its own passes. The caller orders the writes of `costs`,
//! `offsets` and `count` (and earlier uses of `scratch` and `out`) before it, and puts a
//! `compute_to_*` barrier between it and the readers of `out`.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};

use super::reduce::{check_config, misuse, CostIndex};
use super::PrimConfig;
use crate::gpu::{kernels, Buffer, Context, GpuError, Kernel, Recorder, Result, Spec};

/// [`SegmentedMode::Hybrid`]'s default threshold, in segments: about the workgroups a GPU
/// runs at once (a few per compute unit × 40–128 units). Not measured (no GPU here); on
/// lavapipe the measured best is its thread count (module docs), which
/// [`SegmentedMode::hybrid_for`] picks. Too small is the costly direction on a GPU (a few
/// huge segments on single workgroups), too large costs lavapipe about a fifth at the
/// levels in between.
pub const DEFAULT_HYBRID_THRESHOLD: u32 = 256;

/// Loop iterations an invocation may run in total, and 16-byte blocks per iteration of the
/// loops over data. Workaround (Mesa 22.3 lavapipe, found 2026-11): llvmpipe silently stops
/// loops once an invocation has run 65,535 iterations across all its loops; keep in sync with
/// `glsl/common/reduce_lanes.glsl`.
const LOOP_BUDGET: u64 = 60_000;
const UNROLL: u64 = 4;

/// Segments the plan kernel may scan: 128 invocations, two passes over their share each.
const MAX_PLAN_SEGMENTS: u64 = 128 * (LOOP_BUDGET - 1000) / 2;

/// Plan record layout (keep in sync with `glsl/common/reduce_segments.glsl`).
const PLAN_SEGMENT_GROUPS: u64 = 0;
const PLAN_TILE_GROUPS: u64 = 3;
const PLAN_PACKED_GROUPS: u64 = 10;
const PLAN_WORDS: usize = 16;

/// Which path reduces which segments.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SegmentedMode {
    /// One workgroup per segment, looping over its elements (segments longer than
    /// [`SegmentedArgmin::loop_capacity`] still take the tiles).
    WorkgroupPerSegment,
    /// Every segment of at least a tile through the tiles, the shorter ones one workgroup
    /// each.
    DeviceWide,
    /// A segment holding more than 1/`threshold` of all the segments' elements (and at least
    /// a tile) through the tiles, the others one workgroup each; decided on the GPU. With
    /// equal segments: tiles while there are fewer than `threshold` segments.
    Hybrid {
        /// The fraction's denominator: a segment of more than 1/`threshold` of the elements
        /// takes the tiles.
        threshold: u32,
    },
}

impl Default for SegmentedMode {
    fn default() -> Self {
        Self::Hybrid {
            threshold: DEFAULT_HYBRID_THRESHOLD,
        }
    }
}

impl SegmentedMode {
    /// The hybrid with this device's threshold: on a CPU device (lavapipe) the threads that
    /// run its workgroups (`LP_NUM_THREADS`, else the CPUs available), the measured best
    /// (module docs); on a GPU [`DEFAULT_HYBRID_THRESHOLD`].
    pub fn hybrid_for(ctx: &Context) -> Self {
        let threshold = if ctx.info().device_type == "cpu" {
            std::env::var("LP_NUM_THREADS")
                .ok()
                .and_then(|v| v.parse::<u32>().ok())
                .filter(|&t| t > 0)
                .unwrap_or_else(|| {
                    std::thread::available_parallelism().map_or(1, |p| p.get() as u32)
                })
                .max(2)
        } else {
            DEFAULT_HYBRID_THRESHOLD
        };
        Self::Hybrid { threshold }
    }

    /// A short name for reports: `workgroup_per_segment`, `device_wide`, `hybrid_t{threshold}`.
    pub fn name(self) -> String {
        match self {
            Self::WorkgroupPerSegment => "workgroup_per_segment".into(),
            Self::DeviceWide => "device_wide".into(),
            Self::Hybrid { threshold } => format!("hybrid_t{threshold}"),
        }
    }
}

/// Push constants of `segmented_plan.comp` (keep in sync).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PlanPush {
    max_segments: u32,
    n_costs: u32,
    tile: u32,
    share: u32,
    capacity: u32,
    max_groups_x: u32,
    pack_min: u32,
    pack_width: u32,
    pack_cut: u32,
}

/// Push constants of `segmented_tiles.comp` and `segmented_segments.comp` (keep in sync).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PathPush {
    n_costs: u32,
    tile: u32,
    slot_base: u32,
}

/// Push constants of `segmented_packed.comp` (keep in sync).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PackedPush {
    n_costs: u32,
    tile: u32,
    slot_base: u32,
    short_len: u32,
}

/// The packed path's workgroup: segments per workgroup.
const PACK_WIDTH: u32 = 64;
/// The packed path's segments of at most this many elements are reduced by one invocation
/// each (measured: module docs).
const PACK_SHORT: u32 = 32;
/// The packed path's segments of at least this many elements take the tiles: a subgroup
/// reduces up to one such segment per lane in turn, so their sum stays in the loop budget.
const PACK_CUT: u32 = 1 << 17;

/// The segmented argmin, with its kernels compiled for one [`PrimConfig`].
pub struct SegmentedArgmin {
    cfg: PrimConfig,
    segment_workgroup_size: u32,
    plan: Arc<Kernel>,
    tiles: Arc<Kernel>,
    segments: Arc<Kernel>,
    /// One invocation per short segment (`None` with the shared-memory reduction, which
    /// uses no subgroup operations).
    packed: Option<Arc<Kernel>>,
}

/// How a workgroup combines its invocations' winners.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub enum WorkgroupReduction {
    /// Subgroup shuffles (xor butterfly), then one barrier and one subgroup over the
    /// subgroup winners: Kolodzey's Listing 6.7.
    #[default]
    Shuffle,
    /// A tree over shared memory, one barrier per halving step, no subgroup operations.
    SharedMemory,
}

impl SegmentedArgmin {
    /// The measured configuration (module docs): tiles of 256 × 256 elements, segments
    /// reduced by one-subgroup workgroups (on llvmpipe every invocation launched costs about
    /// as much as reading a few hundred elements, and most segments are short).
    pub fn recommended(ctx: &Context) -> Result<Self> {
        let sg = ctx.info().subgroup_size;
        let cfg = PrimConfig {
            workgroup_size: 256u32.max(sg),
            items_per_invocation: 256,
        };
        Self::with_segment_workgroup(ctx, cfg, sg.max(4))
    }

    /// Tiles of `cfg.tile()` elements; segments reduced by workgroups of
    /// `cfg.workgroup_size` invocations.
    pub fn new(ctx: &Context, cfg: PrimConfig) -> Result<Self> {
        Self::with_segment_workgroup(ctx, cfg, cfg.workgroup_size)
    }

    /// Tiles of `cfg.tile()` elements; segments reduced by workgroups of
    /// `segment_workgroup_size` invocations (a power of two, a multiple of the subgroup
    /// size).
    pub fn with_segment_workgroup(
        ctx: &Context,
        cfg: PrimConfig,
        segment_workgroup_size: u32,
    ) -> Result<Self> {
        Self::with_reduction(
            ctx,
            cfg,
            segment_workgroup_size,
            WorkgroupReduction::Shuffle,
        )
    }

    /// [`SegmentedArgmin::with_segment_workgroup`] with the workgroup step done by
    /// `reduction` (the shared-memory one is the ablation benchmark's baseline).
    pub fn with_reduction(
        ctx: &Context,
        cfg: PrimConfig,
        segment_workgroup_size: u32,
        reduction: WorkgroupReduction,
    ) -> Result<Self> {
        check_config(ctx, cfg, "prims.segmented_tiles")?;
        check_config(
            ctx,
            PrimConfig {
                workgroup_size: segment_workgroup_size,
                ..cfg
            },
            "prims.segmented_segments",
        )?;
        if u64::from(cfg.tile()) > loop_capacity(segment_workgroup_size) {
            return Err(GpuError::Kernel {
                kernel: "prims.segmented_segments",
                reason: format!(
                    "a tile of {} elements is longer than a workgroup of {segment_workgroup_size} may loop over ({})",
                    cfg.tile(),
                    loop_capacity(segment_workgroup_size)
                ),
            });
        }
        let tiles = Spec::new().workgroup(cfg.workgroup_size);
        let segments = Spec::new().workgroup(segment_workgroup_size);
        Ok(Self {
            cfg,
            segment_workgroup_size,
            plan: ctx.kernel(&kernels::PRIMS_SEGMENTED_PLAN, &Spec::new())?,
            tiles: ctx.kernel(
                match reduction {
                    WorkgroupReduction::Shuffle => &kernels::PRIMS_SEGMENTED_TILES_SHUFFLE,
                    WorkgroupReduction::SharedMemory => &kernels::PRIMS_SEGMENTED_TILES_SHARED,
                },
                &tiles,
            )?,
            segments: ctx.kernel(
                match reduction {
                    WorkgroupReduction::Shuffle => &kernels::PRIMS_SEGMENTED_SEGMENTS_SHUFFLE,
                    WorkgroupReduction::SharedMemory => &kernels::PRIMS_SEGMENTED_SEGMENTS_SHARED,
                },
                &segments,
            )?,
            packed: match reduction {
                WorkgroupReduction::Shuffle => Some(ctx.kernel(
                    &kernels::PRIMS_SEGMENTED_PACKED,
                    &Spec::new().workgroup(PACK_WIDTH.max(ctx.info().subgroup_size)),
                )?),
                WorkgroupReduction::SharedMemory => None,
            },
        })
    }

    /// The tiled path's configuration.
    pub fn config(&self) -> PrimConfig {
        self.cfg
    }

    /// Invocations of the workgroup that reduces one segment.
    pub fn segment_workgroup_size(&self) -> u32 {
        self.segment_workgroup_size
    }

    /// The longest segment one segment workgroup reduces by itself: what its invocations
    /// may loop over within llvmpipe's loop budget. Longer segments take the tiles in every
    /// mode (the results are the same; only the speed differs).
    pub fn loop_capacity(&self) -> u32 {
        loop_capacity(self.segment_workgroup_size).min(u64::from(u32::MAX)) as u32
    }

    /// On a level the packed path reduces (many segments), a segment of at least this many
    /// elements takes the tiles.
    pub fn packed_cut(&self) -> u32 {
        PACK_CUT.min(self.loop_capacity())
    }

    /// The most segments [`Self::record`] takes (`max_segments`).
    pub fn max_segments(&self) -> usize {
        MAX_PLAN_SEGMENTS as usize
    }

    /// The most costs [`Self::record`] takes: the per-segment combine must read a
    /// segment's tile winners within llvmpipe's loop budget.
    pub fn max_costs(&self) -> usize {
        let slots = LOOP_BUDGET * UNROLL * u64::from(self.segment_workgroup_size) - 2;
        (slots * u64::from(self.cfg.tile())).min(u64::from(u32::MAX)) as usize
    }

    /// Words (u32) of scratch for `n_costs` costs and up to `max_segments` segments: the
    /// plan record, the list of long segments, and the (tile, segment) slots.
    pub fn scratch_len(&self, n_costs: usize, max_segments: usize) -> usize {
        let slot_base = self.slot_base(n_costs, max_segments) as usize;
        let tiles = n_costs.div_ceil(self.cfg.tile() as usize) + 1;
        slot_base + 2 * (tiles + max_segments)
    }

    /// Scratch word of the first (tile, segment) slot: after the plan record and the list
    /// of long segments (at least a tile long each, so at most `n_costs / tile`).
    fn slot_base(&self, n_costs: usize, max_segments: usize) -> u32 {
        let max_long = (n_costs / self.cfg.tile() as usize + 1).min(max_segments);
        u32::try_from(PLAN_WORDS + 2 * max_long).expect("scratch fits u32 words")
    }

    /// Records `out[s] = ` the argmin of segment s for every s < min(`count[0]`,
    /// `max_segments`). `offsets` holds at least `max_segments + 1` non-decreasing entries,
    /// at most `costs.len()` (malformed offsets give unspecified results, never an
    /// out-of-bounds access); `out` at least `max_segments`; costs are NaN-free.
    #[allow(clippy::too_many_arguments, reason = "the buffers of one primitive")]
    pub fn record(
        &self,
        rec: &mut Recorder,
        mode: SegmentedMode,
        costs: &Buffer<f32>,
        offsets: &Buffer<u32>,
        count: &Buffer<u32>,
        max_segments: u32,
        scratch: &Buffer<u32>,
        out: &Buffer<CostIndex>,
    ) {
        let n_costs = u32::try_from(costs.len()).expect("costs fit u32");
        if costs.len() > self.max_costs() {
            misuse(&format!(
                "prims.segmented_argmin: {} costs, above the {} this configuration takes (SegmentedArgmin::max_costs)",
                costs.len(),
                self.max_costs()
            ));
        }
        if u64::from(max_segments) > MAX_PLAN_SEGMENTS {
            misuse(&format!(
                "prims.segmented_argmin: {max_segments} segments, above the {MAX_PLAN_SEGMENTS} the plan may scan"
            ));
        }
        let needed = self.scratch_len(costs.len(), max_segments as usize);
        if offsets.len() < max_segments as usize + 1
            || out.len() < max_segments as usize
            || count.is_empty()
            || scratch.len() < needed
        {
            misuse(&format!(
                "prims.segmented_argmin: max_segments = {max_segments} needs offsets of {} \
                 (got {}), out of {max_segments} (got {}), a count (got {}) and {needed} scratch words (got {})",
                max_segments + 1,
                offsets.len(),
                out.len(),
                count.len(),
                scratch.len()
            ));
        }
        let share = match mode {
            SegmentedMode::WorkgroupPerSegment => 0,
            SegmentedMode::DeviceWide => u32::MAX,
            SegmentedMode::Hybrid { threshold } => threshold.max(1),
        };
        let capacity = self.loop_capacity();
        // The shortest a long segment can be (`cut` in segmented_plan.comp).
        let min_cut = if share == 0 {
            capacity
        } else {
            self.cfg.tile()
        };
        let max_groups_x = rec.context().info().max_workgroup_count[0];
        let plan_push = PlanPush {
            max_segments,
            n_costs,
            tile: self.cfg.tile(),
            share,
            capacity,
            max_groups_x,
            pack_min: self.pack_min(mode, n_costs).unwrap_or(0),
            pack_width: self.packed.as_ref().map_or(0, |k| k.invocations()),
            pack_cut: self.packed_cut(),
        };
        let push = PathPush {
            n_costs,
            tile: self.cfg.tile(),
            slot_base: self.slot_base(costs.len(), max_segments as usize),
        };
        rec.scope("prims.segmented_argmin", |rec| {
            rec.scope("prims.segmented_plan", |rec| {
                rec.dispatch(
                    &self.plan,
                    [1, 1, 1],
                    &[offsets, count, scratch],
                    &plan_push,
                );
            });
            rec.compute_to_indirect();
            // No segment can be long if all the costs together cannot.
            if costs.len() >= min_cut as usize {
                rec.scope("prims.segmented_tiles", |rec| {
                    rec.dispatch_indirect(
                        &self.tiles,
                        scratch,
                        4 * PLAN_TILE_GROUPS,
                        &[costs, offsets, scratch],
                        &push,
                    );
                });
                // The next dispatch reads its workgroup counts from `scratch`, which the
                // tiles kernel wrote (other words, but the binding covers it all).
                rec.compute_to_indirect();
            }
            rec.scope("prims.segmented_segments", |rec| {
                rec.dispatch_indirect(
                    &self.segments,
                    scratch,
                    4 * PLAN_SEGMENT_GROUPS,
                    &[costs, offsets, scratch, out],
                    &push,
                );
            });
            if let Some(packed) = self.packed.as_ref().filter(|_| plan_push.pack_min > 0) {
                // One of the two per-segment paths has no workgroups (the plan chose), but
                // both write `out`.
                rec.compute_to_compute();
                let packed_push = PackedPush {
                    n_costs,
                    tile: push.tile,
                    slot_base: push.slot_base,
                    short_len: PACK_SHORT,
                };
                rec.scope("prims.segmented_packed", |rec| {
                    rec.dispatch_indirect(
                        packed,
                        scratch,
                        4 * PLAN_PACKED_GROUPS,
                        &[costs, offsets, scratch, out],
                        &packed_push,
                    );
                });
            }
        });
    }

    /// The segment count from which `mode` takes the packed path on a level (`None`: never):
    /// the hybrid packs a level once it fills `threshold` packed workgroups, enough for
    /// every thread or compute unit, where the available kernel and llvmpipe's loop budget
    /// allow (its subgroups loop over every long segment's slots).
    fn pack_min(&self, mode: SegmentedMode, n_costs: u32) -> Option<u32> {
        let SegmentedMode::Hybrid { threshold } = mode else {
            return None;
        };
        let packed = self.packed.as_ref()?;
        let slots = u64::from(n_costs) / u64::from(self.cfg.tile()) + 1;
        // Per lane: its own short segment, then up to one segment per subgroup lane (at
        // most 128) of under PACK_CUT elements, UNROLL per lane and iteration, and the slots.
        let iterations = u64::from(PACK_SHORT)
            + u64::from(PACK_CUT) / UNROLL
            + slots / UNROLL
            + 128 * (2 * UNROLL + 8);
        (iterations < LOOP_BUDGET - 1000)
            .then(|| threshold.max(1).saturating_mul(packed.invocations()))
    }

    /// Uploads `costs` and `offsets` (`offsets.len() - 1` segments), runs [`Self::record`]
    /// and downloads the winners.
    pub fn argmin(
        &self,
        ctx: &Context,
        mode: SegmentedMode,
        costs: &[f32],
        offsets: &[u32],
    ) -> Result<Vec<CostIndex>> {
        let segments = offsets.len().saturating_sub(1);
        let max_segments = u32::try_from(segments).expect("segment count fits u32");
        let costs_buf = Buffer::from_slice(ctx, "prims.segmented.costs", costs)?;
        let offsets_buf = if offsets.is_empty() {
            Buffer::from_slice(ctx, "prims.segmented.offsets", &[0u32])?
        } else {
            Buffer::from_slice(ctx, "prims.segmented.offsets", offsets)?
        };
        let count = Buffer::from_slice(ctx, "prims.segmented.count", &[max_segments])?;
        let scratch = Buffer::<u32>::new(
            ctx,
            "prims.segmented.scratch",
            self.scratch_len(costs.len(), segments),
        )?;
        let out = Buffer::<CostIndex>::new(ctx, "prims.segmented.out", segments)?;
        let mut rec = Recorder::new(ctx)?;
        self.record(
            &mut rec,
            mode,
            &costs_buf,
            &offsets_buf,
            &count,
            max_segments,
            &scratch,
            &out,
        );
        rec.compute_to_transfer();
        rec.submit_and_wait()?;
        out.download()
    }
}

/// Elements a segment workgroup of `workgroup_size` invocations may loop over: the loop
/// budget, `UNROLL` 16-byte blocks per iteration, less a margin for its other loops.
fn loop_capacity(workgroup_size: u32) -> u64 {
    (LOOP_BUDGET - 1000) * UNROLL * 4 * u64::from(workgroup_size)
}

/// The CPU twin of [`SegmentedArgmin::record`] (every mode): the argmin of each of the
/// first `count` segments, with the kernels' clamping of malformed offsets. The winner of a
/// segment is unique, so a plain loop gives the kernels' answer whatever their order.
pub fn segmented_argmin_cpu(costs: &[f32], offsets: &[u32], count: u32) -> Vec<CostIndex> {
    let n_costs = costs.len() as u32;
    (0..count as usize)
        .map(|s| {
            let begin = offsets[s].min(n_costs);
            let end = offsets[s + 1].clamp(begin, n_costs);
            let mut best = CostIndex::NONE;
            for e in begin..end {
                let candidate = CostIndex {
                    cost: costs[e as usize],
                    index: e,
                };
                if candidate.better_than(&best) {
                    best = candidate;
                }
            }
            best
        })
        .collect()
}

/// Offsets of `2^level` equal segments over `n` elements (the last ones absorb the
/// remainder): level `level` of a balanced kd-tree.
pub fn level_offsets(n: u32, level: u32) -> Vec<u32> {
    let segments = 1u64 << level;
    (0..=segments)
        .map(|s| (s * u64::from(n) / segments) as u32)
        .collect()
}
