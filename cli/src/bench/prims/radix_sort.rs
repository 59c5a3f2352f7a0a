//! `radix_sort_kv_*`: [`vkrt::prims::radix_sort::RadixSort`] at every measured digit width
//! and ranking, beside the CPU's `sort_unstable_by_key` of the same pairs.

use vkrt::gpu::{Buffer, Context, Recorder, Result};
use vkrt::prims::radix_sort::{RadixSort, Ranking, DEFAULT_BITS_PER_PASS};
use vkrt::prims::PrimConfig;

use super::PrimTiming;
use crate::bench::best_ms;

/// The keys a variant sorts.
#[derive(Clone, Copy, PartialEq, Eq)]
enum KeyKind {
    U32,
    F32,
}

/// The digit widths `bench` measures.
pub const BENCH_BITS: [u32; 6] = [4, 5, 6, 8, 11, 12];

/// Splitmix64: benchmark data without a dependency.
fn splitmix(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Times the sort of `n` random full-range keys with values: `radix_sort_kv_u32` and
/// `radix_sort_kv_f32` with the default digit width, `radix_sort_kv_u32.bits{b}` for every
/// measured width (default ranking) and `….bits{b}.match` / `.counters` with the other, and `cpu_sort_unstable_by_key` — `slice::sort_unstable_by_key` of the
/// same (key, value) pairs on one CPU core, whose `gpu_ms` is CPU milliseconds.
///
/// `min_bytes` is what the passes must at least move: keys and values read and written
/// once per pass (16 n bytes per pass); for the CPU entry, one read and write of the pairs.
/// One warm-up run first (fresh memory costs page faults on lavapipe), then best of `reps`.
pub fn bench(ctx: &Context, n: usize, reps: u32) -> Result<Vec<PrimTiming>> {
    let cfg = PrimConfig::default_for(ctx);
    let mut state = 0x5EED;
    let keys: Vec<u32> = (0..n).map(|_| splitmix(&mut state) as u32).collect();
    let floats: Vec<f32> = (0..n)
        .map(|_| {
            let x = (splitmix(&mut state) >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0;
            x * 1e3
        })
        .collect();
    let values: Vec<u32> = (0..n as u32).collect();

    let mut variants: Vec<(String, RadixSort, KeyKind)> = Vec::new();
    for bits in BENCH_BITS {
        let sort = RadixSort::new(ctx, cfg, bits)?;
        let default = sort.ranking();
        variants.push((format!("radix_sort_kv_u32.bits{bits}"), sort, KeyKind::U32));
        for other in Ranking::ALL.into_iter().filter(|&r| r != default) {
            if let Ok(sort) = RadixSort::with_ranking(ctx, cfg, bits, other) {
                let name = format!(
                    "radix_sort_kv_u32.bits{bits}.{}",
                    format!("{other:?}").to_lowercase()
                );
                variants.push((name, sort, KeyKind::U32));
            }
        }
    }
    variants.push((
        "radix_sort_kv_f32".into(),
        RadixSort::new(ctx, cfg, DEFAULT_BITS_PER_PASS)?,
        KeyKind::F32,
    ));

    let key_src = Buffer::from_slice(ctx, "bench.radix.keys_src", &keys)?;
    let float_src = Buffer::from_slice(ctx, "bench.radix.floats_src", &floats)?;
    let value_src = Buffer::from_slice(ctx, "bench.radix.values_src", &values)?;
    let key_buf = Buffer::<u32>::new(ctx, "bench.radix.keys", n)?;
    let float_buf = Buffer::<f32>::new(ctx, "bench.radix.floats", n)?;
    let value_buf = Buffer::<u32>::new(ctx, "bench.radix.values", n)?;
    let scratches = variants
        .iter()
        .map(|(_, s, _)| s.scratch(ctx, n))
        .collect::<Result<Vec<_>>>()?;
    // Round-robin: every round (one submission) runs every variant once, so a burst of
    // load on the machine slows one round of all variants rather than all rounds of one.
    // Round 0 is the warm-up (first touch of the scratch memory).
    let mut best = vec![f64::INFINITY; variants.len()];
    for round in 0..=reps {
        let mut rec = Recorder::new(ctx)?;
        for ((name, sort, kind), scratch) in variants.iter().zip(&scratches) {
            if *kind == KeyKind::F32 {
                rec.copy(&float_src, &float_buf, n);
            } else {
                rec.copy(&key_src, &key_buf, n);
            }
            rec.copy(&value_src, &value_buf, n);
            rec.transfer_to_compute();
            rec.scope(name, |rec| match kind {
                KeyKind::U32 => sort.record(rec, &key_buf, &value_buf, n, 32, scratch),
                KeyKind::F32 => sort.record_f32(rec, &float_buf, &value_buf, n, scratch),
            });
            rec.compute_to_transfer();
        }
        let profile = rec.submit_and_wait()?;
        if round > 0 {
            for ((name, _, _), best) in variants.iter().zip(&mut best) {
                *best = best.min(best_ms(&profile, name));
            }
        }
    }
    let mut timings: Vec<PrimTiming> = variants
        .iter()
        .zip(best)
        .map(|((name, sort, _), ms)| PrimTiming {
            prim: name.clone(),
            n: n as u64,
            gpu_ms: ms,
            min_bytes: 16 * n as u64 * u64::from(sort.passes(32)),
        })
        .collect();

    // The default width is one of the measured ones: report it under the plain name too.
    let default = timings
        .iter()
        .find(|t| t.prim == format!("radix_sort_kv_u32.bits{DEFAULT_BITS_PER_PASS}"));
    if let Some(t) = default.cloned() {
        timings.push(PrimTiming {
            prim: "radix_sort_kv_u32".into(),
            ..t
        });
    }

    let pairs: Vec<(u32, u32)> = keys.iter().copied().zip(values.iter().copied()).collect();
    let mut best = f64::INFINITY;
    for _ in 0..=reps {
        let mut work = pairs.clone();
        let t = std::time::Instant::now();
        work.sort_unstable_by_key(|p| p.0);
        best = best.min(t.elapsed().as_secs_f64() * 1e3);
        std::hint::black_box(&work);
    }
    timings.push(PrimTiming {
        prim: "cpu_sort_unstable_by_key".into(),
        n: n as u64,
        gpu_ms: best,
        min_bytes: 16 * n as u64,
    });
    Ok(timings)
}
