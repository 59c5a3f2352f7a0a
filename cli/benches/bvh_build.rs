//! Sochora's (2013) Tables 3/4 on this machine: build time of the CPU SAH BVH with each
//! threading scheme (uneven, even, node queue; rayon as today's baseline) at 1 and all
//! threads, full sweep and 16-bin SAH, speed-up over one thread — beside Embree 3's build of
//! the same triangles at 1 and 2 threads (medium quality, best of 3) and Kolodzey's GPU
//! kd-tree build, in one run. Every scheme must give the one-thread tree (checked).
//!
//! Scenes: the Stanford bunny (../shared/scenes), the default scene, icospheres of 100K,
//! 500K, 1M and 2M triangles.
//!
//! `cargo bench --bench bvh_build [-- --json] [-- --quick]` (`--quick`: up to 500K)

#[path = "embree/peer.rs"]
mod embree;

use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::primitives::TraceGeometry;
use vkrt::gpu::Recorder;
use vkrt_cli::bvh_bench::bench;

#[path = "common/args.rs"]
mod args;

fn main() {
    let args::BenchArgs { json, quick, .. } = args::parse();
    let (ctx, embree) = embree::context_and_peer();
    let sizes: &[u64] = if quick {
        &[100_000, 500_000]
    } else {
        &[100_000, 500_000, 1_000_000, 2_000_000]
    };
    let mut scenes = embree::bench_scenes(sizes);
    let default = vkrt::scene::Scene::default_scene();
    scenes.insert(
        1.min(scenes.len()),
        ("default-scene".into(), default.triangles_world(0.0)),
    );
    let rows = bench(&scenes, 3).expect("bench");
    let kd = AccelBuilder::new(&ctx, AccelKind::KdTree).expect("kd-tree builder");
    let mut peers = Vec::new();
    for (name, tris) in &scenes {
        let e1 = embree.as_ref().map(|e| e.run(tris, 1, &[]).build_ms);
        let e2 = embree.as_ref().map(|e| e.run(tris, 2, &[]).build_ms);
        // The GPU kd-tree, built twice on the device (the second timed: first-touch page
        // faults of fresh memory are lavapipe's, not the builder's).
        let g = TraceGeometry::from_triangles(tris);
        let mut kd_ms = f64::NAN;
        for _ in 0..2 {
            let mut rec = Recorder::new(&ctx).expect("recorder");
            // The structure must outlive the submission that builds it.
            let (structure, r) = GpuGeometry::record_build(&mut rec, &kd, &g, 0).expect("build");
            kd_ms = r.ms(&rec.submit_and_wait().expect("submit"));
            drop(structure);
        }
        peers.push(serde_json::json!({
            "scene": name,
            "triangles": tris.len(),
            "embree_1t_ms": e1,
            "embree_2t_ms": e2,
            "kdtree_gpu_ms": kd_ms,
        }));
    }
    if json {
        let v = serde_json::json!({ "device": ctx.info().device, "rows": rows, "peers": peers });
        println!("{}", serde_json::to_string_pretty(&v).unwrap());
        return;
    }
    println!(
        "{} — SAH BVH build, best of 3 (wall); speed-up over 1 thread",
        ctx.info().device
    );
    print!("{}", vkrt_cli::bvh_bench::table(&rows));
    println!("peers: Embree 3 (medium BVH, best of 3) and vkrt's GPU kd-tree (timestamps)");
    let f = |v: &serde_json::Value| v.as_f64().map_or("-".into(), |x| format!("{x:.1}"));
    for p in &peers {
        let sweep_queue = rows
            .iter()
            .filter(|r| r.scene == p["scene"] && r.sah == "sweep" && r.scheme == "queue")
            .map(|r| r.build_ms)
            .fold(f64::INFINITY, f64::min);
        println!(
            "{:<15} embree-1t {:>8} ms  embree-2t {:>8} ms  kd-tree GPU {:>9} ms  \
             SAH BVH queue (sweep, all threads) {:>8.1} ms",
            p["scene"].as_str().unwrap_or(""),
            f(&p["embree_1t_ms"]),
            f(&p["embree_2t_ms"]),
            f(&p["kdtree_gpu_ms"]),
            sweep_queue
        );
    }
}
