//! The GPU primitives measured against the copy baselines of `vkrt bench` (benchmarks, run
//! by hand): the radix sort's digit widths and the reductions.

mod common;

use vkrt::prims::reduce;
use vkrt::prims::PrimConfig;

/// `cargo test --release --test prims_bench -- --ignored --nocapture bench_digit_widths`: the digit-width
/// table of the module docs, the CPU comparison and the copy-kernel bound.
#[test]
#[ignore = "benchmark, minutes on lavapipe: run with --ignored --nocapture"]
fn bench_digit_widths() {
    let Some(ctx) = common::context() else { return };
    let reps = std::env::var("VKRT_BENCH_REPS")
        .ok()
        .and_then(|r| r.parse().ok())
        .unwrap_or(3);
    for n in [1usize << 22, 1 << 24] {
        let timings = vkrt::prims::radix_sort::bench(&ctx, n, reps).unwrap();
        // Keys and values read and written once: what one pass at least moves.
        let (baselines, _) = vkrt_cli::bench::copy_baselines(&ctx, 8 * n as u64, reps).unwrap();
        let copy_kernel = baselines.best_kernel().map_or(f64::NAN, |r| r.gpu_ms);
        let copy = baselines
            .results
            .iter()
            .find(|r| r.method == "vkCmdCopyBuffer")
            .map_or(f64::NAN, |r| r.gpu_ms);
        println!("n = {n}: vkCmdCopyBuffer {copy:.1} ms, best copy kernel {copy_kernel:.1} ms per 8n bytes (one pass of keys+values)");
        for t in timings {
            let passes = t.min_bytes as f64 / (16.0 * n as f64);
            println!(
                "  {:32} {:9.1} ms  {:5.1} copy-kernel passes' worth ({:.0} passes)",
                t.prim,
                t.gpu_ms,
                t.gpu_ms / copy_kernel,
                passes
            );
        }
    }
    common::assert_silent(&ctx);
}

#[test]
#[ignore = "benchmark: cargo test --release --test prims_bench -- --ignored --nocapture bench_reductions"]
fn bench_reductions() {
    let Some(ctx) = common::context() else { return };
    let n = 1 << 24;
    let env = |k: &str| std::env::var(k).ok().and_then(|v| v.parse::<u32>().ok());
    let mut cfg = PrimConfig::default_for(&ctx);
    cfg.workgroup_size = env("BENCH_WG").unwrap_or(cfg.workgroup_size);
    cfg.items_per_invocation = env("BENCH_ITEMS").unwrap_or(cfg.items_per_invocation);
    println!("{cfg:?}");
    if std::env::var("BENCH_COPY").is_ok() {
        let (b, _) = vkrt_cli::bench::copy_baselines(&ctx, 64 << 20, 3).unwrap();
        for r in &b.results {
            println!("{:<26} {:8.3} ms", r.method, r.gpu_ms);
        }
    }
    for t in reduce::bench_with(&ctx, cfg, n, 5).unwrap() {
        println!(
            "{:<16} n = {}  {:8.3} ms  {:7.1} M elements/s  {:6.2} GB/s",
            t.prim,
            t.n,
            t.gpu_ms,
            t.n as f64 / t.gpu_ms / 1e3,
            t.min_bytes as f64 / t.gpu_ms / 1e6
        );
    }
}
