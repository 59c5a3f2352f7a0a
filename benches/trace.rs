//! Ray throughput of every structure and walk against CPU peers in the same run (issues 6
//! and 14).
//!
//! On the Stanford bunny (../shared/scenes, skipped with a message when absent) and
//! icospheres of 100K and 500K triangles: a 512×512 pinhole camera framing the object gives
//! the primary rays (closest hit); from their hits, shadow rays towards a point light (any
//! hit) and mirror reflections (closest hit). The same rays go through
//! - vkrt's GPU tracer on each structure built on the device — seed 001's kd-tree, seed
//!   003's SAH BVH, seed 000's LBVH and PLOC, the BVHs walked with a stack or seed 000's
//!   bitstack
//!   (watertight test; time = GPU timestamps around the trace kernel, best of 3);
//! - obvhs's PLOC BVH (`BvhBuildParams::medium_build`, Möller–Trumbore, one CPU thread;
//!   wall time);
//! - Embree 3.13 (`rtcIntersect1`/`rtcOccluded1`, medium-quality BVH, 2 threads, best of
//!   3), through `benches/embree/embree_trace.c` when `libembree-dev` is installed.
//!
//! Prints Mrays/s per structure and peer, the ratio of the best vkrt BVH walk to Embree, the
//! build times, and whether every structure found the same hits.
//!
//! `cargo bench --bench trace [-- --json] [-- --size 512]`

#[path = "embree/peer.rs"]
mod embree;

use std::time::{Duration, Instant};

use glam::Vec3;
use obvhs::bvh2::builder::build_bvh2_from_tris;
use obvhs::BvhBuildParams;
use vkrt::accel::device::{AccelBuilder, AccelChoice, AccelKind};
use vkrt::gpu::Recorder;
use vkrt::trace::gpu::{GpuGeometry, Tracer};
use vkrt::trace::intersect::offset_ray_origin;
use vkrt::trace::{Hit, Query, Ray, TraceGeometry, TraceOptions};

/// One ray set on one scene.
#[derive(serde::Serialize)]
struct Row {
    scene: String,
    triangles: usize,
    rays_kind: &'static str,
    rays: usize,
    /// Per structure and walk (`AccelChoice::label`): hits, GPU ms, Mrays/s.
    vkrt: Vec<(String, usize, f64, f64)>,
    obvhs_hits: usize,
    obvhs_mrays_per_s: f64,
    embree2_hits: Option<usize>,
    embree2_mrays_per_s: Option<f64>,
    /// Best vkrt BVH walk ÷ Embree on 2 threads.
    best_bvh_over_embree2: Option<f64>,
    /// kd-tree ÷ Embree on 2 threads.
    kdtree_over_embree2: Option<f64>,
    /// Every structure and peer found the same number of hits.
    hits_agree: bool,
}

/// Build times of one scene.
#[derive(serde::Serialize)]
struct Builds {
    scene: String,
    triangles: usize,
    /// Per structure: ms (the kd-tree's GPU passes; the BVH's host build on every core).
    vkrt: Vec<(&'static str, f64)>,
    obvhs_ms: f64,
    embree2_ms: Option<f64>,
}

fn v34(v: Vec3) -> glam034::Vec3A {
    glam034::Vec3A::new(v.x, v.y, v.z)
}

/// Primary rays of a `size`² pinhole camera looking at the box of `tris` from the front-ish.
fn camera_rays(tris: &[[Vec3; 3]], size: u32) -> Vec<Ray> {
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for t in tris {
        for p in t {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
    }
    let c = (lo + hi) * 0.5;
    let radius = (hi - lo).length() * 0.5;
    let eye = c + Vec3::new(0.3, 0.25, 1.0).normalize() * radius * 2.0;
    let fwd = (c - eye).normalize();
    let right = fwd.cross(Vec3::Y).normalize();
    let up = right.cross(fwd);
    let half = (22.5f32).to_radians().tan();
    let mut rays = Vec::with_capacity((size * size) as usize);
    for y in 0..size {
        for x in 0..size {
            let sx = ((x as f32 + 0.5) / size as f32 * 2.0 - 1.0) * half;
            let sy = (1.0 - (y as f32 + 0.5) / size as f32 * 2.0) * half;
            let d = (fwd + right * sx + up * sy).normalize();
            rays.push(Ray::new(eye, d, 0.0, f32::MAX));
        }
    }
    rays
}

/// Shadow rays towards `light` and mirror reflections from every primary hit.
fn secondary(
    g: &TraceGeometry,
    primary: &[Ray],
    hits: &[Hit],
    light: Vec3,
) -> (Vec<Ray>, Vec<Ray>) {
    let (mut shadow, mut mirror) = (Vec::new(), Vec::new());
    for (r, h) in primary.iter().zip(hits) {
        if !h.is_hit() {
            continue;
        }
        let [p0, p1, p2] = g.triangle_at(h.prim as usize, 0.0);
        let p = p0 * (1.0 - h.u - h.v) + p1 * h.u + p2 * h.v;
        let mut n = (p1 - p0).cross(p2 - p0).normalize();
        if n.dot(r.d()) > 0.0 {
            n = -n;
        }
        let o = offset_ray_origin(p, n);
        let to_light = light - o;
        let dist = to_light.length();
        shadow.push(Ray::new(o, to_light / dist, 0.0, dist));
        let d = r.d() - 2.0 * r.d().dot(n) * n;
        mirror.push(Ray::new(o, d.normalize(), 0.0, f32::MAX));
    }
    (shadow, mirror)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let json = args.iter().any(|a| a == "--json");
    let size: u32 = args
        .iter()
        .position(|a| a == "--size")
        .and_then(|i| args.get(i + 1)?.parse().ok())
        .unwrap_or(512);
    let (ctx, embree) = embree::context_and_peer();
    let scenes = embree::bench_scenes(&[100_000, 500_000]);

    let mut rows = Vec::new();
    let mut builds = Vec::new();
    for (name, tris) in &scenes {
        let g = TraceGeometry::from_triangles(tris);
        // Every structure, built on the device as `vkrt trace` builds it.
        let mut built = Vec::new();
        let mut build_ms = Vec::new();
        for kind in AccelKind::ALL {
            let builder = AccelBuilder::new(&ctx, kind).expect("builder");
            let mut rec = Recorder::new(&ctx).expect("recorder");
            let (dev, recorded) =
                GpuGeometry::record_build(&mut rec, &builder, &g, 0).expect("build");
            let profile = rec.submit_and_wait().expect("build");
            build_ms.push((kind.name(), recorded.ms(&profile)));
            built.push((kind, dev));
        }
        let device = |accel: AccelChoice| {
            &built
                .iter()
                .find(|(k, _)| *k == accel.kind)
                .expect("built")
                .1
        };
        let tracers = |query: Query| -> Vec<(AccelChoice, Tracer)> {
            AccelChoice::all()
                .into_iter()
                .map(|a| {
                    let opt = TraceOptions {
                        query,
                        ..TraceOptions::default()
                    };
                    let t = Tracer::for_accel(&ctx, &opt, a.traversal()).expect("tracer");
                    (a, t)
                })
                .collect()
        };
        let (closest, any) = (tracers(Query::Closest), tracers(Query::Any));

        let ob_tris: Vec<obvhs::triangle::Triangle> = tris
            .iter()
            .map(|t| obvhs::triangle::Triangle {
                v0: v34(t[0]),
                v1: v34(t[1]),
                v2: v34(t[2]),
            })
            .collect();
        let ob_start = Instant::now();
        let bvh = build_bvh2_from_tris(
            &ob_tris,
            BvhBuildParams::medium_build(),
            &mut Duration::default(),
        );
        let obvhs_ms = ob_start.elapsed().as_secs_f64() * 1e3;

        let gpu = |accel: AccelChoice, tracer: &Tracer, rays: &[Ray]| {
            let mut best = f64::MAX;
            let mut hits = Vec::new();
            for _ in 0..3 {
                let b = tracer
                    .trace_batched(&ctx, device(accel), rays, 0.0, None)
                    .expect("trace");
                best = best.min(b.profile.ms("trace").unwrap_or(f64::MAX));
                hits = b.hits;
            }
            (hits, best)
        };
        let cpu = |rays: &[Ray], any_hit: bool| {
            let start = Instant::now();
            let mut hits = 0usize;
            for r in rays {
                let ray = obvhs::ray::Ray::new(v34(r.o()), v34(r.d()), r.tmin, r.tmax);
                let intersect = |ray: &obvhs::ray::Ray, id: usize| {
                    ob_tris[bvh.primitive_indices[id] as usize].intersect(ray)
                };
                let hit = if any_hit {
                    !bvh.ray_traverse_miss(ray, intersect)
                } else {
                    let mut h = obvhs::ray::RayHit::none();
                    bvh.ray_traverse(ray, &mut h, intersect)
                };
                hits += hit as usize;
            }
            (hits, start.elapsed().as_secs_f64() * 1e3)
        };

        let primary = camera_rays(tris, size);
        let (p_hits, _) = gpu(closest[0].0, &closest[0].1, &primary);
        let bounds = tris.iter().flatten().fold(
            (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
            |(lo, hi), p| (lo.min(*p), hi.max(*p)),
        );
        let (lo, hi) = bounds;
        let light = (lo + hi) * 0.5 + Vec3::new(1.0, 2.0, 1.5) * (hi - lo).length();
        let (shadow, mirror) = secondary(&g, &primary, &p_hits, light);
        let sets: [(&'static str, &[Ray], bool); 3] = [
            ("primary", &primary, false),
            ("shadow", &shadow, true),
            ("secondary", &mirror, false),
        ];
        let peer = embree.as_ref().map(|e| {
            let s: Vec<(&[Ray], bool)> = sets.iter().map(|(_, r, a)| (*r, *a)).collect();
            e.run(tris, 2, &s)
        });
        builds.push(Builds {
            scene: name.clone(),
            triangles: tris.len(),
            vkrt: build_ms,
            obvhs_ms,
            embree2_ms: peer.as_ref().map(|p| p.build_ms),
        });
        for (k, (kind, rays, any_hit)) in sets.into_iter().enumerate() {
            let mr = |ms: f64| rays.len() as f64 / (ms * 1e3);
            let tracers = if any_hit { &any } else { &closest };
            let vkrt: Vec<(String, usize, f64, f64)> = tracers
                .iter()
                .map(|(a, t)| {
                    let (hits, ms) = gpu(*a, t, rays);
                    (
                        a.label(),
                        hits.iter().filter(|h| h.is_hit()).count(),
                        ms,
                        mr(ms),
                    )
                })
                .collect();
            let (ob_hits, ob_ms) = cpu(rays, any_hit);
            let em = peer.as_ref().map(|p| p.traces[k]);
            let em_mr = em.map(|(_, ms)| mr(ms));
            let best_bvh = vkrt
                .iter()
                .filter(|v| v.0 != "kdtree")
                .map(|v| v.3)
                .fold(0.0, f64::max);
            let hits_agree =
                vkrt.iter().all(|v| v.1 == vkrt[0].1) && em.is_none_or(|(h, _)| h == vkrt[0].1);
            rows.push(Row {
                scene: name.clone(),
                triangles: tris.len(),
                rays_kind: kind,
                rays: rays.len(),
                obvhs_hits: ob_hits,
                obvhs_mrays_per_s: mr(ob_ms),
                embree2_hits: em.map(|(h, _)| h),
                embree2_mrays_per_s: em_mr,
                best_bvh_over_embree2: em_mr.map(|e| best_bvh / e),
                kdtree_over_embree2: em_mr.map(|e| vkrt[0].3 / e),
                hits_agree,
                vkrt,
            });
        }
    }
    if json {
        let v = serde_json::json!({
            "device": ctx.info().device,
            "size": size,
            "rows": rows,
            "builds": builds,
        });
        println!("{}", serde_json::to_string_pretty(&v).unwrap());
        return;
    }
    println!(
        "{} — {size}×{size} camera; Mrays/s (vkrt: GPU timestamps; obvhs: PLOC medium, 1 \
         thread; Embree 3: medium BVH, 2 threads)",
        ctx.info().device
    );
    println!(
        "{:<13} {:<9} {:>7} {:>8} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>8}",
        "scene",
        "rays",
        "n",
        "kdtree",
        "bvh-stk",
        "bvh-bit",
        "lbvh-stk",
        "lbvh-bit",
        "ploc-stk",
        "ploc-bit",
        "obvhs-1t",
        "embree-2t",
        "bvh/emb",
        "kd/emb",
        "hits ok"
    );
    let opt = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.2}"));
    for r in &rows {
        println!(
            "{:<13} {:<9} {:>7} {:>8.2} {:>9.2} {:>9.2} {:>9.2} {:>9.2} {:>9.2} {:>9.2} {:>9.2} {:>9} {:>9} {:>9} {:>8}",
            r.scene,
            r.rays_kind,
            r.rays,
            r.vkrt[0].3,
            r.vkrt[1].3,
            r.vkrt[2].3,
            r.vkrt[3].3,
            r.vkrt[4].3,
            r.vkrt[5].3,
            r.vkrt[6].3,
            r.obvhs_mrays_per_s,
            opt(r.embree2_mrays_per_s),
            opt(r.best_bvh_over_embree2),
            opt(r.kdtree_over_embree2),
            if r.hits_agree { "yes" } else { "NO" }
        );
    }
    println!(
        "build ms: vkrt kd-tree, LBVH and PLOC (GPU passes), SAH BVH (host, every core), obvhs \
         PLOC (1 thread), Embree (2 threads)"
    );
    for b in &builds {
        println!(
            "{:<13} {:>8} tris  kdtree {:>9.1}  sah-bvh {:>8.1}  lbvh {:>8.1}  ploc {:>8.1}  \
             obvhs {:>8.1}  embree-2t {:>8}",
            b.scene,
            b.triangles,
            b.vkrt[0].1,
            b.vkrt[1].1,
            b.vkrt[2].1,
            b.vkrt[3].1,
            b.obvhs_ms,
            opt(b.embree2_ms)
        );
    }
    for r in rows.iter().filter(|r| !r.hits_agree) {
        eprintln!(
            "note: {} {} rays: hits differ: {:?}, Embree {:?}",
            r.scene,
            r.rays_kind,
            r.vkrt.iter().map(|v| (&v.0, v.1)).collect::<Vec<_>>(),
            r.embree2_hits
        );
    }
}
