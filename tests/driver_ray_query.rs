//! The driver's own ray tracing (issue 16): a BLAS/TLAS built by the driver over the device
//! triangles and `trace/ray_query.comp` tracing through it, against brute force over every
//! triangle — closest and any hit, 0, 1 and many triangles, both build preferences — with
//! the validation layer silent. On a device without ray query (Mesa 22.3's lavapipe) the
//! build and the tracer return the error that names the missing extensions.

mod common;

use common::{assert_silent, context, Rng};
use glam::Vec3;
use vkrt::accel::device::DevicePrimitives;
use vkrt::accel::driver::{DriverAccel, Prefer, RayQueryTracer};
use vkrt::gpu::{Context, GpuError, Recorder};
use vkrt::trace::cpu::brute_force;
use vkrt::trace::{Hit, Query, Ray, TraceGeometry, TraceOptions};

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

/// Builds the driver's structure over `g` and traces `rays` through it.
fn driver_trace(
    ctx: &Context,
    g: &TraceGeometry,
    rays: &[Ray],
    query: Query,
    prefer: Prefer,
) -> Vec<Hit> {
    let mut rec = Recorder::new(ctx).unwrap();
    let prims = DevicePrimitives::record_upload(&mut rec, g).unwrap();
    let accel = DriverAccel::record_build(&mut rec, &prims, prefer).unwrap();
    rec.submit_and_wait().unwrap();
    RayQueryTracer::new(ctx, query)
        .unwrap()
        .trace(ctx, &accel, rays)
        .unwrap()
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
fn without_ray_query_the_build_names_the_missing_extensions() {
    let Some(ctx) = context() else { return };
    if ctx.info().features.ray_query {
        eprintln!("skipped: {} has ray query", ctx.info().driver);
        return;
    }
    let g = TraceGeometry::from_triangles(&random_triangles(4, 19));
    let mut rec = Recorder::new(&ctx).unwrap();
    let prims = DevicePrimitives::record_upload(&mut rec, &g).unwrap();
    let err = DriverAccel::record_build(&mut rec, &prims, Prefer::FastTrace)
        .err()
        .expect("a build without ray query");
    rec.submit_and_wait().unwrap();
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
    let err = RayQueryTracer::new(&ctx, Query::Closest)
        .err()
        .expect("no tracer");
    assert!(err.to_string().contains("VK_KHR_ray_query"), "{err}");
    assert_silent(&ctx);
}

/// Upload, build and trace in one command buffer, nothing read back in between: the
/// barriers (transfer → build, BLAS → TLAS, build → kernel) are what synchronization
/// validation checks here.
#[test]
fn driver_build_and_trace_in_one_submission() {
    let Some(ctx) = ray_query_context() else {
        return;
    };
    let tris = random_triangles(500, 20);
    let g = TraceGeometry::from_triangles(&tris);
    let rays = random_rays(&tris, 1024, 91);
    let tracer = RayQueryTracer::new(&ctx, Query::Closest).unwrap();
    let ray_buf = vkrt::gpu::Buffer::new(&ctx, "rays", rays.len()).unwrap();
    let hits = vkrt::gpu::Buffer::<Hit>::new(&ctx, "hits", rays.len()).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.upload(&ray_buf, &rays).unwrap();
    let prims = DevicePrimitives::record_upload(&mut rec, &g).unwrap();
    let accel = DriverAccel::record_build(&mut rec, &prims, Prefer::FastBuild).unwrap();
    tracer.record(&mut rec, &accel, &ray_buf, &hits, rays.len());
    rec.compute_to_transfer();
    let back = rec.read_back(&hits).unwrap();
    rec.transfer_to_host();
    let profile = rec.submit_and_wait().unwrap();
    eprintln!("driver build: {:?} ms", profile.ms("driver_build"));
    assert_eq!(closest_differences(&tris, &rays, &back.read().unwrap()), 0);
    assert_silent(&ctx);
}
