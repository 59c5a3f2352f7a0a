//! The GPU kd-tree build against its CPU twin (seed001), bit for bit, phase by phase.

mod common;

use glam::Vec3;
use vkrt::accel::kdtree::gpu::KdTreeBuilder;
use vkrt::accel::kdtree::seed001;
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
    let boxes: Vec<_> = tris.iter().map(seed001::prim_box).collect();
    let bounds = seed001::bounds_of(&boxes);
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
    let cpu = seed001::initial_events(&boxes);
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
    let (cpu, _) = seed001::build(tris, params);
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
    let (cpu, _) = seed001::build(&tris, &p);
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
    common::assert_silent(&ctx);
}
