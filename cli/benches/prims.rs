//! Criterion front end for the GPU primitive benchmarks: the measured time is GPU time from
//! timestamp queries (`iter_custom`), not host wall time. `vkrt bench prims` prints the
//! same timings against the copy baselines of the same bytes.
//!
//! `cargo bench --bench prims` (VKRT_BENCH_N sets n, default 2^20).

use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use vkrt::gpu::{Context, ContextOptions};

fn prims(c: &mut Criterion) {
    let ctx = Context::new(&ContextOptions::default()).expect("a Vulkan device");
    let n: usize = std::env::var("VKRT_BENCH_N")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1 << 20);
    let mut group = c.benchmark_group(format!("prims.n{n}"));
    group.sample_size(10);
    for (name, bench) in vkrt_cli::bench::prims::prim_benches() {
        // One bench call times several variants; report each as its own criterion id.
        let variants = bench(&ctx, n, 1).expect("bench run");
        for v in variants {
            let prim = v.prim.clone();
            group.bench_function(format!("{name}/{prim}"), |b| {
                b.iter_custom(|iters| {
                    let mut total = Duration::ZERO;
                    for _ in 0..iters {
                        let runs = bench(&ctx, n, 1).expect("bench run");
                        let ms = runs
                            .iter()
                            .find(|r| r.prim == prim)
                            .map_or(0.0, |r| r.gpu_ms);
                        total += Duration::from_secs_f64(ms / 1e3);
                    }
                    total
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, prims);
criterion_main!(benches);
