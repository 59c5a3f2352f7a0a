//! Device-wide reductions: sum, min and max of u32 and f32, and the argmin of (f32 cost,
//! u32 index) that picks the kd-tree's best split planes (Kolodzey 2014, §2.7).
//!
//! Each reduction is a chain of passes of one kernel (`glsl/prims/reduce.comp`,
//! `glsl/prims/reduce_argmin.comp`): workgroup g reduces tile g of `workgroup_size ×
//! items_per_invocation` elements (16-byte loads; Kolodzey's "algorithm cascading") to one
//! partial, and the host records passes over the partials until one value is left. No
//! workgroup waits for another, so this runs on drivers without forward-progress
//! guarantees, and `n` is known when recording, so the chain is fixed then. Partials live in
//! one `u32` scratch buffer (each level at a 16-byte-aligned offset; see
//! [`Reduce::scratch_len`]).
//!
//! Results, and what they are for n = 0:
//!
//! | reduction | result | n = 0 |
//! |---|---|---|
//! | `sum_u32` | wrapping sum (mod 2^32) | 0 |
//! | `min_u32` / `max_u32` | | `u32::MAX` / 0 |
//! | `sum_f32` | pairwise-tree sum, bit-identical to [`sum_f32_cpu`] | +0.0 |
//! | `min_f32` / `max_f32` | -0.0 < +0.0 (IEEE total order) | +inf / -inf |
//! | `argmin` | lowest cost, then lowest index | (+inf, `u32::MAX`) = [`CostIndex::NONE`] |
//!
//! Determinism. Everything but the f32 sum is independent of the order of combination:
//! integer sums and min/max are, f32 min/max compare order-preserving u32 keys of the bits
//! (so ±0.0 are distinct and ordered), and argmin's order (cost, then index, with -0.0 ==
//! +0.0) is total on NaN-free costs, so its winner is unique. Their CPU twins are plain
//! loops. The f32 sum is not associative, so its order is fixed instead of left to
//! `subgroupAdd`: per invocation four running sums (one per vec4 lane) folded as
//! `(x + y) + (z + w)`, then a perfect binary tree over the invocations of the workgroup
//! (xor-shuffle butterflies inside each subgroup; after the workgroup's one barrier, lane l
//! of subgroup 0 folds an aligned block of the subgroup totals as a perfect tree and
//! butterflies combine the blocks), padded with -0.0, the exact additive identity. Workgroup
//! and subgroup sizes are powers of two, so that tree is the same for every subgroup size:
//! the result
//! depends on the workgroup size and the items per invocation only, and [`sum_f32_cpu`]
//! mirrors it bit for bit (the tests check it under subgroup sizes 4 to 32).
//!
//! Argmin is Kolodzey's SAH shuffle reduction: the 64-bit (cost, index) pair moves as two
//! 32-bit `subgroupShuffleXor`s per butterfly step (`glsl/common/argmin.glsl`).
//!
//! Barriers: a `record_*` call orders its own passes. The caller orders the writes of the
//! input (and earlier uses of `scratch` and `out`) before it, and puts a `compute_to_*`
//! barrier between it and the readers of `out`.
//!
//! Layout: within a tile, runs of 8 consecutive invocations read consecutive 16-byte blocks
//! and each run owns one contiguous chunk (`reduce.comp`): 128 contiguous bytes per 8 lanes
//! on a GPU, a streaming chunk per SIMD batch on llvmpipe, and an element-to-invocation map
//! that does not depend on the subgroup size.
//!
//! Measured on lavapipe (Mesa 22.3, LLVM 15, 2 cores shared with other jobs: load average
//! about 3; subgroup 8), `cargo test --release --test prims_bench -- --ignored --nocapture
//! tune` (configurations interleaved in one submission, best of 9, n = 2^22):
//!
//! | workgroup × items | sum_f32 ms | argmin ms |
//! |---|---|---|
//! | 256 × 16 (`PrimConfig::default_for`) | 14.3 | 12.9 |
//! | 256 × 64 | 8.1 | 7.8 |
//! | 256 × 256 | 6.5 | 6.4 |
//! | 256 × 1024 ([`recommended_config`]) | 6.1 | 6.0 |
//! | 64 × 1024 | 6.1 | 6.0 |
//! | 8 × 1024 | 6.3 | 6.6 |
//!
//! Every invocation llvmpipe launches costs about as much as reading a few hundred elements,
//! so the items per invocation decide; the workgroup size hardly matters. With one
//! lavapipe thread (`LP_NUM_THREADS=1`) 256 × 1024 took 3.9 ms and with two 2.05 ms (a
//! quieter moment): the kernel scales and then approaches this machine's memory bandwidth
//! (about 9.6 GB/s for one thread reading). At n = 2^24 (64 MiB), `vkrt bench prims --only
//! reduce`: about 16 ms (1.0 G elements/s) for every reduction with [`recommended_config`],
//! 19–29 ms with the default 256 × 16.
//!
//! Workaround (Mesa 22.3 lavapipe, found 2026-11): llvmpipe silently stops loops once an
//! invocation has run 65,535 iterations in total across all its loops
//! (`LP_MAX_TGSI_LOOP_ITERATIONS`, "shared between every loop" in gallivm). A pass's loop
//! runs `items / 4` (argmin's pair passes `items / 2`) times, so `items_per_invocation` is
//! capped at [`MAX_ITEMS_PER_INVOCATION`]; the segmented kernels bound theirs likewise.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};

use super::PrimConfig;
use crate::gpu::{kernels, Buffer, BufferArg, Context, GpuError, Kernel, Recorder, Result, Spec};

/// The argmin's element: a cost and the index it belongs to (std430 `uvec2` of the cost
/// bits and the index; keep in sync with `glsl/common/argmin.glsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct CostIndex {
    /// The cost compared (NaN-free).
    pub cost: f32,
    /// The index the cost belongs to; breaks ties (lowest wins).
    pub index: u32,
}

impl CostIndex {
    /// The argmin of nothing: (+inf, `u32::MAX`).
    pub const NONE: Self = Self {
        cost: f32::INFINITY,
        index: u32::MAX,
    };

    /// Whether `self` wins over `other`: lower cost, then lower index (-0.0 == +0.0).
    pub fn better_than(&self, other: &Self) -> bool {
        self.cost < other.cost || (self.cost == other.cost && self.index < other.index)
    }

    /// The bits, for exact comparisons (`-0.0` and `+0.0` differ).
    pub fn bits(&self) -> (u32, u32) {
        (self.cost.to_bits(), self.index)
    }
}

/// Lanes per run of the flat layout (`REDUCE_RUN` in `glsl/common/reduce_lanes.glsl`).
const REDUCE_RUN: usize = 8;

/// Push constants of `reduce.comp` and `reduce_argmin.comp` (keep in sync).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PassPush {
    n: u32,
    src_offset4: u32,
    dst_offset: u32,
}

/// The reductions, with their kernels compiled for one [`PrimConfig`].
pub struct Reduce {
    cfg: PrimConfig,
    sum_u32: Arc<Kernel>,
    min_u32: Arc<Kernel>,
    max_u32: Arc<Kernel>,
    sum_f32: Arc<Kernel>,
    min_f32: Arc<Kernel>,
    max_f32: Arc<Kernel>,
    argmin_costs: Arc<Kernel>,
    argmin_pairs: Arc<Kernel>,
}

/// The largest `items_per_invocation` the reductions take. Workaround (Mesa 22.3 lavapipe,
/// found 2026-11): llvmpipe silently stops loops once an invocation has run 65,535
/// iterations across all its loops (`glsl/common/reduce_lanes.glsl`), and a pass's
/// invocation loops `items / 2` times at most (argmin's pair passes), plus a few dozen
/// iterations in the workgroup reduction.
pub const MAX_ITEMS_PER_INVOCATION: u32 = 16384;

/// Checks what every reduction kernel assumes of its configuration.
pub(crate) fn check_config(ctx: &Context, cfg: PrimConfig, kernel: &'static str) -> Result<()> {
    let info = ctx.info();
    let wg = cfg.workgroup_size;
    let reason = if !wg.is_power_of_two() || wg < 4 {
        Some(format!("workgroup size {wg} is not a power of two >= 4"))
    } else if wg % info.subgroup_size != 0 {
        Some(format!(
            "workgroup size {wg} is not a multiple of the subgroup size {}",
            info.subgroup_size
        ))
    } else if cfg.items_per_invocation == 0
        || cfg.items_per_invocation % 4 != 0
        || cfg.items_per_invocation > MAX_ITEMS_PER_INVOCATION
    {
        Some(format!(
            "items per invocation {} is not a multiple of 4 (16-byte loads) in 4..={MAX_ITEMS_PER_INVOCATION} (llvmpipe's loop budget)",
            cfg.items_per_invocation
        ))
    } else if u64::from(wg) * u64::from(cfg.items_per_invocation) > 1 << 24 {
        Some(format!(
            "tile of {wg} x {} is too large",
            cfg.items_per_invocation
        ))
    } else {
        None
    };
    match reason {
        Some(reason) => Err(GpuError::Kernel { kernel, reason }),
        None => Ok(()),
    }
}

/// Words of scratch each level of partials takes: whole 16-byte blocks, so the next pass can
/// read them with 16-byte loads.
fn level_words(partials: u32, words_per_partial: u32) -> u32 {
    (partials * words_per_partial).next_multiple_of(4)
}

/// The measured best configuration on lavapipe (module docs): 256 invocations × 1024
/// elements. Every invocation launched costs about as much as reading a few hundred
/// elements there, so tiles are large; on a GPU, 256 × 16..64 is the usual choice.
pub fn recommended_config(ctx: &Context) -> PrimConfig {
    PrimConfig {
        workgroup_size: 256u32.max(ctx.info().subgroup_size),
        items_per_invocation: 1024,
    }
}

/// A reduction's two entry points: `$record` records `out[0] = ` the reduction of
/// `src[..n]` with kernel `self.$run` (one kernel for every level of the chain), and `$run`
/// uploads `data`, runs it and reads the result back.
macro_rules! reductions {
    ($($(#[doc = $doc:literal])* $record:ident / $run:ident: $t:ty, $label:literal;)*) => {
        $(
            #[doc = "Records `out[0] = `"]
            $(#[doc = $doc])*
            pub fn $record(
                &self,
                rec: &mut Recorder,
                src: &Buffer<$t>,
                n: u32,
                scratch: &Buffer<u32>,
                out: &Buffer<$t>,
            ) {
                check_len($label, src, n, out);
                let k = (&*self.$run, &*self.$run);
                self.record_chain(rec, $label, k, 1, src, n, scratch, out);
            }

            #[doc = concat!("[`Reduce::", stringify!($record), "`] of `data` on the GPU.")]
            pub fn $run(&self, ctx: &Context, data: &[$t]) -> Result<$t> {
                self.run(ctx, data, Self::$record)
            }
        )*
    };
}

impl Reduce {
    /// Compiles every reduction for `cfg`: an error unless the workgroup size is a power of
    /// two of at least 4 and a multiple of the subgroup size, the items per invocation a
    /// multiple of 4 up to [`MAX_ITEMS_PER_INVOCATION`], and a tile at most 2^24 elements.
    pub fn new(ctx: &Context, cfg: PrimConfig) -> Result<Self> {
        check_config(ctx, cfg, "prims.reduce")?;
        let spec = Spec::new()
            .workgroup(cfg.workgroup_size)
            .u32(1, cfg.items_per_invocation);
        let k = |blob| ctx.kernel(blob, &spec);
        Ok(Self {
            cfg,
            sum_u32: k(&kernels::PRIMS_REDUCE_SUM_U32)?,
            min_u32: k(&kernels::PRIMS_REDUCE_MIN_U32)?,
            max_u32: k(&kernels::PRIMS_REDUCE_MAX_U32)?,
            sum_f32: k(&kernels::PRIMS_REDUCE_SUM_F32)?,
            min_f32: k(&kernels::PRIMS_REDUCE_MIN_F32)?,
            max_f32: k(&kernels::PRIMS_REDUCE_MAX_F32)?,
            argmin_costs: k(&kernels::PRIMS_REDUCE_ARGMIN_COSTS)?,
            argmin_pairs: k(&kernels::PRIMS_REDUCE_ARGMIN_PAIRS)?,
        })
    }

    /// The workgroup shape it was compiled for.
    pub fn config(&self) -> PrimConfig {
        self.cfg
    }

    /// Words (u32) of scratch any reduction of `n` elements needs: the partials of every
    /// pass but the last (argmin's are two words each, so this covers every reduction).
    pub fn scratch_len(&self, n: usize) -> usize {
        let n = u32::try_from(n).expect("reductions take at most u32::MAX elements");
        self.levels(n, 2).iter().map(|l| l.words as usize).sum()
    }

    /// The passes of a reduction of `n` elements: (entries read, scratch words written).
    fn levels(&self, n: u32, words_per_partial: u32) -> Vec<Level> {
        let tile = self.cfg.tile();
        let mut levels = Vec::new();
        let mut count = n;
        loop {
            let groups = count.div_ceil(tile).max(1);
            if groups == 1 {
                return levels;
            }
            levels.push(Level {
                groups,
                words: level_words(groups, words_per_partial),
            });
            count = groups;
        }
    }

    /// Records the chain of passes: `first` over `src`, then `rest` over the partials in
    /// `scratch`, the last pass writing `out[0]`.
    #[allow(clippy::too_many_arguments, reason = "a pass chain is these buffers")]
    fn record_chain(
        &self,
        rec: &mut Recorder,
        label: &str,
        (first, rest): (&Kernel, &Kernel),
        words_per_partial: u32,
        src: &dyn BufferArg,
        n: u32,
        scratch: &Buffer<u32>,
        out: &dyn BufferArg,
    ) {
        let levels = self.levels(n, words_per_partial);
        let needed: usize = levels.iter().map(|l| l.words as usize).sum();
        if scratch.len() < needed {
            misuse(&format!(
                "{label}: scratch `{}` has {} words, {n} elements need {needed} (Reduce::scratch_len)",
                scratch.name(),
                scratch.len()
            ));
        }
        rec.scope(label, |rec| {
            let mut kernel = first;
            let mut src_buf = src;
            let mut push = PassPush {
                n,
                src_offset4: 0,
                dst_offset: 0,
            };
            let mut scratch_words = 0;
            for level in &levels {
                push.dst_offset = scratch_words / words_per_partial;
                let groups = rec.groups_1d(u64::from(level.groups), 1);
                rec.dispatch(kernel, groups, &[src_buf, scratch], &push);
                rec.compute_to_compute();
                kernel = rest;
                src_buf = scratch;
                push.n = level.groups;
                push.src_offset4 = scratch_words / 4;
                scratch_words += level.words;
            }
            push.dst_offset = 0;
            rec.dispatch(kernel, [1, 1, 1], &[src_buf, out], &push);
        });
    }

    reductions! {
        /// the wrapping sum of `src[..n]` (0 for n = 0)
        record_sum_u32 / sum_u32: u32, "prims.reduce.sum_u32";
        /// the minimum of `src[..n]` (`u32::MAX` for n = 0)
        record_min_u32 / min_u32: u32, "prims.reduce.min_u32";
        /// the maximum of `src[..n]` (0 for n = 0)
        record_max_u32 / max_u32: u32, "prims.reduce.max_u32";
        /// the pairwise-tree sum of `src[..n]` in the fixed order of [`sum_f32_cpu`], bit
        /// for bit (+0.0 for n = 0)
        record_sum_f32 / sum_f32: f32, "prims.reduce.sum_f32";
        /// the minimum of `src[..n]` in IEEE total order, -0.0 below +0.0 (+inf for n = 0)
        record_min_f32 / min_f32: f32, "prims.reduce.min_f32";
        /// the maximum of `src[..n]` in IEEE total order, +0.0 above -0.0 (-inf for n = 0)
        record_max_f32 / max_f32: f32, "prims.reduce.max_f32";
    }

    /// Records `out[0] = ` the argmin of `costs[..n]`: lowest cost, then lowest index,
    /// -0.0 == +0.0; [`CostIndex::NONE`] for n = 0. Costs must be NaN-free.
    pub fn record_argmin(
        &self,
        rec: &mut Recorder,
        costs: &Buffer<f32>,
        n: u32,
        scratch: &Buffer<u32>,
        out: &Buffer<CostIndex>,
    ) {
        check_len("prims.reduce.argmin", costs, n, out);
        let k = (&*self.argmin_costs, &*self.argmin_pairs);
        self.record_chain(rec, "prims.reduce.argmin", k, 2, costs, n, scratch, out);
    }

    /// Uploads `data`, runs `record` and downloads `out[0]`: the convenience wrappers.
    fn run<T: Pod, R: Pod>(
        &self,
        ctx: &Context,
        data: &[T],
        record: impl FnOnce(&Self, &mut Recorder, &Buffer<T>, u32, &Buffer<u32>, &Buffer<R>),
    ) -> Result<R> {
        let n = u32::try_from(data.len()).expect("reductions take at most u32::MAX elements");
        let src = Buffer::from_slice(ctx, "prims.reduce.src", data)?;
        let scratch =
            Buffer::<u32>::new(ctx, "prims.reduce.scratch", self.scratch_len(data.len()))?;
        let out = Buffer::<R>::new(ctx, "prims.reduce.out", 1)?;
        let mut rec = Recorder::new(ctx)?;
        record(self, &mut rec, &src, n, &scratch, &out);
        rec.compute_to_transfer();
        rec.submit_and_wait()?;
        Ok(out.download()?[0])
    }

    /// The argmin of `costs` on the GPU: (cost, index), (+inf, `u32::MAX`) when empty.
    pub fn argmin(&self, ctx: &Context, costs: &[f32]) -> Result<(f32, u32)> {
        let best = self.run(ctx, costs, Self::record_argmin)?;
        Ok((best.cost, best.index))
    }
}

struct Level {
    /// Workgroups of the pass, one partial each.
    groups: u32,
    /// Scratch words the partials take.
    words: u32,
}

fn check_len<T: Pod, R: Pod>(label: &str, src: &Buffer<T>, n: u32, out: &Buffer<R>) {
    if src.len() < n as usize || out.is_empty() {
        misuse(&format!(
            "{label}: n = {n} but `{}` has {} elements and `{}` {}",
            src.name(),
            src.len(),
            out.name(),
            out.len()
        ));
    }
}

/// Our own misuse of the primitives: a bug in the caller.
#[cold]
#[track_caller]
pub(crate) fn misuse(msg: &str) -> ! {
    panic!("vkrt prims usage error: {msg}")
}

// ---------------------------------------------------------------------------------------
// CPU twins

/// The CPU twin of [`Reduce::record_sum_u32`]: the wrapping sum.
pub fn sum_u32_cpu(src: &[u32]) -> u32 {
    src.iter().fold(0u32, |a, &b| a.wrapping_add(b))
}

/// The CPU twin of [`Reduce::record_min_u32`].
pub fn min_u32_cpu(src: &[u32]) -> u32 {
    src.iter().copied().fold(u32::MAX, u32::min)
}

/// The CPU twin of [`Reduce::record_max_u32`].
pub fn max_u32_cpu(src: &[u32]) -> u32 {
    src.iter().copied().fold(0, u32::max)
}

/// Order-preserving u32 key of an f32's bits (`f32_key` in `reduce.comp`): -0.0 < +0.0.
fn f32_key(bits: u32) -> u32 {
    if bits & 0x8000_0000 != 0 {
        !bits
    } else {
        bits | 0x8000_0000
    }
}

fn f32_unkey(key: u32) -> u32 {
    if key & 0x8000_0000 != 0 {
        key & 0x7fff_ffff
    } else {
        !key
    }
}

/// The CPU twin of [`Reduce::record_min_f32`]: the minimum in IEEE total order (-0.0 <
/// +0.0), +inf when empty.
pub fn min_f32_cpu(src: &[f32]) -> f32 {
    let key = src
        .iter()
        .map(|x| f32_key(x.to_bits()))
        .fold(f32_key(f32::INFINITY.to_bits()), u32::min);
    f32::from_bits(f32_unkey(key))
}

/// The CPU twin of [`Reduce::record_max_f32`]: the maximum in IEEE total order (+0.0 >
/// -0.0), -inf when empty.
pub fn max_f32_cpu(src: &[f32]) -> f32 {
    let key = src
        .iter()
        .map(|x| f32_key(x.to_bits()))
        .fold(f32_key(f32::NEG_INFINITY.to_bits()), u32::max);
    f32::from_bits(f32_unkey(key))
}

/// One pass of `prims.reduce.sum_f32`: the partial sum of every tile of `src`, in the
/// kernel's order (see the module docs). The subgroup size does not appear: the workgroup's
/// tree over invocations is the same for all of them.
#[allow(
    clippy::needless_range_loop,
    reason = "mirrors the kernel's index arithmetic"
)]
pub fn sum_f32_pass_cpu(src: &[f32], cfg: PrimConfig) -> Vec<f32> {
    let n = src.len();
    let wg = cfg.workgroup_size as usize;
    let items = cfg.items_per_invocation as usize;
    let tile = wg * items;
    let run = REDUCE_RUN.min(wg);
    let groups = n.div_ceil(tile).max(1);
    let pad = -0.0f32;
    let mut dst = vec![0.0f32; groups];
    let mut partials = vec![pad; wg];
    for group in 0..groups {
        for lane in 0..wg {
            // Run-striped: run lane / run owns run·items/4 16-byte blocks from `chunk`;
            // lane r of it reads blocks chunk + run·k + r, into four running sums.
            let chunk = group * (tile / 4) + (lane / run) * (run * items / 4);
            let mut acc = [pad; 4];
            for k in 0..items / 4 {
                let j = chunk + run * k + lane % run;
                for c in 0..4 {
                    let e = 4 * j + c;
                    acc[c] += if e < n { src[e] } else { pad };
                }
            }
            partials[lane] = (acc[0] + acc[1]) + (acc[2] + acc[3]);
        }
        // Subgroup butterflies, then the same over subgroup totals: a perfect binary tree.
        let mut width = wg;
        while width > 1 {
            width /= 2;
            for l in 0..width {
                partials[l] = partials[2 * l] + partials[2 * l + 1];
            }
        }
        dst[group] = if n == 0 { 0.0 } else { partials[0] };
    }
    dst
}

/// The CPU twin of [`Reduce::record_sum_f32`]: passes of [`sum_f32_pass_cpu`] until one
/// value is left, bit-identical to the GPU for the same `cfg` on any subgroup size.
pub fn sum_f32_cpu(src: &[f32], cfg: PrimConfig) -> f32 {
    let mut level = sum_f32_pass_cpu(src, cfg);
    while level.len() > 1 {
        level = sum_f32_pass_cpu(&level, cfg);
    }
    level[0]
}

/// The CPU twin of [`Reduce::record_argmin`]: (lowest cost, then lowest index; -0.0 ==
/// +0.0), (+inf, `u32::MAX`) when empty. The winner is unique, so a plain loop gives the
/// kernels' answer whatever their order.
pub fn argmin_cpu(costs: &[f32]) -> (f32, u32) {
    let mut best = CostIndex::NONE;
    for (i, &cost) in costs.iter().enumerate() {
        let candidate = CostIndex {
            cost,
            index: i as u32,
        };
        if candidate.better_than(&best) {
            best = candidate;
        }
    }
    (best.cost, best.index)
}
