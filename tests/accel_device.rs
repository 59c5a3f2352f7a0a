//! Structures built where they are traced, behind the one interface
//! (`vkrt::accel::device`): sizes first, the build recorded into the caller's recorder, the
//! trace in the same submission with nothing read back between. Every kind's device build
//! equals its host twin (the kd-tree bit for bit with Kolodzey's CPU build, the SAH BVH with
//! the one-thread build), fits the sizes it announced, and traces like brute force; a
//! kd-tree that runs out of its reference budget never answers wrongly.

mod common;

use common::{assert_silent, context, edge_sizes, same_answer, Rng};
use glam::{Vec3, Vec4};
use vkrt::accel::bvh::{self, Threading};
use vkrt::accel::device::{AccelBuilder, AccelKind, AccelStructure};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::host::HostStructure;
use vkrt::accel::primitives::TraceGeometry;
use vkrt::accel::walk::Traversal;
use vkrt::gpu::{Buffer, Context, Recorder};
use vkrt::trace::gpu::{build_and_trace, Tracer};
use vkrt::trace::{cpu, Ray, TraceOptions};

fn soup(n: usize, seed: u64) -> Vec<[Vec3; 3]> {
    let mut rng = Rng(seed);
    let mut v = || Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
    (0..n)
        .map(|_| {
            let c = v() * 10.0;
            [c, c + v(), c + v()]
        })
        .collect()
}

/// Triangles, plus a few spheres when `spheres`.
fn scene(n: usize, seed: u64, spheres: bool) -> TraceGeometry {
    let tris = soup(n, seed);
    let s: Vec<Vec4> = if spheres {
        (0..n.div_ceil(7))
            .map(|i| Vec4::new(i as f32, (i % 5) as f32, -3.0, 0.4))
            .collect()
    } else {
        Vec::new()
    };
    TraceGeometry::from_triangles_and_spheres(&tris, &s)
}

fn rays(n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = Rng(seed);
    (0..n)
        .map(|_| {
            let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 14.0 - 2.0;
            let d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
            Ray::new(o, d, 0.0, f32::INFINITY)
        })
        .collect()
}

/// Builds on the device in one submission and reads the structure back.
fn device_build(
    ctx: &Context,
    builder: &AccelBuilder,
    g: &TraceGeometry,
) -> (GpuGeometry, HostStructure) {
    let mut rec = Recorder::new(ctx).unwrap();
    let (dev, _) = GpuGeometry::record_build(&mut rec, builder, g, 0).unwrap();
    rec.submit_and_wait().unwrap();
    let host = dev.structure().download().unwrap();
    (dev, host)
}

#[test]
fn device_builds_equal_their_host_twins_and_fit_their_sizes() {
    let Some(ctx) = context() else { return };
    let sg = ctx.info().subgroup_size as usize;
    let mut sizes = edge_sizes(sg, 256, 1024);
    sizes.retain(|&n| n <= 3000);
    sizes.extend([0, 1, 2, 3000]);
    sizes.sort_unstable();
    sizes.dedup();
    for kind in AccelKind::ALL {
        let mut builder = AccelBuilder::new(&ctx, kind).unwrap();
        builder = builder.with_threading(Threading::Queue { threads: 2 });
        for &n in &sizes {
            for spheres in [false, true] {
                let g = scene(n, n as u64 + 1, spheres);
                let (dev, host) = device_build(&ctx, &builder, &g);
                let twin = builder.host_twin(&g).unwrap();
                assert_eq!(
                    host, twin,
                    "{kind:?} of {n} primitives (spheres: {spheres})"
                );
                let used = match &host {
                    HostStructure::KdTree(tree) => tree.nodes.len() * 16 + tree.prim_refs.len() * 4,
                    HostStructure::Bvh(b) => {
                        bvh::validate::validate(b, &g.boxes).unwrap();
                        b.bytes()
                    }
                };
                let announced = builder.sizes(&ctx, g.primitive_count(), 0).unwrap();
                assert!(
                    used as u64 + 48 <= announced.structure_bytes,
                    "{kind:?}, {n}: {used} bytes used, {announced:?}"
                );
                assert_eq!(dev.structure().kind(), kind);
            }
        }
    }
    assert_silent(&ctx);
}

#[test]
fn build_and_trace_is_one_submission_and_equals_brute_force() {
    let Some(ctx) = context() else { return };
    let g = scene(2000, 5, true);
    let rs = rays(5000, 9);
    let opt = TraceOptions::default();
    let brute: Vec<_> = rs
        .iter()
        .map(|r| cpu::brute_force(&g, r, 0.0, &opt))
        .collect();
    for kind in AccelKind::ALL {
        let mut builder = AccelBuilder::new(&ctx, kind).unwrap();
        for walk in Traversal::ALL {
            builder = builder.with_wide(walk == Traversal::Wide);
            let accel = kind.walked(walk);
            let tracer = Tracer::for_accel(&ctx, &opt, accel).unwrap();
            let before = ctx.traffic();
            let done = build_and_trace(&ctx, &builder, &tracer, &g, &rs, 0.0, None).unwrap();
            let traffic = ctx.traffic() - before;
            assert_eq!(done.traffic, traffic);
            assert_eq!(traffic.submits, 1, "{accel:?}");
            assert_eq!(done.readback_before_trace, 0);
            assert_eq!(done.attempts, 1);
            // What came back: the hits, the error counter, a kd-tree's build report.
            let report = if kind == AccelKind::KdTree { 16 } else { 0 };
            assert_eq!(traffic.readback_bytes, 16 * rs.len() as u64 + 4 + report);
            let wrong = rs
                .iter()
                .zip(&done.batch.hits)
                .zip(&brute)
                .filter(|((_, h), b)| !same_answer(h, b))
                .count();
            assert_eq!(wrong, 0, "{accel:?}: {wrong} rays differ from brute force");
            assert!(done.batch.hits.iter().any(|h| h.is_hit()));
        }
    }
    assert_silent(&ctx);
}

#[test]
fn a_kd_tree_out_of_references_misses_everything_then_is_rebuilt_larger() {
    let Some(ctx) = context() else { return };
    // Overlapping triangles: clipping duplicates references far past a budget of 64.
    let g = scene(3000, 11, false);
    let rs = rays(2000, 3);
    let opt = TraceOptions::default();
    let mut builder = AccelBuilder::new(&ctx, AccelKind::KdTree).unwrap();
    builder = builder.with_kd_refs_per_level(Some(64));
    let tracer = Tracer::new(&ctx, &opt).unwrap();

    // Within the one submission, the trace after an overflowing build misses every ray.
    let mut rec = Recorder::new(&ctx).unwrap();
    let (dev, _) = GpuGeometry::record_build(&mut rec, &builder, &g, 0).unwrap();
    rec.compute_to_transfer();
    let built = dev.structure().record_read_built(&mut rec).unwrap();
    rec.transfer_to_host();
    rec.submit_and_wait().unwrap();
    let report = AccelStructure::kd_built(&built.unwrap().read().unwrap());
    assert!(report.overflow, "{report:?}");
    assert!(report.needed_refs > 64, "{report:?}");
    // The same report copied into the renderer's buffer, as a query pool's result is
    // (vkCmdCopyQueryPoolResults): words past it untouched.
    let caller = vkrt::gpu::Buffer::<u32>::from_slice(&ctx, "caller.status", &[7; 6]).unwrap();
    // SAFETY: the buffer outlives the work (waited for below) and has transfer usage.
    let range = unsafe { caller.as_raw() }.slice(4, 16).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    assert!(dev
        .structure()
        .record_copy_built_into(&mut rec, &range)
        .unwrap());
    rec.submit_and_wait().unwrap();
    let words = caller.download().unwrap();
    assert_eq!((words[0], words[5]), (7, 7), "outside the range");
    assert_eq!(AccelStructure::kd_built(&words[1..5]), report);
    // A range too small is refused, and nothing recorded.
    let mut rec = Recorder::new(&ctx).unwrap();
    let short = unsafe { caller.as_raw() }.slice(0, 12).unwrap();
    assert!(dev
        .structure()
        .record_copy_built_into(&mut rec, &short)
        .is_err());
    let b = tracer.trace(&ctx, &dev, &rs, 0.0).unwrap();
    assert!(
        b.hits.iter().all(|h| !h.is_hit()),
        "an overflowed tree answered a hit"
    );
    assert!(
        dev.structure().download().is_err(),
        "downloading an overflowed tree is an error"
    );

    // build_and_trace notices after its submission and builds again with a larger budget.
    let done = build_and_trace(&ctx, &builder, &tracer, &g, &rs, 0.0, None).unwrap();
    assert!(done.attempts > 1, "{}", done.attempts);
    assert_eq!(done.traffic.submits, u64::from(done.attempts));
    let wrong = rs
        .iter()
        .zip(&done.batch.hits)
        .filter(|(r, h)| !same_answer(h, &cpu::brute_force(&g, r, 0.0, &opt)))
        .count();
    assert_eq!(wrong, 0);
    assert_silent(&ctx);
}

/// `g` with every vertex and sphere moved by up to `amount` (the same primitives).
fn moved(g: &TraceGeometry, amount: f32, seed: u64) -> TraceGeometry {
    let mut rng = Rng(seed);
    let tris: Vec<[Vec3; 3]> = (0..g.triangle_count())
        .map(|i| {
            g.triangle_at(i, 0.0).map(|p| {
                p + (Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5) * amount
            })
        })
        .collect();
    let spheres: Vec<Vec4> = (0..g.spheres.len())
        .map(|i| {
            let s = g.sphere_at(i, 0.0);
            s + Vec4::new(rng.next_f32(), rng.next_f32(), rng.next_f32(), 0.0) * amount
        })
        .collect();
    TraceGeometry::from_triangles_and_spheres(&tris, &spheres)
}

/// Refit keeps the topology and recomputes every box: unmoved, it gives the tree back;
/// moved, the CPU twin's tree validates (every box exactly the union below it) and the GPU
/// refit equals it bit for bit, and the refit tree traces like brute force on the moved
/// geometry. A kd-tree cannot be refit: a clear error.
#[test]
fn refit_follows_moved_primitives_bit_for_bit_with_its_twin() {
    let Some(ctx) = context() else { return };
    let sg = ctx.info().subgroup_size as usize;
    let opt = TraceOptions::default();
    let tracer = Tracer::for_accel(&ctx, &opt, AccelKind::SahBvh.walked(Traversal::Stack)).unwrap();
    // Climbing refit (built without update) and the per-depth refit of structures built to
    // be updated, on every BVH kind.
    let configs = [
        (AccelKind::SahBvh, false),
        (AccelKind::SahBvh, true),
        (AccelKind::Lbvh, true),
        (AccelKind::Ploc, true),
    ];
    for (kind, allow_update) in configs {
        let mut builder = AccelBuilder::new(&ctx, kind).unwrap();
        builder = builder.with_allow_update(allow_update);
        for n in [1, 2, 3, sg - 1, sg + 1, 65, 257, 1025, 3000] {
            let g = scene(n, 40 + n as u64, true);
            let (mut dev, host) = device_build(&ctx, &builder, &g);
            let HostStructure::Bvh(original) = host else {
                unreachable!()
            };
            let mut same = original.clone();
            bvh::refit(&mut same, &g.boxes);
            assert_eq!(same, original, "{n}: refit of an unmoved scene");

            let g2 = moved(&g, 0.7, n as u64);
            let mut twin = original.clone();
            bvh::refit(&mut twin, &g2.boxes);
            bvh::validate::validate(&twin, &g2.boxes).unwrap_or_else(|e| panic!("{n}: {e}"));

            let scratch = builder
                .update_scratch(&ctx, g2.primitive_count())
                .unwrap()
                .unwrap();
            // On the device, too, a refit of the unmoved scene gives the tree back.
            let mut rec = Recorder::new(&ctx).unwrap();
            builder.record_refit(&mut rec, &mut dev, &scratch).unwrap();
            rec.submit_and_wait().unwrap();
            let unmoved = dev.structure().download().unwrap();
            assert!(
                unmoved == HostStructure::Bvh(original.clone()),
                "{kind:?} {allow_update}, {n}: GPU refit of an unmoved scene"
            );
            let mut rec = Recorder::new(&ctx).unwrap();
            dev.primitives().record_update(&mut rec, &g2).unwrap();
            builder.record_refit(&mut rec, &mut dev, &scratch).unwrap();
            rec.submit_and_wait().unwrap();
            let HostStructure::Bvh(gpu) = dev.structure().download().unwrap() else {
                unreachable!()
            };
            let bits = |nd: &bvh::BvhNode| -> Vec<u32> { bytemuck::cast_slice(&[*nd]).to_vec() };
            let differ: Vec<usize> = (0..twin.nodes.len())
                .filter(|&i| bits(&gpu.nodes[i]) != bits(&twin.nodes[i]))
                .collect();
            assert!(
            differ.is_empty(),
            "{kind:?} {allow_update}, {n}: GPU refit differs from its twin at nodes {differ:?} of {} (parents {:?})",
            twin.nodes.len(),
            twin.parents
        );
            assert_eq!(gpu.bounds, twin.bounds, "{n}");

            let rs = rays(1000, n as u64);
            let b = tracer.trace(&ctx, &dev, &rs, 0.0).unwrap();
            for (r, h) in rs.iter().zip(&b.hits) {
                assert!(
                    same_answer(h, &cpu::brute_force(&g2, r, 0.0, &opt)),
                    "{n}: {r:?}"
                );
            }
        }
    }
    let kd = AccelBuilder::new(&ctx, AccelKind::KdTree).unwrap();
    let g = scene(10, 1, false);
    let (mut dev, _) = device_build(&ctx, &kd, &g);
    assert!(kd.update_scratch(&ctx, 10).unwrap().is_none());
    let scratch = Buffer::<u32>::new(&ctx, "unused", 16).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    let err = kd.record_refit(&mut rec, &mut dev, &scratch).unwrap_err();
    assert!(matches!(err, vkrt::gpu::GpuError::Usage { .. }), "{err}");
    assert!(err.to_string().contains("cannot be refit"), "{err}");
    drop(rec);

    // An update that changes the primitives' counts, and GPU leaves past the collapse's
    // limit: the caller's mistakes, each a usage error.
    let lbvh = AccelBuilder::new(&ctx, AccelKind::Lbvh).unwrap();
    let (dev, _) = device_build(&ctx, &lbvh, &g);
    let mut rec = Recorder::new(&ctx).unwrap();
    let err = dev
        .primitives()
        .record_update(&mut rec, &scene(11, 1, false))
        .unwrap_err();
    assert!(matches!(err, vkrt::gpu::GpuError::Usage { .. }), "{err}");
    let wide_leaves = AccelBuilder::new(&ctx, AccelKind::Lbvh)
        .unwrap()
        .with_bvh_params(bvh::BvhParams {
            max_leaf_prims: 33,
            ..bvh::BvhParams::default()
        });
    let err = GpuGeometry::record_build(&mut rec, &wide_leaves, &g, 0)
        .map(|_| ())
        .unwrap_err();
    assert!(matches!(err, vkrt::gpu::GpuError::Usage { .. }), "{err}");
    drop(rec);
    assert_silent(&ctx);
}
