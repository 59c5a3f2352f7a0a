//! The GPU BVH builders over N, one run: Karras's LBVH (63- and 30-bit Morton
//! codes) and PLOC (r = 4, 8, 16) built on the device, per pass (GPU timestamps, best of 3
//! after a warm-up build), the same built to be updated (`allow_update`: the refit's
//! schedule recorded too), the per-depth refit of that tree and the climbing refit of the
//! other, and the fitted growth exponent over the icospheres; beside them the GPU
//! kd-tree (Kolodzey 2014), the CPU SAH BVH on 2 threads (Sochora 2013, node queue, full sweep) and
//! Embree 3's build on 2 threads (when `libembree-dev` is installed), with the SAH cost of
//! each BVH under one cost model (`validate::sah_cost`, `BvhParams::default`) — the SAH
//! BVH's also with leaves of one primitive. The GPU builders run with their SAH leaf
//! collapse (leaves up to 4, the default) and without it (`/l1`: the fast build).
//!
//! Scenes: the Stanford bunny (../shared/scenes), icospheres of 100K, 200K, 500K, 1M, 2M.
//!
//! `cargo bench --bench gpu_bvh_build [-- --json] [-- --quick]` (`--quick`: up to 500K, no
//! kd-tree)

#[path = "embree/peer.rs"]
mod embree;

use vkrt::accel::bvh::lbvh::MortonBits;
use vkrt::accel::bvh::ploc::PlocParams;
use vkrt::accel::bvh::{self, validate, BvhParams, Threading};
use vkrt::accel::device::{AccelBuilder, AccelKind, BuildFlags};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::host::HostStructure;
use vkrt::accel::primitives::TraceGeometry;
use vkrt::gpu::{Context, Profile, Recorder};

const PASSES: [&str; 8] = bvh::GPU_BUILD_PASSES;

#[derive(serde::Serialize)]
struct Row {
    scene: String,
    triangles: usize,
    /// `lbvh-63`, `lbvh-30`, `ploc-r8`, ...
    builder: String,
    build_ms: f64,
    passes_ms: Vec<(&'static str, f64)>,
    /// Per-depth refit of the same tree built to be updated.
    refit_ms: f64,
    /// The climbing refit of the tree built without update.
    refit_climb_ms: f64,
    /// The build with `allow_update` (its refit schedule recorded too).
    build_update_ms: f64,
    sah_cost: f64,
    sah_bvh_2t_ms: f64,
    sah_bvh_sah_cost: f64,
    /// The same sweep with leaves of one primitive, as the GPU builders make them.
    sah_bvh_leaf1_sah_cost: f64,
    embree_2t_ms: Option<f64>,
    kdtree_gpu_ms: Option<f64>,
}

/// What one GPU builder did on one scene.
struct Measured {
    profile: Profile,
    structure: GpuGeometry,
    /// The climbing refit of the structure built as above.
    refit_climb_ms: f64,
    /// Built to be updated (the refit's schedule recorded too), and its per-depth refit.
    build_update_ms: f64,
    refit_ms: f64,
}

/// Best-of-3 builds (after a warm-up) of `builder` over `g`, without and with
/// `allow_update`, and the best refit of each.
fn gpu_build(ctx: &Context, builder: &mut AccelBuilder, g: &TraceGeometry) -> Measured {
    builder.set_flags(BuildFlags {
        allow_update: false,
        ..builder.flags()
    });
    let mut best: Option<(f64, Profile, GpuGeometry)> = None;
    for _ in 0..4 {
        let mut rec = Recorder::new(ctx).expect("recorder");
        let (dev, _) = GpuGeometry::record_build(&mut rec, builder, g, 0).expect("build");
        let prof = rec.submit_and_wait().expect("submit");
        let ms = prof.ms("build").unwrap_or(f64::NAN);
        if best.as_ref().is_none_or(|b| ms < b.0) {
            best = Some((ms, prof, dev));
        }
    }
    let (_, profile, mut structure) = best.expect("built");
    let visits = builder
        .update_scratch(ctx, g.primitive_count())
        .expect("scratch")
        .expect("a BVH");
    let refit = |b: &AccelBuilder, dev: &mut GpuGeometry| {
        best_of::best_of(ctx, "refit", 4, |rec| {
            b.record_refit(rec, dev, &visits).expect("refit")
        })
    };
    let refit_climb_ms = refit(builder, &mut structure);
    builder.set_flags(BuildFlags {
        allow_update: true,
        ..builder.flags()
    });
    let mut updatable = None;
    let build_update_ms = best_of::best_of(ctx, "build", 4, |rec| {
        let (dev, _) = GpuGeometry::record_build(rec, builder, g, 0).expect("build");
        updatable = Some(dev);
    });
    let mut updatable = updatable.expect("built");
    let refit_ms = refit(builder, &mut updatable);
    builder.set_flags(BuildFlags {
        allow_update: false,
        ..builder.flags()
    });
    Measured {
        profile,
        structure,
        refit_climb_ms,
        build_update_ms,
        refit_ms,
    }
}

#[path = "common/args.rs"]
mod args;
#[path = "common/best_of.rs"]
mod best_of;

fn main() {
    let args::BenchArgs { json, quick, .. } = args::parse();
    let (ctx, embree) = embree::context_and_peer();
    let sizes: &[u64] = if quick {
        &[100_000, 200_000, 500_000]
    } else {
        &[100_000, 200_000, 500_000, 1_000_000, 2_000_000]
    };
    let scenes = embree::bench_scenes(sizes);
    // The defaults collapse leaves by the SAH (up to 4 primitives); `/l1` keeps one
    // primitive per leaf (no collapse: the fast build).
    let mut gpu_builders: Vec<(String, AccelBuilder)> = Vec::new();
    for (bits, leaf) in [
        (MortonBits::Bits63, 4),
        (MortonBits::Bits63, 1),
        (MortonBits::Bits30, 4),
    ] {
        let mut b = AccelBuilder::lbvh(&ctx, bits).expect("LBVH builder");
        b = b.with_bvh_params(BvhParams {
            max_leaf_prims: leaf,
            ..Default::default()
        });
        let suffix = if leaf == 1 { "/l1" } else { "" };
        gpu_builders.push((format!("lbvh-{}{suffix}", bits.spec()), b));
    }
    for (radius, leaf) in [(4, 4), (8, 4), (8, 1), (16, 4)] {
        let params = PlocParams {
            radius,
            ..PlocParams::default()
        };
        let mut b = AccelBuilder::ploc(&ctx, params).expect("PLOC builder");
        b = b.with_bvh_params(BvhParams {
            max_leaf_prims: leaf,
            ..Default::default()
        });
        let suffix = if leaf == 1 { "/l1" } else { "" };
        gpu_builders.push((format!("ploc-r{radius}{suffix}"), b));
    }
    let kd = (!quick).then(|| AccelBuilder::new(&ctx, AccelKind::KdTree).expect("kd builder"));
    let params = BvhParams::default();
    let mut rows = Vec::new();
    for (name, tris) in &scenes {
        let g = TraceGeometry::from_triangles(tris);
        let t = std::time::Instant::now();
        let sah = bvh::build(&g.boxes, &params, Threading::Queue { threads: 2 }).expect("SAH BVH");
        let sah_ms = t.elapsed().as_secs_f64() * 1e3;
        let leaf1 = BvhParams {
            max_leaf_prims: 1,
            ..params
        };
        let sah1 = bvh::build(&g.boxes, &leaf1, Threading::Queue { threads: 2 }).expect("SAH BVH");
        let sah1_cost = validate::sah_cost(&sah1, &params);
        let e2 = embree.as_ref().map(|e| e.run(tris, 2, &[]).build_ms);
        let kd_ms = kd.as_ref().map(|kd| {
            let mut ms = f64::NAN;
            for _ in 0..2 {
                let mut rec = Recorder::new(&ctx).expect("recorder");
                let (structure, r) = GpuGeometry::record_build(&mut rec, kd, &g, 0).expect("build");
                ms = r.ms(&rec.submit_and_wait().expect("submit"));
                drop(structure);
            }
            ms
        });
        for (label, builder) in &mut gpu_builders {
            let m = gpu_build(&ctx, builder, &g);
            let (prof, dev) = (m.profile, m.structure);
            let HostStructure::Bvh(tree) = dev.structure().download().expect("download") else {
                unreachable!("a GPU BVH")
            };
            validate::validate(&tree, &g.boxes).expect("a valid tree");
            rows.push(Row {
                scene: name.clone(),
                triangles: tris.len(),
                builder: label.clone(),
                build_ms: prof.ms("build").unwrap_or(f64::NAN),
                passes_ms: PASSES
                    .iter()
                    .map(|p| (*p, prof.ms(p).unwrap_or(0.0)))
                    .collect(),
                refit_ms: m.refit_ms,
                refit_climb_ms: m.refit_climb_ms,
                build_update_ms: m.build_update_ms,
                sah_cost: validate::sah_cost(&tree, &params),
                sah_bvh_2t_ms: sah_ms,
                sah_bvh_sah_cost: validate::sah_cost(&sah, &params),
                sah_bvh_leaf1_sah_cost: sah1_cost,
                embree_2t_ms: e2,
                kdtree_gpu_ms: kd_ms,
            });
        }
    }
    let growth: Vec<(String, Option<f64>)> = gpu_builders
        .iter()
        .map(|(label, _)| {
            let pts: Vec<(f64, f64)> = rows
                .iter()
                .filter(|r| &r.builder == label && r.scene.starts_with("icosphere"))
                .map(|r| (r.triangles as f64, r.build_ms))
                .collect();
            (label.clone(), vkrt_cli::bench::power_law_exponent(&pts))
        })
        .collect();
    if json {
        let v = serde_json::json!({
            "device": ctx.info().device,
            "rows": rows,
            "growth_exponent": growth,
        });
        println!("{}", serde_json::to_string_pretty(&v).unwrap());
        return;
    }
    println!(
        "{} — GPU LBVH build (timestamps, best of 3), refit, peers",
        ctx.info().device
    );
    let f = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.1}"));
    println!(
        "{:<14} {:>8} {:<10} {:>8} {:>36} {:>7} {:>7} {:>8} {:>6} {:>6} {:>7} {:>9} {:>7} {:>7} {:>9} {:>9}",
        "scene",
        "tris",
        "builder",
        "ms",
        "passes",
        "upd ms",
        "refit",
        "climbing",
        "SAH",
        "/emb2",
        "/sweep",
        "sah-bvh2t",
        "its SAH",
        "leaf1",
        "embree2t",
        "kd GPU"
    );
    for r in &rows {
        let passes: Vec<String> = r
            .passes_ms
            .iter()
            .filter(|p| p.1 > 0.0)
            .map(|p| format!("{:.1}", p.1))
            .collect();
        println!(
            "{:<14} {:>8} {:<10} {:>8.1} {:>36} {:>7.1} {:>7.1} {:>8.1} {:>6.1} {:>6} {:>7.3} {:>9.1} {:>7.1} {:>7.1} {:>9} {:>9}",
            r.scene,
            r.triangles,
            r.builder,
            r.build_ms,
            passes.join(" "),
            r.build_update_ms,
            r.refit_ms,
            r.refit_climb_ms,
            r.sah_cost,
            f(r.embree_2t_ms.map(|e| r.build_ms / e)),
            r.sah_cost / r.sah_bvh_sah_cost,
            r.sah_bvh_2t_ms,
            r.sah_bvh_sah_cost,
            r.sah_bvh_leaf1_sah_cost,
            f(r.embree_2t_ms),
            f(r.kdtree_gpu_ms),
        );
    }
    let growth: Vec<String> = growth
        .iter()
        .map(|(l, k)| format!("{l} {}", k.map_or("-".into(), |x| format!("{x:.3}"))))
        .collect();
    println!(
        "growth exponent over the icospheres (build ms ~ N^k): {}",
        growth.join(", ")
    );
}
