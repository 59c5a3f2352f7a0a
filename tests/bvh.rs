//! The CPU SAH BVH of Sochora (2013): valid trees at every edge size and on degenerate input,
//! the same tree from every threading scheme and thread count, the full sweep and binned
//! SAH, the depth cap, clear errors on bad parameters and boxes — both CPU traversals
//! (stack and the bitstack (Áfra & Szirmay-Kalos 2014)) equal to brute force, closest hit bit for bit, and the
//! GPU traversals (`glsl/include/vkrt/bvh.glsl`) equal to their CPU twin, under validation.

mod common;

use common::{assert_silent, context, same_answer, Rng};
use glam::{Vec3, Vec4};
use vkrt::accel::bvh::{self, validate, Bvh, BvhError, BvhParams, Threading};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::primitives::TraceGeometry;
use vkrt::accel::walk::AccelTraversal;
use vkrt::accel::walk::Traversal;
use vkrt::scene::{gen, Aabb};
use vkrt::trace::bvh_cpu;
use vkrt::trace::gpu::Tracer;
use vkrt::trace::{cpu, Intersector, Query, Ray, TraceOptions};

fn soup(n: usize, seed: u64) -> Vec<[Vec3; 3]> {
    let mut rng = Rng(seed);
    (0..n)
        .map(|_| {
            let c = rng.next_vec3() * 10.0;
            let s = 0.05 + rng.next_f32().abs();
            [c, c + rng.next_vec3() * s, c + rng.next_vec3() * s]
        })
        .collect()
}

fn tris(mesh: &vkrt::scene::Mesh) -> Vec<[Vec3; 3]> {
    mesh.indices
        .iter()
        .map(|t| t.map(|i| mesh.positions[i as usize]))
        .collect()
}

fn params() -> Vec<BvhParams> {
    let base = BvhParams::default();
    vec![
        base,
        BvhParams {
            bins: Some(8),
            ..base
        },
        BvhParams {
            bins: Some(256),
            max_leaf_prims: 1,
            ..base
        },
        BvhParams {
            max_leaf_prims: 16,
            ..base
        },
    ]
}

/// Builds with every scheme at 1, 2 and 3 threads; all must equal the single-threaded tree
/// and pass the validator.
fn build_all(name: &str, boxes: &[Aabb], p: &BvhParams) -> Bvh {
    let single = bvh::build(boxes, p, Threading::Single).unwrap();
    validate::validate(&single, boxes).unwrap_or_else(|e| panic!("{name} {p:?}: {e}"));
    assert!(
        single.depth() as usize <= bvh::sah::MAX_DEPTH,
        "{name}: depth"
    );
    for threads in [1, 2, 3] {
        for scheme in Threading::all(threads) {
            let other = bvh::build(boxes, p, scheme).unwrap();
            assert!(
                other == single,
                "{name} {p:?}: {scheme:?} differs from Single"
            );
        }
    }
    single
}

#[test]
fn every_edge_size_and_scheme_gives_one_valid_tree() {
    for n in [
        0usize, 1, 2, 3, 4, 5, 7, 8, 9, 31, 32, 33, 63, 64, 65, 257, 4095, 4097, 20_000,
    ] {
        let g = TraceGeometry::from_triangles(&soup(n, n as u64));
        for p in params() {
            let t = build_all(&format!("soup({n})"), &g.boxes, &p);
            // A binary tree: one leaf more than interior nodes, or a root holding one leaf.
            let root_leaf = t.nodes.len() == 1 && t.leaf_count() == 1;
            if n > 0 && !root_leaf {
                assert_eq!(t.leaf_count(), t.nodes.len() + 1, "soup({n}) {p:?}");
            }
        }
    }
}

#[test]
fn degenerate_inputs_build_valid_trees() {
    let one_point = vec![[Vec3::ONE; 3]; 1000];
    let same = vec![[Vec3::ZERO, Vec3::X, Vec3::Y]; 777];
    let flat: Vec<[Vec3; 3]> = soup(3000, 5)
        .into_iter()
        .map(|t| t.map(|v| Vec3::new(v.x, 0.0, v.z)))
        .collect();
    // Sizes growing geometrically along a line: the SAH peels one off at a time, so the
    // depth cap (median splits) must keep the tree within 64 levels.
    let peel: Vec<[Vec3; 3]> = (0..3000)
        .map(|i| {
            let s = 1.01f32.powi(i);
            let c = Vec3::new(s, 0.0, 0.0);
            [c, c + Vec3::Y * s * 0.1, c + Vec3::Z * s * 0.1]
        })
        .collect();
    for (name, t) in [
        ("one point", one_point),
        ("identical", same),
        ("flat", flat),
        ("peel", peel),
    ] {
        let g = TraceGeometry::from_triangles(&t);
        for p in params() {
            let b = build_all(name, &g.boxes, &p);
            assert!(b.depth() <= 64, "{name}: depth {}", b.depth());
        }
    }
}

#[test]
fn full_sweep_is_at_least_as_good_as_binning_on_the_bunny_or_an_icosphere() {
    let t = match common::bunny() {
        Some(t) => t,
        None => tris(&gen::icosphere(5).unwrap()),
    };
    let g = TraceGeometry::from_triangles(&t);
    let sweep = BvhParams::default();
    let full = bvh::build(&g.boxes, &sweep, Threading::Queue { threads: 2 }).unwrap();
    validate::validate(&full, &g.boxes).unwrap();
    let full_cost = validate::sah_cost(&full, &sweep);
    for bins in [8, 16, 32, 64, 256] {
        let p = BvhParams {
            bins: Some(bins),
            ..sweep
        };
        let binned = bvh::build(&g.boxes, &p, Threading::Rayon).unwrap();
        validate::validate(&binned, &g.boxes).unwrap();
        let cost = validate::sah_cost(&binned, &p);
        eprintln!("SAH cost: full sweep {full_cost:.2}, {bins} bins {cost:.2}");
        // Greedy top-down splits are not globally optimal; allow 3 %.
        assert!(
            full_cost <= cost * 1.03,
            "{bins} bins {cost} beat the sweep {full_cost}"
        );
    }
}

#[test]
fn bad_parameters_and_boxes_are_clear_errors() {
    let g = TraceGeometry::from_triangles(&soup(10, 1));
    let err = |p: BvhParams| bvh::build(&g.boxes, &p, Threading::Single).unwrap_err();
    let base = BvhParams::default();
    assert_eq!(
        err(BvhParams {
            bins: Some(4),
            ..base
        }),
        BvhError::Bins(4)
    );
    assert_eq!(
        err(BvhParams {
            bins: Some(512),
            ..base
        }),
        BvhError::Bins(512)
    );
    assert_eq!(
        err(BvhParams {
            max_leaf_prims: 0,
            ..base
        }),
        BvhError::LeafSize
    );
    assert!(matches!(
        err(BvhParams {
            traversal_cost: f32::NAN,
            ..base
        }),
        BvhError::Costs(..)
    ));
    let mut boxes = g.boxes.clone();
    boxes[3].max.y = f32::INFINITY;
    let e = bvh::build(&boxes, &base, Threading::Single).unwrap_err();
    assert!(e.to_string().contains("primitive 3"), "{e}");
    boxes[3].max.y = boxes[3].min.y - 1.0;
    assert!(matches!(
        bvh::build(&boxes, &base, Threading::Single),
        Err(BvhError::BadBox(3, ..))
    ));
}

/// Rays from anywhere in the box, at points on primitives, axis-parallel with ±0, from
/// primitives outward, unbounded and bounded.
fn rays(g: &TraceGeometry, b: &Aabb, n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = Rng(seed);
    let c = (b.min + b.max) * 0.5;
    let ext = (b.max - b.min).max(Vec3::splat(1e-3));
    (0..n)
        .map(|i| {
            let o = c + rng.next_vec3() * ext * 0.75;
            let p = (rng.next_u64() % g.primitive_count() as u64) as usize;
            let target = if p < g.triangle_count() {
                let [a, b2, c2] = g.triangle_at(p, 0.0);
                (a + b2 + c2) / 3.0
            } else {
                g.sphere_at(p - g.triangle_count(), 0.0).truncate()
            };
            match i % 4 {
                0 => Ray::new(o, rng.next_vec3(), 0.0, f32::INFINITY),
                1 => {
                    let from = c + rng.next_vec3().normalize_or(Vec3::Y) * ext.length();
                    Ray::new(from, target - from, 0.0, f32::MAX)
                }
                2 => {
                    let mut d = [-0.0f32, 0.0, -0.0];
                    d[(rng.next_u64() % 3) as usize] = if i % 8 < 4 { 1.0 } else { -1.0 };
                    Ray::new(o, Vec3::from_array(d), 0.0, ext.length())
                }
                _ => Ray::new(target, rng.next_vec3(), 1e-4, f32::INFINITY),
            }
        })
        .collect()
}

fn check_traversal(name: &str, g: &TraceGeometry, p: &BvhParams, n_rays: usize) {
    let tree = bvh::build(&g.boxes, p, Threading::Rayon).unwrap();
    let rays = rays(g, &tree.bounds, n_rays, 17);
    let mut hits = 0;
    for query in [Query::Closest, Query::Any] {
        let opt = TraceOptions {
            query,
            ..TraceOptions::default()
        };
        for traversal in Traversal::ALL {
            for (i, r) in rays.iter().enumerate() {
                let (h, exhausted) = bvh_cpu::trace(g, &tree, r, 0.0, &opt, traversal);
                assert!(!exhausted, "{name}: ray {i} ran out of steps");
                let bf = cpu::brute_force(g, r, 0.0, &opt);
                if query == Query::Closest {
                    assert_eq!(h, bf, "{name} {traversal:?}: ray {i} {r:?}");
                    hits += h.is_hit() as usize;
                } else {
                    assert_eq!(h.is_hit(), bf.is_hit(), "{name} {traversal:?} any: ray {i}");
                }
            }
        }
    }
    assert!(
        hits > n_rays / 4,
        "{name}: only {hits} hits of {n_rays} rays x 2"
    );
}

#[test]
fn stack_and_bitstack_equal_brute_force() {
    let ico = TraceGeometry::from_triangles(&tris(&gen::icosphere(3).unwrap()));
    let mut rng = Rng(9);
    let spheres: Vec<Vec4> = (0..300)
        .map(|_| (rng.next_vec3() * 5.0).extend(0.05 + rng.next_f32().abs() * 0.5))
        .collect();
    let mixed = TraceGeometry::from_triangles_and_spheres(&soup(2000, 3), &spheres);
    let flat: Vec<[Vec3; 3]> = soup(1500, 5)
        .into_iter()
        .map(|t| t.map(|v| Vec3::new(v.x, 0.0, v.z)))
        .collect();
    let flat = TraceGeometry::from_triangles(&flat);
    for p in [
        BvhParams::default(),
        BvhParams {
            bins: Some(16),
            max_leaf_prims: 8,
            ..BvhParams::default()
        },
    ] {
        check_traversal("icosphere(3)", &ico, &p, 3000);
        check_traversal("soup+spheres", &mixed, &p, 3000);
        check_traversal("flat", &flat, &p, 2000);
    }
}

#[test]
fn empty_and_invalid_rays_miss() {
    let g = TraceGeometry::from_triangles(&[]);
    let t = bvh::build(&g.boxes, &BvhParams::default(), Threading::Single).unwrap();
    let r = Ray::new(Vec3::ZERO, Vec3::X, 0.0, f32::INFINITY);
    for traversal in Traversal::ALL {
        let (h, _) = bvh_cpu::trace(&g, &t, &r, 0.0, &TraceOptions::default(), traversal);
        assert!(!h.is_hit());
    }
    let g = TraceGeometry::from_triangles(&[[
        Vec3::new(0.0, -1.0, -1.0),
        Vec3::new(0.0, 1.0, -1.0),
        Vec3::new(0.0, 0.0, 1.0),
    ]]);
    let t = bvh::build(&g.boxes, &BvhParams::default(), Threading::Single).unwrap();
    let o = Vec3::new(-1.0, 0.0, 0.0);
    let good = Ray::new(o, Vec3::X, 0.0, f32::INFINITY);
    for traversal in Traversal::ALL {
        let opt = TraceOptions::default();
        assert!(bvh_cpu::trace(&g, &t, &good, 0.0, &opt, traversal)
            .0
            .is_hit());
        for bad in [
            Ray::new(o, Vec3::ZERO, 0.0, 1.0),
            Ray::new(o, Vec3::X, f32::NAN, 1.0),
            Ray::new(o, Vec3::X, 2.0, 1.0),
            Ray::new(Vec3::new(f32::INFINITY, 0.0, 0.0), Vec3::X, 0.0, 1.0),
        ] {
            assert!(
                !bvh_cpu::trace(&g, &t, &bad, 0.0, &opt, traversal)
                    .0
                    .is_hit(),
                "{bad:?}"
            );
        }
    }
}

/// The GPU walks (stack and bitstack, closest and any hit, both intersectors) against the
/// CPU twin on every ray, and the twin against brute force on a share of them.
#[test]
fn gpu_stack_and_bitstack_equal_the_cpu_twin() {
    let Some(ctx) = context() else { return };
    let mut rng = Rng(21);
    let spheres: Vec<Vec4> = (0..200)
        .map(|_| (rng.next_vec3() * 5.0).extend(0.05 + rng.next_f32().abs() * 0.5))
        .collect();
    let mut scenes = vec![
        (
            "icosphere(4)".to_string(),
            TraceGeometry::from_triangles(&tris(&gen::icosphere(4).unwrap())),
        ),
        (
            "soup+spheres".to_string(),
            TraceGeometry::from_triangles_and_spheres(&soup(3000, 3), &spheres),
        ),
        (
            "one triangle".to_string(),
            TraceGeometry::from_triangles(&soup(1, 1)),
        ),
    ];
    if let Some(b) = common::bunny() {
        scenes.push(("bunny".to_string(), TraceGeometry::from_triangles(&b)));
    }
    for (name, g) in &scenes {
        let tree = bvh::build(&g.boxes, &BvhParams::default(), Threading::Rayon).unwrap();
        let binary = GpuGeometry::upload_bvh(&ctx, g, &tree).unwrap();
        let wide = GpuGeometry::upload_wide_bvh(&ctx, g, &tree).unwrap();
        let mut rays = rays(g, &tree.bounds, 4000, 5);
        // Invalid rays miss on the GPU too.
        rays.push(Ray::new(Vec3::ZERO, Vec3::ZERO, 0.0, 1.0));
        rays.push(Ray::new(Vec3::ZERO, Vec3::X, f32::NAN, 1.0));
        rays.push(Ray::new(Vec3::ZERO, Vec3::X, 0.0, f32::NEG_INFINITY));
        for traversal in Traversal::ALL {
            let dev = if traversal == Traversal::Wide {
                &wide
            } else {
                &binary
            };
            for (query, intersector) in [
                (Query::Closest, Intersector::Watertight),
                (Query::Any, Intersector::Watertight),
                (Query::Closest, Intersector::MollerTrumbore),
            ] {
                let opt = TraceOptions {
                    query,
                    intersector,
                    ..TraceOptions::default()
                };
                let tracer = Tracer::for_accel(&ctx, &opt, AccelTraversal::Bvh(traversal)).unwrap();
                let opt = tracer.options();
                let batch = tracer.trace(&ctx, dev, &rays, 0.0).unwrap();
                assert_eq!(batch.exhausted, 0, "{name}: rays ran out of steps");
                for (i, r) in rays.iter().enumerate() {
                    let (twin, exhausted) = bvh_cpu::trace(g, &tree, r, 0.0, &opt, traversal);
                    assert!(!exhausted);
                    let gpu = batch.hits[i];
                    let ok = if query == Query::Any {
                        gpu.is_hit() == twin.is_hit()
                    } else {
                        same_answer(&gpu, &twin)
                    };
                    assert!(
                        ok,
                        "{name} {traversal:?} {opt:?}: ray {i} {r:?}: GPU {gpu:?} vs twin {twin:?}"
                    );
                    if i % 16 == 0 && query == Query::Closest {
                        assert_eq!(twin, cpu::brute_force(g, r, 0.0, &opt), "{name}: ray {i}");
                    }
                }
            }
        }
    }
    assert_silent(&ctx);
}
