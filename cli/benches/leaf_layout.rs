//! The leaf shape against the walk: the SAH BVH's own leaves (a leaf collapses while the SAH
//! says so) or one triangle per leaf, as the driver's structure holds them; its triangles in
//! the caller's order or in leaf order (a leaf's triangles contiguous, its references the
//! identity: what an inline leaf reads); walked over binary nodes with float boxes (the
//! stack walk) or over 4-wide quantized nodes (Ylitie et al. 2017). The binary walk over
//! one-triangle leaves in leaf order is the driver's node shape in vkrt's walk.
//!
//! Per scene (the Stanford bunny from ../shared/scenes, icospheres of 100 K and 500 K
//! triangles): the GPU ms of `vkrt bench trace`'s primary, shadow (any hit) and mirror rays,
//! the best of 5 traces in each of 3 interleaved rounds, and ÷ the SAH leaves in the
//! caller's order over 4-wide nodes (what lavapipe from Mesa 25.1 traces). Every layout must
//! give the same answers (closest-hit `t` bit for bit, any-hit hit or miss).
//!
//! `cargo bench --bench leaf_layout [-- --json] [-- --quick] [-- --size N]` (`--quick`: the
//! bunny or a 10 K icosphere, 128² rays)

#[path = "common/args.rs"]
mod args;
#[path = "embree/peer.rs"]
#[allow(dead_code, reason = "the scenes only: no Embree column here")]
mod embree;

use glam::Vec3;
use vkrt::accel::bvh::{self, Bvh, BvhParams, Threading};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::primitives::TraceGeometry;
use vkrt::accel::walk::{AccelTraversal, Traversal};
use vkrt::gpu::{Context, ContextOptions, Validation};
use vkrt::trace::gpu::Tracer;
use vkrt::trace::{Hit, Query, Ray, TraceOptions, NO_HIT};
use vkrt_cli::trace_bench::{BenchScene, RayKind};

const ROUNDS: usize = 3;
const REPS: usize = 5;

#[derive(serde::Serialize)]
struct Row {
    scene: String,
    triangles: usize,
    leaves: String,
    leaf_count: usize,
    order: &'static str,
    walk: &'static str,
    /// Primary, shadow, mirror: best GPU ms.
    ms: [f64; 3],
    /// ÷ the SAH leaves in the caller's order over 4-wide nodes.
    vs_default: [f64; 3],
}

/// One layout on the device, with the map from its triangle ids back to the caller's.
struct Layout {
    leaves: String,
    leaf_count: usize,
    order: &'static str,
    walk: Traversal,
    geom: GpuGeometry,
    ids: Option<Vec<u32>>,
    best: [f64; 3],
    hits: [Vec<Hit>; 3],
}

/// `b` over `tris` with its triangles renumbered in leaf order: triangle i is reference i,
/// so the references are the identity.
fn in_leaf_order(tris: &[[Vec3; 3]], b: &Bvh) -> (Vec<[Vec3; 3]>, Bvh) {
    let ordered = b.refs.iter().map(|&r| tris[r as usize]).collect();
    let mut identity = b.clone();
    identity.refs = (0..b.refs.len() as u32).collect();
    (ordered, identity)
}

fn layouts(ctx: &Context, tris: &[[Vec3; 3]], g: &TraceGeometry) -> Vec<Layout> {
    let mut out = Vec::new();
    for one in [false, true] {
        let params = BvhParams {
            max_leaf_prims: if one {
                1
            } else {
                BvhParams::default().max_leaf_prims
            },
            ..BvhParams::default()
        };
        let b = bvh::build(&g.boxes, &params, Threading::all_cores()).expect("SAH BVH");
        let (ordered, identity) = in_leaf_order(tris, &b);
        let g_ordered = TraceGeometry::from_triangles(&ordered);
        for (order, geometry, tree, ids) in [
            ("caller's", g, &b, None),
            ("leaf order", &g_ordered, &identity, Some(b.refs.clone())),
        ] {
            for walk in [Traversal::Stack, Traversal::Wide] {
                let geom = if walk == Traversal::Wide {
                    GpuGeometry::upload_wide_bvh(ctx, geometry, tree)
                } else {
                    GpuGeometry::upload_bvh(ctx, geometry, tree)
                }
                .expect("upload");
                out.push(Layout {
                    leaves: if one {
                        "one triangle".into()
                    } else {
                        "SAH".into()
                    },
                    leaf_count: b.leaf_count(),
                    order,
                    walk,
                    geom,
                    ids: ids.clone(),
                    best: [f64::INFINITY; 3],
                    hits: Default::default(),
                });
            }
        }
    }
    out
}

fn walk_name(w: Traversal) -> &'static str {
    match w {
        Traversal::Stack => "binary",
        Traversal::Bitstack => "bitstack",
        Traversal::Wide => "4-wide",
    }
}

/// The answers two layouts must share: closest hits' `t` bit for bit (which of two
/// triangles at one `t` answers is left open), any hits' hit or miss.
fn same(a: &Hit, b: &Hit, any: bool) -> bool {
    if any {
        (a.prim == NO_HIT) == (b.prim == NO_HIT)
    } else {
        a.t.to_bits() == b.t.to_bits()
    }
}

fn bench_scene(ctx: &Context, name: &str, tris: &[[Vec3; 3]], size: u32) -> Vec<Row> {
    let scene = BenchScene::from_triangles(name, tris);
    let g = &scene.geometry;
    let closest = TraceOptions::default();
    let any = TraceOptions {
        query: Query::Any,
        ..TraceOptions::default()
    };
    let tracer = |walk, opt: &TraceOptions| {
        Tracer::for_accel(ctx, opt, AccelTraversal::Bvh(walk)).expect("tracer")
    };
    let tracers =
        [Traversal::Stack, Traversal::Wide].map(|w| [tracer(w, &closest), tracer(w, &any)]);
    let mut layouts = layouts(ctx, tris, g);

    // The ray sets of `vkrt bench trace`, from the default layout's primary hits.
    let primary = scene.primary_rays(size);
    let first = tracers[1][0]
        .trace(ctx, &layouts[1].geom, &primary, 0.0)
        .expect("trace");
    let (shadow, mirror) = scene.secondary_rays(&primary, &first.hits);
    assert_eq!(shadow.kind, RayKind::Shadow);
    let sets: [(&[Ray], bool); 3] = [
        (&primary, false),
        (&shadow.rays, true),
        (&mirror.rays, false),
    ];

    for round in 0..ROUNDS {
        for l in layouts.iter_mut() {
            let ts = &tracers[usize::from(l.walk == Traversal::Wide)];
            for (s, (rays, is_any)) in sets.iter().enumerate() {
                for _ in 0..REPS {
                    let batch = ts[usize::from(*is_any)]
                        .trace(ctx, &l.geom, rays, 0.0)
                        .expect("trace");
                    assert_eq!(batch.exhausted, 0, "{name}: rays ran out of steps");
                    l.best[s] = l.best[s].min(batch.profile.ms("trace").unwrap_or(f64::NAN));
                    if round == 0 && l.hits[s].is_empty() {
                        let mut hits = batch.hits;
                        if let Some(ids) = &l.ids {
                            for h in hits.iter_mut().filter(|h| h.prim != NO_HIT) {
                                h.prim = ids[h.prim as usize];
                            }
                        }
                        l.hits[s] = hits;
                    }
                }
            }
        }
    }
    for l in &layouts {
        for (s, (_, is_any)) in sets.iter().enumerate() {
            let differ = layouts[0].hits[s]
                .iter()
                .zip(&l.hits[s])
                .filter(|(a, b)| !same(a, b, *is_any))
                .count();
            assert_eq!(
                differ,
                0,
                "{name}: {} leaves in {} over {} nodes: {differ} rays answer otherwise",
                l.leaves,
                l.order,
                walk_name(l.walk)
            );
        }
    }
    let default = layouts
        .iter()
        .find(|l| l.leaves == "SAH" && l.ids.is_none() && l.walk == Traversal::Wide)
        .map(|l| l.best)
        .expect("the default layout");
    layouts
        .iter()
        .map(|l| Row {
            scene: name.to_string(),
            triangles: tris.len(),
            leaves: l.leaves.clone(),
            leaf_count: l.leaf_count,
            order: l.order,
            walk: walk_name(l.walk),
            ms: l.best,
            vs_default: [0, 1, 2].map(|s| l.best[s] / default[s]),
        })
        .collect()
}

fn main() {
    let a = args::parse();
    let size = if a.quick { 128 } else { a.size };
    let sizes: &[u64] = if a.quick { &[] } else { &[100_000, 500_000] };
    let ctx = Context::new(&ContextOptions {
        validation: Validation::Off,
        ..Default::default()
    })
    .expect("a Vulkan device");
    let mut scenes = embree::bench_scenes(sizes);
    if scenes.is_empty() {
        scenes = embree::bench_scenes(&[10_000]);
    }
    let mut rows = Vec::new();
    for (name, tris) in &scenes {
        let scene_rows = bench_scene(&ctx, name, tris, size);
        if !a.json {
            println!(
                "\n{name} ({} triangles), {}: GPU ms (best of {ROUNDS}×{REPS}), ÷ SAH leaves \
                 in the caller's order over 4-wide nodes",
                tris.len(),
                ctx.info().driver
            );
            println!(
                "{:<14} {:>8} {:<11} {:<7} {:>8} {:>8} {:>8}   {:>6} {:>6} {:>6}",
                "leaves", "count", "order", "nodes", "primary", "shadow", "mirror", "÷", "÷", "÷"
            );
            for r in &scene_rows {
                println!(
                    "{:<14} {:>8} {:<11} {:<7} {:>8.2} {:>8.2} {:>8.2}   {:>6.2} {:>6.2} {:>6.2}",
                    r.leaves,
                    r.leaf_count,
                    r.order,
                    r.walk,
                    r.ms[0],
                    r.ms[1],
                    r.ms[2],
                    r.vs_default[0],
                    r.vs_default[1],
                    r.vs_default[2]
                );
            }
        }
        rows.extend(scene_rows);
    }
    if a.json {
        println!(
            "{}",
            serde_json::json!({ "device": ctx.info().driver, "leaf_layout": rows })
        );
    }
}
