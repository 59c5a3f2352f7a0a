//! Ray throughput of every structure and walk against the driver and CPU peers in the same
//! run: `vkrt bench trace`'s measurement (`vkrt_cli::trace_bench`: every
//! structure vkrt builds, walked every way, the driver's ray query where the device has it,
//! obvhs on one thread) on the Stanford bunny (../shared/scenes, skipped with a message when
//! absent) and icospheres of 100K and 500K triangles, with Embree 3.13 on top
//! (`rtcIntersect1`/`rtcOccluded1`, medium-quality BVH, 2 threads, best of 3, through
//! `benches/embree/embree_trace.c` when `libembree-dev` is installed) tracing the same rays.
//!
//! Prints the table of `vkrt bench trace` with Embree's rows added, then the ratio of the
//! best vkrt BVH walk and of the kd-tree to Embree.
//!
//! `cargo bench --bench trace [-- --json] [-- --size 512]`

#[path = "embree/peer.rs"]
mod embree;

use vkrt::trace::Query;
use vkrt_cli::trace_bench::{self as bench, Backend, BenchOptions, BenchScene, BuildRow, TraceRow};

#[path = "common/args.rs"]
mod args;

fn main() {
    let args::BenchArgs { json, size, .. } = args::parse();
    let opt = BenchOptions {
        size,
        reps: 3,
        node_access: None,
    };
    let (ctx, embree) = embree::context_and_peer();
    let mut report = bench::TraceBenchReport {
        device: ctx.info().device.clone(),
        node_access: opt.accesses_on(&ctx),
        ray_query: ctx.info().features.ray_query,
        driver_note: bench::driver_note(&ctx),
        size,
        reps: opt.reps,
        scenes: Vec::new(),
    };
    for (name, tris) in embree::bench_scenes(&[100_000, 500_000]) {
        let scene = BenchScene::from_triangles(name, &tris);
        let (mut s, sets) = bench::bench_scene(&ctx, &scene, &opt).expect("bench");
        if let Some(e) = &embree {
            let peer_sets: Vec<_> = sets
                .iter()
                .map(|s| (&s.rays[..], s.kind.query() == Query::Any))
                .collect();
            let run = e.run(&tris, 2, &peer_sets);
            s.builds.push(BuildRow {
                structure: "embree-2t".into(),
                backend: Backend::CpuPeer,
                ms: run.build_ms,
            });
            for (set, (hits, ms)) in s.ray_sets.iter_mut().zip(run.traces) {
                let row = TraceRow::new(
                    "embree-2t",
                    Backend::CpuPeer,
                    run.build_ms,
                    ms,
                    set.rays,
                    hits,
                );
                set.rows.push(row);
                set.finish();
            }
        }
        report.scenes.push(s);
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&report).unwrap());
        return;
    }
    print!("{report}");
    println!("embree-2t: Embree 3, medium BVH, 2 threads, wall time");
    for s in &report.scenes {
        for set in &s.ray_sets {
            let mr = |f: &dyn Fn(&str) -> bool| {
                set.rows
                    .iter()
                    .filter(|r| f(&r.structure))
                    .map(|r| r.mrays_per_s)
                    .fold(0.0, f64::max)
            };
            let embree = mr(&|l| l == "embree-2t");
            if embree > 0.0 {
                let bvh = mr(&|l| l.contains("bvh/") || l.starts_with("ploc/"));
                println!(
                    "{} {}: best vkrt BVH / Embree {:.2}, kd-tree / Embree {:.2}",
                    s.name,
                    set.kind.name(),
                    bvh / embree,
                    mr(&|l| l == "kdtree") / embree
                );
            }
        }
    }
}
