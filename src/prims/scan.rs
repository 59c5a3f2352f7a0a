//! Prefix sums of u32 elements and of 0/1 byte flags.
//!
//! **Chained (the default, [`ScanVariant::Chained`])**: one pass, `prims.scan_chained`.
//! A tile is one subgroup's share (lanes × 16 granules of 32 bytes at the default; 128 for
//! u32 and 64 for flag scans of 256 such large tiles or more); every tile publishes its
//! sum, then looks back over its predecessors' published sums (decoupled look-back, Merrill
//! & Garland 2016). A predecessor that has published nothing yet is never waited for: the
//! looking-back subgroup reduces that tile's input itself and goes on (the fallback of
//! Levien & Smith 2022). So no workgroup waits for another and the scan
//! terminates on drivers without forward-progress guarantees (lavapipe runs a thread's
//! workgroups one after another), while reading the input once. A tile's flag and value
//! share one 64-bit word, written and read with relaxed atomics. It needs `shaderInt64` and
//! `shaderBufferInt64Atomics`, and an output that does not alias the input (a fallback
//! re-reads predecessors' input); other scans take the reduce-then-scan path below.
//!
//! What made it fast on lavapipe, each measured (`vkrt bench prims --only scan`): 64-bit
//! granules (every buffer access is a loop over lanes and components there: u64vec4 halves
//! the trips of a uvec4; the copy kernels show the same 2×); tiles per subgroup, so the
//! kernel has no barrier (a barrier is a coroutine switch that saves and restores the
//! subgroup's live tile: 1.4–2× with the workgroup-tile version); no array indexed by a
//! loop variable (such arrays live in memory, every access a loop over lanes: the flag
//! scan's tail handling alone cost 1.8×); the look-back reading a tile's word in one lane
//! and broadcasting it, instead of a locked read-modify-write in every lane. Tiles are
//! numbered in start order by an atomic counter: lavapipe gives each thread a contiguous
//! range of workgroup ids and silently ends loops after 65,535 trips, so with tiles numbered
//! by id a look-back walked over tens of thousands of tiles and lost its prefix.
//!
//! **Reduce-then-scan**, multi-level: `prims.scan_reduce` writes the sum of every tile, the
//! tile sums are scanned (recursively, with the same kernels) in place, and
//! `prims.scan_downsweep` rescans every tile from its carry-in. It reads the input twice.
//!
//! Measured at n = 2^24 on lavapipe (`vkrt bench prims --min-n 16777216 --only scan
//! --reps 6`, four runs, 128 granules per lane): the u32 scan 14.1–14.6 ms chained (with
//! 16 granules per lane: 25–29 ms) vs 78–124 ms reduce-then-scan, 0.60–0.99 of the best
//! copy kernel measured in the same run on the same bytes (that kernel itself takes 8–15 ms
//! from run to run, hence the spread); the flag scan 8.4–10.0 ms with 64 granules,
//! 0.60–1.08 of the copy kernel (16 granules: 10–11 ms). What is left is per granule: a
//! variant with only the loads, stores and tile bookkeeping took about 0.75 of the full
//! kernel's time.
//!
//! Inside a workgroup: a subgroup scan (`subgroupInclusiveAdd`, or `subgroupShuffleUp`
//! steps with [`Scan::with_shuffle`]), subgroup totals through shared memory, and several
//! elements per invocation (Kolodzey's "algorithm cascading"). Flags are bytes read four
//! per u32 word (Kolodzey's uchar4 trick, here 32 per granule), so a flag scan reads a
//! quarter of the bytes of a u32 scan of the same length.
//!
//! Sums wrap modulo 2^32, on the GPU and in the CPU twins alike.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};

use super::PrimConfig;
use crate::gpu::{kernels, Buffer, BufferArg, Context, GpuError, Kernel, Recorder, Result, Spec};

/// The count buffer to bind and `(index, mul, div)` for the kernels' push constants:
/// `div == 0` means "n = capacity", and `unused` is bound in the count's place.
fn count_binding<'a>(
    count: Option<GpuCount<'a>>,
    unused: &'a Buffer<u32>,
) -> (&'a Buffer<u32>, u32, u32, u32) {
    match count {
        Some(c) => (c.counts, c.index, c.mul, c.div),
        None => (unused, 0, 0, 0),
    }
}

/// Inclusive (element i included) or exclusive (elements before i).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScanOp {
    /// Output i is the sum of elements 0..=i.
    Inclusive,
    /// Output i is the sum of elements 0..i (0 for the first).
    Exclusive,
}

/// What the first level reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScanInput {
    /// u32 elements.
    U32,
    /// One byte per element, each 0 or 1.
    Flags,
}

/// Where a count that lives on the GPU is: `n = ceil(counts[index] · mul / div)`, at most
/// the capacity the scan was recorded for (see `glsl/common/gpu_count.glsl`).
#[derive(Clone, Copy)]
pub struct GpuCount<'a> {
    /// The buffer holding the count.
    pub counts: &'a Buffer<u32>,
    /// Which u32 of `counts` holds it.
    pub index: u32,
    /// Multiplier applied to the stored count.
    pub mul: u32,
    /// Divisor (rounding up); 0 means `n` is the capacity and `counts` is not read.
    pub div: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ReducePush {
    capacity: u32,
    count_index: u32,
    count_mul: u32,
    count_div: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct DownsweepPush {
    capacity: u32,
    has_carry: u32,
    inclusive: u32,
    count_index: u32,
    count_mul: u32,
    count_div: u32,
}

/// How a tile is scanned inside the workgroup (`vkrt bench prims` measures each).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScanVariant {
    /// Granules strided by the workgroup (coalesced loads), `subgroupInclusiveAdd`.
    Strided,
    /// As `Strided`, with `subgroupShuffleUp` steps instead of the intrinsic.
    StridedShuffle,
    /// Each invocation owns consecutive granules: one subgroup scan per tile.
    Contiguous,
    /// One pass, decoupled look-back with fallback (`glsl/prims/scan_chained.comp`): the
    /// input is read once. Scans whose output aliases their input use `Contiguous`.
    Chained,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ChainedPush {
    capacity: u32,
    inclusive: u32,
    count_index: u32,
    count_mul: u32,
    count_div: u32,
}

/// The single-pass kernel at one tile size.
struct ChainedTiles {
    kernel: Arc<Kernel>,
    /// Elements per workgroup (the grid is sized by it).
    tile: usize,
    /// Elements per subgroup tile with the smallest subgroups the kernels take (4 lanes):
    /// the state holds one word per subgroup tile. Not the device's reported minimum: under
    /// LP_NATIVE_VECTOR_WIDTH=512 lavapipe reports 16 (min 16), and a state sized for 16
    /// lanes gave wrong prefixes from element 12,118,016 of a 2^24 + 3 scan, every run —
    /// the kernel used more tiles than 16-lane subgroups make. (A bounds check on the
    /// state in the kernel made it right with any sizing, but doubled the default shape's
    /// time on lavapipe, 25-29 -> 53-55 ms at 2^24: the host sizes for 4 lanes instead.)
    min_subgroup_tile: usize,
}

/// The single-pass kernel at two tile sizes: per-tile work (the start-order counter, the
/// subgroup scan, publishing, the look-back) is amortised over more granules by large
/// tiles, while small scans need enough tiles to spread over the device.
struct Chained {
    small: ChainedTiles,
    large: ChainedTiles,
    /// Scans of at least this many elements (capacity) take the large tiles.
    large_from: usize,
}

impl Chained {
    fn tiles_for(&self, n: usize) -> &ChainedTiles {
        if n >= self.large_from {
            &self.large
        } else {
            &self.small
        }
    }
}

/// Granules per lane of the chained scan's small tiles: the configured items per invocation
/// times this over 8 (16 at the default 16 items).
const CHAINED_SMALL_ROUNDS_PER_ITEM: u32 = 8;
/// The same for large tiles: 128 granules per lane for u32 scans, 64 for flag scans at the
/// default. Measured (`vkrt bench prims --only scan`, three or four runs each at 2^24,
/// default shape): u32 scan 25–29 ms with 16 granules per lane, 19–20 with 32, 15.4–17.0
/// with 64, 14.1–14.6 with 128 (four runs in a row); flag scan 10–11, 9.7–10, 8.4–8.7,
/// 9–13 ms.
const CHAINED_LARGE_ROUNDS_PER_ITEM_U32: u32 = 64;
const CHAINED_LARGE_ROUNDS_PER_ITEM_FLAGS: u32 = 32;
/// The most granules per lane: each lane holds its granules (32 bytes each) in registers,
/// and NVIDIA's compiler (driver 580) refuses the kernel at 256 (`VK_ERROR_UNKNOWN` at
/// pipeline creation) while 128, the default's large tiles, compiles and runs.
const MAX_CHAINED_ROUNDS: u32 = 128;
/// Scans take the large tiles from this many large tiles on. Measured: at 2^18 elements
/// (64 large u32 tiles) both sizes took 0.6 ms; at 2^20 large tiles were faster for u32
/// (1.5 vs 1.8 ms) but slower for flags (64 large tiles: 1.04 vs 0.84 ms); at 2^16 small
/// tiles won (0.21 vs 0.27 ms).
const CHAINED_LARGE_FROM_TILES: usize = 256;

/// A scan of one input kind, with its kernels compiled.
pub struct Scan {
    cfg: PrimConfig,
    input: ScanInput,
    rounds: u32,
    first_reduce: Arc<Kernel>,
    first_downsweep: Arc<Kernel>,
    reduce: Arc<Kernel>,
    downsweep: Arc<Kernel>,
    chained: Option<Chained>,
}

/// Scratch for one scan: the tile sums of every level and the grand total.
pub struct ScanScratch {
    max_n: usize,
    levels: Vec<Buffer<u32>>,
    level_totals: Vec<Buffer<u32>>,
    /// The grand total (one u32), written by every `record`.
    pub total: Buffer<u32>,
    /// The chained scan's tile counter and per-tile (flag, sum) words.
    chain_state: Buffer<u64>,
}

impl Scan {
    /// The measured default: the single-pass chained scan (see `vkrt bench prims`).
    pub fn new(ctx: &Context, cfg: PrimConfig, input: ScanInput) -> Result<Self> {
        Self::with_variant(ctx, cfg, input, ScanVariant::Chained)
    }

    /// A u32 scan whose subgroup scan is `subgroupShuffleUp` steps instead of
    /// `subgroupInclusiveAdd` (for measuring one against the other).
    pub fn with_shuffle(ctx: &Context, cfg: PrimConfig) -> Result<Self> {
        Self::with_variant(ctx, cfg, ScanInput::U32, ScanVariant::StridedShuffle)
    }

    /// A scan with the given in-tile variant (the shuffle variant exists for u32 input only;
    /// flags fall back to the intrinsic).
    pub fn with_variant(
        ctx: &Context,
        cfg: PrimConfig,
        input: ScanInput,
        variant: ScanVariant,
    ) -> Result<Self> {
        let sg = ctx.info().subgroup_size;
        let wg = cfg.workgroup_size;
        if !wg.is_power_of_two() || wg % ctx.info().max_subgroup_size.max(sg) != 0 {
            return Err(GpuError::Kernel {
                kernel: "prims.scan",
                reason: format!("workgroup size {wg} must be a power of two and a multiple of the subgroup size {sg}"),
            });
        }
        let rounds = (cfg.items_per_invocation / 4).max(1);
        let spec = Spec::new().workgroup(wg).u32(1, rounds);
        let reduce = ctx.kernel(&kernels::PRIMS_SCAN_REDUCE_U32, &spec)?;
        let downsweep = ctx.kernel(
            match variant {
                ScanVariant::Strided => &kernels::PRIMS_SCAN_DOWNSWEEP_U32,
                ScanVariant::StridedShuffle => &kernels::PRIMS_SCAN_DOWNSWEEP_U32_SHUFFLE,
                ScanVariant::Contiguous | ScanVariant::Chained => {
                    &kernels::PRIMS_SCAN_DOWNSWEEP_U32_CONTIGUOUS
                }
            },
            &spec,
        )?;
        let chained = if variant == ScanVariant::Chained {
            Self::chained(ctx, cfg, input, false, ctx.info().rolled_scan_tiles)?
        } else {
            None
        };
        let (first_reduce, first_downsweep) = match input {
            ScanInput::U32 => (reduce.clone(), downsweep.clone()),
            ScanInput::Flags => (
                ctx.kernel(&kernels::PRIMS_SCAN_REDUCE_FLAGS, &spec)?,
                ctx.kernel(
                    if matches!(variant, ScanVariant::Contiguous | ScanVariant::Chained) {
                        &kernels::PRIMS_SCAN_DOWNSWEEP_FLAGS_CONTIGUOUS
                    } else {
                        &kernels::PRIMS_SCAN_DOWNSWEEP_FLAGS
                    },
                    &spec,
                )?,
            ),
        };
        Ok(Self {
            cfg,
            input,
            rounds,
            first_reduce,
            first_downsweep,
            reduce,
            downsweep,
            chained,
        })
    }

    /// The single-pass kernel (32-byte granules, 64-bit state words), where the device has
    /// 64-bit integers and 64-bit buffer atomics; `None` elsewhere.
    fn chained(
        ctx: &Context,
        cfg: PrimConfig,
        input: ScanInput,
        force_fallback: bool,
        rolled: bool,
    ) -> Result<Option<Chained>> {
        let f = ctx.info().features;
        if !(f.shader_int64 && f.shader_buffer_int64_atomics) {
            return Ok(None);
        }
        const WORDS: u32 = 8;
        let (blob, per_word) = match (input, rolled) {
            (ScanInput::U32, false) => (&kernels::PRIMS_SCAN_CHAINED_U32, 1),
            (ScanInput::U32, true) => (&kernels::PRIMS_SCAN_CHAINED_U32_ROLLED, 1),
            (ScanInput::Flags, false) => (&kernels::PRIMS_SCAN_CHAINED_FLAGS, 4),
            (ScanInput::Flags, true) => (&kernels::PRIMS_SCAN_CHAINED_FLAGS_ROLLED, 4),
        };
        let tiles = |per_item: u32| -> Result<ChainedTiles> {
            let rounds = (per_item * cfg.items_per_invocation / WORDS).clamp(1, MAX_CHAINED_ROUNDS);
            let spec = Spec::new()
                .workgroup(cfg.workgroup_size)
                .u32(1, rounds)
                .u32(2, u32::from(force_fallback));
            Ok(ChainedTiles {
                kernel: ctx.kernel(blob, &spec)?,
                tile: (cfg.workgroup_size * rounds * WORDS * per_word) as usize,
                min_subgroup_tile: (4 * rounds * WORDS * per_word) as usize,
            })
        };
        let small = tiles(CHAINED_SMALL_ROUNDS_PER_ITEM)?;
        let large = tiles(match input {
            ScanInput::U32 => CHAINED_LARGE_ROUNDS_PER_ITEM_U32,
            ScanInput::Flags => CHAINED_LARGE_ROUNDS_PER_ITEM_FLAGS,
        })?;
        let lanes = ctx.info().subgroup_size.max(4) as usize;
        let large_from = CHAINED_LARGE_FROM_TILES * large.min_subgroup_tile / 4 * lanes;
        Ok(Some(Chained {
            small,
            large,
            large_from,
        }))
    }

    /// A chained scan whose look-back ignores every published sum and reduces all
    /// predecessor tiles from the input (O(tiles²) work: for testing the fallback path,
    /// which timing alone reaches only sometimes), with only small tiles or, with
    /// `large_tiles`, only large ones. Keep such scans to a few dozen tiles: lavapipe cuts
    /// long loops short without a word, and a forced look-back over ~500 large or ~1800
    /// small tiles lost one round of its fallback sum. `None` where the device has no
    /// chained scan.
    pub fn with_forced_fallback(
        ctx: &Context,
        cfg: PrimConfig,
        input: ScanInput,
        large_tiles: bool,
    ) -> Result<Option<Self>> {
        let rolled = ctx.info().rolled_scan_tiles;
        Self::with_chained(ctx, cfg, input, true, rolled, large_tiles)
    }

    /// A chained scan with its granule loops `rolled` or not (the device's own form is
    /// [`DeviceInfo::rolled_scan_tiles`](crate::gpu::DeviceInfo::rolled_scan_tiles)), with
    /// only small tiles or, with `large_tiles`, only large ones: for testing both forms on
    /// one device. `None` where the device has no chained scan.
    pub fn with_tile_loops(
        ctx: &Context,
        cfg: PrimConfig,
        input: ScanInput,
        rolled: bool,
        large_tiles: bool,
    ) -> Result<Option<Self>> {
        Self::with_chained(ctx, cfg, input, false, rolled, large_tiles)
    }

    /// A chained scan with only small tiles or, with `large_tiles`, only large ones.
    fn with_chained(
        ctx: &Context,
        cfg: PrimConfig,
        input: ScanInput,
        force_fallback: bool,
        rolled: bool,
        large_tiles: bool,
    ) -> Result<Option<Self>> {
        let mut scan = Self::with_variant(ctx, cfg, input, ScanVariant::Contiguous)?;
        scan.chained = Self::chained(ctx, cfg, input, force_fallback, rolled)?.map(|mut c| {
            c.large_from = if large_tiles { 0 } else { usize::MAX };
            c
        });
        Ok(scan.chained.is_some().then_some(scan))
    }

    /// The workgroup shape it was compiled for.
    pub fn config(&self) -> PrimConfig {
        self.cfg
    }

    /// Whether non-aliasing scans run as one chained pass (see [`ScanVariant::Chained`]).
    pub fn is_chained(&self) -> bool {
        self.chained.is_some()
    }

    /// Elements per workgroup tile of the first (or only) pass of scans below
    /// [`Scan::large_tiles`]: where tile-boundary edge cases lie.
    pub fn tile_elements(&self) -> usize {
        self.chained.as_ref().map_or(self.tile(0), |c| c.small.tile)
    }

    /// The chained scan's large tiles: (elements per workgroup tile, the scan length from
    /// which they are used). `None` without the chained scan.
    pub fn large_tiles(&self) -> Option<(usize, usize)> {
        self.chained.as_ref().map(|c| (c.large.tile, c.large_from))
    }

    /// Elements per workgroup tile at a level (flags pack 16 per 16-byte load, u32 four).
    fn tile(&self, level: usize) -> usize {
        let per_granule = if level == 0 && self.input == ScanInput::Flags {
            16
        } else {
            4
        };
        (self.cfg.workgroup_size * self.rounds) as usize * per_granule
    }

    /// Lengths of the tile-sum arrays for a scan of `n` elements.
    fn level_lengths(&self, n: usize) -> Vec<usize> {
        let mut lengths = Vec::new();
        let mut len = n;
        let mut level = 0;
        while len > self.tile(level) {
            len = len.div_ceil(self.tile(level));
            lengths.push(len);
            level += 1;
        }
        lengths
    }

    /// Bytes of [`Scan::scratch`] for `max_n` elements (without allocating them).
    pub fn scratch_bytes(&self, max_n: usize) -> u64 {
        let lengths = self.level_lengths(max_n);
        let tiles = self
            .chained
            .as_ref()
            .map_or(0, |c| max_n.div_ceil(c.small.min_subgroup_tile));
        let words: usize = lengths.iter().map(|&l| l.max(1)).sum::<usize>() + lengths.len() + 1;
        4 * words as u64 + 8 * (1 + tiles) as u64
    }

    /// Scratch for scans of up to `max_n` elements.
    pub fn scratch(&self, ctx: &Context, max_n: usize) -> Result<ScanScratch> {
        let lengths = self.level_lengths(max_n);
        let levels = lengths
            .iter()
            .enumerate()
            .map(|(i, &len)| Buffer::new(ctx, &format!("prims.scan.partials{i}"), len))
            .collect::<Result<Vec<_>>>()?;
        let level_totals = (0..lengths.len())
            .map(|i| Buffer::new(ctx, &format!("prims.scan.total{i}"), 1))
            .collect::<Result<Vec<_>>>()?;
        let tiles = self
            .chained
            .as_ref()
            .map_or(0, |c| max_n.div_ceil(c.small.min_subgroup_tile));
        Ok(ScanScratch {
            max_n,
            levels,
            level_totals,
            total: Buffer::new(ctx, "prims.scan.total", 1)?,
            chain_state: Buffer::new(ctx, "prims.scan.chain_state", 1 + tiles)?,
        })
    }

    /// Records the scan of `n` elements of `input` into `output` (u32, may alias `input`
    /// for u32 scans) and the grand total into `scratch.total`. Orders its own passes;
    /// the caller orders what comes before (writes of `input`) and after.
    pub fn record(
        &self,
        rec: &mut Recorder,
        input: &dyn BufferArg,
        output: &dyn BufferArg,
        n: usize,
        op: ScanOp,
        scratch: &ScanScratch,
    ) {
        if n > scratch.max_n {
            panic!(
                "scan of {n} elements with scratch sized for {}",
                scratch.max_n
            );
        }
        self.record_scan(rec, input, output, n, None, op, scratch);
    }

    /// Like [`Scan::record`] for a count that lives on the GPU (at most `capacity`): the
    /// passes are recorded for the capacity and every workgroup past the real count exits
    /// at once, so nothing is read back.
    #[allow(
        clippy::too_many_arguments,
        reason = "record's arguments plus the count"
    )]
    pub fn record_counted(
        &self,
        rec: &mut Recorder,
        input: &dyn BufferArg,
        output: &dyn BufferArg,
        capacity: usize,
        count: GpuCount,
        op: ScanOp,
        scratch: &ScanScratch,
    ) {
        assert!(
            capacity <= scratch.max_n,
            "scan capacity {capacity} above its scratch's {}",
            scratch.max_n
        );
        self.record_scan(rec, input, output, capacity, Some(count), op, scratch);
    }

    /// The whole scan under its profiler scope: one chained pass where it applies, the
    /// reduce-then-scan levels otherwise.
    #[allow(
        clippy::too_many_arguments,
        reason = "record_counted's arguments, the count optional"
    )]
    fn record_scan(
        &self,
        rec: &mut Recorder,
        input: &dyn BufferArg,
        output: &dyn BufferArg,
        n: usize,
        count: Option<GpuCount>,
        op: ScanOp,
        scratch: &ScanScratch,
    ) {
        let name = match self.input {
            ScanInput::U32 => "prims.scan",
            ScanInput::Flags => "prims.flag_scan",
        };
        rec.scope(name, |rec| {
            if !self.record_chained(rec, input, output, n, count, op, scratch) {
                let total = &scratch.total;
                self.record_level(rec, 0, input, output, n, count, op, scratch, total);
            }
        });
    }

    /// Records the single-pass scan if this scan has one and `output` does not alias
    /// `input` (a fallback re-reads predecessors' input); returns whether it did.
    #[allow(
        clippy::too_many_arguments,
        reason = "record_counted's arguments, the count optional"
    )]
    fn record_chained(
        &self,
        rec: &mut Recorder,
        input: &dyn BufferArg,
        output: &dyn BufferArg,
        n: usize,
        count: Option<GpuCount>,
        op: ScanOp,
        scratch: &ScanScratch,
    ) -> bool {
        let Some(chained) = &self.chained else {
            return false;
        };
        let chained = chained.tiles_for(n);
        if input.raw() == output.raw() {
            return false;
        }
        let total = &scratch.total;
        let (counts, count_index, count_mul, count_div) = count_binding(count, total);
        let push = ChainedPush {
            capacity: n as u32,
            inclusive: u32::from(op == ScanOp::Inclusive),
            count_index,
            count_mul,
            count_div,
        };
        let state = &scratch.chain_state;
        // The previous scan with this scratch may still read or write the state. Only the
        // counter and the tiles of `n` (capacity) elements are cleared, not the scratch's
        // whole state.
        rec.compute_to_transfer();
        rec.fill_first(state, 1 + n.div_ceil(chained.min_subgroup_tile), 0);
        rec.transfer_to_compute();
        let groups = rec.groups_1d(n.max(1) as u64, chained.tile as u32);
        rec.scope("prims.scan_chained", |rec| {
            rec.dispatch(
                &chained.kernel,
                groups,
                &[input, input, output, output, state, total, counts],
                &push,
            )
        });
        true
    }

    #[allow(
        clippy::too_many_arguments,
        reason = "one level of the recursion, named like the bindings"
    )]
    fn record_level(
        &self,
        rec: &mut Recorder,
        level: usize,
        input: &dyn BufferArg,
        output: &dyn BufferArg,
        n: usize,
        count: Option<GpuCount>,
        op: ScanOp,
        scratch: &ScanScratch,
        total: &Buffer<u32>,
    ) {
        let (counts, count_index, count_mul, count_div) = count_binding(count, total);
        let (reduce, downsweep) = if level == 0 {
            (&self.first_reduce, &self.first_downsweep)
        } else {
            (&self.reduce, &self.downsweep)
        };
        let tile = self.tile(level);
        let groups = rec.groups_1d(n.max(1) as u64, tile as u32);
        let inclusive = u32::from(op == ScanOp::Inclusive);
        let push = |has_carry| DownsweepPush {
            capacity: n as u32,
            has_carry,
            inclusive,
            count_index,
            count_mul,
            count_div,
        };
        if n <= tile {
            rec.scope("prims.scan_downsweep", |rec| {
                rec.dispatch(
                    downsweep,
                    groups,
                    &[input, input, output, output, input, total, counts],
                    &push(0),
                )
            });
            return;
        }
        let partials = &scratch.levels[level];
        let tiles = n.div_ceil(tile);
        let reduce_push = ReducePush {
            capacity: n as u32,
            count_index,
            count_mul,
            count_div,
        };
        rec.scope("prims.scan_reduce", |rec| {
            rec.dispatch(
                reduce,
                groups,
                &[input, input, partials, counts],
                &reduce_push,
            )
        });
        rec.compute_to_compute();
        // The tile sums of a GPU count c number ceil(c · mul / (div · tile)).
        let upper = count.map(|c| GpuCount {
            div: c.div * tile as u32,
            ..c
        });
        let level_total = &scratch.level_totals[level];
        self.record_level(
            rec,
            level + 1,
            partials,
            partials,
            tiles,
            upper,
            ScanOp::Exclusive,
            scratch,
            level_total,
        );
        rec.compute_to_compute();
        rec.scope("prims.scan_downsweep", |rec| {
            rec.dispatch(
                downsweep,
                groups,
                &[input, input, output, output, partials, total, counts],
                &push(1),
            )
        });
    }

    /// Convenience: scans `input` (u32 elements) on the GPU; returns the scan and the total.
    pub fn run_u32(&self, ctx: &Context, input: &[u32], op: ScanOp) -> Result<(Vec<u32>, u32)> {
        assert_eq!(self.input, ScanInput::U32, "run_u32 on a flag scan");
        let data = Buffer::from_slice(ctx, "prims.scan.input", input)?;
        self.run(ctx, &data, input.len(), op)
    }

    /// Convenience: exclusive offsets of 0/1 byte flags and their total.
    pub fn run_flags(&self, ctx: &Context, flags: &[u8]) -> Result<(Vec<u32>, u32)> {
        assert_eq!(self.input, ScanInput::Flags, "run_flags on a u32 scan");
        let data = Buffer::from_slice(ctx, "prims.flag_scan.flags", flags)?;
        self.run(ctx, &data, flags.len(), ScanOp::Exclusive)
    }

    fn run(
        &self,
        ctx: &Context,
        input: &dyn BufferArg,
        n: usize,
        op: ScanOp,
    ) -> Result<(Vec<u32>, u32)> {
        let output = Buffer::<u32>::new(ctx, "prims.scan.output", n)?;
        let scratch = self.scratch(ctx, n)?;
        let mut rec = Recorder::new(ctx)?;
        self.record(&mut rec, input, &output, n, op, &scratch);
        rec.compute_to_transfer();
        rec.submit_and_wait()?;
        Ok((output.download()?, scratch.total.download()?[0]))
    }
}

/// CPU twin of the u32 scan: prefix sums modulo 2^32 and the total.
pub fn scan_cpu(input: &[u32], op: ScanOp) -> (Vec<u32>, u32) {
    let mut sum = 0u32;
    let out = input
        .iter()
        .map(|&x| {
            let before = sum;
            sum = sum.wrapping_add(x);
            if op == ScanOp::Inclusive {
                sum
            } else {
                before
            }
        })
        .collect();
    (out, sum)
}

/// CPU twin of the flag scan: exclusive offsets of 0/1 flags and the number of ones.
pub fn flag_scan_cpu(flags: &[u8]) -> (Vec<u32>, u32) {
    assert!(flags.iter().all(|&f| f <= 1), "flags must be 0 or 1");
    let mut sum = 0u32;
    let out = flags
        .iter()
        .map(|&f| {
            let before = sum;
            sum += u32::from(f);
            before
        })
        .collect();
    (out, sum)
}
