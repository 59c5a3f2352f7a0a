//! The 4-wide quantized BVH (Ylitie et al. 2017): every decoded child box contains the
//! child's box (hard coordinates included), the wide tree names every leaf of the binary
//! one exactly once, `accel.bvh_widen` equals its CPU twin bit for bit at every edge size
//! and on the device builders' trees (stale slots of the leaf collapse included), and the
//! structures refuse a walk that does not fit them, under validation.

mod common;

use common::{assert_silent, context, Rng};
use glam::Vec3;
use vkrt::accel::bvh::wide::{widen, WideNode};
use vkrt::accel::bvh::wide_gpu::Widen;
use vkrt::accel::bvh::{self, Bvh, BvhNode, BvhParams, Child, Threading};
use vkrt::accel::device::{AccelBuilder, AccelChoice, AccelKind};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::primitives::TraceGeometry;
use vkrt::accel::walk::AccelTraversal;
use vkrt::accel::walk::Traversal;
use vkrt::gpu::Recorder;
use vkrt::scene::Aabb;
use vkrt::trace::gpu::Tracer;
use vkrt::trace::TraceOptions;

fn soup(n: usize, seed: u64, scale: f32, offset: Vec3) -> Vec<[Vec3; 3]> {
    let mut rng = Rng(seed);
    (0..n)
        .map(|_| {
            let c = rng.next_vec3() * scale + offset;
            let s = scale * 0.01 * (0.05 + rng.next_f32().abs());
            [c, c + rng.next_vec3() * s, c + rng.next_vec3() * s]
        })
        .collect()
}

fn contains(outer: &Aabb, inner: &Aabb) -> bool {
    (0..3).all(|a| outer.min[a] <= inner.min[a] && outer.max[a] >= inner.max[a])
}

/// Walks the wide tree from the root and checks every child against the binary tree: its
/// decoded box contains the binary child's box, and the leaves met are the binary tree's,
/// each once.
fn check_wide(bvh: &Bvh, label: &str) {
    let wide = bvh.wide();
    assert_eq!(wide.len(), bvh.nodes.len(), "{label}");
    // Every binary child by what it names: its exact box.
    let mut exact = std::collections::HashMap::new();
    for n in &bvh.nodes {
        for which in 0..2 {
            let (b, c) = n.child(which);
            if c != Child::None {
                exact.insert(format!("{c:?}"), b);
            }
        }
    }
    let mut leaves = Vec::new();
    let mut stack = if bvh.nodes.is_empty() {
        vec![]
    } else {
        vec![0u32]
    };
    while let Some(i) = stack.pop() {
        for k in 0..4 {
            let (b, c) = wide[i as usize].child(k);
            match c {
                Child::None => continue,
                Child::Node(n) => stack.push(n),
                Child::Leaf { first, count } => leaves.push((first, count)),
            }
            let want = exact[&format!("{c:?}")];
            assert!(
                contains(&b, &want),
                "{label}: node {i} child {k}: {b:?} ⊉ {want:?}"
            );
        }
    }
    leaves.sort_unstable();
    let mut binary: Vec<(u32, u32)> = bvh
        .nodes
        .iter()
        .flat_map(|n| [n.child(0).1, n.child(1).1])
        .filter_map(|c| match c {
            Child::Leaf { first, count } => Some((first, count)),
            _ => None,
        })
        .collect();
    binary.sort_unstable();
    assert_eq!(leaves, binary, "{label}: the wide tree's leaves");
}

fn sah(tris: &[[Vec3; 3]], max_leaf: u32) -> Bvh {
    let g = TraceGeometry::from_triangles(tris);
    let p = BvhParams {
        max_leaf_prims: max_leaf,
        ..BvhParams::default()
    };
    bvh::build(&g.boxes, &p, Threading::Single).unwrap()
}

#[test]
fn decoded_boxes_contain_their_children_and_every_leaf_is_named_once() {
    let cases: Vec<(&str, Vec<[Vec3; 3]>)> = vec![
        ("one", soup(1, 1, 1.0, Vec3::ZERO)),
        ("two", soup(2, 2, 1.0, Vec3::ZERO)),
        ("soup", soup(5000, 3, 10.0, Vec3::ZERO)),
        // Small boxes far from the origin: the frame's rounding is coarser than its scale.
        ("far", soup(3000, 4, 1e-3, Vec3::new(1e6, -3e5, 7e4))),
        ("huge", soup(2000, 5, 1e30, Vec3::ZERO)),
        ("tiny", soup(2000, 6, 1e-30, Vec3::ZERO)),
        // Flat in z (every box zero-thick there), with -0 and +0 planes.
        (
            "flat",
            soup(2000, 7, 5.0, Vec3::ZERO)
                .into_iter()
                .enumerate()
                .map(|(i, t)| {
                    let z = if i % 2 == 0 { -0.0 } else { 0.0 };
                    t.map(|v| Vec3::new(v.x, v.y, z))
                })
                .collect(),
        ),
        // Every triangle the same: one point of centroids.
        ("identical", vec![soup(1, 8, 1.0, Vec3::ZERO)[0]; 300]),
    ];
    for (name, tris) in &cases {
        for max_leaf in [1, 4, 16] {
            check_wide(
                &sah(tris, max_leaf),
                &format!("{name}, leaves of {max_leaf}"),
            );
        }
    }
}

/// Binary node arrays the GPU builders leave: real trees, and slots whose links are stale
/// (past the slots given, or pointing anywhere).
fn random_nodes(n: usize, seed: u64) -> Vec<BvhNode> {
    let mut rng = Rng(seed);
    (0..n)
        .map(|_| {
            let mut node = BvhNode::empty();
            for which in 0..2 {
                let c = rng.next_vec3() * 100.0;
                let b = Aabb {
                    min: c,
                    max: c + rng.next_vec3().abs() * 3.0,
                };
                let child = match rng.next_u64() % 5 {
                    0 => Child::None,
                    1 | 2 => Child::Leaf {
                        first: (rng.next_u64() % 1000) as u32,
                        count: 1 + (rng.next_u64() % 40) as u32,
                    },
                    3 => Child::Node((rng.next_u64() % (n as u64 + 3)) as u32),
                    _ => Child::Node((rng.next_u64() % n.max(1) as u64) as u32),
                };
                node.set_child(which, b, child);
            }
            node
        })
        .collect()
}

#[test]
fn the_widen_kernel_equals_its_twin_at_every_edge_size() {
    let Some(ctx) = context() else { return };
    let widen_gpu = Widen::new(&ctx).unwrap();
    let sg = ctx.info().subgroup_size as usize;
    let mut sizes = vec![0, 1, 2, 3, 63, 64, 65, 1000, 4097];
    sizes.extend([sg - 1, sg, sg + 1]);
    sizes.sort_unstable();
    sizes.dedup();
    let same = |a: &[WideNode], b: &[WideNode]| -> usize {
        a.iter().zip(b).filter(|(x, y)| x != y).count() + a.len().abs_diff(b.len())
    };
    for &n in &sizes {
        // A real tree over n + 1 primitives (its nodes), and random slots.
        let tree = sah(&soup(n + 1, n as u64, 10.0, Vec3::ZERO), 1);
        for (label, nodes) in [
            ("tree", tree.nodes.clone()),
            ("random", random_nodes(n, 77)),
        ] {
            let gpu = widen_gpu.run(&ctx, &nodes).unwrap();
            let cpu = widen(&nodes, nodes.len());
            assert_eq!(same(&gpu, &cpu), 0, "{label}, {} slots", nodes.len());
        }
    }
    // The hard coordinates of the containment test.
    for (scale, offset) in [
        (1e30, Vec3::ZERO),
        (1e-30, Vec3::ZERO),
        (1e-3, Vec3::splat(1e6)),
    ] {
        let nodes = sah(&soup(3000, 9, scale, offset), 4).nodes;
        let gpu = widen_gpu.run(&ctx, &nodes).unwrap();
        assert_eq!(same(&gpu, &widen(&nodes, nodes.len())), 0, "scale {scale}");
    }
    assert_silent(&ctx);
}

/// The device builders' trees keep the slots a leaf collapse freed: the wide nodes the build
/// recorded equal the twin's over the same slots, and after a refit too.
#[test]
fn device_built_wide_nodes_equal_the_twin_after_build_and_refit() {
    let Some(ctx) = context() else { return };
    for kind in [AccelKind::SahBvh, AccelKind::Lbvh, AccelKind::Ploc] {
        for n in [1, 2, 3, 100, 5000] {
            let tris = soup(n, 40 + n as u64, 10.0, Vec3::ZERO);
            let g = TraceGeometry::from_triangles(&tris);
            let mut builder =
                AccelBuilder::for_choice(&ctx, AccelChoice::new(kind, Traversal::Wide)).unwrap();
            builder = builder.with_allow_update(n % 2 == 0);
            let mut rec = Recorder::new(&ctx).unwrap();
            let (mut dev, _) = GpuGeometry::record_build(&mut rec, &builder, &g, 0).unwrap();
            rec.submit_and_wait().unwrap();
            assert!(dev.structure().is_wide());
            let (binary, wide) = dev.structure().download_wide().unwrap().unwrap();
            assert_eq!(
                wide,
                widen(&binary, binary.len()),
                "{kind:?}, {n}: after the build"
            );
            if n >= 3 {
                // Every triangle moved: the refit rewrites the binary nodes and the wide ones.
                let moved: Vec<[Vec3; 3]> = tris
                    .iter()
                    .map(|t| t.map(|v| v * 1.5 + Vec3::new(0.3, -2.0, 1.0)))
                    .collect();
                let moved = TraceGeometry::from_triangles(&moved);
                let scratch = builder.update_scratch(&ctx, n).unwrap().unwrap();
                let mut rec = Recorder::new(&ctx).unwrap();
                dev.primitives().record_update(&mut rec, &moved).unwrap();
                builder.record_refit(&mut rec, &mut dev, &scratch).unwrap();
                rec.submit_and_wait().unwrap();
                let (binary2, wide2) = dev.structure().download_wide().unwrap().unwrap();
                assert_ne!(binary2, binary, "{kind:?}, {n}: the refit moved nothing");
                assert_eq!(
                    wide2,
                    widen(&binary2, binary2.len()),
                    "{kind:?}, {n}: after a refit"
                );
            }
        }
    }
    assert_silent(&ctx);
}

#[test]
fn a_walk_that_does_not_fit_the_structure_is_refused() {
    let Some(ctx) = context() else { return };
    let g = TraceGeometry::from_triangles(&soup(100, 3, 1.0, Vec3::ZERO));
    let build = |walk: Traversal| {
        let builder =
            AccelBuilder::for_choice(&ctx, AccelChoice::new(AccelKind::Lbvh, walk)).unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        let (dev, _) = GpuGeometry::record_build(&mut rec, &builder, &g, 0).unwrap();
        rec.submit_and_wait().unwrap();
        dev
    };
    let (binary, wide) = (build(Traversal::Stack), build(Traversal::Wide));
    let rays = [vkrt::trace::Ray::new(Vec3::ZERO, Vec3::X, 0.0, 1.0)];
    for walk in Traversal::ALL {
        let tracer =
            Tracer::for_accel(&ctx, &TraceOptions::default(), AccelTraversal::Bvh(walk)).unwrap();
        let (fits, other) = match walk {
            Traversal::Wide => (&wide, &binary),
            _ => (&binary, &wide),
        };
        assert!(tracer.trace(&ctx, fits, &rays, 0.0).is_ok(), "{walk:?}");
        let e = tracer
            .trace(&ctx, other, &rays, 0.0)
            .err()
            .expect("refused");
        assert!(
            matches!(e, vkrt::gpu::GpuError::KindMismatch { .. }),
            "{walk:?}: {e}"
        );
    }
    // The SAH BVH's leaves must fit the walks' 8-bit leaf sizes.
    let mut builder =
        AccelBuilder::for_choice(&ctx, AccelChoice::new(AccelKind::SahBvh, Traversal::Wide))
            .unwrap();
    builder = builder.with_bvh_params(vkrt::accel::bvh::BvhParams {
        max_leaf_prims: 256,
        ..Default::default()
    });
    let mut rec = Recorder::new(&ctx).unwrap();
    let e = GpuGeometry::record_build(&mut rec, &builder, &g, 0)
        .err()
        .expect("refused");
    assert!(e.to_string().contains("at most 255"), "{e}");
    assert_silent(&ctx);
}
