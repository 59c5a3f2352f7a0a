//! Ray throughput of the GPU tracer against a CPU peer in the same run (issue 6).
//!
//! On the Stanford bunny (../shared/scenes, skipped with a message when absent) and
//! icospheres of 100K and 500K triangles: a 512×512 pinhole camera framing the object gives
//! the primary rays (closest hit); from their hits, shadow rays towards a point light
//! (any hit) and mirror reflections (closest hit). The same rays go through our GPU kd-tree
//! tracer (watertight test; time = GPU timestamps around the trace kernel, best of 3) and
//! through obvhs's PLOC BVH (`BvhBuildParams::medium_build`, Möller–Trumbore, one CPU
//! thread; wall time). Prints Mrays/s for both, their ratio and the hit counts.
//!
//! `cargo bench --bench trace [-- --json] [-- --size 512]`

use std::path::PathBuf;
use std::time::{Duration, Instant};

use glam::Vec3;
use obvhs::bvh2::builder::build_bvh2_from_tris;
use obvhs::BvhBuildParams;
use vkrt::gpu::{Context, ContextOptions, Validation};
use vkrt::trace::gpu::{build_kdtree, GpuGeometry, Tracer};
use vkrt::trace::intersect::offset_ray_origin;
use vkrt::trace::{Hit, Query, Ray, TraceGeometry, TraceOptions};

#[derive(serde::Serialize)]
struct Row {
    scene: String,
    triangles: usize,
    rays_kind: &'static str,
    rays: usize,
    gpu_hits: usize,
    gpu_ms: f64,
    gpu_mrays_per_s: f64,
    obvhs_hits: usize,
    obvhs_ms: f64,
    obvhs_mrays_per_s: f64,
    /// GPU Mrays/s ÷ obvhs Mrays/s.
    ratio: f64,
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
    let ctx = Context::new(&ContextOptions {
        validation: Validation::Off,
        device_name: None,
    })
    .expect("a Vulkan device");

    let mut scenes: Vec<(String, Vec<[Vec3; 3]>)> = Vec::new();
    let bunny =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes/stanford-bunny.obj");
    if bunny.exists() {
        let scene = vkrt::scene::Scene::load(&bunny)
            .expect("load the bunny")
            .scene;
        scenes.push(("bunny".into(), scene.triangles_world(0.0)));
    } else {
        eprintln!("skipped the bunny: {} is absent", bunny.display());
    }
    for n in [100_000u64, 500_000] {
        let m = vkrt::scene::gen::icosphere_with_at_least(n).expect("icosphere");
        let tris = m
            .indices
            .iter()
            .map(|t| t.map(|i| m.positions[i as usize]))
            .collect();
        scenes.push((format!("icosphere{}k", n / 1000), tris));
    }

    let mut rows = Vec::new();
    for (name, tris) in &scenes {
        let g = TraceGeometry::from_triangles(tris);
        let (tree, _) = build_kdtree(&ctx, &g, &Default::default()).expect("kd-tree build");
        let dev = GpuGeometry::upload(&ctx, &g, &tree).expect("upload");
        let closest = Tracer::new(&ctx, &TraceOptions::default()).expect("tracer");
        let any = Tracer::new(
            &ctx,
            &TraceOptions {
                query: Query::Any,
                ..TraceOptions::default()
            },
        )
        .expect("tracer");

        let ob_tris: Vec<obvhs::triangle::Triangle> = tris
            .iter()
            .map(|t| obvhs::triangle::Triangle {
                v0: v34(t[0]),
                v1: v34(t[1]),
                v2: v34(t[2]),
            })
            .collect();
        let bvh = build_bvh2_from_tris(
            &ob_tris,
            BvhBuildParams::medium_build(),
            &mut Duration::default(),
        );

        let gpu = |tracer: &Tracer, rays: &[Ray]| {
            let mut best = f64::MAX;
            let mut hits = Vec::new();
            for _ in 0..3 {
                let b = tracer
                    .trace_batched(&ctx, &dev, rays, 0.0, None)
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
        let (p_hits, p_ms) = gpu(&closest, &primary);
        let (lo, hi) = (tree.bounds.min, tree.bounds.max);
        let light = (lo + hi) * 0.5 + Vec3::new(1.0, 2.0, 1.5) * (hi - lo).length();
        let (shadow, mirror) = secondary(&g, &primary, &p_hits, light);
        let (s_hits, s_ms) = gpu(&any, &shadow);
        let (m_hits, m_ms) = gpu(&closest, &mirror);
        for (kind, rays, hits, ms, any_hit) in [
            ("primary", &primary, &p_hits, p_ms, false),
            ("shadow", &shadow, &s_hits, s_ms, true),
            ("secondary", &mirror, &m_hits, m_ms, false),
        ] {
            let (ob_hits, ob_ms) = cpu(rays, any_hit);
            let mr = |ms: f64| rays.len() as f64 / (ms * 1e3);
            rows.push(Row {
                scene: name.clone(),
                triangles: tris.len(),
                rays_kind: kind,
                rays: rays.len(),
                gpu_hits: hits.iter().filter(|h| h.is_hit()).count(),
                gpu_ms: ms,
                gpu_mrays_per_s: mr(ms),
                obvhs_hits: ob_hits,
                obvhs_ms: ob_ms,
                obvhs_mrays_per_s: mr(ob_ms),
                ratio: mr(ms) / mr(ob_ms),
            });
        }
    }
    if json {
        let v = serde_json::json!({ "device": ctx.info().device, "size": size, "rows": rows });
        println!("{}", serde_json::to_string_pretty(&v).unwrap());
        return;
    }
    println!(
        "{} — {size}×{size} camera; obvhs: PLOC medium_build, 1 CPU thread",
        ctx.info().device
    );
    println!(
        "{:<14} {:>8} {:<10} {:>8} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>7}",
        "scene",
        "tris",
        "rays",
        "n",
        "gpu hits",
        "gpu ms",
        "gpu Mr/s",
        "cpu hits",
        "cpu ms",
        "cpu Mr/s",
        "ratio"
    );
    for r in &rows {
        println!(
            "{:<14} {:>8} {:<10} {:>8} {:>9} {:>9.1} {:>9.2} {:>9} {:>9.1} {:>9.2} {:>7.2}",
            r.scene,
            r.triangles,
            r.rays_kind,
            r.rays,
            r.gpu_hits,
            r.gpu_ms,
            r.gpu_mrays_per_s,
            r.obvhs_hits,
            r.obvhs_ms,
            r.obvhs_mrays_per_s,
            r.ratio
        );
    }
}
