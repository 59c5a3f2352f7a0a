//! The driver's own ray tracing as a structure kind (`AccelKind::Driver`): a
//! BLAS/TLAS built by the driver over the device primitives in the caller's recorder and the
//! `query` variant of `render/trace.comp` tracing through it, against brute force —
//! closest and any hit, 0, 1 and many triangles, spheres as boxes, moving primitives at
//! several times, both build preferences, a refit after motion — with the validation layer
//! silent. On a device without ray query (Mesa 22.3's lavapipe) the builder and the tracer
//! return the error that names the missing extensions.

mod common;

use common::{assert_silent, context, same_answer, Rng};
use glam::{Vec3, Vec4};
use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::driver::Prefer;
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::primitives::TraceGeometry;
use vkrt::accel::walk::AccelTraversal;
use vkrt::gpu::{Context, GpuError, Recorder};
use vkrt::trace::cpu::brute_force;
use vkrt::trace::gpu::{build_and_trace, Tracer};
use vkrt::trace::{Hit, Query, Ray, TraceOptions};

/// Relative tolerance on `t` between the driver's intersector and ours.
const T_TOL: f32 = 1e-4;

/// `n` random triangles in [-1, 1]³, each within a box of about 0.3 around its centre.
fn random_triangles(n: usize, seed: u64) -> Vec<[Vec3; 3]> {
    let mut rng = Rng(seed);
    (0..n)
        .map(|_| {
            let c = rng.next_vec3();
            [
                c + rng.next_vec3() * 0.15,
                c + rng.next_vec3() * 0.15,
                c + rng.next_vec3() * 0.15,
            ]
        })
        .collect()
}

/// Random rays: from anywhere in a box twice the scene's, in random directions, and aimed
/// at random points inside random triangles.
fn random_rays(tris: &[[Vec3; 3]], n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = Rng(seed);
    (0..n)
        .map(|i| {
            let o = rng.next_vec3() * 2.0;
            if i % 2 == 0 || tris.is_empty() {
                Ray::new(o, rng.next_vec3(), 0.0, f32::MAX)
            } else {
                let [a, b, c] = tris[(rng.next_u64() % tris.len() as u64) as usize];
                let (mut u, mut v) = (rng.next_f32() * 0.5 + 0.5, rng.next_f32() * 0.5 + 0.5);
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                let target = a + (b - a) * u + (c - a) * v;
                Ray::new(o, target - o, 0.0, f32::MAX)
            }
        })
        .collect()
}

/// Builds the driver's structure over `g` and traces `rays` through it at `time`, in one
/// submission.
fn driver_trace_at(
    ctx: &Context,
    g: &TraceGeometry,
    rays: &[Ray],
    query: Query,
    prefer: Prefer,
    time: f32,
) -> Vec<Hit> {
    let mut builder = AccelBuilder::new(ctx, AccelKind::Driver).unwrap();
    builder = builder.with_driver_prefer(prefer);
    let opt = TraceOptions {
        query,
        ..TraceOptions::default()
    };
    let tracer = Tracer::for_accel(ctx, &opt, AccelTraversal::RayQuery).unwrap();
    let done = build_and_trace(ctx, &builder, &tracer, g, rays, time, None).unwrap();
    assert_eq!(done.traffic.submits, 1);
    assert_eq!(done.readback_before_trace, 0);
    assert_eq!(done.batch.exhausted, 0);
    done.batch.hits
}

fn driver_trace(
    ctx: &Context,
    g: &TraceGeometry,
    rays: &[Ray],
    query: Query,
    prefer: Prefer,
) -> Vec<Hit> {
    driver_trace_at(ctx, g, rays, query, prefer, 0.0)
}

/// The driver's triangle test is its own and not exact: the same answer as brute force,
/// with `t` within [`T_TOL`] of it, or 10 [`T_TOL`] for the same primitive (grazing rays make
/// `t` ill-conditioned), or another primitive in a tie.
fn driver_agrees(d: &Hit, b: &Hit) -> bool {
    match (d.is_hit(), b.is_hit()) {
        (false, false) => true,
        (true, true) if d.prim == b.prim => {
            (d.t - b.t).abs() <= 10.0 * T_TOL * d.t.abs().max(b.t.abs())
        }
        (true, true) => close(d.t, b.t),
        _ => false,
    }
}

fn close(a: f32, b: f32) -> bool {
    (a - b).abs() <= T_TOL * a.abs().max(b.abs()).max(1e-30)
}

/// `t` of triangle `prim` alone along `r` (brute force over that one triangle).
fn t_of(tris: &[[Vec3; 3]], prim: u32, r: &Ray) -> Option<f32> {
    let one = TraceGeometry::from_triangles(&[tris[prim as usize]]);
    let h = brute_force(&one, r, 0.0, &TraceOptions::default());
    h.is_hit().then_some(h.t)
}

/// Differences between the driver's closest hits and brute force: a different hit or miss,
/// `t` off by more than [`T_TOL`], or another triangle that is not at the same `t` within
/// [`T_TOL`] (a tie). Prints each.
fn closest_differences(tris: &[[Vec3; 3]], rays: &[Ray], hits: &[Hit]) -> usize {
    let g = TraceGeometry::from_triangles(tris);
    let mut diffs = 0;
    for (i, (r, d)) in rays.iter().zip(hits).enumerate() {
        let b = brute_force(&g, r, 0.0, &TraceOptions::default());
        let ok = match (b.is_hit(), d.is_hit()) {
            (false, false) => d.prim == u32::MAX && d.t == f32::INFINITY,
            (true, true) if b.prim == d.prim => {
                close(b.t, d.t) && (b.u - d.u).abs() < 1e-3 && (b.v - d.v).abs() < 1e-3
            }
            (true, true) => close(b.t, d.t) && t_of(tris, d.prim, r).is_some_and(|t| close(t, b.t)),
            _ => false,
        };
        if !ok {
            diffs += 1;
            eprintln!("ray {i} {r:?}: brute force {b:?}, driver {d:?}");
        }
    }
    diffs
}

fn ray_query_context() -> Option<common::TestContext> {
    let ctx = context()?;
    if !ctx.info().features.ray_query {
        eprintln!("skipped: {} has no ray query", ctx.info().driver);
        return None;
    }
    Some(ctx)
}

#[test]
fn driver_closest_hits_equal_brute_force() {
    let Some(ctx) = ray_query_context() else {
        return;
    };
    let tris = random_triangles(2000, 16);
    let g = TraceGeometry::from_triangles(&tris);
    let rays = random_rays(&tris, 4096, 61);
    for prefer in [Prefer::FastTrace, Prefer::FastBuild] {
        let hits = driver_trace(&ctx, &g, &rays, Query::Closest, prefer);
        let hit_count = hits.iter().filter(|h| h.is_hit()).count();
        let diffs = closest_differences(&tris, &rays, &hits);
        eprintln!(
            "{prefer:?}: {} rays, {hit_count} hits, {diffs} differences from brute force",
            rays.len()
        );
        assert!(hit_count > rays.len() / 3, "too few hits to mean anything");
        assert_eq!(diffs, 0, "{prefer:?}");
    }
    assert_silent(&ctx);
}

#[test]
fn driver_any_hit_agrees_on_hit_or_miss() {
    let Some(ctx) = ray_query_context() else {
        return;
    };
    let tris = random_triangles(1000, 17);
    let g = TraceGeometry::from_triangles(&tris);
    // Bounded rays too, so that some hit only beyond tmax (0.5: aimed rays reach their
    // target at t = 1, where a bound would make the answer a matter of rounding).
    let mut rays = random_rays(&tris, 2048, 71);
    for r in rays.iter_mut().skip(2).step_by(3) {
        r.tmax = 0.5;
    }
    let hits = driver_trace(&ctx, &g, &rays, Query::Any, Prefer::FastTrace);
    let mut diffs = 0;
    for (i, (r, d)) in rays.iter().zip(&hits).enumerate() {
        let b = brute_force(&g, r, 0.0, &TraceOptions::default());
        // Any hit: the same answer to "is there a hit in [tmin, tmax]", and a reported hit is
        // a true one of that triangle, no nearer than the closest.
        let ok = b.is_hit() == d.is_hit()
            && (!d.is_hit()
                || (t_of(&tris, d.prim, r).is_some_and(|t| close(t, d.t))
                    && d.t >= b.t * (1.0 - T_TOL)
                    && d.t <= r.tmax));
        if !ok {
            diffs += 1;
            eprintln!("ray {i} {r:?}: brute force {b:?}, driver any hit {d:?}");
        }
    }
    eprintln!("any hit: {} rays, {diffs} differences", rays.len());
    assert_eq!(diffs, 0);
    assert_silent(&ctx);
}

#[test]
fn driver_traces_zero_and_one_triangle() {
    let Some(ctx) = ray_query_context() else {
        return;
    };
    for n in [0, 1] {
        let tris = random_triangles(n, 18);
        let g = TraceGeometry::from_triangles(&tris);
        let rays = random_rays(&tris, 256, 81);
        for query in [Query::Closest, Query::Any] {
            let hits = driver_trace(&ctx, &g, &rays, query, Prefer::FastTrace);
            assert_eq!(
                closest_differences(&tris, &rays, &hits),
                0,
                "{n} triangles, {query:?}"
            );
            if n == 0 {
                assert!(hits.iter().all(|h| *h == Hit::MISS));
            } else {
                assert!(hits.iter().any(|h| h.is_hit()));
            }
        }
    }
    assert_silent(&ctx);
}

#[test]
fn without_ray_query_the_builder_and_tracer_name_the_missing_extensions() {
    let Some(ctx) = context() else { return };
    if ctx.info().features.ray_query {
        eprintln!("skipped: {} has ray query", ctx.info().driver);
        return;
    }
    let err = AccelBuilder::new(&ctx, AccelKind::Driver)
        .err()
        .expect("a driver builder without ray query");
    let text = err.to_string();
    eprintln!("{text}");
    assert!(matches!(err, GpuError::MissingCapability { .. }), "{err:?}");
    for ext in [
        "VK_KHR_acceleration_structure",
        "VK_KHR_ray_query",
        "VK_KHR_deferred_host_operations",
    ] {
        assert!(text.contains(ext), "{text}");
    }
    let err = Tracer::for_accel(&ctx, &TraceOptions::default(), AccelTraversal::RayQuery)
        .err()
        .expect("no tracer");
    assert!(err.to_string().contains("VK_KHR_ray_query"), "{err}");
    assert!(!AccelKind::available(&ctx).contains(&AccelKind::Driver));
    assert_silent(&ctx);
}

/// Random spheres among random triangles: spheres are box geometry the kernel intersects.
#[test]
fn driver_spheres_and_triangles_equal_brute_force() {
    let Some(ctx) = ray_query_context() else {
        return;
    };
    let tris = random_triangles(700, 21);
    let mut rng = Rng(22);
    let spheres: Vec<Vec4> = (0..300)
        .map(|_| rng.next_vec3().extend(0.02 + 0.1 * rng.next_f32().abs()))
        .collect();
    let g = TraceGeometry::from_triangles_and_spheres(&tris, &spheres);
    let rays = random_rays(&tris, 4096, 23);
    for query in [Query::Closest, Query::Any] {
        let hits = driver_trace(&ctx, &g, &rays, query, Prefer::FastTrace);
        let opt = TraceOptions {
            query,
            ..TraceOptions::default()
        };
        let mut sphere_hits = 0;
        let mut wrong = 0;
        for (r, h) in rays.iter().zip(&hits) {
            let b = brute_force(&g, r, 0.0, &TraceOptions::default());
            sphere_hits += (h.is_hit() && h.prim >= tris.len() as u32) as usize;
            let ok = match query {
                Query::Closest => same_answer(h, &b),
                // A hit iff there is one, and a true one of that primitive.
                Query::Any => {
                    h.is_hit() == b.is_hit()
                        && (!h.is_hit() || {
                            let one = brute_force(
                                &g,
                                &Ray {
                                    tmax: h.t * (1.0 + T_TOL),
                                    ..*r
                                },
                                0.0,
                                &opt,
                            );
                            one.is_hit()
                        })
                }
            };
            if !ok {
                wrong += 1;
                eprintln!("{query:?} {r:?}: brute force {b:?}, driver {h:?}");
            }
        }
        eprintln!("{query:?}: {sphere_hits} sphere hits, {wrong} wrong");
        assert!(sphere_hits > 100, "{sphere_hits} sphere hits");
        assert_eq!(wrong, 0, "{query:?}");
    }
    assert_silent(&ctx);
}

/// Moving meshes and a moving sphere (the motion-blur example): every primitive is a swept
/// box the kernel intersects at the ray's time.
#[test]
fn driver_moving_scene_equals_brute_force_at_each_time() {
    let Some(ctx) = ray_query_context() else {
        return;
    };
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/motion_blur.toml");
    let scene = vkrt::scene::Scene::load(&path).unwrap().scene;
    let g = TraceGeometry::over_interval(&scene, 0.0, 1.0);
    assert!(g.has_motion());
    let mut bounds = vkrt::scene::Aabb::EMPTY;
    g.boxes.iter().for_each(|b| bounds.union(b));
    let mut rng = Rng(31);
    let rays: Vec<Ray> = (0..3000)
        .map(|_| {
            let u = (rng.next_vec3() + 1.0) * 0.5;
            let target = bounds.min + (bounds.max - bounds.min) * u;
            let o = target + rng.next_vec3().normalize_or_zero() * 20.0;
            Ray::new(o, target - o, 0.0, f32::INFINITY)
        })
        .collect();
    for time in [0.0, 0.37, 1.0] {
        let hits = driver_trace_at(&ctx, &g, &rays, Query::Closest, Prefer::FastTrace, time);
        let opt = TraceOptions::default();
        let wrong = rays
            .iter()
            .zip(&hits)
            .filter(|(r, h)| !same_answer(h, &brute_force(&g, r, time, &opt)))
            .count();
        let n_hits = hits.iter().filter(|h| h.is_hit()).count();
        eprintln!("time {time}: {n_hits} hits, {wrong} wrong");
        assert!(n_hits > rays.len() / 4, "{n_hits} hits");
        assert_eq!(wrong, 0, "time {time}");
    }
    assert_silent(&ctx);
}

/// Built to be updated, moved, refit by the driver in place: traces like brute force on the
/// moved primitives.
#[test]
fn driver_refit_follows_moved_primitives() {
    let Some(ctx) = ray_query_context() else {
        return;
    };
    let tris = random_triangles(1500, 41);
    let spheres = [
        Vec4::new(0.0, 0.0, 0.0, 0.3),
        Vec4::new(0.5, -0.5, 0.2, 0.2),
    ];
    let g = TraceGeometry::from_triangles_and_spheres(&tris, &spheres);
    let mut rng = Rng(42);
    let moved_tris: Vec<[Vec3; 3]> = tris
        .iter()
        .map(|t| {
            let d = rng.next_vec3() * 0.1;
            t.map(|p| p + d)
        })
        .collect();
    let moved_spheres = spheres.map(|s| s + Vec4::new(0.2, 0.1, 0.0, 0.0));
    let moved = TraceGeometry::from_triangles_and_spheres(&moved_tris, &moved_spheres);
    let rays = random_rays(&moved_tris, 4096, 43);

    let mut builder = AccelBuilder::new(&ctx, AccelKind::Driver).unwrap();
    builder = builder.with_allow_update(true);
    let opt = TraceOptions::default();
    let tracer = Tracer::for_accel(&ctx, &opt, AccelTraversal::RayQuery).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    let (mut dev, _) = GpuGeometry::record_build(&mut rec, &builder, &g, 0).unwrap();
    dev.primitives().record_update(&mut rec, &moved).unwrap();
    let scratch = builder
        .update_scratch(&ctx, g.primitive_count())
        .unwrap()
        .unwrap();
    builder.record_refit(&mut rec, &mut dev, &scratch).unwrap();
    rec.submit_and_wait().unwrap();
    let hits = tracer.trace(&ctx, &dev, &rays, 0.0).unwrap().hits;
    let wrong = rays
        .iter()
        .zip(&hits)
        .filter(|(r, h)| {
            let b = brute_force(&moved, r, 0.0, &opt);
            let ok = driver_agrees(h, &b);
            if !ok {
                eprintln!("{r:?}: brute force {b:?}, refit driver {h:?}");
            }
            !ok
        })
        .count();
    let n_hits = hits.iter().filter(|h| h.is_hit()).count();
    eprintln!("refit: {n_hits} hits, {wrong} wrong");
    assert!(n_hits > rays.len() / 3);
    assert_eq!(wrong, 0);

    // Built without allow_update, a refit is a clear error.
    let plain = AccelBuilder::new(&ctx, AccelKind::Driver).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    let (mut dev, _) = GpuGeometry::record_build(&mut rec, &plain, &g, 0).unwrap();
    let err = plain
        .record_refit(&mut rec, &mut dev, &scratch)
        .expect_err("a refit without allow_update");
    assert!(matches!(err, GpuError::Usage { .. }), "{err}");
    assert!(err.to_string().contains("rebuild"), "{err}");
    rec.submit_and_wait().unwrap();
    let opaque = dev.structure().download().map(|_| ()).unwrap_err();
    assert!(
        matches!(opaque, GpuError::Usage { .. }),
        "the driver's structure is opaque: {opaque}"
    );
    assert_silent(&ctx);
}
