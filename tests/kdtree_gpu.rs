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
    let (gpu, _) = builder.phase_one(ctx, tris).unwrap();
    let boxes: Vec<_> = tris.iter().map(seed001::prim_box).collect();
    let bounds = seed001::bounds_of(&boxes);
    let got = gpu.bounds().unwrap();
    if !tris.is_empty() {
        assert_eq!(bits(&got.min.to_array()), bits(&bounds.min.to_array()), "{name}: bounds.min");
        assert_eq!(bits(&got.max.to_array()), bits(&bounds.max.to_array()), "{name}: bounds.max");
    }
    let cpu = seed001::initial_events(&boxes);
    for a in 0..3 {
        let g = gpu.events[a].download().unwrap();
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
