//! `reduce_*` and `argmin_f32`: the reductions of [`vkrt::prims::reduce::Reduce`].

use vkrt::gpu::{Buffer, Context, Recorder, Result};
use vkrt::prims::reduce::{recommended_config, CostIndex, Reduce};
use vkrt::prims::PrimConfig;

use super::PrimTiming;
use crate::bench::{best_ms, rep_scope};

/// Times the reductions over `n` elements with [`recommended_config`]: the best of `reps`
/// runs after one untimed warm-up. `min_bytes` is the input read plus the result.
pub fn bench(ctx: &Context, n: usize, reps: u32) -> Result<Vec<PrimTiming>> {
    bench_with(ctx, recommended_config(ctx), n, reps)
}

/// [`bench()`] with a given configuration (for tuning).
pub fn bench_with(ctx: &Context, cfg: PrimConfig, n: usize, reps: u32) -> Result<Vec<PrimTiming>> {
    let reduce = Reduce::new(ctx, cfg)?;
    let n32 = u32::try_from(n).expect("bench size fits u32");
    let data_u32: Vec<u32> = (0..n as u32)
        .map(|i| i.wrapping_mul(2_654_435_761))
        .collect();
    let data_f32: Vec<f32> = data_u32
        .iter()
        .map(|&x| (x >> 8) as f32 / (1 << 24) as f32)
        .collect();
    let src_u32 = Buffer::from_slice(ctx, "bench.reduce.u32", &data_u32)?;
    let src_f32 = Buffer::from_slice(ctx, "bench.reduce.f32", &data_f32)?;
    let scratch = Buffer::<u32>::new(ctx, "bench.reduce.scratch", reduce.scratch_len(n))?;
    let out_u32 = Buffer::<u32>::new(ctx, "bench.reduce.out_u32", 1)?;
    let out_f32 = Buffer::<f32>::new(ctx, "bench.reduce.out_f32", 1)?;
    let out_arg = Buffer::<CostIndex>::new(ctx, "bench.reduce.out_argmin", 1)?;

    type Run<'a> = Box<dyn Fn(&mut Recorder) + 'a>;
    let runs: Vec<(&str, u64, Run)> = vec![
        (
            "reduce_sum_u32",
            4,
            Box::new(|rec| reduce.record_sum_u32(rec, &src_u32, n32, &scratch, &out_u32)),
        ),
        (
            "reduce_min_u32",
            4,
            Box::new(|rec| reduce.record_min_u32(rec, &src_u32, n32, &scratch, &out_u32)),
        ),
        (
            "reduce_sum_f32",
            4,
            Box::new(|rec| reduce.record_sum_f32(rec, &src_f32, n32, &scratch, &out_f32)),
        ),
        (
            "reduce_min_f32",
            4,
            Box::new(|rec| reduce.record_min_f32(rec, &src_f32, n32, &scratch, &out_f32)),
        ),
        (
            "argmin_f32",
            8,
            Box::new(|rec| reduce.record_argmin(rec, &src_f32, n32, &scratch, &out_arg)),
        ),
    ];
    let mut rec = Recorder::new(ctx)?;
    for rep in 0..=reps {
        for (name, _, run) in &runs {
            rec.scope(&rep_scope(rep, name), |rec| run(rec));
            rec.compute_to_compute();
        }
    }
    let profile = rec.submit_and_wait()?;
    Ok(runs
        .iter()
        .map(|(name, out_bytes, _)| PrimTiming {
            prim: (*name).to_string(),
            n: n as u64,
            gpu_ms: best_ms(&profile, name),
            min_bytes: 4 * n as u64 + out_bytes,
        })
        .collect())
}
