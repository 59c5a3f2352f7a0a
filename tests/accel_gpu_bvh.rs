//! The GPU BVH builders against their CPU twins, bit for bit: the LBVH (seed 000, Karras
//! 2012) with 30- and 63-bit Morton codes and PLOC (Meister & Bittner 2018) with search
//! radii 4, 8 and 16 (and with the pairing fallback after two rounds), on every size edge (0, 1, 2, subgroup ± 1, workgroup ± 1, the radix
//! sort's tile ± 1, large, random) and the inputs that break naive builders: every code
//! equal, every primitive in one point, flat and degenerate boxes, huge and tiny
//! coordinates. Every tree passes the validator (each primitive exactly once, parents
//! consistent, every box the exact union of what lies below), and the same input gives the
//! same tree on every run. Traversal of these trees against brute force and the robustness suite
//! are in `accel_device.rs` and `trace_robustness.rs` (every kind).

mod common;

use common::{assert_silent, context, edge_sizes, Rng};
use glam::Vec3;
use vkrt::accel::bvh::lbvh::{self, MortonBits};
use vkrt::accel::bvh::ploc::{self, PlocParams};
use vkrt::accel::bvh::validate::validate;
use vkrt::accel::bvh::Bvh;
use vkrt::accel::device::{AccelBuilder, HostStructure};
use vkrt::gpu::{Context, Recorder};
use vkrt::trace::gpu::GpuGeometry;
use vkrt::trace::TraceGeometry;

fn device_bvh(ctx: &Context, builder: &AccelBuilder, g: &TraceGeometry) -> Bvh {
    let mut rec = Recorder::new(ctx).unwrap();
    let (dev, _) = GpuGeometry::record_build(&mut rec, builder, g, 0).unwrap();
    rec.submit_and_wait().unwrap();
    match dev.accel.download().unwrap() {
        HostStructure::Bvh(b) => b,
        HostStructure::KdTree(_) => unreachable!("an LBVH is a BVH"),
    }
}

fn soup(n: usize, seed: u64, scale: f32, offset: f32) -> Vec<[Vec3; 3]> {
    let mut rng = Rng(seed);
    let mut v = || Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
    (0..n)
        .map(|_| {
            let c = v() * scale + Vec3::splat(offset);
            [c, c + v() * scale * 0.05, c + v() * scale * 0.05]
        })
        .collect()
}

/// Named inputs: random soups at every size edge, then the hard cases.
fn inputs(subgroup: usize) -> Vec<(String, Vec<[Vec3; 3]>)> {
    let mut sizes = edge_sizes(subgroup, 64, 4096);
    sizes.retain(|&n| n <= 5000);
    sizes.extend([0, 1, 2, 3, 20_000]);
    sizes.sort_unstable();
    sizes.dedup();
    let mut out: Vec<_> = sizes
        .iter()
        .map(|&n| (format!("soup {n}"), soup(n, n as u64 + 3, 10.0, 0.0)))
        .collect();
    let p = Vec3::new(1.0, 2.0, 3.0);
    out.push(("every triangle one point".into(), vec![[p, p, p]; 300]));
    // A cluster far smaller than one grid cell beside one far triangle: the cluster's codes
    // are all equal.
    let mut cluster = soup(200, 7, 1e-6, 5.0);
    cluster.push([
        Vec3::splat(1e3),
        Vec3::splat(1e3) + Vec3::X,
        Vec3::splat(1e3) + Vec3::Y,
    ]);
    out.push(("equal codes".into(), cluster));
    let flat: Vec<_> = soup(500, 11, 4.0, -2.0)
        .into_iter()
        .map(|t| t.map(|v| Vec3::new(v.x, v.y, 0.25)))
        .collect();
    out.push(("flat in z".into(), flat));
    let lines: Vec<_> = (0..257)
        .map(|i| {
            let a = Vec3::new(i as f32 * 0.5, 0.0, 0.0);
            [a, a + Vec3::X, a + Vec3::X * 2.0]
        })
        .collect();
    out.push(("degenerate on a line".into(), lines));
    out.push(("huge coordinates".into(), soup(1000, 13, 1e30, -5e29)));
    out.push(("tiny coordinates".into(), soup(1000, 17, 1e-30, 0.0)));
    out
}

/// Every GPU builder configuration with its CPU twin.
fn builders(ctx: &Context) -> Vec<(String, AccelBuilder, Box<dyn Fn(&TraceGeometry) -> Bvh>)> {
    let mut out: Vec<(String, AccelBuilder, Box<dyn Fn(&TraceGeometry) -> Bvh>)> = Vec::new();
    for bits in [MortonBits::Bits63, MortonBits::Bits30] {
        out.push((
            format!("LBVH {bits:?}"),
            AccelBuilder::lbvh(ctx, bits).unwrap(),
            Box::new(move |g| lbvh::build(&g.boxes, bits)),
        ));
    }
    // The last: two rounds only, then the pairing fallback finishes the tree.
    for (radius, max_rounds) in [(4, None), (8, None), (16, None), (8, Some(2))] {
        let params = PlocParams {
            radius,
            max_rounds,
            ..PlocParams::default()
        };
        out.push((
            format!("PLOC r = {radius}, rounds {max_rounds:?}"),
            AccelBuilder::ploc(ctx, params).unwrap(),
            Box::new(move |g| ploc::build(&g.boxes, &params).0),
        ));
    }
    out
}

#[test]
fn gpu_builders_equal_their_cpu_twins_bit_for_bit() {
    let Some(ctx) = context() else { return };
    let sg = ctx.info().subgroup_size as usize;
    let inputs = inputs(sg);
    for (what, builder, twin) in builders(&ctx) {
        for (name, tris) in &inputs {
            let g = TraceGeometry::from_triangles(tris);
            let gpu = device_bvh(&ctx, &builder, &g);
            validate(&gpu, &g.boxes).unwrap_or_else(|e| panic!("{what}, {name}: {e}"));
            assert!(
                gpu == twin(&g),
                "{what}, {name}: the GPU tree differs from its twin"
            );
            assert!(
                device_bvh(&ctx, &builder, &g) == gpu,
                "{what}, {name}: a second build differs"
            );
        }
    }
    assert_silent(&ctx);
}

#[test]
fn equal_codes_fall_back_to_the_index_and_stay_shallow() {
    // 4096 primitives in one point: one code, so Karras's index rule alone shapes the tree,
    // which must be balanced (depth log2 n + 1), not a list.
    let Some(ctx) = context() else { return };
    let p = Vec3::splat(-3.0);
    let g = TraceGeometry::from_triangles(&vec![[p, p, p]; 4096]);
    let builder = AccelBuilder::lbvh(&ctx, MortonBits::Bits63).unwrap();
    let gpu = device_bvh(&ctx, &builder, &g);
    validate(&gpu, &g.boxes).unwrap();
    assert_eq!(gpu.depth(), 12);
    assert_silent(&ctx);
}
