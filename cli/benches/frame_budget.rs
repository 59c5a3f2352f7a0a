//! A frame's structure work at three scene sizes: the bunny (69 K triangles) and icospheres
//! of 1 M and 4 M. Per structure that can be rebuilt every frame — the LBVH (Karras 2012)
//! and PLOC (Meister & Bittner 2018), and the driver's own where it has ray query — the
//! build, the update of a structure built to be updated (vkrt: the per-depth refit; the
//! driver: its UPDATE mode), and a trace of one primary ray per pixel of a 512² image with
//! the structure's fastest walk (GPU timestamps, best of 3 after a warm-up); beside them
//! Embree 3's build and trace of the same rays on 2 threads (when `libembree-dev` is
//! installed). A scene past what one bottom level holds on the device (lavapipe's 128 MiB
//! `maxStorageBufferRange`: 2.1 M triangles) is cut into pieces under a top level, as
//! `vkrt trace` cuts it: its row is the pieces' builds plus the top level's, and the trace
//! through both levels.
//!
//! `cargo bench --bench frame_budget [-- --json] [-- --quick]` (`--quick`: the bunny and
//! 100 K, for a check that it runs).

#[path = "embree/peer.rs"]
mod embree;

#[path = "common/args.rs"]
mod args;
#[path = "common/best_of.rs"]
mod best_of;

use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::primitives::TraceGeometry;
use vkrt::accel::two_levels;
use vkrt::accel::walk::{AccelChoice, NodeAccess, Traversal};
use vkrt::gpu::{Context, Recorder};
use vkrt::scene::{Material, Mesh, Scene};
use vkrt::trace::{instanced, TraceOptions};
use vkrt_cli::trace_bench::{self, BenchScene};

/// Builds and traces repeated after the warm-up; the best is kept.
const REPS: u32 = 3;

#[derive(serde::Serialize)]
struct Row {
    scene: String,
    triangles: usize,
    /// `lbvh`, `ploc`, `driver/fast-build`, `embree-2t`.
    structure: String,
    build_ms: f64,
    /// The update of the same structure built to be updated (`None`: not measured).
    update_ms: Option<f64>,
    /// The primary rays with the fastest walk.
    trace_ms: f64,
    /// That walk's label.
    walk: String,
}

/// The update of `choice`'s structure over `g`, built to be updated.
fn update_ms(ctx: &Context, choice: AccelChoice, g: &TraceGeometry) -> Option<f64> {
    let builder = AccelBuilder::for_choice(ctx, choice)
        .ok()?
        .with_allow_update(true);
    let mut rec = Recorder::new(ctx).ok()?;
    let (mut dev, _) = GpuGeometry::record_build(&mut rec, &builder, g, 0).ok()?;
    rec.submit_and_wait().ok()?;
    let visits = builder
        .update_scratch(ctx, g.primitive_count())
        .ok()
        .flatten()?;
    let scope = match choice.kind {
        AccelKind::Driver => "driver_update",
        _ => "refit",
    };
    let ms = best_of::best_of(ctx, scope, REPS + 1, |rec| {
        builder
            .record_refit(rec, &mut dev, &visits)
            .expect("update")
    });
    ms.is_finite().then_some(ms)
}

/// A scene past what one bottom level holds on this device (`max_level_primitives`): its
/// pieces' builds, the top level's and the trace through both levels, best of `REPS` after
/// a warm-up (no update: a piece's update is a bottom level's).
fn measure_pieces(
    ctx: &Context,
    choice: AccelChoice,
    mesh: &Mesh,
    rays: &[vkrt::trace::Ray],
) -> Option<(f64, f64, usize)> {
    let scene = Scene::from_geometry(vec![mesh.clone()], Vec::new(), vec![Material::default()]);
    let per_level = two_levels::max_level_primitives(ctx, choice.kind);
    let two = two_levels::TwoLevelScene::of_within(&scene, 0.0, per_level)?;
    let mut best: Option<(f64, f64)> = None;
    for _ in 0..=REPS {
        let done = match instanced::build_and_trace(
            ctx,
            choice,
            &TraceOptions::default(),
            &two,
            rays,
            0.0,
        ) {
            Ok(done) => done,
            Err(e) => {
                eprintln!("{}: not built in pieces: {e}", choice.label());
                return None;
            }
        };
        let build = done.bottom_build_ms + done.top_build_ms;
        if best.is_none_or(|b| build + done.trace_ms < b.0 + b.1) {
            best = Some((build, done.trace_ms));
        }
    }
    best.map(|(b, t)| (b, t, two.bottoms.len()))
}

fn measure(ctx: &Context, scene: &BenchScene, mesh: Option<&Mesh>, size: u32) -> Vec<Row> {
    let g = &scene.geometry;
    let set = trace_bench::RaySet {
        kind: trace_bench::RayKind::Primary,
        rays: scene.primary_rays(size),
    };
    let access = NodeAccess::for_device(ctx);
    let mut rows = Vec::new();
    for (structure, walks) in trace_bench::structures(ctx) {
        if !matches!(
            structure.kind,
            AccelKind::Lbvh | AccelKind::Ploc | AccelKind::Driver
        ) {
            continue;
        }
        let label = match structure.kind {
            AccelKind::Driver => structure.label(),
            _ if structure.walk == Traversal::Wide => structure.label(),
            kind => kind.name().to_string(),
        };
        let per_level = two_levels::max_level_primitives(ctx, structure.kind);
        if g.primitive_count() > per_level {
            let walk = walks[0];
            if let Some((build_ms, trace_ms, pieces)) =
                mesh.and_then(|m| measure_pieces(ctx, walk, m, &set.rays))
            {
                rows.push(Row {
                    scene: scene.name.clone(),
                    triangles: g.triangle_count(),
                    structure: format!("{label}, {pieces} pieces"),
                    build_ms,
                    update_ms: None,
                    trace_ms,
                    walk: walk.label(),
                });
            }
            continue;
        }
        let (geom, build_ms) = match trace_bench::best_build(ctx, structure, g, REPS + 1) {
            Ok(built) => built,
            Err(e) => {
                eprintln!("{}, {}: not built: {e}", scene.name, structure.label());
                continue;
            }
        };
        let mut best = (f64::INFINITY, String::new());
        for walk in walks {
            let (_, ms, _) =
                trace_bench::best_trace(ctx, walk, access, &geom, &set, REPS + 1).expect("trace");
            if ms < best.0 {
                best = (ms, walk.label());
            }
        }
        drop(geom);
        rows.push(Row {
            scene: scene.name.clone(),
            triangles: g.triangle_count(),
            structure: label,
            build_ms,
            update_ms: update_ms(ctx, structure, g),
            trace_ms: best.0,
            walk: best.1,
        });
    }
    rows
}

fn main() {
    let args::BenchArgs {
        json, quick, size, ..
    } = args::parse();
    let (ctx, embree) = embree::context_and_peer();
    let sizes: &[u64] = if quick {
        &[100_000]
    } else {
        &[1_000_000, 4_000_000]
    };
    let mut rows = Vec::new();
    for (name, tris) in embree::bench_scenes(sizes) {
        let scene = BenchScene::from_triangles(name, &tris);
        eprintln!("{}: {} triangles", scene.name, tris.len());
        // The icosphere as a mesh again, for a scene cut into pieces.
        let mesh = (scene.name != "bunny")
            .then(|| vkrt::scene::gen::icosphere_with_at_least(tris.len() as u64).ok())
            .flatten();
        rows.extend(measure(&ctx, &scene, mesh.as_ref(), size));
        if let Some(e) = &embree {
            let rays = scene.primary_rays(size);
            let run = e.run(&tris, 2, &[(&rays, true)]);
            rows.push(Row {
                scene: scene.name.clone(),
                triangles: tris.len(),
                structure: "embree-2t".into(),
                build_ms: run.build_ms,
                update_ms: None,
                trace_ms: run.traces[0].1,
                walk: "rtcIntersect1".into(),
            });
        }
    }
    if json {
        let v = serde_json::json!({ "device": ctx.info().device, "size": size, "rows": rows });
        println!("{}", serde_json::to_string_pretty(&v).unwrap());
        return;
    }
    println!(
        "{} — a frame's structure work, ms (GPU timestamps; Embree's wall time), {size}² primary rays",
        ctx.info().device
    );
    println!(
        "{:<14} {:>8} {:<22} {:>9} {:>9} {:>9} {:>10}  walk",
        "scene", "tris", "structure", "build", "update", "trace", "build+trace"
    );
    let f = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.1}"));
    for r in &rows {
        println!(
            "{:<14} {:>8} {:<22} {:>9.1} {:>9} {:>9.1} {:>10.1}  {}",
            r.scene,
            r.triangles,
            r.structure,
            r.build_ms,
            f(r.update_ms),
            r.trace_ms,
            r.build_ms + r.trace_ms,
            r.walk
        );
    }
}
