//! The GPU kd-tree build against its CPU twin (seed001), bit for bit, phase by phase.

mod common;

use glam::Vec3;
use vkrt::accel::kdtree::gpu::KdTreeBuilder;
use vkrt::accel::kdtree::seed001;
use vkrt::scene::gen;

fn mesh_triangles(mesh: &vkrt::scene::Mesh) -> Vec<[Vec3; 3]> {
    mesh.indices
        .iter()
        .map(|t| [mesh.positions[t[0] as usize], mesh.positions[t[1] as usize], mesh.positions[t[2] as usize]])
        .collect()
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn assert_phase_one_equal(ctx: &vkrt::gpu::Context, builder: &KdTreeBuilder, name: &str, tris: &[[Vec3; 3]]) {
    let (got, events) = builder.phase_one(ctx, tris).unwrap();
    let boxes: Vec<_> = tris.iter().map(seed001::prim_box).collect();
    let bounds = seed001::bounds_of(&boxes);
    if !tris.is_empty() {
        assert_eq!(bits(&got.min.to_array()), bits(&bounds.min.to_array()), "{name}: bounds.min");
        assert_eq!(bits(&got.max.to_array()), bits(&bounds.max.to_array()), "{name}: bounds.max");
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
            assert_eq!(bits(&g.box_min[b]), bits(&c.box_min[b]), "{name}: axis {a} box min {b}");
            assert_eq!(bits(&g.box_max[b]), bits(&c.box_max[b]), "{name}: axis {a} box max {b}");
        }
    }
}

#[test]
fn phase_one_equals_cpu_twin() {
    let Some(ctx) = common::context() else { return };
    let builder = KdTreeBuilder::new(&ctx).unwrap();
    let t = [Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 1.0, 0.0)];
    assert_phase_one_equal(&ctx, &builder, "single", &[t]);
    assert_phase_one_equal(&ctx, &builder, "identical", &vec![t; 1000]);
    let signed_zero = [Vec3::new(-0.0, 0.0, -0.0), Vec3::new(0.0, -0.0, 1.0), Vec3::new(-0.0, 1.0, 0.0)];
    assert_phase_one_equal(&ctx, &builder, "signed-zero", &[signed_zero, t]);
    assert_phase_one_equal(&ctx, &builder, "icosphere", &mesh_triangles(&gen::icosphere(5).unwrap()));
    assert_phase_one_equal(&ctx, &builder, "soup", &mesh_triangles(&gen::random_soup(50_000, 9).unwrap()));
    assert_phase_one_equal(&ctx, &builder, "grid", &mesh_triangles(&gen::integer_grid(64, 64).unwrap()));
    common::assert_silent(&ctx);
}

fn assert_build_equal(ctx: &vkrt::gpu::Context, builder: &KdTreeBuilder, name: &str, tris: &[[Vec3; 3]], params: &vkrt::accel::kdtree::SahParams) {
    let (cpu, _) = seed001::build(tris, params);
    let (gpu, _) = builder.build(ctx, tris, params).unwrap();
    assert_eq!(gpu.nodes.len(), cpu.nodes.len(), "{name}: node count");
    let first = gpu.nodes.iter().zip(&cpu.nodes).position(|(g, c)| g.split.to_bits() != c.split.to_bits() || g.kind != c.kind || g.a != c.a || g.b != c.b);
    assert_eq!(first, None, "{name}: first differing node {:?} vs {:?}", first.map(|i| gpu.nodes[i]), first.map(|i| cpu.nodes[i]));
    assert_eq!(gpu.prim_refs, cpu.prim_refs, "{name}: leaf references");
    vkrt::accel::kdtree::validate::validate(&gpu, tris).unwrap_or_else(|e| panic!("{name}: invalid tree: {e}"));
    eprintln!("{name}: {} triangles, {} nodes, {} refs: GPU == CPU twin", tris.len(), gpu.nodes.len(), gpu.prim_refs.len());
}

#[test]
fn gpu_build_equals_cpu_twin() {
    let Some(ctx) = common::context() else { return };
    let builder = KdTreeBuilder::new(&ctx).unwrap();
    let p = vkrt::accel::kdtree::SahParams::default();
    let t = [Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 1.0, 0.0)];
    assert_build_equal(&ctx, &builder, "single", &[t], &p);
    assert_build_equal(&ctx, &builder, "two", &[t, [t[0] + 2.0, t[1] + 2.0, t[2] + 2.0]], &p);
    assert_build_equal(&ctx, &builder, "icosphere", &mesh_triangles(&gen::icosphere(3).unwrap()), &p);
    assert_build_equal(&ctx, &builder, "identical", &vec![t; 300], &p);
    assert_build_equal(&ctx, &builder, "soup", &mesh_triangles(&gen::random_soup(20_000, 3).unwrap()), &p);
    assert_build_equal(&ctx, &builder, "grid", &mesh_triangles(&gen::integer_grid(50, 50).unwrap()), &p);
    let seed = vkrt::accel::kdtree::SahParams { sah_leaf_test: false, max_leaf_prims: 63, ..p };
    assert_build_equal(&ctx, &builder, "icosphere.seed", &mesh_triangles(&gen::icosphere(5).unwrap()), &seed);
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes/stanford-bunny.obj");
    if path.exists() {
        let scene = vkrt::scene::Scene::load(&path).unwrap().scene;
        assert_build_equal(&ctx, &builder, "bunny", &scene.triangles_world(0.0), &p);
    } else {
        eprintln!("skipped the bunny: {} not present", path.display());
    }
    common::assert_silent(&ctx);
}

#[test]
fn overflow_stops_cleanly_and_the_retry_builds_the_same_tree() {
    let Some(ctx) = common::context() else { return };
    let builder = KdTreeBuilder::new(&ctx).unwrap();
    let p = vkrt::accel::kdtree::SahParams::default();
    let tris = mesh_triangles(&gen::random_soup(3000, 11).unwrap());
    let (cpu, _) = seed001::build(&tris, &p);
    // Room for barely the root's references: the first clipping level overflows.
    let tiny = vkrt::accel::kdtree::gpu::BuildCapacity::with_refs(tris.len(), tris.len());
    let r = builder.build_from(&ctx, &tris, &p, tiny).unwrap();
    assert!(r.attempts > 1, "the tiny capacity should have overflowed");
    assert!(r.capacity.refs_per_level > tris.len());
    assert!(r.tree.nodes == cpu.nodes && r.tree.prim_refs == cpu.prim_refs, "retry differs from the twin");
    common::assert_silent(&ctx);
}

#[test]
fn gpu_build_equals_cpu_twin_on_hard_cases() {
    let Some(ctx) = common::context() else { return };
    let builder = KdTreeBuilder::new(&ctx).unwrap();
    let p = vkrt::accel::kdtree::SahParams::default();
    let mut rng = common::Rng(3);
    // All in one plane.
    let planar: Vec<[Vec3; 3]> = (0..2000)
        .map(|_| {
            let o = Vec3::new(rng.next_f32() * 10.0, rng.next_f32() * 10.0, 0.0);
            [o, o + Vec3::new(0.3, 0.0, 0.0), o + Vec3::new(0.0, 0.3, 0.0)]
        })
        .collect();
    assert_build_equal(&ctx, &builder, "planar", &planar, &p);
    // Axis-aligned flat quads lying on candidate planes.
    let mut flats = Vec::new();
    for i in 0..40 {
        let x = i as f32;
        flats.push([Vec3::new(x, 0.0, 0.0), Vec3::new(x, 1.0, 0.0), Vec3::new(x, 0.0, 1.0)]);
        flats.push([Vec3::new(0.0, x, 0.0), Vec3::new(1.0, x, 0.0), Vec3::new(0.0, x, 1.0)]);
        flats.push([Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 1.0, 0.0), Vec3::new(x, 1.0, 0.0)]);
    }
    assert_build_equal(&ctx, &builder, "flat-quads", &flats, &p);
    // One huge triangle over many tiny ones.
    let mut mixed: Vec<[Vec3; 3]> = (0..5000)
        .map(|_| {
            let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
            [o, o + Vec3::splat(1e-3), o + Vec3::new(1e-3, 0.0, 0.0)]
        })
        .collect();
    mixed.push([Vec3::splat(-100.0), Vec3::new(100.0, -100.0, 0.0), Vec3::new(0.0, 100.0, 100.0)]);
    assert_build_equal(&ctx, &builder, "huge+tiny", &mixed, &p);
    // Zero-area triangles and signed zeros.
    let t = [Vec3::ZERO, Vec3::X, Vec3::Y];
    let degenerate =
        vec![[Vec3::ONE; 3], [Vec3::ZERO, Vec3::X, Vec3::X * 2.0], t, [Vec3::new(-0.0, 0.0, -0.0), Vec3::X, Vec3::Z]];
    assert_build_equal(&ctx, &builder, "degenerate", &degenerate, &p);
    common::assert_silent(&ctx);
}
