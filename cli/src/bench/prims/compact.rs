//! `compact_1_array` and `compact_4_arrays`: [`vkrt::prims::compact::Compact`] moving one
//! and four SoA arrays.

use vkrt::gpu::{Buffer, BufferArg, Context, Recorder, Result};
use vkrt::prims::compact::{Compact, MAX_ARRAYS};
use vkrt::prims::PrimConfig;

use super::PrimTiming;
use crate::bench::{best_ms, rep_scope};

/// Times the compaction of one and of four SoA arrays at `n` elements (half the flags set).
pub fn bench(ctx: &Context, n: usize, reps: u32) -> Result<Vec<PrimTiming>> {
    let compact = Compact::new(ctx, PrimConfig::default_for(ctx))?;
    let scratch = compact.scratch(ctx, n)?;
    let flags = Buffer::<u8>::new(ctx, "bench.compact.flags", n)?;
    let ins = (0..MAX_ARRAYS)
        .map(|_| Buffer::<u32>::new(ctx, "bench.compact.in", n))
        .collect::<Result<Vec<_>>>()?;
    let outs = (0..MAX_ARRAYS)
        .map(|_| Buffer::<u32>::new(ctx, "bench.compact.out", n))
        .collect::<Result<Vec<_>>>()?;
    let mut rec = Recorder::new(ctx)?;
    rec.fill(&flags, 0x0001_0001);
    for b in ins.iter().chain(&outs) {
        rec.fill(b, 7);
    }
    rec.transfer_to_compute();
    let variants = [
        ("compact_1_array", 1usize),
        ("compact_4_arrays", MAX_ARRAYS),
    ];
    for rep in 0..=reps {
        for (name, k) in variants {
            let i: Vec<&dyn BufferArg> = ins[..k].iter().map(|b| b as &dyn BufferArg).collect();
            let o: Vec<&dyn BufferArg> = outs[..k].iter().map(|b| b as &dyn BufferArg).collect();
            rec.scope(&rep_scope(rep, name), |rec| {
                compact.record(rec, &flags, n, &i, &o, &scratch)
            });
            rec.compute_to_compute();
        }
    }
    let profile = rec.submit_and_wait()?;
    Ok(variants
        .iter()
        .map(|&(name, k)| PrimTiming {
            prim: name.to_string(),
            n: n as u64,
            gpu_ms: best_ms(&profile, name),
            // flags read, offsets written and read, k arrays read and half written
            min_bytes: n as u64 * (1 + 4 + 4 * k as u64) + 2 * n as u64 * k as u64,
        })
        .collect())
}
