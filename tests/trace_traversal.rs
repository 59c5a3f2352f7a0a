//! kd-tree traversal (GPU kernel and CPU twin) against brute force over every primitive, on
//! random rays of several kinds, for closest and any hit, both intersectors, a tiny short
//! stack (restarts), spheres and moving geometry, and rays that must be misses.

mod common;

use common::{assert_silent, context, same_answer, Rng};
use glam::{Vec3, Vec4};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::kdtree::{breadth_first, KdTree, SahParams};
use vkrt::accel::primitives::TraceGeometry;
use vkrt::gpu::Context;
use vkrt::trace::cpu::{self, TraceScene};
use vkrt::trace::gpu::Tracer;
use vkrt::trace::{Hit, Intersector, Query, Ray, TraceOptions};

fn tree_of(g: &TraceGeometry) -> KdTree {
    breadth_first::build_boxes(&g.boxes, &SahParams::default()).0
}

/// A point on primitive `p` of `g` (triangles by random barycentrics, spheres on the
/// surface).
fn point_on(g: &TraceGeometry, p: usize, rng: &mut Rng) -> Vec3 {
    if p < g.triangle_count() {
        let [a, b, c] = g.triangle_at(p, 0.0);
        let (mut u, mut v) = (rng.next_f32() * 0.5 + 0.5, rng.next_f32() * 0.5 + 0.5);
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        a + (b - a) * u + (c - a) * v
    } else {
        let s = g.sphere_at(p - g.triangle_count(), 0.0);
        s.truncate() + rng.next_vec3().normalize_or(Vec3::X) * s.w
    }
}

/// Random rays: through the box from anywhere, aimed at points on primitives, parallel to
/// the axes with ±0 components, and starting on primitives.
/// `n` rays, a quarter of them at quick sizes (the other drivers' legs): every ray class
/// still comes thousands of times.
fn scaled(n: usize) -> usize {
    if common::quick() {
        n / 4
    } else {
        n
    }
}

fn random_rays(g: &TraceGeometry, tree: &KdTree, n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = Rng(seed);
    let (lo, hi) = (tree.bounds.min, tree.bounds.max);
    let c = (lo + hi) * 0.5;
    let ext = (hi - lo).max(Vec3::splat(1e-3));
    let prims = g.primitive_count();
    (0..n)
        .map(|i| {
            let o = c + rng.next_vec3() * ext * 0.75;
            match i % 4 {
                0 => Ray::new(o, rng.next_vec3(), 0.0, f32::MAX),
                1 => {
                    let target = point_on(g, (rng.next_u64() % prims as u64) as usize, &mut rng);
                    let from = c + rng.next_vec3().normalize_or(Vec3::Y) * ext.length();
                    Ray::new(from, target - from, 0.0, f32::MAX)
                }
                2 => {
                    let axis = (rng.next_u64() % 3) as usize;
                    let mut d = Vec3::ZERO;
                    d[axis] = if rng.next_u64() % 2 == 0 { 1.0 } else { -1.0 };
                    let mut d = d.to_array();
                    for (k, x) in d.iter_mut().enumerate() {
                        if k != axis && rng.next_u64() % 2 == 0 {
                            *x = -0.0;
                        }
                    }
                    Ray::new(o, Vec3::from_array(d), 0.0, f32::MAX)
                }
                _ => {
                    let p = point_on(g, (rng.next_u64() % prims as u64) as usize, &mut rng);
                    Ray::new(p, rng.next_vec3(), 1e-4, f32::MAX)
                }
            }
        })
        .collect()
}

/// Checks the GPU kernel and the CPU twin against brute force on `rays` (brute force on the
/// first `brute` of them, the twin on all).
fn check(
    ctx: &Context,
    name: &str,
    g: &TraceGeometry,
    tree: &KdTree,
    rays: &[Ray],
    brute: usize,
    opt: TraceOptions,
) {
    let dev = GpuGeometry::upload(ctx, g, tree).unwrap();
    let tracer = Tracer::new(ctx, &opt).unwrap();
    let batch = tracer.trace(ctx, &dev, rays, 0.0).unwrap();
    assert_eq!(batch.exhausted, 0, "{name}: rays ran out of steps");
    let scene = TraceScene { geometry: g, tree };
    let mut hits = 0;
    for (i, r) in rays.iter().enumerate() {
        let (twin, exhausted) = cpu::trace(&scene, r, 0.0, &opt);
        assert!(!exhausted, "{name}: twin ran out of steps on ray {i}");
        let gpu = batch.hits[i];
        hits += gpu.is_hit() as usize;
        assert!(
            same_answer(&gpu, &twin),
            "{name} {opt:?}: ray {i} {r:?}: GPU {gpu:?} vs CPU twin {twin:?}"
        );
        if i < brute {
            let bf = cpu::brute_force(g, r, 0.0, &opt);
            match opt.query {
                Query::Closest => assert!(
                    same_answer(&gpu, &bf),
                    "{name} {opt:?}: ray {i} {r:?}: GPU {gpu:?} vs brute force {bf:?}"
                ),
                Query::Any => assert_eq!(
                    gpu.is_hit(),
                    bf.is_hit(),
                    "{name} {opt:?}: ray {i} {r:?}: any-hit {gpu:?} vs brute force {bf:?}"
                ),
            }
        }
    }
    assert!(
        hits > rays.len() / 10,
        "{name}: only {hits} of {} rays hit",
        rays.len()
    );
    assert_silent(ctx);
}

fn mesh_tris(m: &vkrt::scene::Mesh) -> Vec<[Vec3; 3]> {
    common::mesh_triangles(m)
}

fn scenes() -> Vec<(&'static str, TraceGeometry)> {
    use vkrt::scene::gen;
    let mut out = vec![
        (
            "icosphere",
            TraceGeometry::from_triangles(&mesh_tris(&gen::icosphere(4).unwrap())),
        ),
        (
            "soup",
            TraceGeometry::from_triangles(&mesh_tris(&gen::random_soup(3000, 7).unwrap())),
        ),
        (
            "integer-grid",
            TraceGeometry::from_triangles(&mesh_tris(&gen::integer_grid(40, 40).unwrap())),
        ),
    ];
    let mut rng = Rng(11);
    let tris: Vec<[Vec3; 3]> = (0..500)
        .map(|_| {
            let o = rng.next_vec3() * 5.0;
            [o, o + rng.next_vec3(), o + rng.next_vec3()]
        })
        .collect();
    let spheres: Vec<Vec4> = (0..300)
        .map(|_| (rng.next_vec3() * 5.0).extend(0.05 + 0.3 * rng.next_f32().abs()))
        .collect();
    out.push((
        "triangles+spheres",
        TraceGeometry::from_triangles_and_spheres(&tris, &spheres),
    ));
    for (name, tris) in common::kdtree_hard_cases() {
        if name != "single" && name != "two" {
            out.push((name, TraceGeometry::from_triangles(&tris)));
        }
    }
    out
}

#[test]
fn closest_hit_equals_brute_force() {
    let Some(ctx) = context() else { return };
    for (name, g) in scenes() {
        let tree = tree_of(&g);
        let rays = random_rays(&g, &tree, 100_000, 5);
        // Every ray against the twin, the first 25,000 (the four ray classes alike) against
        // brute force too: brute force over every ray was most of the suite's time.
        check(
            &ctx,
            name,
            &g,
            &tree,
            &rays,
            25_000,
            TraceOptions::default(),
        );
    }
}

#[test]
fn bunny_closest_hit_equals_brute_force() {
    let Some(ctx) = context() else { return };
    let Some(tris) = common::bunny() else { return };
    let g = TraceGeometry::from_triangles(&tris);
    let tree = tree_of(&g);
    let rays = random_rays(&g, &tree, scaled(100_000), 9);
    // Brute force over 69K triangles for every ray is minutes on 2 cores: the first 4,000
    // rays (every kind) against brute force, all 100,000 against the twin.
    check(
        &ctx,
        "bunny",
        &g,
        &tree,
        &rays,
        4_000,
        TraceOptions::default(),
    );
}

#[test]
fn any_hit_and_moller_trumbore_and_short_stack() {
    let Some(ctx) = context() else { return };
    for (name, g) in scenes().into_iter().take(4) {
        let tree = tree_of(&g);
        let rays = random_rays(&g, &tree, scaled(20_000), 13);
        for opt in [
            TraceOptions {
                query: Query::Any,
                ..TraceOptions::default()
            },
            TraceOptions {
                intersector: Intersector::MollerTrumbore,
                ..TraceOptions::default()
            },
            // A two-entry stack drops entries on every deep path: restarts must not lose hits.
            TraceOptions {
                stack_size: 2,
                ..TraceOptions::default()
            },
        ] {
            check(&ctx, name, &g, &tree, &rays, rays.len(), opt);
        }
    }
}

#[test]
fn invalid_rays_miss() {
    let Some(ctx) = context() else { return };
    let g = TraceGeometry::from_triangles(&[[Vec3::ZERO, Vec3::X, Vec3::Y]]);
    let tree = tree_of(&g);
    let (nan, inf) = (f32::NAN, f32::INFINITY);
    let o = Vec3::new(0.2, 0.2, 1.0);
    let d = -Vec3::Z;
    let good = Ray::new(o, d, 0.0, 10.0);
    let bad = [
        Ray::new(Vec3::new(nan, 0.2, 1.0), d, 0.0, 10.0),
        Ray::new(Vec3::new(0.2, inf, 1.0), d, 0.0, 10.0),
        Ray::new(o, Vec3::new(0.0, nan, -1.0), 0.0, 10.0),
        Ray::new(o, Vec3::new(-inf, 0.0, -1.0), 0.0, 10.0),
        Ray::new(o, Vec3::ZERO, 0.0, 10.0),
        Ray::new(o, Vec3::new(-0.0, 0.0, -0.0), 0.0, 10.0),
        Ray::new(o, d, nan, 10.0),
        Ray::new(o, d, 0.0, nan),
        Ray::new(o, d, 0.0, -inf),
        Ray::new(o, d, -inf, 10.0),
        Ray::new(o, d, inf, inf),
        Ray::new(o, d, 5.0, 1.0),
    ];
    // tmax = +inf is unbounded, not invalid: the same hit as the bounded ray.
    let unbounded = Ray::new(o, d, 0.0, inf);
    let mut rays = vec![good, unbounded];
    rays.extend_from_slice(&bad);
    for opt in [
        TraceOptions::default(),
        TraceOptions {
            query: Query::Any,
            ..TraceOptions::default()
        },
    ] {
        let dev = GpuGeometry::upload(&ctx, &g, &tree).unwrap();
        let batch = Tracer::new(&ctx, &opt)
            .unwrap()
            .trace(&ctx, &dev, &rays, 0.0)
            .unwrap();
        assert!(batch.hits[0].is_hit() && (batch.hits[0].t - 1.0).abs() < 1e-6);
        assert_eq!(batch.hits[1], batch.hits[0], "tmax = inf vs tmax = 10");
        for (i, h) in batch.hits.iter().enumerate().skip(2) {
            assert_eq!(*h, Hit::MISS, "bad ray {:?} must miss", rays[i]);
            let scene = TraceScene {
                geometry: &g,
                tree: &tree,
            };
            assert_eq!(cpu::trace(&scene, &rays[i], 0.0, &opt).0, Hit::MISS);
        }
    }
    assert_silent(&ctx);
}

#[test]
fn empty_scene_misses() {
    let Some(ctx) = context() else { return };
    let g = TraceGeometry::default();
    let tree = tree_of(&g);
    let dev = GpuGeometry::upload(&ctx, &g, &tree).unwrap();
    let rays = [Ray::new(Vec3::ZERO, Vec3::X, 0.0, 1e30)];
    let batch = Tracer::new(&ctx, &TraceOptions::default())
        .unwrap()
        .trace(&ctx, &dev, &rays, 0.0)
        .unwrap();
    assert_eq!(batch.hits, vec![Hit::MISS]);
    assert_silent(&ctx);
}

#[test]
fn moving_geometry_is_traced_at_the_ray_time() {
    use vkrt::scene::{Mesh, Motion, Scene};
    let Some(ctx) = context() else { return };
    // One triangle moving +x at 1 unit/s; rays straight down at x = 0.25 and x = 2.25.
    let mut scene = Scene::default_scene();
    scene.spheres.clear();
    scene.meshes = vec![Mesh::new(
        "tri",
        vec![Vec3::ZERO, Vec3::X, Vec3::new(0.0, 0.0, 1.0)],
        vec![[0, 1, 2]],
        0,
    )];
    scene.meshes[0].motion = Motion {
        velocity: Vec3::X,
        orbit: None,
    };
    let g = TraceGeometry::over_interval(&scene, 0.0, 3.0);
    assert!(g.has_motion());
    let tree = tree_of(&g);
    let dev = GpuGeometry::upload(&ctx, &g, &tree).unwrap();
    let tracer = Tracer::new(&ctx, &TraceOptions::default()).unwrap();
    let rays = [
        Ray::new(Vec3::new(0.25, 1.0, 0.25), -Vec3::Y, 0.0, 10.0),
        Ray::new(Vec3::new(2.25, 1.0, 0.25), -Vec3::Y, 0.0, 10.0),
    ];
    let at0 = tracer.trace(&ctx, &dev, &rays, 0.0).unwrap().hits;
    let at2 = tracer.trace(&ctx, &dev, &rays, 2.0).unwrap().hits;
    assert!(at0[0].is_hit() && !at0[1].is_hit(), "{at0:?}");
    assert!(!at2[0].is_hit() && at2[1].is_hit(), "{at2:?}");
    let scene_ref = TraceScene {
        geometry: &g,
        tree: &tree,
    };
    let opt = TraceOptions::default();
    assert_eq!(
        cpu::trace(&scene_ref, &rays[1], 2.0, &opt).0.prim,
        at2[1].prim
    );
    assert_silent(&ctx);
}

/// Rays lying exactly in the split planes of a grid of axis-aligned squares, through a
/// two-entry stack that overflows on every path: GPU and CPU twin agree, and every ray the
/// walk answers equals brute force (a ray that ran out of steps would be reported and
/// answered as a miss). The restart past the last cell can still lose a flat triangle
/// lying in the plane itself (docs/features.md, Ray queries).
#[test]
fn in_plane_rays_through_an_overflowing_stack_equal_brute_force() {
    let Some(ctx) = context() else { return };
    // Unit squares in the planes z = 0..4, over x, y in 0..8: every integer is a split.
    let mut tris = Vec::new();
    for z in 0..4 {
        for x in 0..8 {
            for y in 0..8 {
                let p = |dx: i32, dy: i32| Vec3::new((x + dx) as f32, (y + dy) as f32, z as f32);
                tris.push([p(0, 0), p(1, 0), p(1, 1)]);
                tris.push([p(0, 0), p(1, 1), p(0, 1)]);
            }
        }
    }
    let g = TraceGeometry::from_triangles(&tris);
    let tree = tree_of(&g);
    let mut rng = Rng(5);
    let mut rays = Vec::new();
    for k in 0..4000 {
        // In a plane x = i or y = j (direction component exactly 0), through the stack of
        // squares from above or sideways.
        let i = (rng.next_u64() % 9) as f32;
        let (u, w) = ((rng.next_f32() + 1.0) * 4.0, (rng.next_f32() + 1.0) * 1.5);
        let (o, d) = match k % 3 {
            0 => (
                Vec3::new(i, u, 6.0),
                Vec3::new(0.0, rng.next_f32() * 0.5, -1.0),
            ),
            1 => (
                Vec3::new(u, i, 6.0),
                Vec3::new(rng.next_f32() * 0.5, 0.0, -1.0),
            ),
            _ => (Vec3::new(i, -1.0, w + 0.5), Vec3::new(0.0, 1.0, -0.1)),
        };
        rays.push(Ray::new(o, d, 0.0, f32::INFINITY));
    }
    let opt = TraceOptions {
        stack_size: 2,
        ..TraceOptions::default()
    };
    let dev = GpuGeometry::upload(&ctx, &g, &tree).unwrap();
    let tracer = Tracer::new(&ctx, &opt).unwrap();
    let batch = tracer.trace(&ctx, &dev, &rays, 0.0).unwrap();
    // The twin runs with the tracer's step cap (the device's).
    let opt = tracer.options();
    let scene = TraceScene {
        geometry: &g,
        tree: &tree,
    };
    let mut exhausted = 0;
    for (i, r) in rays.iter().enumerate() {
        let (twin, out_of_steps) = cpu::trace(&scene, r, 0.0, &opt);
        let gpu = batch.hits[i];
        if out_of_steps {
            // Reported, and answered as a miss.
            assert!(!gpu.is_hit(), "ray {i} {r:?}: exhausted but {gpu:?}");
            exhausted += 1;
        } else {
            assert!(
                same_answer(&gpu, &twin),
                "ray {i} {r:?}: GPU {gpu:?} vs twin {twin:?}"
            );
            let bf = cpu::brute_force(&g, r, 0.0, &opt);
            assert!(
                same_answer(&twin, &bf),
                "ray {i} {r:?}: {twin:?} vs brute force {bf:?}"
            );
        }
    }
    assert_eq!(batch.exhausted, exhausted, "GPU and twin exhausted counts");
    println!(
        "{exhausted} of {} in-plane rays reported exhausted",
        rays.len()
    );
    assert!(
        exhausted < rays.len() as u32 / 2,
        "{exhausted} of {} exhausted",
        rays.len()
    );
    assert_silent(&ctx);
}

/// The walk `--traversal auto` takes follows the measured rule: 4-wide on lavapipe from
/// Mesa 25.1 (where it traced faster in every measured case), the binary stack walk on
/// older lavapipe (Mesa 25.0 and 22.3 are in the test matrix) and on other devices.
#[test]
fn the_device_walk_is_wide_only_where_it_measured_faster() {
    let Some(ctx) = context() else { return };
    if std::env::var("VKRT_TRAVERSAL").is_ok() {
        return;
    }
    let info = ctx.info();
    // "llvmpipe ... Mesa 26.1.6 ..." → (26, 1)
    let mesa = info.driver.split("Mesa ").nth(1).and_then(|v| {
        let mut parts = v.split(['.', '-', ' ']).map(|p| p.parse::<u32>().ok());
        Some((parts.next()??, parts.next()??))
    });
    let lavapipe = info.device.contains("llvmpipe");
    let expected = match (lavapipe, mesa) {
        (true, Some(v)) if v >= (25, 1) => vkrt::accel::walk::Traversal::Wide,
        _ => vkrt::accel::walk::Traversal::Stack,
    };
    assert_eq!(
        vkrt::accel::walk::Traversal::for_device(&ctx),
        expected,
        "{} / {}",
        info.device,
        info.driver
    );
    assert_eq!(
        info.wide_walks,
        expected == vkrt::accel::walk::Traversal::Wide
    );
}

/// The step cap is the device's (specialization constant 22), never above it, and one set
/// lower is honoured: rays that need more steps are reported exhausted and answered as
/// misses, the same rays on the GPU and in the CPU twin, on every walk.
#[test]
fn the_step_cap_comes_from_the_device_and_a_lower_one_is_honoured() {
    let Some(ctx) = context() else { return };
    let cap = ctx.info().max_traversal_steps;
    assert_eq!(
        cap,
        vkrt::gpu::traversal_steps_within(ctx.info().loop_budget)
    );
    let resolved = Tracer::new(&ctx, &TraceOptions::default())
        .unwrap()
        .options();
    assert_eq!(resolved.max_steps, Some(cap));
    let above = TraceOptions {
        max_steps: Some(u32::MAX),
        ..TraceOptions::default()
    };
    assert_eq!(
        Tracer::new(&ctx, &above).unwrap().options().max_steps,
        Some(cap)
    );

    let (_, g) = scenes().into_iter().next().unwrap();
    let tree = tree_of(&g);
    let rays = random_rays(&g, &tree, 2000, 17);
    let dev = GpuGeometry::upload(&ctx, &g, &tree).unwrap();
    let scene = TraceScene {
        geometry: &g,
        tree: &tree,
    };
    for steps in [8, 24, 60] {
        let opt = TraceOptions {
            max_steps: Some(steps),
            ..TraceOptions::default()
        };
        let tracer = Tracer::new(&ctx, &opt).unwrap();
        assert_eq!(tracer.options().max_steps, Some(steps));
        let batch = tracer.trace(&ctx, &dev, &rays, 0.0).unwrap();
        let mut exhausted = 0;
        for (i, r) in rays.iter().enumerate() {
            let (twin, out_of_steps) = cpu::trace(&scene, r, 0.0, &tracer.options());
            let gpu = batch.hits[i];
            if out_of_steps {
                assert!(
                    !gpu.is_hit(),
                    "{steps} steps, ray {i}: exhausted but {gpu:?}"
                );
                exhausted += 1;
            } else {
                assert!(
                    same_answer(&gpu, &twin),
                    "{steps} steps, ray {i}: {gpu:?} vs {twin:?}"
                );
            }
        }
        assert_eq!(
            batch.exhausted, exhausted,
            "{steps} steps: GPU and twin exhausted counts"
        );
        println!(
            "{steps} steps: {exhausted} of {} rays exhausted",
            rays.len()
        );
        assert!(exhausted > 0, "{steps} steps: no ray ran out of steps");
        assert!(
            exhausted < rays.len() as u32,
            "{steps} steps: every ray ran out"
        );
    }
    assert_silent(&ctx);
}

#[test]
fn nodes_read_through_texel_buffers_give_the_storage_walks_hits_bit_for_bit() {
    use vkrt::accel::device::{AccelBuilder, AccelChoice, AccelKind};
    use vkrt::accel::walk::NodeAccess;
    use vkrt::accel::walk::Traversal;
    use vkrt::gpu::Recorder;
    let Some(ctx) = context() else { return };
    let bits = |h: &[Hit]| -> Vec<[u32; 4]> {
        h.iter()
            .map(|h| [h.t.to_bits(), h.prim, h.u.to_bits(), h.v.to_bits()])
            .collect()
    };
    for (name, g) in scenes().into_iter().take(4) {
        let tree = tree_of(&g);
        let rays = random_rays(&g, &tree, scaled(20_000), 13);
        for kind in [
            AccelKind::KdTree,
            AccelKind::SahBvh,
            AccelKind::Lbvh,
            AccelKind::Ploc,
        ] {
            let walks: &[Traversal] = match kind {
                AccelKind::KdTree => &[Traversal::Stack],
                _ => &Traversal::ALL,
            };
            for &walk in walks {
                let choice = AccelChoice::new(kind, walk);
                let builder = AccelBuilder::for_choice(&ctx, choice).unwrap();
                let mut rec = Recorder::new(&ctx).unwrap();
                let (dev, _) = GpuGeometry::record_build(&mut rec, &builder, &g, 0).unwrap();
                rec.submit_and_wait().unwrap();
                for query in [Query::Closest, Query::Any] {
                    let opt = TraceOptions {
                        query,
                        ..TraceOptions::default()
                    };
                    let run = |nodes| {
                        let t = Tracer::for_accel_reading(&ctx, &opt, kind.walked(walk), nodes)
                            .unwrap();
                        let b = t.trace(&ctx, &dev, &rays, 0.0).unwrap();
                        assert_eq!(b.exhausted, 0);
                        bits(&b.hits)
                    };
                    let storage = run(NodeAccess::Storage);
                    let texel = run(NodeAccess::Texel);
                    assert!(
                        storage == texel,
                        "{name} {kind:?} {walk:?} {query:?}: texel reads differ"
                    );
                    assert!(storage.iter().any(|h| h[1] != u32::MAX), "{name}: no hits");
                }
            }
        }
    }
    assert_silent(&ctx);
}
