//! The GPU BVH builders against their CPU twins, bit for bit: the LBVH (Karras
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
use vkrt::accel::bvh::collapse::RefLayout;
use vkrt::accel::bvh::collapse_gpu::{CollapseKernels, MAX_COLLAPSE_LEAF};
use vkrt::accel::bvh::lbvh::MortonBits;
use vkrt::accel::bvh::ploc::PlocParams;
use vkrt::accel::bvh::sah::BvhParams;
use vkrt::accel::bvh::validate::validate;
use vkrt::accel::bvh::{Bvh, BvhNode};
use vkrt::accel::device::AccelBuilder;
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::host::HostStructure;
use vkrt::accel::primitives::TraceGeometry;
use vkrt::gpu::{Buffer, Context, GpuError, Recorder};

fn device_bvh(ctx: &Context, builder: &AccelBuilder, g: &TraceGeometry) -> Bvh {
    let mut rec = Recorder::new(ctx).unwrap();
    let (dev, _) = GpuGeometry::record_build(&mut rec, builder, g, 0).unwrap();
    rec.submit_and_wait().unwrap();
    device_bvh_of(&dev)
}

/// A structure built on the device, read back.
fn device_bvh_of(dev: &GpuGeometry) -> Bvh {
    match dev.structure().download().unwrap() {
        HostStructure::Bvh(b) => b,
        HostStructure::KdTree(_) => unreachable!("a GPU BVH"),
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

/// Groups of tiny triangles, 40 groups with sizes cycling through `sizes`, each group's
/// centroids inside one cell of the 63-bit codes' high words (the grid spans 1024 units: a
/// high-word cell is 0.5 × 1 × 1) at random low words, listed member by member across groups.
fn runs(sizes: &[usize]) -> Vec<[Vec3; 3]> {
    let mut rng = Rng(29);
    let tiny = |c: Vec3| [c, c + Vec3::X * 1e-4, c + Vec3::Y * 1e-4];
    let groups: Vec<usize> = (0..40).map(|g| sizes[g % sizes.len()]).collect();
    let mut out = vec![tiny(Vec3::ZERO), tiny(Vec3::splat(1000.0))];
    for member in 0..*sizes.iter().max().unwrap() {
        for (g, &size) in groups.iter().enumerate() {
            if member < size {
                let corner = Vec3::new(g as f32 * 2.0 + 0.25, 0.25, 0.25);
                let jitter = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 0.2;
                out.push(tiny(corner + jitter));
            }
        }
    }
    out
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
    // Runs of equal high words (63-bit codes) with scrambled low words: up to the longest run
    // the tie kernel sorts (32), then one run longer, which takes the whole two-word sort.
    out.push((
        "runs of up to 32 equal high words".into(),
        runs(&[2, 3, 31, 32]),
    ));
    out.push(("a run of 33 equal high words".into(), runs(&[2, 32, 33])));
    out.push(("huge coordinates".into(), soup(1000, 13, 1e30, -5e29)));
    out.push(("tiny coordinates".into(), soup(1000, 17, 1e-30, 0.0)));
    out
}

/// A GPU builder configuration and its name.
type Builder = (String, AccelBuilder);

/// Every GPU builder configuration (its CPU twin, `AccelBuilder::host_twin`: the tree, then
/// the SAH leaf collapse).
fn builders(ctx: &Context) -> Vec<Builder> {
    let mut out: Vec<Builder> = Vec::new();
    // Leaves of up to 4 (the default), 1 (no collapse) and 32 (the largest the GPU makes).
    for (bits, leaf) in [
        (MortonBits::Bits63, 4),
        (MortonBits::Bits30, 4),
        (MortonBits::Bits63, 1),
        (MortonBits::Bits63, MAX_COLLAPSE_LEAF),
    ] {
        let mut builder = AccelBuilder::lbvh(ctx, bits).unwrap();
        builder = builder.with_bvh_params(vkrt::accel::bvh::BvhParams {
            max_leaf_prims: leaf,
            ..Default::default()
        });
        out.push((format!("LBVH {bits:?}, leaves <= {leaf}"), builder));
    }
    // The last: two rounds only, then the pairing fallback finishes the tree.
    for (radius, max_rounds, leaf) in [
        (4, None, 4),
        (8, None, 4),
        (16, None, 4),
        (8, Some(2), 4),
        (8, None, 1),
        (8, None, MAX_COLLAPSE_LEAF),
    ] {
        let params = PlocParams {
            radius,
            max_rounds,
            ..PlocParams::default()
        };
        let mut builder = AccelBuilder::ploc(ctx, params).unwrap();
        builder = builder.with_bvh_params(vkrt::accel::bvh::BvhParams {
            max_leaf_prims: leaf,
            ..Default::default()
        });
        let what = format!("PLOC r = {radius}, rounds {max_rounds:?}, leaves <= {leaf}");
        out.push((what, builder));
    }
    out
}

#[test]
fn gpu_builders_equal_their_cpu_twins_bit_for_bit() {
    let Some(ctx) = context() else { return };
    let sg = ctx.info().subgroup_size as usize;
    let inputs = inputs(sg);
    for (what, builder) in builders(&ctx) {
        for (name, tris) in &inputs {
            let g = TraceGeometry::from_triangles(tris);
            let gpu = device_bvh(&ctx, &builder, &g);
            validate(&gpu, &g.boxes).unwrap_or_else(|e| panic!("{what}, {name}: {e}"));
            assert!(
                HostStructure::Bvh(gpu.clone()) == builder.host_twin(&g).unwrap(),
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
    // which must be balanced (depth log2 n + 1 with a primitive per leaf), not a list.
    let Some(ctx) = context() else { return };
    let p = Vec3::splat(-3.0);
    let g = TraceGeometry::from_triangles(&vec![[p, p, p]; 4096]);
    let mut builder = AccelBuilder::lbvh(&ctx, MortonBits::Bits63).unwrap();
    builder = builder.with_bvh_params(vkrt::accel::bvh::BvhParams {
        max_leaf_prims: 1,
        ..Default::default()
    });
    let gpu = device_bvh(&ctx, &builder, &g);
    validate(&gpu, &g.boxes).unwrap();
    assert_eq!(gpu.depth(), 12);
    // The SAH collapse (leaves of up to 4 by default; every box has area 0, so every leaf
    // of 4 is no dearer) takes two levels off.
    let collapsed = device_bvh(
        &ctx,
        &AccelBuilder::lbvh(&ctx, MortonBits::Bits63).unwrap(),
        &g,
    );
    validate(&collapsed, &g.boxes).unwrap();
    assert_eq!(collapsed.depth(), 10);
    assert_eq!(collapsed.leaf_count(), 1024);
    assert_silent(&ctx);
}

/// A chain of 63 levels (sorted Morton codes 2^62, 2^61, ..., 1: one grid axis bit each,
/// 2^k grid units along one axis) over a balanced subtree of 2^15 triangles in grid cell 0
/// (code 0): over 64
/// levels, deeper than a 64-bit trail. The triangle at x = 2^19 has a partner at x = 2^19 + 1
/// (their node waits as a sibling near the top while the walk goes 70 levels down), and it
/// and the one at x = 2^20 stand across the +x ray of the test; the rest are tiny and away.
fn deep_chain() -> Vec<[Vec3; 3]> {
    let tiny = |p: Vec3| {
        [
            p,
            p + Vec3::new(1e-3, 0.0, 0.0),
            p + Vec3::new(0.0, 1e-3, 0.0),
        ]
    };
    let across = |p: Vec3| [p, p + Vec3::Y, p + Vec3::Z];
    let mut tris: Vec<[Vec3; 3]> = (0..63u32)
        .map(|b| {
            let (axis, k) = ((2 - b % 3) as usize, b / 3);
            let mut p = [0.0f32; 3];
            p[axis] = (1u32 << k) as f32;
            let p = Vec3::from_array(p);
            if axis == 0 && k >= 19 {
                across(p)
            } else {
                tiny(p)
            }
        })
        .collect();
    tris.push(across(Vec3::new((1 << 19) as f32 + 1.0, 0.0, 0.0)));
    // The bottom: flat in z, 1/2^15 apart (all in grid cell 0), as wide as the ray's y.
    tris.extend((0..1 << 15).map(|i| {
        let p = Vec3::new(0.0, 0.0, i as f32 / (1 << 15) as f32);
        [p, p + Vec3::new(1e-3, 0.0, 0.0), p + Vec3::Y]
    }));
    tris
}

/// The deep chain's geometry, its LBVH built on the device, and the tree read back.
/// The deep chain's LBVH, with leaves of up to `max_leaf` primitives.
fn deep_lbvh(ctx: &Context, max_leaf: u32, wide: bool) -> (TraceGeometry, GpuGeometry, Bvh) {
    let g = TraceGeometry::from_triangles(&deep_chain());
    let mut builder = AccelBuilder::lbvh(ctx, MortonBits::Bits63).unwrap();
    builder = builder.with_bvh_params(vkrt::accel::bvh::BvhParams {
        max_leaf_prims: max_leaf,
        ..Default::default()
    });
    builder = builder.with_wide(wide);
    let dev = {
        let mut rec = Recorder::new(ctx).unwrap();
        let (dev, _) = GpuGeometry::record_build(&mut rec, &builder, &g, 0).unwrap();
        rec.submit_and_wait().unwrap();
        dev
    };
    let tree = device_bvh_of(&dev);
    (g, dev, tree)
}

#[test]
fn trees_deeper_than_64_levels_trace_like_brute_force() {
    use vkrt::accel::walk::AccelTraversal;
    use vkrt::accel::walk::Traversal;
    use vkrt::trace::bvh_cpu;
    use vkrt::trace::gpu::Tracer;
    use vkrt::trace::{cpu, Ray, TraceOptions};
    let Some(ctx) = context() else { return };
    let (g, binary, tree) = deep_lbvh(&ctx, 4, false);
    let wide = deep_lbvh(&ctx, 4, true).1;
    assert!(
        tree.depth() > 70,
        "depth {}: the case is not deep",
        tree.depth()
    );
    // Along +x between the bottom's planes, through its boxes to the bottom of the tree,
    // missing its triangles, then onto the triangle at x = 2^19 (a walk with a 64-bit trail
    // loses the level where that triangle's node waits, and answers x = 2^20); and rays
    // straight down onto triangles of the bottom and the chain.
    let mut rays = vec![Ray::new(
        Vec3::new(-0.5, 0.4, 0.4 + 0.5 / (1 << 15) as f32),
        Vec3::X,
        0.0,
        f32::INFINITY,
    )];
    rays.extend((0..g.triangle_count()).step_by(13).map(|p| {
        let t = g.triangle_at(p, 0.0);
        let c = (t[0] + t[1] + t[2]) / 3.0;
        Ray::new(c + Vec3::Z * 8.0, -Vec3::Z, 0.0, f32::INFINITY)
    }));
    let opt = TraceOptions::default();
    let first = cpu::brute_force(&g, &rays[0], 0.0, &opt);
    assert!(
        first.is_hit() && (first.t - (1 << 19) as f32 - 0.5).abs() < 1.0,
        "{first:?}"
    );

    for walk in Traversal::ALL {
        let dev = if walk == Traversal::Wide {
            &wide
        } else {
            &binary
        };
        let tracer = Tracer::for_accel(&ctx, &opt, AccelTraversal::Bvh(walk)).unwrap();
        let batch = tracer.trace(&ctx, dev, &rays, 0.0).unwrap();
        assert_eq!(batch.exhausted, 0);
        for (r, h) in rays.iter().zip(&batch.hits) {
            let b = cpu::brute_force(&g, r, 0.0, &opt);
            let twin = bvh_cpu::trace(&g, &tree, r, 0.0, &opt, walk).0;
            assert!(
                common::same_answer(&twin, &b),
                "twin {walk:?}: {r:?}: {twin:?} vs {b:?}"
            );
            assert!(
                common::same_answer(h, &b),
                "{walk:?}: {r:?}: {h:?} vs {b:?}"
            );
        }
    }
    assert_silent(&ctx);
}

/// A slanted ray grazing the deep chain's 2^15 stacked bottom triangles: the walks test
/// thousands of leaves before the hit. Mesa 22.3's lavapipe ends every loop of an invocation
/// after 65,535 iterations in all (its `loop_limiter`, `DeviceInfo::loop_budget`), which
/// these walks reach below the step cap: there the ray must be reported exhausted, never
/// answered a silent miss. Mesa 25 has no such budget: there, and on the CPU twins, the
/// walk hits.
#[test]
fn slanted_ray_in_a_deep_tree() {
    use vkrt::accel::walk::AccelTraversal;
    use vkrt::accel::walk::Traversal;
    use vkrt::trace::gpu::Tracer;
    use vkrt::trace::{cpu, Ray, TraceOptions};
    let Some(ctx) = context() else { return };
    // One primitive per leaf: the longest walk (with leaves of 4 it fits 22.3's budget).
    let (g, binary, _) = deep_lbvh(&ctx, 1, false);
    let wide = deep_lbvh(&ctx, 1, true).1;
    let r = Ray::new(
        Vec3::new(0.009_917_641, -0.526_685_6, 8.012_146),
        Vec3::new(-0.009_584_308, 0.860_018_97, -8.0),
        0.0,
        f32::INFINITY,
    );
    let opt = TraceOptions::default();
    let b = cpu::brute_force(&g, &r, 0.0, &opt);
    assert!(b.is_hit());
    let budgeted = ctx.info().loop_budget.is_some();
    for walk in Traversal::ALL {
        let dev = if walk == Traversal::Wide {
            &wide
        } else {
            &binary
        };
        let tracer = Tracer::for_accel(&ctx, &opt, AccelTraversal::Bvh(walk)).unwrap();
        let out = tracer.trace(&ctx, dev, &[r], 0.0).unwrap();
        let h = out.hits[0];
        if out.exhausted == 1 {
            eprintln!(
                "{walk:?}: exhausted on {} (its loop budget)",
                ctx.info().driver
            );
            assert!(budgeted, "{walk:?}: exhausted on {}", ctx.info().driver);
        } else {
            assert!(common::same_answer(&h, &b), "{walk:?}: {h:?} vs {b:?}");
        }
    }
    assert_silent(&ctx);
}

#[test]
fn a_collapse_refuses_scratch_made_for_the_other_layout() {
    // Scratch made for references left in place holds no flags or scan: a node-order
    // collapse over it is refused with a usage error before anything is recorded.
    let Some(ctx) = context() else { return };
    let kernels = CollapseKernels::new(&ctx, ctx.info().subgroup_size.max(1)).unwrap();
    let n = 100;
    let scratch = kernels.scratch(&ctx, n, RefLayout::InPlace).unwrap();
    assert!(
        kernels.scratch_bytes(n, RefLayout::InPlace)
            < kernels.scratch_bytes(n, RefLayout::NodeOrder)
    );
    let visits = Buffer::<u32>::new(&ctx, "visits", n).unwrap();
    let nodes = Buffer::<BvhNode>::new(&ctx, "nodes", n).unwrap();
    let refs = Buffer::<u32>::new(&ctx, "refs", 2 * n).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    let params = BvhParams::default();
    let err = kernels
        .record(
            &mut rec,
            n,
            &visits,
            &scratch,
            &params,
            &nodes,
            &refs,
            false,
            RefLayout::NodeOrder,
        )
        .unwrap_err();
    assert!(matches!(err, GpuError::Usage { .. }), "{err}");
    assert!(err.to_string().contains("in place"), "{err}");
    drop(rec);
    assert_silent(&ctx);
}
