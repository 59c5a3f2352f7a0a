//! The GPU kd-tree build against its CPU twin (breadth_first), bit for bit, phase by phase.

mod common;

use glam::Vec3;
use vkrt::accel::kdtree::breadth_first;
use vkrt::accel::kdtree::gpu::KdTreeBuilder;
use vkrt::scene::gen;

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn assert_phase_one_equal(
    ctx: &vkrt::gpu::Context,
    builder: &KdTreeBuilder,
    name: &str,
    tris: &[[Vec3; 3]],
) {
    let (got, events) = builder.phase_one(ctx, tris).unwrap();
    let boxes: Vec<_> = tris.iter().map(breadth_first::prim_box).collect();
    let bounds = breadth_first::bounds_of(&boxes);
    if !tris.is_empty() {
        assert_eq!(
            bits(&got.min.to_array()),
            bits(&bounds.min.to_array()),
            "{name}: bounds.min"
        );
        assert_eq!(
            bits(&got.max.to_array()),
            bits(&bounds.max.to_array()),
            "{name}: bounds.max"
        );
    }
    let cpu = breadth_first::initial_events(&boxes);
    for a in 0..3 {
        let g = &events[a];
        let c = &cpu[a];
        assert_eq!(bits(&g.plane), bits(&c.plane), "{name}: axis {a} planes");
        assert_eq!(g.kind, c.kind, "{name}: axis {a} kinds");
        assert_eq!(g.prim, c.prim, "{name}: axis {a} prims");
        assert_eq!(g.node, c.node, "{name}: axis {a} nodes");
        for b in 0..3 {
            assert_eq!(
                bits(&g.box_min[b]),
                bits(&c.box_min[b]),
                "{name}: axis {a} box min {b}"
            );
            assert_eq!(
                bits(&g.box_max[b]),
                bits(&c.box_max[b]),
                "{name}: axis {a} box max {b}"
            );
        }
    }
}

#[test]
fn phase_one_equals_cpu_twin() {
    let Some(ctx) = common::context() else { return };
    let builder = KdTreeBuilder::new(&ctx).unwrap();
    let t = [
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(0.0, 1.0, 0.0),
    ];
    assert_phase_one_equal(&ctx, &builder, "single", &[t]);
    assert_phase_one_equal(&ctx, &builder, "identical", &vec![t; 1000]);
    let signed_zero = [
        Vec3::new(-0.0, 0.0, -0.0),
        Vec3::new(0.0, -0.0, 1.0),
        Vec3::new(-0.0, 1.0, 0.0),
    ];
    assert_phase_one_equal(&ctx, &builder, "signed-zero", &[signed_zero, t]);
    assert_phase_one_equal(
        &ctx,
        &builder,
        "icosphere",
        &common::mesh_triangles(&gen::icosphere(5).unwrap()),
    );
    assert_phase_one_equal(
        &ctx,
        &builder,
        "soup",
        &common::mesh_triangles(&gen::random_soup(50_000, 9).unwrap()),
    );
    assert_phase_one_equal(
        &ctx,
        &builder,
        "grid",
        &common::mesh_triangles(&gen::integer_grid(64, 64).unwrap()),
    );
    common::assert_silent(&ctx);
}

fn assert_build_equal(
    ctx: &vkrt::gpu::Context,
    builder: &KdTreeBuilder,
    name: &str,
    tris: &[[Vec3; 3]],
    params: &vkrt::accel::kdtree::SahParams,
) {
    let (cpu, _) = breadth_first::build(tris, params);
    let (gpu, _) = builder.build(ctx, tris, params).unwrap();
    assert_eq!(gpu.nodes.len(), cpu.nodes.len(), "{name}: node count");
    let first = gpu.nodes.iter().zip(&cpu.nodes).position(|(g, c)| {
        g.split.to_bits() != c.split.to_bits() || g.kind != c.kind || g.a != c.a || g.b != c.b
    });
    assert_eq!(
        first,
        None,
        "{name}: first differing node {:?} vs {:?}",
        first.map(|i| gpu.nodes[i]),
        first.map(|i| cpu.nodes[i])
    );
    assert_eq!(gpu.prim_refs, cpu.prim_refs, "{name}: leaf references");
    vkrt::accel::kdtree::validate::validate(&gpu, tris)
        .unwrap_or_else(|e| panic!("{name}: invalid tree: {e}"));
    eprintln!(
        "{name}: {} triangles, {} nodes, {} refs: GPU == CPU twin",
        tris.len(),
        gpu.nodes.len(),
        gpu.prim_refs.len()
    );
}

#[test]
fn gpu_build_equals_cpu_twin() {
    let Some(ctx) = common::context() else { return };
    let builder = KdTreeBuilder::new(&ctx).unwrap();
    let p = vkrt::accel::kdtree::SahParams::default();
    let t = [
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(0.0, 1.0, 0.0),
    ];
    assert_build_equal(&ctx, &builder, "single", &[t], &p);
    assert_build_equal(
        &ctx,
        &builder,
        "two",
        &[t, [t[0] + 2.0, t[1] + 2.0, t[2] + 2.0]],
        &p,
    );
    assert_build_equal(
        &ctx,
        &builder,
        "icosphere",
        &common::mesh_triangles(&gen::icosphere(3).unwrap()),
        &p,
    );
    assert_build_equal(&ctx, &builder, "identical", &vec![t; 300], &p);
    assert_build_equal(
        &ctx,
        &builder,
        "soup",
        &common::mesh_triangles(&gen::random_soup(20_000, 3).unwrap()),
        &p,
    );
    assert_build_equal(
        &ctx,
        &builder,
        "grid",
        &common::mesh_triangles(&gen::integer_grid(50, 50).unwrap()),
        &p,
    );
    let seed = vkrt::accel::kdtree::SahParams {
        sah_leaf_test: false,
        max_leaf_prims: 63,
        ..p
    };
    assert_build_equal(
        &ctx,
        &builder,
        "icosphere.seed",
        &common::mesh_triangles(&gen::icosphere(5).unwrap()),
        &seed,
    );
    if let Some(bunny) = common::bunny() {
        assert_build_equal(&ctx, &builder, "bunny", &bunny, &p);
    }
    common::assert_silent(&ctx);
}

#[test]
fn overflow_stops_cleanly_and_the_retry_builds_the_same_tree() {
    let Some(ctx) = common::context() else { return };
    let builder = KdTreeBuilder::new(&ctx).unwrap();
    let p = vkrt::accel::kdtree::SahParams::default();
    let tris = common::mesh_triangles(&gen::random_soup(3000, 11).unwrap());
    let (cpu, _) = breadth_first::build(&tris, &p);
    // Room for barely the root's references: the first clipping level overflows.
    let tiny = vkrt::accel::kdtree::gpu::BuildCapacity::with_refs(tris.len(), tris.len());
    let r = builder.build_from(&ctx, &tris, &p, tiny).unwrap();
    assert!(r.attempts > 1, "the tiny capacity should have overflowed");
    assert!(r.capacity.refs_per_level > tris.len());
    assert!(
        r.tree.nodes == cpu.nodes && r.tree.prim_refs == cpu.prim_refs,
        "retry differs from the twin"
    );
    common::assert_silent(&ctx);
}

#[test]
fn gpu_build_equals_cpu_twin_on_hard_cases() {
    let Some(ctx) = common::context() else { return };
    let builder = KdTreeBuilder::new(&ctx).unwrap();
    let p = vkrt::accel::kdtree::SahParams::default();
    for (name, tris) in common::kdtree_hard_cases() {
        assert_build_equal(&ctx, &builder, name, &tris, &p);
    }
    // Zero triangles: one empty leaf, as the twin (no GPU work).
    let (gpu, _) = builder.build(&ctx, &[], &p).unwrap();
    assert_trees_equal("zero triangles", &gpu, &breadth_first::build(&[], &p).0);
    common::assert_silent(&ctx);
}

fn assert_trees_equal(
    name: &str,
    gpu: &vkrt::accel::kdtree::KdTree,
    cpu: &vkrt::accel::kdtree::KdTree,
) {
    assert_eq!(gpu.nodes.len(), cpu.nodes.len(), "{name}: node count");
    let first = gpu.nodes.iter().zip(&cpu.nodes).position(|(g, c)| {
        g.split.to_bits() != c.split.to_bits() || g.kind != c.kind || g.a != c.a || g.b != c.b
    });
    assert_eq!(
        first,
        None,
        "{name}: first differing node {:?} vs {:?}",
        first.map(|i| gpu.nodes[i]),
        first.map(|i| cpu.nodes[i])
    );
    assert_eq!(gpu.prim_refs, cpu.prim_refs, "{name}: leaf references");
    assert_eq!(gpu.primitives, cpu.primitives, "{name}: primitives");
    for (g, c) in [
        (gpu.bounds.min, cpu.bounds.min),
        (gpu.bounds.max, cpu.bounds.max),
    ] {
        assert_eq!(bits(&g.to_array()), bits(&c.to_array()), "{name}: bounds");
    }
}

/// Spheres with centers in [-1, 1]³ and radii in (0, 0.05].
fn random_spheres(n: usize, seed: u64) -> Vec<(Vec3, f32)> {
    let mut rng = common::Rng(seed);
    (0..n)
        .map(|_| {
            let c = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
            (c, 0.025 * (rng.next_f32() + 1.0) + 1e-4)
        })
        .collect()
}

/// The box inputs that matter: triangle boxes followed by sphere boxes (as the renderer
/// builds them), flat boxes on candidate planes, points, identical boxes, one and two
/// boxes, random boxes, signed zeros.
fn box_cases() -> Vec<(&'static str, Vec<vkrt::accel::kdtree::Aabb>)> {
    use vkrt::accel::kdtree::Aabb;
    let mut rng = common::Rng(17);
    let unit = Aabb {
        min: Vec3::ZERO,
        max: Vec3::ONE,
    };
    let mut mixed: Vec<Aabb> = common::mesh_triangles(&gen::icosphere(3).unwrap())
        .iter()
        .map(breadth_first::prim_box)
        .collect();
    mixed.extend(
        random_spheres(700, 5)
            .into_iter()
            .map(|(c, r)| breadth_first::sphere_box(c, r)),
    );
    let flat: Vec<Aabb> = (0..300)
        .map(|i| {
            let x = (i % 30) as f32;
            let axis = i % 3;
            let mut min = Vec3::new(x, x * 0.5, 1.0);
            let mut max = min + Vec3::splat(2.0);
            max[axis] = min[axis];
            if i % 7 == 0 {
                min = max; // a point
            }
            Aabb { min, max }
        })
        .collect();
    let random: Vec<Aabb> = (0..5000)
        .map(|_| {
            let a = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 10.0;
            let d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()).abs() * 0.3;
            Aabb { min: a, max: a + d }
        })
        .collect();
    let signed_zero = vec![
        Aabb {
            min: Vec3::new(-0.0, 0.0, -0.0),
            max: Vec3::new(0.0, -0.0, 1.0),
        },
        unit,
    ];
    vec![
        ("mixed triangles+spheres", mixed),
        ("flat+points", flat),
        ("identical", vec![unit; 300]),
        ("single", vec![unit]),
        (
            "two",
            vec![
                unit,
                Aabb {
                    min: Vec3::splat(3.0),
                    max: Vec3::splat(4.0),
                },
            ],
        ),
        ("random", random),
        ("signed-zero", signed_zero),
    ]
}

#[test]
fn box_input_equals_cpu_twin() {
    use vkrt::accel::kdtree::gpu::BuildInput;
    let Some(ctx) = common::context() else { return };
    let builder = KdTreeBuilder::new(&ctx).unwrap();
    let p = vkrt::accel::kdtree::SahParams::default();
    for (name, boxes) in box_cases() {
        // Phase I (the input_boxes kernel and everything after it) against the twin.
        let (bounds, events) = builder
            .phase_one_input(&ctx, BuildInput::Boxes(&boxes))
            .unwrap();
        let cpu_bounds = breadth_first::bounds_of(&boxes);
        assert_eq!(
            bits(&[bounds.min.to_array(), bounds.max.to_array()].concat()),
            bits(&[cpu_bounds.min.to_array(), cpu_bounds.max.to_array()].concat()),
            "{name}: phase one bounds"
        );
        assert_eq!(
            events,
            breadth_first::initial_events(&boxes),
            "{name}: events"
        );
        let (cpu, _) = breadth_first::build_boxes(&boxes, &p);
        let (gpu, _) = builder.build_boxes(&ctx, &boxes, &p).unwrap();
        assert_trees_equal(name, &gpu, &cpu);
        eprintln!(
            "{name}: {} boxes, {} nodes, {} refs: GPU == CPU twin",
            boxes.len(),
            gpu.nodes.len(),
            gpu.prim_refs.len()
        );
    }
    // Zero boxes: one empty leaf, as the twin.
    let (gpu, _) = builder.build_boxes(&ctx, &[], &p).unwrap();
    assert_trees_equal("empty", &gpu, &breadth_first::build_boxes(&[], &p).0);
    // Triangles through their boxes give the triangle build's tree.
    let tris = common::mesh_triangles(&gen::random_soup(3000, 4).unwrap());
    let boxes: Vec<_> = tris.iter().map(breadth_first::prim_box).collect();
    let (via_boxes, _) = builder.build_boxes(&ctx, &boxes, &p).unwrap();
    let (direct, _) = builder.build(&ctx, &tris, &p).unwrap();
    assert_trees_equal("soup via boxes", &via_boxes, &direct);
    // The overflow retry works for box input too.
    let tiny = vkrt::accel::kdtree::gpu::BuildCapacity::with_refs(boxes.len(), boxes.len());
    let r = builder
        .build_input_from(&ctx, BuildInput::Boxes(&boxes), &p, tiny)
        .unwrap();
    assert!(r.attempts > 1, "the tiny capacity should have overflowed");
    assert_trees_equal("soup via boxes, retried", &r.tree, &direct);
    common::assert_silent(&ctx);
}

#[test]
fn bad_boxes_are_errors() {
    use vkrt::accel::kdtree::Aabb;
    let Some(ctx) = common::context() else { return };
    let builder = KdTreeBuilder::new(&ctx).unwrap();
    let p = vkrt::accel::kdtree::SahParams::default();
    let good = Aabb {
        min: Vec3::ZERO,
        max: Vec3::ONE,
    };
    let bad = [
        Aabb {
            min: Vec3::new(0.0, f32::NAN, 0.0),
            max: Vec3::ONE,
        },
        Aabb {
            min: Vec3::ZERO,
            max: Vec3::new(1.0, f32::INFINITY, 1.0),
        },
        Aabb {
            min: Vec3::new(0.0, 0.0, 2.0),
            max: Vec3::ONE,
        },
        Aabb::EMPTY,
    ];
    for b in bad {
        let err = builder
            .build_boxes(&ctx, &[good, b], &p)
            .expect_err("a bad box must be an error");
        assert!(err.to_string().contains("primitive box 1"), "{err}");
    }
    common::assert_silent(&ctx);
}

#[test]
fn sphere_boxes_on_the_gpu_equal_the_cpu_twin_and_build_the_same_tree() {
    use vkrt::accel::kdtree::gpu::BuildCapacity;
    use vkrt::gpu::{Buffer, Recorder};
    let Some(ctx) = common::context() else { return };
    let builder = KdTreeBuilder::new(&ctx).unwrap();
    let p = vkrt::accel::kdtree::SahParams::default();
    // Triangle boxes from the host, then sphere boxes written by the GPU after them, built
    // in the same command buffer: the renderer's path with no host round trip.
    let tri_boxes: Vec<_> = common::mesh_triangles(&gen::icosphere(2).unwrap())
        .iter()
        .map(breadth_first::prim_box)
        .collect();
    let mut spheres = random_spheres(1000, 8);
    spheres.push((Vec3::new(-0.0, 1e-30, 3.0e7), 0.1)); // rounding: 3e7 ± 0.1 rounds
    spheres.push((Vec3::splat(0.5), 0.0)); // a point
    let (nt, ns) = (tri_boxes.len(), spheres.len());
    let n = nt + ns;
    let mut flat: Vec<f32> = tri_boxes
        .iter()
        .flat_map(|b| b.min.to_array().into_iter().chain(b.max.to_array()))
        .collect();
    flat.resize(6 * n, f32::NAN);
    let sphere_data: Vec<f32> = spheres
        .iter()
        .flat_map(|(c, r)| [c.x, c.y, c.z, *r])
        .collect();
    let boxes_buf = Buffer::from_slice(&ctx, "test.boxes", &flat).unwrap();
    let spheres_buf = Buffer::from_slice(&ctx, "test.spheres", &sphere_data).unwrap();
    let cap = BuildCapacity::for_primitives(n);
    let scratch = builder.scratch(&ctx, n, cap).unwrap();
    let out = builder.output(&ctx, &cap).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    // Misuse is an error, never a panic or an out-of-bounds write: more spheres than the
    // box buffer holds after `nt`, a build of more primitives than the scratch was made for.
    let e = builder
        .record_sphere_boxes(&mut rec, &spheres_buf, ns, &boxes_buf, nt + 1)
        .unwrap_err();
    assert!(e.to_string().contains("record_sphere_boxes"), "{e}");
    let e = builder
        .record_build_boxes(&mut rec, &boxes_buf, n + 1, &p, &scratch, &out)
        .unwrap_err();
    assert!(
        e.to_string().contains("record_build_boxes") || e.to_string().contains("record_build"),
        "{e}"
    );
    builder
        .record_sphere_boxes(&mut rec, &spheres_buf, ns, &boxes_buf, nt)
        .unwrap();
    rec.compute_to_compute();
    builder
        .record_build_boxes(&mut rec, &boxes_buf, n, &p, &scratch, &out)
        .unwrap();
    rec.compute_to_transfer();
    rec.submit_and_wait().unwrap();
    // The sphere boxes, bit for bit.
    let got = boxes_buf.download().unwrap();
    let mut boxes = tri_boxes.clone();
    boxes.extend(
        spheres
            .iter()
            .map(|&(c, r)| breadth_first::sphere_box(c, r)),
    );
    let want: Vec<f32> = boxes
        .iter()
        .flat_map(|b| b.min.to_array().into_iter().chain(b.max.to_array()))
        .collect();
    assert_eq!(bits(&got), bits(&want), "sphere boxes");
    // The tree.
    let outcome = builder.read_outcome(&scratch).unwrap();
    assert!(!outcome.overflow);
    let nodes = out.download_nodes(outcome.nodes as usize).unwrap();
    let mut refs = out.prim_refs.download().unwrap();
    refs.truncate(outcome.refs as usize);
    let (cpu, _) = breadth_first::build_boxes(&boxes, &p);
    let gpu = vkrt::accel::kdtree::KdTree {
        nodes,
        prim_refs: refs,
        bounds: cpu.bounds,
        primitives: n as u32,
    };
    assert_trees_equal("recorded triangles+spheres", &gpu, &cpu);
    common::assert_silent(&ctx);
}

#[test]
fn ablation_variants_build_the_same_tree() {
    use vkrt::accel::kdtree::gpu::Ablation;
    use vkrt::prims::segmented::SegmentedMode;
    let Some(ctx) = common::context() else { return };
    let p = vkrt::accel::kdtree::SahParams::default();
    let scenes = [
        (
            "icosphere",
            common::mesh_triangles(&gen::icosphere(3).unwrap()),
        ),
        (
            "soup",
            common::mesh_triangles(&gen::random_soup(3000, 12).unwrap()),
        ),
    ];
    let variants = [
        (
            "shared-memory argmin",
            Ablation {
                shared_memory_argmin: true,
                ..Ablation::default()
            },
            None,
        ),
        (
            "u32 event scan",
            Ablation {
                u32_event_scan: true,
                ..Ablation::default()
            },
            None,
        ),
        (
            "full-record scatter",
            Ablation {
                full_record_scatter: true,
                ..Ablation::default()
            },
            None,
        ),
        (
            "narrow moves",
            Ablation {
                narrow_moves: true,
                ..Ablation::default()
            },
            None,
        ),
        (
            "all, workgroup per segment",
            Ablation {
                shared_memory_argmin: true,
                u32_event_scan: true,
                full_record_scatter: true,
                narrow_moves: false,
            },
            Some(SegmentedMode::WorkgroupPerSegment),
        ),
        (
            "all, narrow moves",
            Ablation {
                shared_memory_argmin: true,
                u32_event_scan: true,
                full_record_scatter: true,
                narrow_moves: true,
            },
            None,
        ),
    ];
    for (label, ablation, mode) in variants {
        let mut builder = KdTreeBuilder::with_ablation(&ctx, ablation).unwrap();
        if let Some(mode) = mode {
            builder.segmented_mode = mode;
        }
        for (name, tris) in &scenes {
            let (cpu, _) = breadth_first::build(tris, &p);
            let (gpu, _) = builder.build(&ctx, tris, &p).unwrap();
            assert_trees_equal(&format!("{name}, {label}"), &gpu, &cpu);
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn capacities_fit_the_device_buffer_limit() {
    use vkrt::accel::kdtree::gpu::BuildCapacity;
    let limit = 128u64 << 20; // lavapipe's maxStorageBufferRange
    let small = BuildCapacity::for_primitives(1000);
    assert_eq!(small.fit(limit), small);
    let big = BuildCapacity::for_primitives(2_000_000).fit(limit);
    // Slot offsets: 4 u32 per reference; event boxes: 6 buffers of 2 floats per reference.
    assert!(16 * big.refs_per_level as u64 <= limit, "{big:?}");
    assert!(24 * big.nodes_per_level as u64 <= limit, "{big:?}");
    // The output nodes live in two buffers.
    assert!(16 * big.nodes as u64 <= 2 * limit, "{big:?}");
    assert!(4 * big.refs as u64 <= limit, "{big:?}");
    // The default 2 M capacity (8 M references per level) fits as it is; the tree of a 2 M
    // icosphere needs ≈ 3 references per triangle in its widest level and ≈ 6 nodes per
    // triangle (the CPU twin's counts).
    assert_eq!(big.refs_per_level, 8_000_064);
    assert!(big.nodes >= 13_000_000, "{big:?}");
}

#[test]
fn output_nodes_split_across_two_buffers() {
    // The output nodes' second buffer (trees above maxStorageBufferRange / 16 nodes), with a
    // first buffer of 1000 nodes so a small tree crosses the boundary.
    let Some(ctx) = common::context() else { return };
    let p = vkrt::accel::kdtree::SahParams::default();
    let tris = common::mesh_triangles(&gen::random_soup(2000, 7).unwrap());
    let mut builder = KdTreeBuilder::new(&ctx).unwrap();
    builder.max_nodes_per_buffer = Some(1000);
    let (cpu, _) = breadth_first::build(&tris, &p);
    assert!(cpu.nodes.len() > 1000, "{} nodes", cpu.nodes.len());
    let (gpu, _) = builder.build(&ctx, &tris, &p).unwrap();
    assert_trees_equal("two node buffers", &gpu, &cpu);
    common::assert_silent(&ctx);
}
