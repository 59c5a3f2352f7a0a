//! Segmented argmin: the best (cost, index) of every segment of a flat cost array — the
//! kd-tree builder's "best split of every node of a level" (seed 001 §2.8).
//!
//! Segment s is `costs[offsets[s]..offsets[s + 1]]`; the segment count lives in a GPU buffer
//! (the previous level's compaction wrote it), with a host-side capacity `max_segments` for
//! sizing, so a whole build level records without reading anything back. Output: `out[s]` =
//! (best cost, global index of it), lowest cost then lowest index, -0.0 == +0.0 (the order of
//! [`super::reduce`]); [`CostIndex::NONE`] = (+inf, `u32::MAX`) for an empty segment.
//!
//! Two paths, as in the seed:
//!
//! - **workgroup per segment** (`segmented_segments.comp`): workgroup s loops over segment
//!   s. Ideal with many segments; with a few huge ones (the first kd-tree levels) a few
//!   workgroups do all the work while the rest of the device idles.
//! - **device-wide, tiled** (`segmented_tiles.comp`): fixed tiles over the flat array, each
//!   reducing the parts of the segments it covers into a (tile, segment) slot, then a combine
//!   per segment (done by the per-segment kernel, which reads those slots instead of the
//!   elements). Every workgroup gets the same work whatever the segment sizes.
//!
//! **Hybrid, decided on the GPU.** A one-invocation plan kernel (`segmented_plan.comp`)
//! reads the count and the segments' span and writes the indirect workgroup counts of both
//! paths; the host records plan → `compute_to_indirect` → tiles (indirect) →
//! `compute_to_indirect` → segments (indirect) without knowing the count. The split is by
//! segment **length**, not by level: a segment of at least `threshold` elements goes through
//! the tiles, the others get their own workgroup. That subsumes the seed's switch on the
//! node count (level k of a balanced tree has 2^k segments of n / 2^k elements, so the tiles
//! serve exactly the first levels) and also handles the skewed levels of real scenes, where
//! one huge node would otherwise keep a single workgroup busy. The plan stays O(1): it gives
//! the tiles 0 workgroups when the span of all segments is below the threshold (then no
//! segment can reach it); otherwise every tile runs, finds its first and last segment by
//! binary search and, with `threshold >= tile`, reduces at most those two (a segment
//! strictly inside a tile is shorter than the tile).
//!
//! The three [`SegmentedMode`]s are the same kernels with different thresholds:
//! workgroup-per-segment is `u32::MAX` (no tiles), device-wide is 1 (every non-empty
//! segment through the tiles; a tile covering many tiny segments then does one workgroup
//! reduction per segment, which is why it loses when there are many).
//!
//! **Threshold, measured** (lavapipe, 2 cores, subgroup 8, default config 256 × 16 = 4096
//! elements per tile; n = 2^22 costs, level k = 2^k equal segments; GPU ms, best of 3;
//! `cargo test --release --test prims_segmented -- --ignored --nocapture threshold`):
//!
//! THRESHOLD_TABLE
//!
//! Scratch: [`SegmentedArgmin::scratch_len`] words — the 16-word plan, then two words per
//! (tile, segment) slot.
//!
//! Barriers: `record` orders its own passes. The caller orders the writes of `costs`,
//! `offsets` and `count` (and earlier uses of `scratch` and `out`) before it, and puts a
//! `compute_to_*` barrier between it and the readers of `out`.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};

use super::reduce::{check_config, misuse, CostIndex};
use super::{PrimConfig, PrimTiming};
use crate::gpu::{kernels, Buffer, Context, Kernel, Recorder, Result, Spec};

/// The measured default of [`SegmentedMode::Hybrid`]'s threshold, in elements (see the
/// module docs).
pub const DEFAULT_HYBRID_THRESHOLD: u32 = 1 << 16;

/// Plan record layout (keep in sync with `glsl/common/reduce_segments.glsl`).
const PLAN_SEGMENT_GROUPS: u64 = 0;
const PLAN_TILE_GROUPS: u64 = 3;
const PLAN_WORDS: usize = 16;

/// Which path reduces which segments.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SegmentedMode {
    /// One workgroup per segment, looping over its elements.
    WorkgroupPerSegment,
    /// Fixed tiles over the flat array for every segment, then a combine per segment.
    DeviceWide,
    /// Segments of at least `threshold` elements (at least 1) through the tiles, the others
    /// one workgroup each; decided per segment on the GPU.
    Hybrid { threshold: u32 },
}

impl Default for SegmentedMode {
    fn default() -> Self {
        Self::Hybrid {
            threshold: DEFAULT_HYBRID_THRESHOLD,
        }
    }
}

impl SegmentedMode {
    /// The length from which a segment goes through the tiles (`u32::MAX`: never).
    pub fn threshold(self) -> u32 {
        match self {
            Self::WorkgroupPerSegment => u32::MAX,
            Self::DeviceWide => 1,
            Self::Hybrid { threshold } => threshold.max(1),
        }
    }

    /// The name `bench` reports: `hybrid` at the default threshold, `hybrid_t{threshold}`
    /// at another.
    pub fn name(self) -> String {
        match self {
            Self::WorkgroupPerSegment => "workgroup_per_segment".into(),
            Self::DeviceWide => "device_wide".into(),
            Self::Hybrid { threshold } if threshold == DEFAULT_HYBRID_THRESHOLD => "hybrid".into(),
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
    threshold: u32,
    max_groups_x: u32,
}

/// Push constants of `segmented_tiles.comp` and `segmented_segments.comp` (keep in sync).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PathPush {
    n_costs: u32,
    threshold: u32,
    tile: u32,
}

/// The segmented argmin, with its kernels compiled for one [`PrimConfig`].
pub struct SegmentedArgmin {
    cfg: PrimConfig,
    segment_workgroup_size: u32,
    plan: Arc<Kernel>,
    tiles: Arc<Kernel>,
    segments: Arc<Kernel>,
}

impl SegmentedArgmin {
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
        check_config(ctx, cfg, "prims.segmented_tiles")?;
        check_config(
            ctx,
            PrimConfig {
                workgroup_size: segment_workgroup_size,
                ..cfg
            },
            "prims.segmented_segments",
        )?;
        let tiles = Spec::new().workgroup(cfg.workgroup_size);
        let segments = Spec::new().workgroup(segment_workgroup_size);
        Ok(Self {
            cfg,
            segment_workgroup_size,
            plan: ctx.kernel(&kernels::PRIMS_SEGMENTED_PLAN, &Spec::new())?,
            tiles: ctx.kernel(&kernels::PRIMS_SEGMENTED_TILES, &tiles)?,
            segments: ctx.kernel(&kernels::PRIMS_SEGMENTED_SEGMENTS, &segments)?,
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

    /// Words (u32) of scratch for `n_costs` costs and up to `max_segments` segments.
    pub fn scratch_len(&self, n_costs: usize, max_segments: usize) -> usize {
        let tiles = n_costs.div_ceil(self.cfg.tile() as usize) + 1;
        PLAN_WORDS + 2 * (tiles + max_segments)
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
        let threshold = mode.threshold();
        let max_groups_x = rec.context().info().max_workgroup_count[0];
        let plan_push = PlanPush {
            max_segments,
            n_costs,
            tile: self.cfg.tile(),
            threshold,
            max_groups_x,
        };
        let push = PathPush {
            n_costs,
            threshold,
            tile: self.cfg.tile(),
        };
        rec.scope("prims.segmented_argmin", |rec| {
            rec.scope("prims.segmented_plan", |rec| {
                rec.dispatch(&self.plan, [1, 1, 1], &[offsets, count, scratch], &plan_push);
            });
            rec.compute_to_indirect();
            if mode != SegmentedMode::WorkgroupPerSegment {
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
        });
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

/// Times the three modes at `n` costs on kd-tree-like levels (level k: 2^k equal segments)
/// for k in `levels`, best of `reps` after one untimed warm-up. Names are
/// `segmented_argmin.{mode}.level{k}`; `min_bytes` = costs and offsets read, winners
/// written.
pub fn bench_levels(
    ctx: &Context,
    seg: &SegmentedArgmin,
    n: usize,
    reps: u32,
    levels: &[u32],
    modes: &[SegmentedMode],
) -> Result<Vec<PrimTiming>> {
    let n32 = u32::try_from(n).expect("bench size fits u32");
    let max_level = levels.iter().copied().max().unwrap_or(0);
    let max_segments = 1u32 << max_level;
    let costs: Vec<f32> = (0..n32)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 8) as f32)
        .collect();
    let costs = Buffer::from_slice(ctx, "bench.segmented.costs", &costs)?;
    let scratch = Buffer::<u32>::new(
        ctx,
        "bench.segmented.scratch",
        seg.scratch_len(n, max_segments as usize),
    )?;
    let out = Buffer::<CostIndex>::new(ctx, "bench.segmented.out", max_segments as usize)?;
    let mut inputs = Vec::new();
    for &level in levels {
        let offsets = level_offsets(n32, level);
        let count = offsets.len() as u32 - 1;
        inputs.push((
            level,
            count,
            Buffer::from_slice(ctx, "bench.segmented.offsets", &offsets)?,
            Buffer::from_slice(ctx, "bench.segmented.count", &[count])?,
        ));
    }
    let mut rec = Recorder::new(ctx)?;
    let name = |mode: SegmentedMode, level: u32| {
        format!("segmented_argmin.{}.level{level}", mode.name())
    };
    for rep in 0..=reps {
        for (level, count, offsets, count_buf) in &inputs {
            for &mode in modes {
                let label = if rep == 0 {
                    format!("warmup.{}", name(mode, *level))
                } else {
                    name(mode, *level)
                };
                rec.scope(&label, |rec| {
                    seg.record(rec, mode, &costs, offsets, count_buf, *count, &scratch, &out)
                });
                rec.compute_to_compute();
            }
        }
    }
    let profile = rec.submit_and_wait()?;
    let mut timings = Vec::new();
    for (level, count, _, _) in &inputs {
        for &mode in modes {
            let label = name(mode, *level);
            timings.push(PrimTiming {
                gpu_ms: profile
                    .passes
                    .iter()
                    .filter(|p| p.name == label)
                    .filter_map(|p| p.ms)
                    .fold(f64::INFINITY, f64::min),
                prim: label,
                n: n as u64,
                min_bytes: 4 * n as u64 + 4 * (u64::from(*count) + 1) + 8 * u64::from(*count),
            });
        }
    }
    Ok(timings)
}

/// Times the three modes (hybrid at its default threshold) at `n` costs on kd-tree levels
/// 0, 4, 8 and 12 (see [`bench_levels`]).
pub fn bench(ctx: &Context, n: usize, reps: u32) -> Result<Vec<PrimTiming>> {
    let seg = SegmentedArgmin::new(ctx, PrimConfig::default_for(ctx))?;
    bench_levels(
        ctx,
        &seg,
        n,
        reps,
        &[0, 4, 8, 12],
        &[
            SegmentedMode::default(),
            SegmentedMode::WorkgroupPerSegment,
            SegmentedMode::DeviceWide,
        ],
    )
}
