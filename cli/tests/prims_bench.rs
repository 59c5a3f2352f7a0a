//! The GPU primitives measured: `vkrt bench prims`'s report, and benchmarks run by hand
//! (ignored): the radix sort's digit widths and the reductions against the copy baselines
//! of `vkrt bench`, the reductions' workgroup shapes, and the segmented argmin's modes and
//! hybrid thresholds on kd-tree levels.

mod common;

use vkrt::gpu::{Buffer, Recorder};
use vkrt::prims::reduce::{self, CostIndex, Reduce};
use vkrt::prims::segmented::{self, SegmentedArgmin, SegmentedMode};
use vkrt::prims::PrimConfig;
use vkrt_cli::bench::{best_ms, prims, rep_scope};

/// The number in the environment variable `key`, if it is set and parses: the knobs of
/// these measurements.
fn env<T: std::str::FromStr>(key: &str) -> Option<T> {
    std::env::var(key).ok()?.parse().ok()
}

/// `vkrt bench prims --json` as the docs describe it: a row per timed variant with its
/// size, its bytes and its ratios to the copy baselines of the same bytes.
#[test]
fn bench_prims_reports_every_reduction_against_the_copies() {
    let n = 4096u64;
    let Some(out) = common::vkrt_ok(&[
        "bench", "prims", "--min-n", "4096", "--max-n", "4096", "--reps", "1", "--only", "reduce",
        "--json",
    ]) else {
        return;
    };
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(
        v["device"].is_string() && v["subgroup_size"].as_u64().unwrap() >= 4,
        "{v}"
    );
    let rows = v["results"].as_array().unwrap();
    let names: Vec<&str> = rows.iter().map(|r| r["prim"].as_str().unwrap()).collect();
    assert_eq!(
        names,
        [
            "reduce_sum_u32",
            "reduce_min_u32",
            "reduce_sum_f32",
            "reduce_min_f32",
            "argmin_f32"
        ]
    );
    for r in rows {
        assert_eq!(r["n"], n, "{r}");
        // The input read plus the result: a u32 or f32, or argmin's (cost, index).
        let result_bytes = if r["prim"] == "argmin_f32" { 8 } else { 4 };
        assert_eq!(r["min_bytes"], 4 * n + result_bytes, "{r}");
        for key in [
            "gpu_ms",
            "elements_per_s",
            "copy_ms",
            "copy_kernel_ms",
            "ratio_to_copy",
            "ratio_to_copy_kernel",
        ] {
            let x = r[key].as_f64().unwrap_or(f64::NAN);
            assert!(x.is_finite() && x > 0.0, "{key} in {r}");
        }
        let per_s = n as f64 / (r["gpu_ms"].as_f64().unwrap() / 1e3);
        assert!(
            (r["elements_per_s"].as_f64().unwrap() / per_s - 1.0).abs() < 1e-9,
            "{r}"
        );
    }
}

/// `cargo test --release --test prims_bench -- --ignored --nocapture bench_digit_widths`: the digit-width
/// table of the module docs, the CPU comparison and the copy-kernel bound.
#[test]
#[ignore = "benchmark, minutes on lavapipe: run with --ignored --nocapture"]
fn bench_digit_widths() {
    let Some(ctx) = common::context() else { return };
    let reps = env("VKRT_BENCH_REPS").unwrap_or(3);
    for n in [1usize << 22, 1 << 24] {
        let timings = prims::radix_sort::bench(&ctx, n, reps).unwrap();
        // Keys and values read and written once: what one pass at least moves.
        let (baselines, _) =
            vkrt_cli::bench::copy::copy_baselines(&ctx, 8 * n as u64, reps).unwrap();
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
    let mut cfg = PrimConfig::default_for(&ctx);
    cfg.workgroup_size = env("BENCH_WG").unwrap_or(cfg.workgroup_size);
    cfg.items_per_invocation = env("BENCH_ITEMS").unwrap_or(cfg.items_per_invocation);
    println!("{cfg:?}");
    if std::env::var("BENCH_COPY").is_ok() {
        let (b, _) = vkrt_cli::bench::copy::copy_baselines(&ctx, 64 << 20, 3).unwrap();
        for r in &b.results {
            println!("{:<26} {:8.3} ms", r.method, r.gpu_ms);
        }
    }
    for t in prims::reduce::bench_with(&ctx, cfg, n, 5).unwrap() {
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

/// Configurations interleaved in one submission (best of many repetitions), so machine load
/// affects them alike: the measurement behind the configuration the docs recommend.
#[test]
#[ignore = "measurement: cargo test --release --test prims_bench -- --ignored --nocapture tune"]
fn tune_configs() {
    let Some(ctx) = common::context() else { return };
    let n: usize = env("BENCH_N").unwrap_or(1 << 22);
    let reps = 9;
    let sg = ctx.info().subgroup_size;
    let list = std::env::var("TUNE").unwrap_or_else(|_| "256x16,256x64,256x256,256x1024".into());
    let cfgs: Vec<PrimConfig> = list
        .split(',')
        .map(|c| {
            let (w, i) = c.split_once('x').unwrap();
            (w.parse::<u32>().unwrap(), i.parse::<u32>().unwrap())
        })
        .map(|(w, i)| PrimConfig {
            workgroup_size: u32::max(w, sg),
            items_per_invocation: i,
        })
        .collect();
    let reduces: Vec<Reduce> = cfgs
        .iter()
        .map(|&c| Reduce::new(&ctx, c).unwrap())
        .collect();
    let data: Vec<f32> = (0..n).map(|i| (i % 1000) as f32).collect();
    let src = Buffer::from_slice(&ctx, "tune.src", &data).unwrap();
    let scratch_len = reduces.iter().map(|r| r.scratch_len(n)).max().unwrap();
    let scratch = Buffer::<u32>::new(&ctx, "tune.scratch", scratch_len).unwrap();
    let out = Buffer::<f32>::new(&ctx, "tune.out", 1).unwrap();
    let out_arg = Buffer::<CostIndex>::new(&ctx, "tune.arg", 1).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    for rep in 0..=reps {
        for (i, r) in reduces.iter().enumerate() {
            rec.scope(&rep_scope(rep, &format!("sum{i}")), |rec| {
                r.record_sum_f32(rec, &src, n as u32, &scratch, &out)
            });
            rec.compute_to_compute();
            rec.scope(&rep_scope(rep, &format!("argmin{i}")), |rec| {
                r.record_argmin(rec, &src, n as u32, &scratch, &out_arg)
            });
            rec.compute_to_compute();
        }
    }
    rec.compute_to_transfer();
    let profile = rec.submit_and_wait().unwrap();
    // The last configuration's results must be right.
    let last = *cfgs.last().unwrap();
    assert_eq!(
        out.download().unwrap()[0].to_bits(),
        reduce::sum_f32_cpu(&data, last).to_bits(),
        "sum_f32 with {last:?}"
    );
    let got = out_arg.download().unwrap()[0];
    let (c, i) = reduce::argmin_cpu(&data);
    assert_eq!(got.bits(), (c.to_bits(), i), "argmin with {last:?}");
    let best = |name: &str| best_ms(&profile, name);
    println!("n = {n}, best of {reps}");
    for (i, c) in cfgs.iter().enumerate() {
        println!(
            "wg {:5} items {:5}: sum_f32 {:8.3} ms  argmin {:8.3} ms",
            c.workgroup_size,
            c.items_per_invocation,
            best(&format!("sum{i}")),
            best(&format!("argmin{i}"))
        );
    }
}

#[test]
#[ignore = "benchmark: cargo test --release --test prims_bench -- --ignored --nocapture bench_segmented"]
fn bench_segmented() {
    let Some(ctx) = common::context() else { return };
    let n = 1 << 24;
    for t in prims::segmented::bench(&ctx, n, 3).unwrap() {
        println!(
            "{:<46} n = {}  {:8.3} ms  {:7.1} M elements/s",
            t.prim,
            t.n,
            t.gpu_ms,
            t.n as f64 / t.gpu_ms / 1e3
        );
    }
}

/// The measurement behind `DEFAULT_HYBRID_THRESHOLD`: both pure paths on kd-tree levels,
/// and hybrids at several thresholds.
#[test]
#[ignore = "measurement: cargo test --release --test prims_bench -- --ignored --nocapture threshold"]
fn threshold_measurement() {
    let Some(ctx) = common::context() else { return };
    let n = env("BENCH_N").unwrap_or(1 << 22);
    let levels: Vec<u32> = (0..=16).collect();
    let mut modes = vec![
        SegmentedMode::WorkgroupPerSegment,
        SegmentedMode::DeviceWide,
    ];
    for t in [2u32, 4, 16, 64, 256] {
        modes.push(SegmentedMode::Hybrid { threshold: t });
    }
    let labelled: Vec<(String, SegmentedMode)> = modes.iter().map(|m| (m.name(), *m)).collect();
    let mut cfg = PrimConfig::default_for(&ctx);
    cfg.workgroup_size = env("BENCH_WG").unwrap_or(256);
    cfg.items_per_invocation = env("BENCH_ITEMS").unwrap_or(256);
    let seg_wg = env("BENCH_SEG_WG").unwrap_or(ctx.info().subgroup_size);
    let seg = SegmentedArgmin::with_segment_workgroup(&ctx, cfg, seg_wg).unwrap();
    println!("n = {n}, tiles {cfg:?}, segment workgroup {seg_wg}");
    let timings = prims::segmented::bench_levels(&ctx, &seg, n, 3, &levels, &labelled).unwrap();
    print!("{:>6} {:>8}", "level", "seg len");
    for m in &modes {
        let name = m.name();
        print!(" {:>12}", &name[..12.min(name.len())]);
    }
    println!();
    for (i, level) in levels.iter().enumerate() {
        print!("{level:>6} {:>8}", n >> level);
        for j in 0..modes.len() {
            print!(" {:>12.3}", timings[i * modes.len() + j].gpu_ms);
        }
        println!();
    }
}

/// Per-pass times of one huge segment in the two pure modes (diagnostic).
#[test]
#[ignore = "diagnostic: cargo test --release --test prims_bench -- --ignored --nocapture breakdown"]
fn pass_breakdown() {
    let Some(ctx) = common::context() else { return };
    let n = 1u32 << 22;
    let cfg = PrimConfig {
        workgroup_size: env("BENCH_WG").unwrap_or(256),
        items_per_invocation: env("BENCH_ITEMS").unwrap_or(256),
    };
    let seg = SegmentedArgmin::with_segment_workgroup(&ctx, cfg, 8).unwrap();
    let costs: Vec<f32> = (0..n).map(|i| (i % 1000) as f32).collect();
    let costs = Buffer::from_slice(&ctx, "d.costs", &costs).unwrap();
    let offsets = Buffer::from_slice(&ctx, "d.off", &segmented::level_offsets(n, 0)).unwrap();
    let count = Buffer::from_slice(&ctx, "d.count", &[1u32]).unwrap();
    let scratch = Buffer::<u32>::new(&ctx, "d.s", seg.scratch_len(n as usize, 1)).unwrap();
    let out = Buffer::<CostIndex>::new(&ctx, "d.o", 1).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    for _ in 0..8 {
        for mode in [
            SegmentedMode::DeviceWide,
            SegmentedMode::WorkgroupPerSegment,
        ] {
            seg.record(&mut rec, mode, &costs, &offsets, &count, 1, &scratch, &out);
            rec.compute_to_indirect();
        }
    }
    let profile = rec.submit_and_wait().unwrap();
    for name in [
        "prims.segmented_plan",
        "prims.segmented_tiles",
        "prims.segmented_segments",
        "prims.segmented_argmin",
    ] {
        let v: Vec<String> = profile
            .passes
            .iter()
            .filter(|p| p.name == name)
            .filter_map(|p| p.ms)
            .map(|m| format!("{m:.2}"))
            .collect();
        println!("{name}: {}", v.join(" "));
    }
}
