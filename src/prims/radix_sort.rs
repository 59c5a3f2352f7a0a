//! Stable key-value radix sort of u32 keys (or f32 keys) with u32 values, on the GPU.
//!
//! LSD radix sort, `bits_per_pass` key bits per pass, each pass reduce-then-scan:
//!
//! 1. `prims.radix_histogram` counts the digits of every tile of `tile()` elements and
//!    writes the counts digit-major, `counts[digit][tile]`;
//! 2. the multi-level [`Scan`] scans that table exclusively into `offsets`: the first
//!    output position of every (digit, tile), in key order and then tile order;
//! 3. `prims.radix_scatter` re-reads its tile and writes every element to
//!    `offsets[digit][tile]` + its rank among the tile's elements of that digit.
//!
//! Keys and values ping-pong between the caller's buffers and the scratch; after an odd
//! number of passes `prims.radix_copy` moves them back. No workgroup ever waits for another
//! (lavapipe runs a thread's workgroups one after another, so a single-pass "Onesweep" with
//! decoupled look-back could hang); the price is that every pass reads the keys twice.
//!
//! **Stable ranking**, three variants ([`Ranking`]); in all of them the output is a
//! function of the input alone — not of timing, schedule or subgroup size — and equal to the
//! CPU twin's:
//!
//! - `Runs` (`glsl/prims/radix_runs.comp`, the default on CPU devices): a tile is one
//!   invocation's run of [`RUN_LENGTH`] elements, and that invocation walks it in order on
//!   its own, like one thread of a CPU radix sort: the histogram kernel counts the run's
//!   digits in the run's own column of the count table in device memory, the scatter hands
//!   out the scanned positions from that column and advances them in place. No shared
//!   memory, barrier, subgroup operation or atomic; per element one counter load and store
//!   and the two stores, and the run is read 32 bytes at a time. Its count table is in
//!   device memory, so it takes digits up to 12 bits.
//! - `Counters` (`glsl/prims/radix_scatter.comp`): tiles of a workgroup; each invocation owns
//!   a contiguous run of the tile and counts its digits in its own column of shared counters
//!   `ctr[digit][invocation]`; one exclusive scan of the counters in digit-major order gives
//!   each (digit, invocation) the tile position of its first element, and a second walk over
//!   the run hands positions out in order (the counting approach of CUB's block radix rank).
//!   2^bits × workgroup counters, so 8-bit digits get 16-invocation workgroups in 32 KiB of
//!   shared memory (17 KiB used; 32 invocations would need 33 KiB).
//! - `Match` (same file, the default on GPUs): each subgroup walks a contiguous chunk of the
//!   tile in rounds of one element per lane; the lanes holding the same digit find each other
//!   with one ballot per digit bit (the warp-level "match" of Onesweep and multisplit); a
//!   lane's rank is its peers on lower lanes plus the subgroup's running count of that digit,
//!   which the round's last peer advances. Several subgroups first count their chunks, and
//!   the counts are scanned per digit in subgroup order. (workgroup / 4) × 2^bits words of
//!   shared memory. Every subgroup runs the same number of rounds: Mesa 25.0 lavapipe takes
//!   `subgroupBarrier()` for a workgroup barrier, and per-subgroup round counts lost whole
//!   subgroups there (glsl/gpu/subgroup_barrier_probe.comp).
//!
//! On lavapipe a barrier is a coroutine switch that saves the subgroup's registers, and
//! every ballot and lane-varying memory access is a loop over the lanes: the tile rankings
//! spend most of their time ranking, `Runs` only what each element must cost. Measured at
//! 2^24 (table below) `Runs` is 1.6–1.8× faster than `Counters` and 2.5× faster than
//! `Match` on Mesa 22.3; on Mesa 25.0 (8-bit digits, one run) `Runs` 0.67 s, `Counters`
//! 0.81 s, `Match` 3.07 s (its subgroup barriers are coroutine switches there). On a GPU the lanes of a subgroup would read runs 16 KiB apart, uncoalesced, and
//! ballots are single instructions: [`Ranking::preferred`] picks `Match` there (a reasoned
//! choice, not measured here) and [`RadixSort::with_ranking`] overrides.
//!
//! **Tiles.** `Runs`: one run per invocation, [`RUNS_WORKGROUP`] invocations per workgroup;
//! run lengths of 1024 to 8192 measured alike within the noise at 2^24 (8-bit digits:
//! 720–910 ms), 4096 keeps the count table at n / 16 entries. `Counters` and `Match`: the
//! scatter's workgroup is `cfg.workgroup_size`, halved until the ranking's shared memory
//! fits the device. A tile is that workgroup times `max(cfg.items_per_invocation, min_tile
//! / workgroup)` elements with `min_tile = max(8192, 32 × 2^bits)`: the count table (2^bits
//! rows of n / tile) stays under n / 32 entries, and per-tile work (zeroing and scanning
//! counters) stays small per element. The histogram runs with `cfg.workgroup_size` over the
//! same tiles. A tile whose keys all have the same digit in a pass (sorted runs, the zero top
//! bits of small keys) skips the ranking and moves as one contiguous run.
//!
//! **Keys.** `key_bits` says how many low key bits to sort by; higher bits are carried
//! along and ignored (Morton codes: 30). f32 keys are sorted through the order-preserving
//! bit flip — negative floats flip all bits, positive floats flip the sign bit — which the
//! first pass applies as it reads and the last pass undoes as it writes. Under that order
//! -0.0 sorts before +0.0, and ±inf and denormals fall where they belong. NaN is not
//! accepted: [`RadixSort::sort_f32`] returns an error, and NaN keys given to
//! [`RadixSort::record_f32`] land wherever their bits put them (beyond ±inf).
//!
//! **Bits per pass**, measured on lavapipe (Mesa 22.3.6, LLVM 15, 2 cores, AVX2, 8-lane
//! subgroups) with `PrimConfig::default_for` (256 × 16), random full-range u32 keys with u32
//! values, n = 2^24: GPU ms of the whole sort, best of 2 rounds, all rows from one run of
//! `vkrt bench prims --only radix --min-n 16777216 --reps 2` (other runs: ±25 %).
//!
//! | bits per pass | passes | Runs | Counters | Match |
//! |---|---|---|---|---|
//! | 4 | 8 | 1171 | 2180 | 3034 |
//! | 5 | 7 | 1063 | 1832 | 2657 |
//! | 6 | 6 | 1046 | 1579 | 2382 |
//! | **8** | 4 | **717** | 1260 | 1917 |
//! | 11 | 3 | 814 | – | – |
//! | 12 | 3 | 873 | – | – |
//!
//! Same run: the f32 sort 586 ms (its keys in ±1000 use few top digits, so its scatters
//! write fewer places at once); `slice::sort_unstable_by_key` of the (key, value) pairs on
//! one core 340 ms; the copy-kernel bound of the 4 passes (keys and values read and written
//! once per pass) ≈ 67 ms, so the sort reaches ≈ 0.09 of it. Per pass (`--profile`): the
//! histogram ≈ 48 ms, the scan of the count table ≈ 5 ms, the scatter ≈ 150 ms. 11 and 12
//! bits save a pass but their count tables cost as much in scans (≈ 30–50 ms per pass) and
//! their scatters write to 2048–4096 places per run.
//!
//! Tried and dropped: the `Runs` scatter counting the next pass's digits as it places each
//! element (an atomic add into the column of the run the element lands in), so that only
//! the first pass needs a histogram. The atomic made each scatter 50–65 ms slower — what
//! the histogram it replaced costs — and the 8-bit sort took 859–1180 ms in one run (three
//! rounds) against 717–910 ms without it.
//!
//! What bounds it on lavapipe: each lane-varying access is a scalar loop trip (≈ 0.6 ns of
//! wall time per trip in the copy kernel, where 8 lanes × 4 components of u64 move 256
//! bytes). A pass must make, per element, two stores to its sorted position and a counter
//! load and store, and the histogram another load and store: ≈ 7 trips per element where
//! the copy of keys and values makes 2, before the cost of scattering to 256 places. That
//! caps any LSD radix sort built of such accesses near 0.25 of the copy-kernel bound here.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};

use super::scan::{GpuCount, Scan, ScanInput, ScanOp, ScanScratch};
use super::PrimConfig;
use crate::gpu::{
    kernels, Buffer, BufferArg, Context, GpuError, Kernel, Recorder, Result, ShaderBlob, Spec,
};

/// The measured default digit width (see the table in the module docs).
pub const DEFAULT_BITS_PER_PASS: u32 = 8;

/// Digit widths the kernels accept: the `Runs` ranking takes up to 12 bits (its count table
/// is in device memory), the shared-memory rankings up to 8.
pub const BITS_RANGE: std::ops::RangeInclusive<u32> = 1..=12;

/// Widest digit of the `Counters` and `Match` rankings (their counters are in shared memory).
const SHARED_MAX_BITS: u32 = 8;

/// A tile holds at least this many elements per digit value, so the count table of a pass
/// (2^bits × n / tile entries) stays under n / 32 and the per-tile work on counters (scans,
/// zeroing) stays small per element.
const MIN_TILE_PER_DIGIT: u32 = 32;

/// Elements a tile holds at least. Measured on lavapipe (`Counters`, 2^22 keys): 6-bit
/// sorts took ≈ 1.7× longer with 1024-element tiles than with 8192, and 8192 to 32768 were
/// alike within the noise.
const MIN_TILE: u32 = 8192;

/// Elements of one invocation's run in the `Runs` ranking (a multiple of 8; see the module
/// docs).
pub const RUN_LENGTH: u32 = 4096;

/// Invocations per workgroup of the `Runs` kernels (at least one subgroup): small, so that
/// even small sorts spread over the device's threads.
pub const RUNS_WORKGROUP: u32 = 32;

/// Push constants of the histogram and scatter kernels (keep in sync with `Push` in
/// glsl/prims/radix_common.glsl).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PassPush {
    n: u32,
    blocks: u32,
    shift: u32,
    digits: u32,
    flags: u32,
}

/// `PassPush::flags`: the first pass of an f32 sort flips keys as it reads them.
const FLIP_IN: u32 = 1;
/// `PassPush::flags`: the last pass of an f32 sort flips keys back as it writes them.
const UNFLIP_OUT: u32 = 2;

/// How keys are ordered.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum KeyKind {
    U32,
    F32,
}

/// How the scatter ranks a tile's elements (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ranking {
    /// Per-invocation digit counters in shared memory over contiguous runs, one workgroup
    /// scan per tile; no subgroup operations. 2^bits × workgroup words of shared memory.
    Counters,
    /// Subgroup ballot "match" per round, running counts per subgroup. (workgroup / 4) ×
    /// 2^bits words of shared memory.
    Match,
    /// Every invocation sorts its own run of the input like one thread of a CPU radix sort
    /// (`glsl/prims/radix_runs.comp`): a column of the count table per run, no shared
    /// memory, barriers or subgroup operations. For CPU devices.
    Runs,
}

impl Ranking {
    /// The ranking `RadixSort::new` tries first on this device: `Runs` on CPU devices
    /// (lavapipe, where it measured 1.6–1.8× faster than `Counters` and 2.5× faster than
    /// `Match`: barriers are coroutine switches and every ballot and lane-varying memory
    /// access is a loop over the lanes there), `Match` on GPUs (where ballots are single
    /// instructions and lanes reading far-apart runs would not coalesce; a reasoned choice,
    /// not measured here).
    pub fn preferred(ctx: &Context) -> Self {
        if ctx.info().device_type == "cpu" {
            Ranking::Runs
        } else {
            Ranking::Match
        }
    }

    /// Widest digit this ranking takes: `Runs` keeps its counters in device memory, the
    /// others in shared memory.
    fn max_bits(self) -> u32 {
        match self {
            Ranking::Runs => *BITS_RANGE.end(),
            Ranking::Counters | Ranking::Match => SHARED_MAX_BITS,
        }
    }

    /// Every ranking, for tests and benchmarks.
    pub const ALL: [Ranking; 3] = [Ranking::Counters, Ranking::Match, Ranking::Runs];

    /// Shared memory of the scatter kernel in bytes, for a workgroup of `wg` invocations.
    fn shared_bytes(self, wg: u32, radix: u32) -> u32 {
        // tile_digit, and the workgroup scan's subgroup sums and total (subgroup_scan.glsl).
        let common = 4 + 4 * (wg / 4 + 1);
        match self {
            Ranking::Counters => common + 4 * radix * wg + 4 * radix,
            Ranking::Match => common + 4 * (wg / 4) * radix,
            Ranking::Runs => 0,
        }
    }
}

/// Indirect dispatch arguments that run a recorded sort ([`RadixSort::record_gated`]) or
/// skip it, as a kernel before it decides on the GPU.
pub struct SortGate<'a> {
    /// The buffer of arguments.
    pub args: &'a Buffer<u32>,
    /// Byte offset of the tile kernels' grid (three u32: zeros, or [`RadixSort::grids`]'s
    /// first).
    pub tiles: u64,
    /// Byte offset of the final copy's grid (zeros, or [`RadixSort::grids`]'s second).
    pub copy: u64,
    /// Index of the word holding how many entries of the count table each pass scans: 0,
    /// or at least [`RadixSort::table_len`].
    pub table: u32,
}

/// A radix sort of one digit width, with its kernels compiled.
pub struct RadixSort {
    cfg: PrimConfig,
    bits: u32,
    ranking: Ranking,
    tile: u32,
    scatter_workgroup: u32,
    histogram: Arc<Kernel>,
    scatter: Arc<Kernel>,
    scatter_blob: &'static ShaderBlob,
    copy: Arc<Kernel>,
    scan: Scan,
}

/// Scratch for sorts of up to `max_n` elements: the ping-pong keys and values, the count
/// table and its scan.
pub struct RadixScratch {
    max_n: usize,
    keys: Buffer<u32>,
    values: Buffer<u32>,
    counts: Buffer<u32>,
    offsets: Buffer<u32>,
    scan: ScanScratch,
}

impl RadixSort {
    /// A sort of `bits_per_pass`-bit digits ([`BITS_RANGE`]; [`DEFAULT_BITS_PER_PASS`] is
    /// measured best) with the workgroup shape `cfg`, ranking with [`Ranking::preferred`]
    /// where it can and with the first other ranking of [`Ranking::ALL`] that can otherwise.
    pub fn new(ctx: &Context, cfg: PrimConfig, bits_per_pass: u32) -> Result<Self> {
        let preferred = Ranking::preferred(ctx);
        Ranking::ALL.into_iter().filter(|&r| r != preferred).fold(
            Self::with_ranking(ctx, cfg, bits_per_pass, preferred),
            |sort, other| sort.or_else(|_| Self::with_ranking(ctx, cfg, bits_per_pass, other)),
        )
    }

    /// A sort with the given ranking; an error if its shared memory cannot fit with at
    /// least one subgroup per workgroup.
    pub fn with_ranking(
        ctx: &Context,
        cfg: PrimConfig,
        bits_per_pass: u32,
        ranking: Ranking,
    ) -> Result<Self> {
        let err = |reason: String| GpuError::Kernel {
            kernel: "prims.radix_sort",
            reason,
        };
        let max_bits = ranking.max_bits();
        if !(*BITS_RANGE.start()..=max_bits).contains(&bits_per_pass) {
            return Err(err(format!(
                "{bits_per_pass} bits per pass; the {ranking:?} ranking takes 1 to {max_bits}"
            )));
        }
        let info = ctx.info();
        let lanes = info.max_subgroup_size.max(info.subgroup_size);
        let wg = cfg.workgroup_size;
        if !wg.is_power_of_two() || wg % lanes != 0 {
            return Err(err(format!(
                "workgroup size {wg} must be a power of two and a multiple of the subgroup size {lanes}"
            )));
        }
        let radix = 1u32 << bits_per_pass;
        if ranking == Ranking::Runs {
            return Self::with_runs(ctx, cfg, bits_per_pass, lanes);
        }
        let mut scatter_workgroup = wg;
        while ranking.shared_bytes(scatter_workgroup, radix) > info.max_shared_memory
            && scatter_workgroup > lanes
        {
            scatter_workgroup /= 2;
        }
        if ranking.shared_bytes(scatter_workgroup, radix) > info.max_shared_memory {
            return Err(err(format!(
                "{ranking:?} ranking of {bits_per_pass}-bit digits with {lanes}-lane subgroups needs {} bytes of shared memory, over this device's {}",
                ranking.shared_bytes(scatter_workgroup, radix),
                info.max_shared_memory
            )));
        }
        let min_tile = MIN_TILE.max(MIN_TILE_PER_DIGIT * radix);
        let mut per_invocation = cfg
            .items_per_invocation
            .max(min_tile.div_ceil(scatter_workgroup))
            .max(1);
        if ranking == Ranking::Counters {
            per_invocation = per_invocation.next_multiple_of(4); // runs load 16 bytes at a time
        }
        let tile = scatter_workgroup * per_invocation;
        let common = |w: u32| Spec::new().workgroup(w).u32(1, bits_per_pass).u32(2, tile);
        let scatter: &'static ShaderBlob = match ranking {
            Ranking::Counters => &kernels::PRIMS_RADIX_SCATTER_COUNTERS,
            _ => &kernels::PRIMS_RADIX_SCATTER_MATCH,
        };
        Ok(Self {
            cfg,
            bits: bits_per_pass,
            ranking,
            tile,
            scatter_workgroup,
            histogram: ctx.kernel(&kernels::PRIMS_RADIX_HISTOGRAM, &common(wg))?,
            scatter: ctx.kernel(scatter, &common(scatter_workgroup))?,
            scatter_blob: scatter,
            copy: ctx.kernel(&kernels::PRIMS_RADIX_COPY, &Spec::new().workgroup(wg))?,
            scan: Scan::new(ctx, cfg, ScanInput::U32)?,
        })
    }

    /// The `Runs` ranking: a tile is one invocation's run, both kernels have one invocation
    /// per run.
    fn with_runs(ctx: &Context, cfg: PrimConfig, bits_per_pass: u32, lanes: u32) -> Result<Self> {
        let run = RUN_LENGTH;
        let wg = lanes.max(RUNS_WORKGROUP);
        // The digit width comes with each pass (`PassPush::digits`): no BITS constant here.
        let spec = Spec::new().workgroup(wg).u32(2, run);
        Ok(Self {
            cfg,
            bits: bits_per_pass,
            ranking: Ranking::Runs,
            tile: run,
            scatter_workgroup: wg,
            histogram: ctx.kernel(&kernels::PRIMS_RADIX_RUNS_HISTOGRAM, &spec)?,
            scatter: ctx.kernel(&kernels::PRIMS_RADIX_RUNS_SCATTER, &spec)?,
            scatter_blob: &kernels::PRIMS_RADIX_RUNS_SCATTER,
            copy: ctx.kernel(
                &kernels::PRIMS_RADIX_COPY,
                &Spec::new().workgroup(cfg.workgroup_size),
            )?,
            scan: Scan::new(ctx, cfg, ScanInput::U32)?,
        })
    }

    /// The ranking this sort uses (the preferred one, or the fallback [`RadixSort::new`]
    /// took).
    pub fn ranking(&self) -> Ranking {
        self.ranking
    }

    /// The workgroup shape it was compiled for.
    pub fn config(&self) -> PrimConfig {
        self.cfg
    }

    /// Key bits sorted per pass (the digit width).
    pub fn bits_per_pass(&self) -> u32 {
        self.bits
    }

    /// Elements per tile: the block of the count table.
    pub fn tile(&self) -> usize {
        self.tile as usize
    }

    /// Invocations per workgroup of the scatter kernel (after the shared-memory cap).
    pub fn scatter_workgroup_size(&self) -> u32 {
        self.scatter_workgroup
    }

    /// Passes for a sort by `key_bits` key bits.
    pub fn passes(&self, key_bits: u32) -> u32 {
        key_bits.div_ceil(self.bits)
    }

    /// Bytes of [`RadixSort::scratch`] for `max_n` elements (without allocating them).
    pub fn scratch_bytes(&self, max_n: usize) -> u64 {
        let table = self.table_len(max_n).max(1);
        4 * (2 * max_n.max(1) + 2 * table) as u64 + self.scan.scratch_bytes(table)
    }

    /// Scratch for sorts of up to `max_n` elements.
    pub fn scratch(&self, ctx: &Context, max_n: usize) -> Result<RadixScratch> {
        let table = self.table_len(max_n).max(1);
        Ok(RadixScratch {
            max_n,
            keys: Buffer::new(ctx, "prims.radix_sort.keys", max_n)?,
            values: Buffer::new(ctx, "prims.radix_sort.values", max_n)?,
            counts: Buffer::new(ctx, "prims.radix_sort.counts", table)?,
            offsets: Buffer::new(ctx, "prims.radix_sort.offsets", table)?,
            scan: self.scan.scratch(ctx, table)?,
        })
    }

    /// Records a stable sort of the first `n` `keys` and `values` by the low `key_bits`
    /// bits of the keys (0 to 32), in place. Orders its own passes; the caller orders what
    /// comes before (writes of keys and values) and after (the result is written by
    /// kernels, so a `compute_to_*` barrier).
    pub fn record(
        &self,
        rec: &mut Recorder,
        keys: &Buffer<u32>,
        values: &Buffer<u32>,
        n: usize,
        key_bits: u32,
        scratch: &RadixScratch,
    ) {
        self.check(keys.len(), values.len(), n, scratch);
        self.record_passes(rec, keys, values, n, key_bits, KeyKind::U32, scratch, None);
    }

    /// Like [`RadixSort::record`], switched on or off on the GPU by `gate`: its tile kernels
    /// and its copy take their grids from the gate's indirect arguments, and its scans of the
    /// count table their length from the gate's table word, which a kernel before it writes
    /// (ordered by [`Recorder::compute_to_indirect`]) as zeros, for no sort, or as
    /// [`RadixSort::grids`] and [`RadixSort::table_len`].
    #[allow(
        clippy::too_many_arguments,
        reason = "record's arguments plus the gate"
    )]
    pub fn record_gated(
        &self,
        rec: &mut Recorder,
        keys: &Buffer<u32>,
        values: &Buffer<u32>,
        n: usize,
        key_bits: u32,
        scratch: &RadixScratch,
        gate: &SortGate,
    ) {
        self.check(keys.len(), values.len(), n, scratch);
        let kind = KeyKind::U32;
        self.record_passes(rec, keys, values, n, key_bits, kind, scratch, Some(gate));
    }

    /// Entries of the largest count table a pass over `n` elements scans.
    pub fn table_len(&self, n: usize) -> usize {
        n.div_ceil(self.tile as usize) << self.bits
    }

    /// The workgroup grids of a sort of `n` elements: its tile kernels' (histogram and
    /// scatter), then its final copy's (recorded after an odd number of passes), as a
    /// [`SortGate`]'s arguments hold them to let the sort run.
    pub fn grids(&self, rec: &Recorder, n: usize) -> [[u32; 3]; 2] {
        let blocks = n.div_ceil(self.tile as usize);
        let per_group = if self.ranking == Ranking::Runs {
            self.scatter_workgroup // an invocation per run
        } else {
            1 // a workgroup per tile
        };
        [
            rec.groups_1d(blocks as u64, per_group),
            rec.groups_1d(n.div_ceil(4) as u64, self.copy.invocations()),
        ]
    }

    /// Records a stable sort of the first `n` f32 `keys` (NaN-free) and their `values` in
    /// place, in float order with -0.0 before +0.0. Ordering as in [`RadixSort::record`].
    pub fn record_f32(
        &self,
        rec: &mut Recorder,
        keys: &Buffer<f32>,
        values: &Buffer<u32>,
        n: usize,
        scratch: &RadixScratch,
    ) {
        self.check(keys.len(), values.len(), n, scratch);
        self.record_passes(rec, keys, values, n, 32, KeyKind::F32, scratch, None);
    }

    fn check(&self, keys: usize, values: usize, n: usize, scratch: &RadixScratch) {
        assert!(
            n <= keys && n <= values,
            "radix sort of {n} elements with {keys} keys and {values} values"
        );
        assert!(
            n <= scratch.max_n,
            "radix sort of {n} elements with scratch sized for {}",
            scratch.max_n
        );
    }

    #[allow(
        clippy::too_many_arguments,
        reason = "record's arguments plus the key kind and the gate"
    )]
    fn record_passes(
        &self,
        rec: &mut Recorder,
        keys: &dyn BufferArg,
        values: &dyn BufferArg,
        n: usize,
        key_bits: u32,
        kind: KeyKind,
        scratch: &RadixScratch,
        gate: Option<&SortGate>,
    ) {
        assert!(key_bits <= 32, "radix sort by {key_bits} key bits");
        let passes = self.passes(key_bits);
        if n <= 1 || passes == 0 {
            return;
        }
        let blocks = n.div_ceil(self.tile as usize);
        let [groups, copy_groups] = self.grids(rec, n);
        // A tile kernel's dispatch: direct, or from the gate's tile grid.
        let tiles =
            |rec: &mut Recorder, kernel: &Kernel, b: &[&dyn BufferArg], push: &PassPush| match gate
            {
                Some(g) => rec.dispatch_indirect(kernel, g.args, g.tiles, b, push),
                None => rec.dispatch(kernel, groups, b, push),
            };
        rec.scope("prims.radix_sort", |rec| {
            for pass in 0..passes {
                let shift = pass * self.bits;
                let digits = 1u32 << self.bits.min(key_bits - shift);
                let (src, dst): ([&dyn BufferArg; 2], [&dyn BufferArg; 2]) = if pass % 2 == 0 {
                    ([keys, values], [&scratch.keys, &scratch.values])
                } else {
                    ([&scratch.keys, &scratch.values], [keys, values])
                };
                let mut flags = 0;
                if kind == KeyKind::F32 && pass == 0 {
                    flags |= FLIP_IN;
                }
                if kind == KeyKind::F32 && pass == passes - 1 {
                    flags |= UNFLIP_OUT;
                }
                let push = PassPush {
                    n: n as u32,
                    blocks: blocks as u32,
                    shift,
                    digits,
                    flags,
                };
                if pass > 0 {
                    rec.compute_to_compute();
                }
                rec.scope("prims.radix_histogram", |rec| {
                    tiles(
                        rec,
                        &self.histogram,
                        &[src[0], src[0], &scratch.counts],
                        &push,
                    );
                });
                rec.compute_to_compute();
                let table = digits as usize * blocks;
                let (counts, offsets) = (&scratch.counts, &scratch.offsets);
                let op = ScanOp::Exclusive;
                match gate {
                    Some(g) => {
                        let count = GpuCount {
                            counts: g.args,
                            index: g.table,
                            mul: 1,
                            div: 1,
                        };
                        let s = &scratch.scan;
                        self.scan
                            .record_counted(rec, counts, offsets, table, count, op, s);
                    }
                    None => self
                        .scan
                        .record(rec, counts, offsets, table, op, &scratch.scan),
                }
                rec.compute_to_compute();
                rec.scope("prims.radix_scatter", |rec| {
                    // Binding numbers of glsl/prims/radix_scatter.comp (radix_runs.comp's
                    // scatter takes the same); a variant binds a subset.
                    let bindings: Vec<&dyn BufferArg> = self
                        .scatter_blob
                        .bindings
                        .iter()
                        .map(|&b| match b {
                            0 | 1 => src[0],
                            2 | 3 => src[1],
                            4 => &scratch.counts,
                            5 => &scratch.offsets,
                            6 => dst[0],
                            7 => dst[1],
                            _ => unreachable!("radix scatter has no binding {b}"),
                        })
                        .collect();
                    tiles(rec, &self.scatter, &bindings, &push);
                });
            }
            if passes % 2 == 1 {
                rec.compute_to_compute();
                let (k, v): (&dyn BufferArg, &dyn BufferArg) = (&scratch.keys, &scratch.values);
                let b: [&dyn BufferArg; 8] = [k, k, v, v, keys, keys, values, values];
                rec.scope("prims.radix_copy", |rec| match gate {
                    Some(g) => rec.dispatch_indirect(&self.copy, g.args, g.copy, &b, &(n as u32)),
                    None => rec.dispatch(&self.copy, copy_groups, &b, &(n as u32)),
                });
            }
        });
    }

    /// Convenience: sorts `keys` (all 32 bits) and their `values` on the GPU, stably.
    pub fn sort_u32(
        &self,
        ctx: &Context,
        keys: &[u32],
        values: &[u32],
    ) -> Result<(Vec<u32>, Vec<u32>)> {
        check_pairs(keys.len(), values.len())?;
        let n = keys.len();
        let key_buf = Buffer::from_slice(ctx, "prims.radix_sort.in_keys", keys)?;
        let value_buf = Buffer::from_slice(ctx, "prims.radix_sort.in_values", values)?;
        let scratch = self.scratch(ctx, n)?;
        let mut rec = Recorder::new(ctx)?;
        self.record(&mut rec, &key_buf, &value_buf, n, 32, &scratch);
        rec.compute_to_transfer();
        rec.submit_and_wait()?;
        Ok((key_buf.download()?, value_buf.download()?))
    }

    /// Convenience: sorts f32 `keys` and their `values` on the GPU, stably, in float order
    /// with -0.0 before +0.0. A NaN key is an error.
    pub fn sort_f32(
        &self,
        ctx: &Context,
        keys: &[f32],
        values: &[u32],
    ) -> Result<(Vec<f32>, Vec<u32>)> {
        check_pairs(keys.len(), values.len())?;
        check_no_nan(keys)?;
        let n = keys.len();
        let key_buf = Buffer::from_slice(ctx, "prims.radix_sort.in_keys", keys)?;
        let value_buf = Buffer::from_slice(ctx, "prims.radix_sort.in_values", values)?;
        let scratch = self.scratch(ctx, n)?;
        let mut rec = Recorder::new(ctx)?;
        self.record_f32(&mut rec, &key_buf, &value_buf, n, &scratch);
        rec.compute_to_transfer();
        rec.submit_and_wait()?;
        Ok((key_buf.download()?, value_buf.download()?))
    }
}

fn check_pairs(keys: usize, values: usize) -> Result<()> {
    if keys != values {
        return Err(GpuError::Usage {
            call: "RadixSort",
            reason: format!("{keys} keys and {values} values: one value per key"),
        });
    }
    Ok(())
}

fn check_no_nan(keys: &[f32]) -> Result<()> {
    match keys.iter().position(|k| k.is_nan()) {
        Some(i) => Err(GpuError::Kernel {
            kernel: "prims.radix_sort",
            reason: format!("key {i} is NaN; f32 keys must be NaN-free"),
        }),
        None => Ok(()),
    }
}

/// f32 bits → a u32 whose unsigned order is the float order: negative floats flip every
/// bit, positive floats the sign bit (so -0.0 < +0.0; NaN-free input). Mirrors
/// `f32_to_ordered` in glsl/prims/radix_common.glsl.
pub fn f32_to_ordered(x: f32) -> u32 {
    let bits = x.to_bits();
    bits ^ (((bits as i32) >> 31) as u32 | 0x8000_0000)
}

/// The inverse of [`f32_to_ordered`].
pub fn ordered_to_f32(key: u32) -> f32 {
    f32::from_bits(key ^ (((!key as i32) >> 31) as u32 | 0x8000_0000))
}

/// CPU twin: a stable LSD radix sort of `keys` (all 32 bits) and `values`, with
/// [`DEFAULT_BITS_PER_PASS`]-bit digits.
pub fn radix_sort_cpu(keys: &[u32], values: &[u32]) -> (Vec<u32>, Vec<u32>) {
    radix_sort_passes_cpu(keys, values, 32, DEFAULT_BITS_PER_PASS)
}

/// CPU twin of the f32 sort: flip, sort, flip back.
pub fn radix_sort_f32_cpu(keys: &[f32], values: &[u32]) -> (Vec<f32>, Vec<u32>) {
    let ordered: Vec<u32> = keys.iter().map(|&k| f32_to_ordered(k)).collect();
    let (sorted, values) = radix_sort_passes_cpu(&ordered, values, 32, DEFAULT_BITS_PER_PASS);
    (sorted.into_iter().map(ordered_to_f32).collect(), values)
}

/// CPU twin of [`RadixSort::record`]: the same passes (digits of `bits_per_pass` bits from
/// the lowest, the last pass cut at `key_bits`), each a histogram, an exclusive scan of it
/// and a stable scatter. Tiles are not simulated: they do not change the output.
#[allow(clippy::needless_range_loop, reason = "reads like the kernels")]
pub fn radix_sort_passes_cpu(
    keys: &[u32],
    values: &[u32],
    key_bits: u32,
    bits_per_pass: u32,
) -> (Vec<u32>, Vec<u32>) {
    assert_eq!(keys.len(), values.len(), "one value per key");
    assert!(key_bits <= 32 && BITS_RANGE.contains(&bits_per_pass));
    let n = keys.len();
    let (mut keys_in, mut values_in) = (keys.to_vec(), values.to_vec());
    let (mut keys_out, mut values_out) = (vec![0; n], vec![0; n]);
    for pass in 0..key_bits.div_ceil(bits_per_pass) {
        let shift = pass * bits_per_pass;
        let digits = 1usize << bits_per_pass.min(key_bits - shift);
        let digit_of = |key: u32| (key >> shift) as usize & (digits - 1);
        // radix_histogram
        let mut offsets = vec![0u32; digits];
        for i in 0..n {
            offsets[digit_of(keys_in[i])] += 1;
        }
        // scan
        let mut sum = 0;
        for d in 0..digits {
            let count = offsets[d];
            offsets[d] = sum;
            sum += count;
        }
        // radix_scatter
        for i in 0..n {
            let d = digit_of(keys_in[i]);
            let dst = offsets[d] as usize;
            offsets[d] += 1;
            keys_out[dst] = keys_in[i];
            values_out[dst] = values_in[i];
        }
        std::mem::swap(&mut keys_in, &mut keys_out);
        std::mem::swap(&mut values_in, &mut values_out);
    }
    (keys_in, values_in)
}
