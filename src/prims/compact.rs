//! Stream compaction: keep the elements whose 0/1 byte flag is set, in order.
//!
//! Flags → exclusive flag scan ([`Scan`] over bytes) → one scatter pass that moves up to
//! four SoA arrays at once (`prims.compact_scatter.{one,two,three,four}`), so the flags and
//! offsets are read once however many arrays move. The count of kept elements stays on the
//! GPU (`CompactScratch::count`) for indirect dispatches downstream.

use std::sync::Arc;

use super::scan::{GpuCount, Scan, ScanInput, ScanOp, ScanScratch};
use super::PrimConfig;
use crate::gpu::{kernels, Buffer, BufferArg, Context, Kernel, Recorder, Result, Spec};

/// Arrays one scatter pass moves at most.
pub const MAX_ARRAYS: usize = 4;

/// Stream compaction of up to [`MAX_ARRAYS`] arrays by one set of flags, with its kernels
/// compiled for one [`PrimConfig`].
pub struct Compact {
    scan: Scan,
    scatter: [Arc<Kernel>; MAX_ARRAYS],
}

/// Scratch for compactions of up to `max_n` elements.
pub struct CompactScratch {
    scan: ScanScratch,
    offsets: Buffer<u32>,
}

impl CompactScratch {
    /// The number of kept elements (one u32), on the GPU.
    pub fn count(&self) -> &Buffer<u32> {
        &self.scan.total
    }
}

impl Compact {
    /// Compiles the flag scan and the scatter kernels for the workgroup shape `cfg`; an
    /// error if the scan rejects `cfg`.
    pub fn new(ctx: &Context, cfg: PrimConfig) -> Result<Self> {
        let spec = Spec::new().workgroup(cfg.workgroup_size);
        let k = |blob| ctx.kernel(blob, &spec);
        Ok(Self {
            scan: Scan::new(ctx, cfg, ScanInput::Flags)?,
            scatter: [
                k(&kernels::PRIMS_COMPACT_SCATTER_ONE)?,
                k(&kernels::PRIMS_COMPACT_SCATTER_TWO)?,
                k(&kernels::PRIMS_COMPACT_SCATTER_THREE)?,
                k(&kernels::PRIMS_COMPACT_SCATTER_FOUR)?,
            ],
        })
    }

    /// Elements per tile of the flag scan: where tile-boundary edge cases lie.
    pub fn tile_elements(&self) -> usize {
        self.scan.tile_elements()
    }

    /// Scratch for compactions of up to `max_n` elements.
    pub fn scratch(&self, ctx: &Context, max_n: usize) -> Result<CompactScratch> {
        Ok(CompactScratch {
            scan: self.scan.scratch(ctx, max_n)?,
            offsets: Buffer::new(ctx, "prims.compact.offsets", max_n)?,
        })
    }

    /// Records the compaction of `n` elements of each array in `inputs` (u32 words, e.g.
    /// f32 bits) into the matching `outputs`, keeping those whose flag is 1.
    pub fn record(
        &self,
        rec: &mut Recorder,
        flags: &dyn BufferArg,
        n: usize,
        inputs: &[&dyn BufferArg],
        outputs: &[&dyn BufferArg],
        scratch: &CompactScratch,
    ) {
        self.record_impl(rec, flags, n, None, inputs, outputs, scratch);
    }

    /// Like [`Compact::record`] over the first `count` elements, a count that lives on the
    /// GPU (at most `capacity`): dispatches are recorded for the capacity, the work follows
    /// the count, so a caller chains compactions without read-backs and without paying for
    /// empty slots.
    #[allow(
        clippy::too_many_arguments,
        reason = "record's arguments plus the count"
    )]
    pub fn record_counted(
        &self,
        rec: &mut Recorder,
        flags: &dyn BufferArg,
        capacity: usize,
        count: GpuCount,
        inputs: &[&dyn BufferArg],
        outputs: &[&dyn BufferArg],
        scratch: &CompactScratch,
    ) {
        self.record_impl(rec, flags, capacity, Some(count), inputs, outputs, scratch);
    }

    #[allow(clippy::too_many_arguments, reason = "the union of both entry points")]
    fn record_impl(
        &self,
        rec: &mut Recorder,
        flags: &dyn BufferArg,
        n: usize,
        count: Option<GpuCount>,
        inputs: &[&dyn BufferArg],
        outputs: &[&dyn BufferArg],
        scratch: &CompactScratch,
    ) {
        assert!(
            !inputs.is_empty() && inputs.len() <= MAX_ARRAYS && inputs.len() == outputs.len(),
            "compaction moves 1 to {MAX_ARRAYS} arrays, with one output per input"
        );
        rec.scope("prims.compact", |rec| {
            match count {
                Some(c) => self.scan.record_counted(
                    rec,
                    flags,
                    &scratch.offsets,
                    n,
                    c,
                    ScanOp::Exclusive,
                    &scratch.scan,
                ),
                None => self.scan.record(
                    rec,
                    flags,
                    &scratch.offsets,
                    n,
                    ScanOp::Exclusive,
                    &scratch.scan,
                ),
            }
            rec.compute_to_compute();
            // Bindings 0..=1, the inputs from 2, the outputs from 6, the counts at 10.
            let mut bindings: Vec<&dyn BufferArg> = vec![flags, &scratch.offsets];
            bindings.extend_from_slice(inputs);
            bindings.extend_from_slice(outputs);
            let push = match count {
                Some(c) => {
                    bindings.push(c.counts);
                    [n as u32, c.index, c.mul, c.div]
                }
                None => {
                    bindings.push(&scratch.offsets);
                    [n as u32, 0, 0, 0]
                }
            };
            let kernel = &self.scatter[inputs.len() - 1];
            let groups = rec.groups_1d(n.div_ceil(4) as u64, kernel.invocations());
            rec.scope("prims.compact_scatter", |rec| {
                rec.dispatch(kernel, groups, &bindings, &push);
            });
        });
    }

    /// Convenience: compacts each of `arrays` by `flags` on the GPU.
    pub fn run(&self, ctx: &Context, flags: &[u8], arrays: &[&[u32]]) -> Result<Vec<Vec<u32>>> {
        let n = flags.len();
        let flag_buf = Buffer::from_slice(ctx, "prims.compact.flags", flags)?;
        let inputs = arrays
            .iter()
            .map(|a| Buffer::from_slice(ctx, "prims.compact.in", a))
            .collect::<Result<Vec<_>>>()?;
        let outputs = arrays
            .iter()
            .map(|_| Buffer::<u32>::new(ctx, "prims.compact.out", n))
            .collect::<Result<Vec<_>>>()?;
        let scratch = self.scratch(ctx, n)?;
        let mut rec = Recorder::new(ctx)?;
        let ins: Vec<&dyn BufferArg> = inputs.iter().map(|b| b as &dyn BufferArg).collect();
        let outs: Vec<&dyn BufferArg> = outputs.iter().map(|b| b as &dyn BufferArg).collect();
        self.record(&mut rec, &flag_buf, n, &ins, &outs, &scratch);
        rec.compute_to_transfer();
        rec.submit_and_wait()?;
        let count = scratch.count().download()?[0] as usize;
        outputs
            .iter()
            .map(|o| {
                o.download().map(|mut v| {
                    v.truncate(count);
                    v
                })
            })
            .collect()
    }
}

/// CPU twin: the elements of each array whose flag is 1, in order.
pub fn compact_cpu(flags: &[u8], arrays: &[&[u32]]) -> Vec<Vec<u32>> {
    arrays
        .iter()
        .map(|a| {
            a.iter()
                .zip(flags)
                .filter(|(_, &f)| f != 0)
                .map(|(&x, _)| x)
                .collect()
        })
        .collect()
}
