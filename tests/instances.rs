//! Two levels: a top level over instances of bottom-level structures, traced through
//! `vkrt/ray_query.glsl` at device addresses. `accel.instance_boxes` against its CPU twin bit
//! for bit; the top level's tree the same as the one built from the same boxes on the host;
//! hits against the CPU twin of the two-level walk and against the flattened scene (every
//! instance's triangles moved to the world); identity instances against the bottom level
//! itself; masks, custom indices, any-hit, empty levels, updates and every misuse class.

mod common;

use glam::{Affine3A, Quat, Vec3};
use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::embedded::BuildFlags;
use vkrt::accel::geometry::transform_point;
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::instance::MAX_BOTTOM_LEVELS;
use vkrt::accel::instances::{
    instance_boxes, instance_pointers_on_host, lerp_rows, world_to_object, Instance,
    InstanceMotion, InstancePointers, InstanceRecord, TopLevelBuilder,
};
use vkrt::accel::primitives::SceneInfo;
use vkrt::accel::primitives::TraceGeometry;
use vkrt::gpu::{Buffer, Context, GpuError, Recorder};
use vkrt::scene::Aabb;
use vkrt::trace::instanced::{object_ray, trace_instances};
use vkrt::trace::{cpu, Hit, Ray, TraceOptions};

fn opt() -> TraceOptions {
    TraceOptions {
        exact: false,
        ..TraceOptions::default()
    }
}

/// A bottom level of `kind` (walked wide where `wide`) over `tris`, built on the device.
fn bottom(ctx: &Context, kind: AccelKind, wide: bool, tris: &[[Vec3; 3]]) -> GpuGeometry {
    let mut builder = AccelBuilder::new(ctx, kind).unwrap();
    builder = builder.with_wide(wide);
    let g = TraceGeometry::from_triangles(tris);
    let mut rec = Recorder::new(ctx).unwrap();
    let (out, _) = GpuGeometry::record_build(&mut rec, &builder, &g, 0).unwrap();
    rec.submit_and_wait().unwrap();
    out
}

/// Closest (or any) hits through `gpu.handle_probe`'s address variant from the structure
/// whose handle lies at `handle`: (t bits, geometry, primitive, instance or custom index).
fn probe(ctx: &Context, handle: u64, rays: &[Ray], mode: u32) -> Vec<[u32; 4]> {
    probe_at(ctx, handle, rays, mode, 0.0)
}

/// [`probe`] with every ray at `time`.
fn probe_at(ctx: &Context, handle: u64, rays: &[Ray], mode: u32, time: f32) -> Vec<[u32; 4]> {
    common::probe_handle(ctx, handle, rays, mode, time)
}

/// A flat structure's handle, written where the probe reads it.
fn flat_handle(ctx: &Context, g: &GpuGeometry) -> Buffer<u64> {
    Buffer::from_slice(ctx, "probe.handle", &g.handle_words().unwrap()).unwrap()
}

/// In [0, 1).
fn unit(rng: &mut common::Rng) -> f32 {
    (rng.next_f32() + 1.0) * 0.5
}

/// In [-0.5, 0.5)³.
fn centered(rng: &mut common::Rng) -> Vec3 {
    rng.next_vec3() * 0.5
}

fn random_transform(rng: &mut common::Rng, spread: f32) -> Affine3A {
    let axis = centered(rng).normalize_or(Vec3::Y);
    let angle = unit(rng) * std::f32::consts::TAU;
    let s = 0.3 + unit(rng);
    // Every fourth instance mirrored (a negative determinant), some scaled unevenly.
    let mirror = if rng.next_u64() % 4 == 0 { -1.0 } else { 1.0 };
    let scale = Vec3::new(s * mirror, s * (0.5 + unit(rng)), s);
    let t = centered(rng) * spread;
    Affine3A::from_scale_rotation_translation(scale, Quat::from_axis_angle(axis, angle), t)
}

fn sphere_tris(subdivisions: u32) -> Vec<[Vec3; 3]> {
    common::mesh_triangles(&vkrt::scene::gen::icosphere(subdivisions).unwrap())
}

fn random_tris(rng: &mut common::Rng, n: usize) -> Vec<[Vec3; 3]> {
    (0..n)
        .map(|_| {
            let c = rng.next_vec3();
            [0, 1, 2].map(|_| c + centered(rng) * 0.4)
        })
        .collect()
}

/// Rays from a sphere of radius `r` around the origin towards points near it.
fn rays_at(rng: &mut common::Rng, n: usize, r: f32) -> Vec<Ray> {
    (0..n)
        .map(|_| {
            let o = centered(rng).normalize_or(Vec3::X) * r;
            let target = centered(rng) * r * 0.8;
            Ray::new(o, target - o, 0.0, f32::INFINITY)
        })
        .collect()
}

/// The CPU twin's answers: the two-level walk over `records` with brute force in each
/// bottom level.
fn twin(
    records: &[InstanceRecord],
    bottoms: &[TraceGeometry],
    rays: &[Ray],
) -> Vec<(Hit, Option<u32>)> {
    rays.iter()
        .map(|r| {
            let h = trace_instances(records, &[], r, 0.0, 0xff, false, |b, ro| {
                (
                    cpu::brute_force(&bottoms[b as usize], ro, 0.0, &opt()),
                    false,
                )
            });
            assert!(!h.exhausted);
            (h.hit, h.instance)
        })
        .collect()
}

/// Every instance's triangles in the world, and per flat triangle its (instance, primitive).
fn flattened(
    instances: &[Instance],
    bottoms: &[Vec<[Vec3; 3]>],
) -> (TraceGeometry, Vec<(u32, u32)>) {
    let mut tris = Vec::new();
    let mut owner = Vec::new();
    for (i, inst) in instances.iter().enumerate() {
        for (p, t) in bottoms[inst.bottom as usize].iter().enumerate() {
            tris.push(t.map(|v| transform_point(&inst.transform, v)));
            owner.push((i as u32, p as u32));
        }
    }
    (TraceGeometry::from_triangles(&tris), owner)
}

fn as_hit(h: &[u32; 4]) -> (Hit, Option<u32>) {
    if h[0] == u32::MAX {
        return (Hit::MISS, None);
    }
    assert_ne!(h[0], 0xffff_fffe, "a walk gave up");
    let hit = Hit {
        t: f32::from_bits(h[0]),
        prim: h[2],
        u: 0.0,
        v: 0.0,
    };
    (hit, Some(h[3]))
}

/// Each bottom level's scene constants and reference, as the twin takes them.
fn scene_infos(bottoms: &[&GpuGeometry]) -> Vec<(SceneInfo, u64)> {
    bottoms
        .iter()
        .map(|b| {
            (
                b.structure().scene_info().download().unwrap()[0],
                b.reference().unwrap(),
            )
        })
        .collect()
}

#[test]
fn instance_boxes_equal_their_cpu_twin_bit_for_bit_and_the_tree_the_host_s() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(5);
    let a = bottom(&ctx, AccelKind::Lbvh, false, &sphere_tris(1));
    let b = bottom(&ctx, AccelKind::Ploc, false, &random_tris(&mut rng, 50));
    let empty = bottom(&ctx, AccelKind::Lbvh, false, &[]);
    let bottoms = [&a, &b, &empty];
    let infos = scene_infos(&bottoms);
    for kind in [AccelKind::Lbvh, AccelKind::Ploc] {
        let builder = TopLevelBuilder::new(&ctx, kind).unwrap();
        for n in [0usize, 1, 2, 63, 64, 65, 1000] {
            // Valid instances, and among them every class the device must neutralise: a
            // singular transform, a non-finite one, a bottom level out of range, mask 0, an
            // empty bottom level.
            let instances: Vec<Instance> = (0..n)
                .map(|i| {
                    let rows = Instance::rows_of(&random_transform(&mut rng, 20.0));
                    let inst = Instance::new((i % 2) as u32, rows).with_custom_index(i as u32);
                    vkrt::verify::invalid_instance_mix(i, inst, Some(2))
                })
                .collect();
            let flags = BuildFlags::default();
            let sizes = builder.sizes_for(&ctx, n as u32, 3, &flags).unwrap();
            let memory =
                Buffer::<u8>::arena(&ctx, "caller.top", sizes.structure_bytes as usize).unwrap();
            let scratch =
                Buffer::<u8>::arena(&ctx, "caller.scratch", sizes.build_scratch_bytes as usize)
                    .unwrap();
            let input = Buffer::from_slice(&ctx, "caller.instances", &instances[..])
                .unwrap_or_else(|_| Buffer::new(&ctx, "caller.instances", 1).unwrap());
            let mut top = builder
                .create_in(&ctx, &bottoms, n as u32, &flags, unsafe { memory.as_raw() })
                .unwrap();
            let mut rec = Recorder::new(&ctx).unwrap();
            builder
                .record_build_from(
                    &mut rec,
                    &mut top,
                    unsafe { input.as_raw() },
                    n as u32,
                    unsafe { scratch.as_raw() },
                )
                .unwrap();
            rec.compute_to_transfer();
            let status = top.record_read_status(&mut rec).unwrap();
            rec.transfer_to_host();
            rec.submit_and_wait().unwrap();
            let (boxes, records) = top.download().unwrap();
            let want = instance_boxes(
                &instances,
                InstanceMotion::STATIC,
                &infos,
                Some(top.bottom_handles_address()),
            );
            let (want_boxes, want_records, invalid) = (want.boxes, want.records, want.invalid);
            let bits =
                |b: &[[f32; 6]]| -> Vec<u32> { b.iter().flatten().map(|x| x.to_bits()).collect() };
            assert_eq!(bits(&boxes), bits(&want_boxes), "{kind:?} n {n}: boxes");
            assert_eq!(
                bytemuck::cast_slice::<_, u32>(&records),
                bytemuck::cast_slice::<_, u32>(&want_records),
                "{kind:?} n {n}: records"
            );
            assert_eq!(
                status.read().unwrap().invalid_primitives,
                invalid,
                "{kind:?} n {n}"
            );
            assert_eq!(
                invalid as usize,
                (0..n).filter(|i| [3, 5, 7].contains(&(i % 17))).count()
            );
            // The tree: the one the same builder makes from the same boxes given on the host.
            if n > 0 {
                let host = TraceGeometry::from_primitives(
                    &[],
                    &[],
                    &want_boxes
                        .iter()
                        .map(|b| Aabb {
                            min: Vec3::from_slice(&b[..3]),
                            max: Vec3::from_slice(&b[3..]),
                        })
                        .collect::<Vec<_>>(),
                );
                let tree_builder = AccelBuilder::new(&ctx, kind).unwrap();
                let mut rec = Recorder::new(&ctx).unwrap();
                let (g, _) = GpuGeometry::record_build(&mut rec, &tree_builder, &host, 0).unwrap();
                rec.submit_and_wait().unwrap();
                assert_eq!(
                    top.tree().structure().download().unwrap(),
                    g.structure().download().unwrap(),
                    "{kind:?} n {n}: tree"
                );
            }
        }
    }
    common::assert_silent(&ctx);
}

/// Two-level hits against the CPU twin (bit for bit in t where the device divides exactly,
/// else within a few ulps) and against the flattened scene: the same instance and primitive
/// except where another triangle is hit within 1e-5 of the same t, t within 1e-5 relative.
#[test]
fn two_level_hits_equal_the_twin_and_the_flattened_scene_under_every_bottom_walk() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(11);
    let meshes = vec![sphere_tris(2), random_tris(&mut rng, 300), sphere_tris(1)];
    let hosts: Vec<TraceGeometry> = meshes
        .iter()
        .map(|m| TraceGeometry::from_triangles(m))
        .collect();
    let choices = [
        (AccelKind::KdTree, false),
        (AccelKind::Lbvh, false),
        (AccelKind::Ploc, true),
        (AccelKind::SahBvh, false),
        (AccelKind::SahBvh, true),
    ];
    let instances: Vec<Instance> = (0..40)
        .map(|i| {
            Instance::new(
                (i % 3) as u32,
                Instance::rows_of(&random_transform(&mut rng, 24.0)),
            )
            .with_custom_index(1000 + i as u32)
        })
        .collect();
    // Rays from afar towards points near the instances' centres.
    let rays: Vec<Ray> = (0..600)
        .map(|k| {
            let c = Vec3::from_array(instances[k % 40].transform.map(|r| r[3]));
            let o = centered(&mut rng).normalize_or(Vec3::X) * 40.0;
            let target = c + centered(&mut rng) * 1.5;
            Ray::new(o, target - o, 0.0, f32::INFINITY)
        })
        .collect();
    let (flat, owner) = flattened(&instances, &meshes);
    let flat_hits: Vec<Hit> = rays
        .iter()
        .map(|r| cpu::brute_force(&flat, r, 0.0, &opt()))
        .collect();
    for (kind, wide) in choices {
        let levels: Vec<GpuGeometry> = meshes.iter().map(|m| bottom(&ctx, kind, wide, m)).collect();
        let refs: Vec<&GpuGeometry> = levels.iter().collect();
        let top = TopLevelBuilder::new(&ctx, AccelKind::Lbvh)
            .unwrap()
            .build(&ctx, &refs, &instances, &BuildFlags::default())
            .unwrap();
        let got = probe(&ctx, top.handle_address(), &rays, 0);
        let customs = probe(&ctx, top.handle_address(), &rays, 1);
        let (_, records) = top.download().unwrap();
        let want = twin(&records, &hosts, &rays);
        let mut ties = 0;
        let mut hits = 0;
        let mut exact = 0;
        let mut worst = 0f32;
        for (k, (g, w)) in got.iter().zip(&want).enumerate() {
            let (h, inst) = as_hit(g);
            let label = format!("{kind:?} wide {wide} ray {k}");
            assert_eq!(inst, w.1, "{label}: instance (twin)");
            assert!(
                common::same_answer(&h, &w.0),
                "{label}: {h:?} vs twin {:?}",
                w.0
            );
            exact += usize::from(h.t.to_bits() == w.0.t.to_bits() && h.prim == w.0.prim);
            let f = flat_hits[k];
            assert_eq!(h.is_hit(), f.is_hit(), "{label}: hit (flattened)");
            if !h.is_hit() {
                continue;
            }
            hits += 1;
            assert_eq!(customs[k][3], 1000 + inst.unwrap(), "{label}: custom index");
            assert!(
                (h.t - f.t).abs() <= 1e-5 * f.t.abs(),
                "{label}: t {} vs {}",
                h.t,
                f.t
            );
            worst = worst.max((h.t - f.t).abs() / f.t.abs());
            if (inst.unwrap(), h.prim) != owner[f.prim as usize] {
                ties += 1;
            }
        }
        eprintln!("{kind:?} wide {wide}: {hits} hits, {exact} of all rays bit for bit as the twin, {ties} on another triangle than the flattened scene's, t within {worst:e} of its");
        assert!(hits > 200, "{kind:?}: {hits} hits");
        assert!(
            ties * 100 <= hits,
            "{kind:?}: {ties} of {hits} hits on another triangle"
        );
    }
    common::assert_silent(&ctx);
}

/// An identity instance is the bottom level itself: the same hits, bit for bit, for every
/// kind; a top level of none misses everything; an instance of an empty level is never hit.
#[test]
fn an_identity_instance_traces_as_its_bottom_level_and_empty_levels_miss() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(3);
    let tris = sphere_tris(2);
    let rays = rays_at(&mut rng, 400, 3.0);
    for (kind, wide) in [
        (AccelKind::KdTree, false),
        (AccelKind::Lbvh, false),
        (AccelKind::Lbvh, true),
        (AccelKind::Ploc, false),
    ] {
        let level = bottom(&ctx, kind, wide, &tris);
        let handle = flat_handle(&ctx, &level);
        let flat = probe(&ctx, handle.device_address().unwrap(), &rays, 0);
        for top_kind in [AccelKind::Lbvh, AccelKind::Ploc] {
            let top = TopLevelBuilder::new(&ctx, top_kind)
                .unwrap()
                .build(
                    &ctx,
                    &[&level],
                    &[Instance::new(0, Instance::IDENTITY)],
                    &BuildFlags::default(),
                )
                .unwrap();
            let got = probe(&ctx, top.handle_address(), &rays, 0);
            for (k, (g, f)) in got.iter().zip(&flat).enumerate() {
                assert_eq!(
                    g[..3],
                    f[..3],
                    "{kind:?} wide {wide} under {top_kind:?}: ray {k}"
                );
                if f[0] != u32::MAX {
                    assert_eq!(g[3], 0, "ray {k}: the instance");
                    assert_eq!(f[3], u32::MAX, "a flat structure names no instance");
                }
            }
            assert!(flat.iter().filter(|h| h[0] != u32::MAX).count() > 100);
        }
    }
    let level = bottom(&ctx, AccelKind::Lbvh, false, &tris);
    let empty = bottom(&ctx, AccelKind::Lbvh, false, &[]);
    let builder = TopLevelBuilder::new(&ctx, AccelKind::Lbvh).unwrap();
    let none = builder
        .build(&ctx, &[&level], &[], &BuildFlags::default())
        .unwrap();
    let of_empty = builder
        .build(
            &ctx,
            &[&level, &empty],
            &[Instance::new(1, Instance::IDENTITY)],
            &BuildFlags::default(),
        )
        .unwrap();
    for top in [&none, &of_empty] {
        let got = probe(&ctx, top.handle_address(), &rays, 0);
        assert!(got.iter().all(|h| h[0] == u32::MAX), "a hit on nothing");
    }
    common::assert_silent(&ctx);
}

/// Masks against the cull mask, any-hit queries, and an update (moved instances, a refit)
/// that traces as a fresh build.
#[test]
fn masks_any_hit_and_updates() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(8);
    let tris = sphere_tris(2);
    let level = bottom(&ctx, AccelKind::Ploc, false, &tris);
    let rays = rays_at(&mut rng, 500, 20.0);
    let place = |rng: &mut common::Rng| -> Vec<Instance> {
        (0..30)
            .map(|i| {
                Instance::new(0, Instance::rows_of(&random_transform(rng, 14.0)))
                    .with_mask(if i % 2 == 0 { 0x01 } else { 0x02 })
            })
            .collect()
    };
    let first = place(&mut rng);
    let flags = BuildFlags {
        allow_update: true,
        ..BuildFlags::default()
    };
    let builder = TopLevelBuilder::new(&ctx, AccelKind::Lbvh).unwrap();
    let mut top = builder.build(&ctx, &[&level], &first, &flags).unwrap();
    let hosts = [TraceGeometry::from_triangles(&tris)];
    let (_, records) = top.download().unwrap();
    // Mode bits 8..16: the inverted cull mask. 0x01 sees the even instances only.
    let even = probe(&ctx, top.handle_address(), &rays, 0xfe << 8);
    for (k, (g, r)) in even.iter().zip(&rays).enumerate() {
        let w = trace_instances(&records, &[], r, 0.0, 0x01, false, |b, ro| {
            (cpu::brute_force(&hosts[b as usize], ro, 0.0, &opt()), false)
        });
        let (h, inst) = as_hit(g);
        assert_eq!(inst, w.instance, "ray {k}");
        assert!(common::same_answer(&h, &w.hit), "ray {k}");
        if let Some(i) = inst {
            assert_eq!(i % 2, 0);
        }
    }
    // Any hit: hit or miss as the closest-hit query.
    let any = probe(&ctx, top.handle_address(), &rays, 2);
    let closest = probe(&ctx, top.handle_address(), &rays, 0);
    for (a, c) in any.iter().zip(&closest) {
        assert_eq!(a[0] == u32::MAX, c[0] == u32::MAX);
    }
    // Moved: the update traces as a new build over the same instances.
    let moved = place(&mut rng);
    builder.update(&ctx, &mut top, &moved).unwrap();
    let fresh = builder.build(&ctx, &[&level], &moved, &flags).unwrap();
    assert_eq!(
        probe(&ctx, top.handle_address(), &rays, 0),
        probe(&ctx, fresh.handle_address(), &rays, 0)
    );
    common::assert_silent(&ctx);
}

#[test]
fn instances_name_bottom_levels_by_reference_as_by_index() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(21);
    let levels = [
        bottom(&ctx, AccelKind::Lbvh, false, &sphere_tris(1)),
        bottom(&ctx, AccelKind::Ploc, false, &sphere_tris(2)),
        bottom(&ctx, AccelKind::SahBvh, false, &random_tris(&mut rng, 50)),
    ];
    let refs: Vec<&GpuGeometry> = levels.iter().collect();
    let references: Vec<u64> = levels.iter().map(|l| l.reference().unwrap()).collect();
    assert!(references.iter().all(|&r| r >= MAX_BOTTOM_LEVELS as u64));
    let by_index: Vec<Instance> = (0..25)
        .map(|i| Instance::new(i % 3, Instance::rows_of(&random_transform(&mut rng, 10.0))))
        .collect();
    let by_reference: Vec<Instance> = by_index
        .iter()
        .map(|i| Instance::referencing(references[i.bottom as usize], i.transform))
        .collect();
    let builder = TopLevelBuilder::new(&ctx, AccelKind::Lbvh).unwrap();
    let flags = BuildFlags::default();
    let a = builder.build(&ctx, &refs, &by_index, &flags).unwrap();
    let b = builder.build(&ctx, &refs, &by_reference, &flags).unwrap();
    let (boxes_a, records_a) = a.download().unwrap();
    let (boxes_b, records_b) = b.download().unwrap();
    assert_eq!(boxes_a, boxes_b);
    // The same records but for where each top level keeps its copies of the handles.
    let strip = |r: &[InstanceRecord], at: u64| -> Vec<InstanceRecord> {
        r.iter()
            .map(|r| InstanceRecord {
                handle: r.handle - at,
                ..*r
            })
            .collect()
    };
    assert_eq!(
        strip(&records_a, a.bottom_handles_address()),
        strip(&records_b, b.bottom_handles_address())
    );
    let infos = scene_infos(&refs);
    let want = instance_boxes(
        &by_reference,
        InstanceMotion::STATIC,
        &infos,
        Some(b.bottom_handles_address()),
    );
    assert_eq!(want.records, records_b);
    let rays = rays_at(&mut rng, 300, 15.0);
    assert_eq!(
        probe(&ctx, a.handle_address(), &rays, 0),
        probe(&ctx, b.handle_address(), &rays, 0)
    );
    // A reference to no level of the list is refused by the host, and never hit (counted)
    // when it reaches the device in the caller's records.
    let stranger = bottom(&ctx, AccelKind::Lbvh, false, &sphere_tris(0));
    let mut bad = by_reference.clone();
    bad[3].bottom = stranger.reference().unwrap();
    let err = match builder.build(&ctx, &refs, &bad, &flags) {
        Err(GpuError::Usage { reason, .. }) => reason,
        other => panic!("{:?}", other.map(|_| ())),
    };
    assert!(
        err.contains("instance 3") && err.contains("references"),
        "{err}"
    );
    let want = instance_boxes(&bad, InstanceMotion::STATIC, &infos, Some(0));
    assert_eq!(want.invalid, 1);
    common::assert_silent(&ctx);
}

/// A top level as a Vulkan renderer keeps one: created for at most 40 instances with no list
/// of bottom levels (its instances reference theirs, as `accelerationStructureReference`
/// does, and it borrows none), built from the renderer's own instance buffer with 40, then
/// 7, then 0 of them, then updated; after each, every ray answers as a top level built for
/// exactly those instances and as brute force over them flattened. A count past the maximum
/// is an error; an index (a null reference included) names nothing without a list: never
/// hit, counted.
#[test]
fn builds_read_up_to_the_maximum_count_of_referenced_levels() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(31);
    let meshes = [sphere_tris(1), random_tris(&mut rng, 40)];
    let levels = [
        bottom(&ctx, AccelKind::Lbvh, false, &meshes[0]),
        bottom(&ctx, AccelKind::Ploc, false, &meshes[1]),
    ];
    let refs: Vec<&GpuGeometry> = levels.iter().collect();
    let references: Vec<u64> = levels.iter().map(|l| l.reference().unwrap()).collect();
    let place = |rng: &mut common::Rng| -> Vec<Instance> {
        (0..40)
            .map(|i| {
                Instance::new(i % 2, Instance::rows_of(&random_transform(rng, 14.0)))
                    .with_custom_index(i)
            })
            .collect()
    };
    let by_reference = |by_index: &[Instance]| -> Vec<Instance> {
        by_index
            .iter()
            .map(|i| Instance {
                bottom: references[i.bottom as usize],
                ..*i
            })
            .collect()
    };
    let rays = rays_at(&mut rng, 400, 20.0);
    let flags = BuildFlags {
        allow_update: true,
        ..BuildFlags::default()
    };
    // Every ray against a top level built for exactly `by_index` and against brute force
    // over those of them with a mask.
    let check =
        |builder: &TopLevelBuilder, got: &[[u32; 4]], by_index: &[Instance], label: &str| {
            let exact = builder
                .build(&ctx, &refs, &by_reference(by_index), &flags)
                .unwrap();
            assert_eq!(
                got,
                probe(&ctx, exact.handle_address(), &rays, 0),
                "{label}"
            );
            let seen: Vec<Instance> = by_index.iter().filter(|i| i.mask() != 0).copied().collect();
            let (flat, _) = flattened(&seen, &meshes);
            for (k, (g, r)) in got.iter().zip(&rays).enumerate() {
                let (h, inst) = as_hit(g);
                let f = cpu::brute_force(&flat, r, 0.0, &opt());
                assert_eq!(h.is_hit(), f.is_hit(), "{label} ray {k}: hit (flattened)");
                assert!(
                    inst.is_none_or(|i| (i as usize) < by_index.len()),
                    "{label}"
                );
                if h.is_hit() {
                    assert!((h.t - f.t).abs() <= 1e-5 * f.t.abs(), "{label} ray {k}");
                }
            }
            got.iter().filter(|h| h[0] != u32::MAX).count()
        };
    for kind in [AccelKind::Lbvh, AccelKind::Ploc] {
        let builder = TopLevelBuilder::new(&ctx, kind).unwrap();
        let sizes = builder.sizes_for(&ctx, 40, 0, &flags).unwrap();
        let memory =
            Buffer::<u8>::arena(&ctx, "renderer.top", sizes.structure_bytes as usize).unwrap();
        let scratch_bytes = sizes
            .build_scratch_bytes
            .max(sizes.update_scratch_bytes.unwrap());
        let scratch =
            Buffer::<u8>::arena(&ctx, "renderer.scratch", scratch_bytes as usize).unwrap();
        let mut top = builder
            .create_in(&ctx, &[], 40, &flags, unsafe { memory.as_raw() })
            .unwrap();
        assert_eq!(top.max_instances(), 40);
        let first = place(&mut rng);
        let input = Buffer::from_slice(&ctx, "renderer.instances", &by_reference(&first)).unwrap();
        let build = |top: &mut vkrt::accel::instances::TopLevel, count: u32, update: bool| {
            let mut rec = Recorder::new(&ctx).unwrap();
            match update {
                false => builder.record_build_from(
                    &mut rec,
                    top,
                    unsafe { input.as_raw() },
                    count,
                    unsafe { scratch.as_raw() },
                ),
                true => {
                    builder.record_update_from(&mut rec, top, unsafe { input.as_raw() }, unsafe {
                        scratch.as_raw()
                    })
                }
            }
            .unwrap();
            rec.compute_to_transfer();
            let status = top.record_read_status(&mut rec).unwrap();
            rec.transfer_to_host();
            rec.submit_and_wait().unwrap();
            assert_eq!(status.read().unwrap().invalid_primitives, 0);
        };
        let mut hits = Vec::new();
        for count in [40u32, 7, 0] {
            build(&mut top, count, false);
            assert_eq!(top.instance_count(), count);
            assert_eq!(top.download().unwrap().0.len(), count as usize);
            let got = probe(&ctx, top.handle_address(), &rays, 0);
            let label = format!("{kind:?}, {count} of 40");
            hits.push(check(&builder, &got, &first[..count as usize], &label));
        }
        assert!(hits[0] > hits[1] && hits[1] > 5 && hits[2] == 0, "{hits:?}");
        // 7 again, moved: an update of those 7 (its count kept) traces as a build of them.
        build(&mut top, 7, false);
        let moved = place(&mut rng);
        input.upload(&by_reference(&moved)).unwrap();
        build(&mut top, 0, true);
        assert_eq!(top.instance_count(), 7);
        let got = probe(&ctx, top.handle_address(), &rays, 0);
        check(&builder, &got, &moved[..7], &format!("{kind:?}, 7 moved"));
        // Past the maximum.
        let mut rec = Recorder::new(&ctx).unwrap();
        let e = builder
            .record_build_from(&mut rec, &mut top, unsafe { input.as_raw() }, 41, unsafe {
                scratch.as_raw()
            })
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("41 instances") && e.contains("at most 40"),
            "{e}"
        );
        drop(rec);
        // Without a list an index names nothing, 0 (a null reference) too: never hit, counted.
        let mut named = by_reference(&first[..7]);
        named[0].bottom = 0;
        named[2].bottom = 1;
        input.upload(&named).unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        builder
            .record_build_from(&mut rec, &mut top, unsafe { input.as_raw() }, 7, unsafe {
                scratch.as_raw()
            })
            .unwrap();
        rec.compute_to_transfer();
        let status = top.record_read_status(&mut rec).unwrap();
        rec.transfer_to_host();
        rec.submit_and_wait().unwrap();
        assert_eq!(status.read().unwrap().invalid_primitives, 2);
        let (_, records) = top.download().unwrap();
        assert_eq!(records[0].handle, 0);
        assert_eq!(records[1].handle, references[1]);
        assert_eq!(records[1].bottom(), InstanceRecord::UNLISTED);
        let infos = scene_infos(&refs);
        let want = instance_boxes(&named, InstanceMotion::STATIC, &infos, None);
        assert_eq!((want.records, want.invalid), (records, 2));
        let got = probe(&ctx, top.handle_address(), &rays, 0);
        let mut masked = first[..7].to_vec();
        masked[0] = masked[0].with_mask(0);
        masked[2] = masked[2].with_mask(0);
        let n = check(&builder, &got, &masked, &format!("{kind:?}, null"));
        assert!(n > 0);
    }
    common::assert_silent(&ctx);
}

#[test]
fn misuse_is_an_error_naming_the_instance() {
    let Some(ctx) = common::context() else { return };
    let level = bottom(&ctx, AccelKind::Lbvh, false, &sphere_tris(0));
    fn refused<T>(r: Result<T, GpuError>) -> String {
        match r {
            Ok(_) => panic!("misuse accepted"),
            Err(e) => e.to_string(),
        }
    }
    assert!(refused(TopLevelBuilder::new(&ctx, AccelKind::KdTree)).contains("LBVH or a PLOC"));
    let builder = TopLevelBuilder::new(&ctx, AccelKind::Lbvh).unwrap();
    let flags = BuildFlags::default();
    let good = Instance::new(0, Instance::IDENTITY);
    let cases = [
        (
            Instance {
                transform: [
                    [1.0, 0.0, 0.0, 0.0],
                    [0.0, 1.0, 0.0, 0.0],
                    [0.0, 0.0, 0.0, 0.0],
                ],
                ..good
            },
            "singular",
        ),
        (
            Instance {
                transform: [
                    [1.0, 0.0, 0.0, f32::INFINITY],
                    [0.0, 1.0, 0.0, 0.0],
                    [0.0, 0.0, 1.0, 0.0],
                ],
                ..good
            },
            "not finite",
        ),
        (Instance { bottom: 1, ..good }, "bottom level 1"),
    ];
    for (bad, words) in cases {
        let m = refused(builder.build(&ctx, &[&level], &[good, bad], &flags));
        assert!(m.contains("instance 1") && m.contains(words), "{m}");
    }
    // An update of another count, and one of a top level not built to be updated.
    let mut top = builder.build(&ctx, &[&level], &[good], &flags).unwrap();
    assert!(builder.update(&ctx, &mut top, &[good, good]).is_err());
    assert!(refused(builder.update(&ctx, &mut top, &[good])).contains("allow_update"));
    // A top-level builder of the other kind.
    let ploc = TopLevelBuilder::new(&ctx, AccelKind::Ploc).unwrap();
    assert!(ploc.update(&ctx, &mut top, &[good]).is_err());
    // Too little memory.
    let sizes = builder.sizes_for(&ctx, 4, 1, &flags).unwrap();
    let small = Buffer::<u8>::arena(&ctx, "caller.small", 64).unwrap();
    let err = builder
        .create_in(&ctx, &[&level], 4, &flags, unsafe { small.as_raw() })
        .err()
        .expect("a top level in too little memory");
    // The same class as a bottom level's: a placement error.
    assert!(matches!(err, GpuError::Placement { .. }), "{err}");
    assert!(sizes.structure_bytes > 64);
    // The records' own checks, for a renderer that writes them itself.
    for (bad, words) in [
        (Instance { bottom: 1, ..good }, "bottom level 1"),
        (
            Instance {
                transform: [[0.0; 4]; 3],
                ..good
            },
            "singular",
        ),
    ] {
        let err = bad.check(&[level.reference().unwrap()]).unwrap_err();
        assert!(
            matches!(&err, GpuError::Usage { call: "Instance::check", reason } if reason.contains(words)),
            "{err}"
        );
    }
    assert!(good.check(&[level.reference().unwrap()]).is_ok());
    let still = vkrt::accel::instance::InstanceMotion::new(3, 1.0, 1.0).check();
    assert!(matches!(still, Err(GpuError::Usage { .. })), "{still:?}");
    common::assert_silent(&ctx);
}

/// A scene's repeated meshes: the dynamic demo's 24 spheres are one icosphere placed 24
/// times, and split as two levels they are one bottom level with 24 instances; the bunny,
/// named once but turning on keyframes, is placed by its own instance (its motion then moves
/// one transform); the static rest (the room) is one more level under an identity instance.
#[test]
fn repeated_meshes_become_instances_of_one_bottom_level() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/dynamic_demo.toml");
    let scene = vkrt::scene::Scene::load(&path).unwrap().scene;
    let groups = scene.mesh_groups();
    let repeated: Vec<&Vec<usize>> = groups.iter().filter(|g| g.len() > 1).collect();
    assert_eq!(repeated.len(), 1);
    assert_eq!(repeated[0].len(), 24);
    let summary = scene.summary();
    let sphere = scene.meshes[repeated[0][0]].indices.len() as u64;
    assert_eq!(summary.instances, 24);
    assert_eq!(summary.unique_triangles, summary.triangles - 23 * sphere);
    let two = vkrt::accel::two_levels::TwoLevelScene::of(&scene, 0.0).unwrap();
    assert_eq!(two.bottoms.len(), 3);
    assert_eq!((two.instances.len(), two.mesh_instances()), (26, 25));
    assert_eq!(
        two.unique_primitives as u64,
        summary.unique_triangles + summary.spheres
    );
    // Every instance of the sphere is placed where the flat scene has its triangles.
    let flat = scene.triangles_world(0.0);
    for inst in two.instances.iter().filter(|i| i.bottom == 0) {
        let mesh = inst.custom_index() as usize;
        let first = two.mesh_first[mesh] as usize;
        let [a, _, _] = scene.meshes[mesh].indices[0];
        let p = transform_point(&inst.transform, scene.meshes[mesh].positions[a as usize]);
        assert!((p - flat[first][0]).length() < 1e-5, "mesh {mesh}");
    }
    // A scene without repeats stays flat.
    let once = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/motion_blur.toml");
    let once = vkrt::scene::Scene::load(&once).unwrap().scene;
    assert!(vkrt::accel::two_levels::TwoLevelScene::of(&once, 0.0).is_none());
    assert_eq!(once.summary().instances, 0);
}

/// Rays grazing the instances' boxes: a unit cube placed by exact transforms (quarter turns,
/// a mirror, a stretch, integer offsets), so the world boxes coincide with the cube's faces
/// up to their padding. Rays parallel to a face 1e-4 inside it (they enter through a side)
/// and 1e-4 outside it (they miss), at random heights and angles: the flattened scene's
/// answers (hit or miss, hit points within 1e-5 of the coordinates' size, the instance and triangle except at ties). Rays
/// exactly in a face plane or at a corner may go either way (a measure-zero boundary that the
/// two roundings see differently): a hit must be a point of the cube, and no walk gives up.
#[test]
fn rays_grazing_instance_boxes_answer_as_the_flattened_scene() {
    let Some(ctx) = common::context() else { return };
    let corner = |k: usize| Vec3::new((k & 1) as f32, ((k >> 1) & 1) as f32, ((k >> 2) & 1) as f32);
    let faces = [
        [0, 1, 3, 2],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 3, 7, 6],
        [0, 2, 6, 4],
        [1, 3, 7, 5],
    ];
    let cube: Vec<[Vec3; 3]> = faces
        .iter()
        .flat_map(|f| {
            [
                [corner(f[0]), corner(f[1]), corner(f[2])],
                [corner(f[0]), corner(f[2]), corner(f[3])],
            ]
        })
        .collect();
    let rows = [
        Instance::IDENTITY,
        [
            [0.0, -1.0, 0.0, 3.0],
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ],
        [
            [-1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 2.0],
            [0.0, 0.0, 1.0, 0.0],
        ],
        [
            [0.0, 0.0, 2.0, -3.0],
            [0.0, 1.0, 0.0, 0.0],
            [-1.0, 0.0, 0.0, 1.0],
        ],
    ];
    let instances: Vec<Instance> = rows.iter().map(|r| Instance::new(0, *r)).collect();
    // (ray, the instance it is about, whether it must answer as the flattened scene)
    let mut rays = Vec::new();
    let mut rng = common::Rng(21);
    for (i, inst) in instances.iter().enumerate() {
        let world = |p: Vec3| transform_point(&inst.transform, p);
        for _ in 0..80 {
            // In the plane z = h, from outside the cube's x extent towards a point in it.
            for (h, decided) in [
                (1e-4, true),
                (-1e-4, true),
                (0.0, false),
                (1.0 + 1e-4, true),
            ] {
                let y0 = unit(&mut rng) * 1.4 - 0.2;
                let y1 = unit(&mut rng) * 1.4 - 0.2;
                let from = world(Vec3::new(-2.0, y0, h));
                let to = world(Vec3::new(unit(&mut rng), y1, h));
                rays.push((Ray::new(from, to - from, 0.0, f32::INFINITY), i, decided));
            }
            let c = corner((rng.next_u64() % 8) as usize);
            let from = world(c + rng.next_vec3().normalize_or(Vec3::X) * 4.0);
            rays.push((
                Ray::new(from, world(c) - from, 0.0, f32::INFINITY),
                i,
                false,
            ));
        }
    }
    let level = bottom(&ctx, AccelKind::Lbvh, false, &cube);
    let top = TopLevelBuilder::new(&ctx, AccelKind::Ploc)
        .unwrap()
        .build(&ctx, &[&level], &instances, &BuildFlags::default())
        .unwrap();
    let only: Vec<Ray> = rays.iter().map(|r| r.0).collect();
    let got = probe(&ctx, top.handle_address(), &only, 0);
    let (flat, owner) = flattened(&instances, &[cube]);
    let (mut hits, mut decided_hits) = (0, 0);
    for (k, (g, (r, _, decided))) in got.iter().zip(&rays).enumerate() {
        let (h, inst) = as_hit(g);
        if !*decided {
            if let Some(i) = inst {
                let m = world_to_object(&instances[i as usize].transform).unwrap();
                let p = object_ray(&m, r, f32::INFINITY);
                let at = p.o() + p.d() * h.t;
                let outside = (at - at.clamp(Vec3::ZERO, Vec3::ONE)).length();
                assert!(outside < 1e-5, "ray {k}: a hit {outside} off the cube");
            }
            continue;
        }
        let f = cpu::brute_force(&flat, r, 0.0, &opt());
        assert_eq!(h.is_hit(), f.is_hit(), "ray {k} {r:?}: {h:?} vs {f:?}");
        if !h.is_hit() {
            continue;
        }
        decided_hits += 1;
        // The hit points within 1e-5 of the coordinates' magnitude (a small t's relative
        // error is large: the two roundings act on positions, not on t).
        let scale = r.o().abs().max_element() + r.d().length() * f.t;
        let apart = (h.t - f.t).abs() * r.d().length();
        assert!(apart <= 1e-5 * scale, "ray {k}: t {} vs {}", h.t, f.t);
        if (inst.unwrap(), h.prim) != owner[f.prim as usize] {
            assert!(apart <= 1e-6 * scale, "ray {k}: another triangle");
        }
        hits += 1;
    }
    assert!(
        decided_hits > rays.len() / 8,
        "{decided_hits} hits of {}",
        rays.len()
    );
    assert!(hits > 0);
    common::assert_silent(&ctx);
}

/// Moving instances (three time steps, most instances moving and turning): the device's boxes,
/// records and steps equal the CPU twin's bit for bit; at every time (before, inside and
/// after the interval) the hits equal the twin's and the flattened scene's at that time
/// (every instance's triangles placed by its interpolated transform); at a step's time they
/// are the static top level of that step's instances, bit for bit; an update equals a new
/// build; and misuse of motion is refused, naming the instance and the step.
#[test]
fn moving_instances_trace_as_their_interpolated_transforms() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(31);
    let meshes = vec![sphere_tris(2), random_tris(&mut rng, 200)];
    let hosts: Vec<TraceGeometry> = meshes
        .iter()
        .map(|m| TraceGeometry::from_triangles(m))
        .collect();
    let levels: Vec<GpuGeometry> = meshes
        .iter()
        .map(|m| bottom(&ctx, AccelKind::Lbvh, false, m))
        .collect();
    let refs: Vec<&GpuGeometry> = levels.iter().collect();
    let infos = scene_infos(&refs);
    let (n, steps) = (24usize, 3u32);
    let motion = InstanceMotion::new(steps, 1.0, 2.0);
    // Step s: moved by s·v and turned by s·0.4 rad about the instance's own centre.
    let moving = |rng: &mut common::Rng| -> Vec<Instance> {
        let start: Vec<Instance> = (0..n)
            .map(|i| {
                Instance::new(
                    (i % 2) as u32,
                    Instance::rows_of(&random_transform(rng, 20.0)),
                )
                .with_custom_index(i as u32)
            })
            .collect();
        let paths: Vec<(Vec3, Vec3)> = (0..n)
            .map(|_| (centered(rng) * 2.0, centered(rng).normalize_or(Vec3::Y)))
            .collect();
        let mut all = start.clone();
        for s in 1..steps {
            all.extend(
                start
                    .iter()
                    .zip(&paths)
                    .enumerate()
                    .map(|(i, (inst, (v, axis)))| {
                        if i % 5 == 0 {
                            return *inst; // still: recorded as one step
                        }
                        let t0 = Instance::affine_of(&inst.transform);
                        let c = t0.translation.into();
                        let spin = Affine3A::from_translation(c)
                            * Affine3A::from_axis_angle(*axis, 0.4 * s as f32)
                            * Affine3A::from_translation(-c);
                        let moved = Affine3A::from_translation(*v * s as f32) * spin * t0;
                        Instance {
                            transform: Instance::rows_of(&moved),
                            ..*inst
                        }
                    }),
            );
        }
        all
    };
    let instances = moving(&mut rng);
    let rays: Vec<Ray> = (0..400)
        .map(|k| {
            // (towards the centre at the middle step)
            let c = Vec3::from_array(instances[n + k % n].transform.map(|r| r[3]));
            let o = centered(&mut rng).normalize_or(Vec3::X) * 45.0;
            Ray::new(o, c + centered(&mut rng) * 2.5 - o, 0.0, f32::INFINITY)
        })
        .collect();
    let flags = BuildFlags {
        allow_update: true,
        ..BuildFlags::default()
    };
    let builder = TopLevelBuilder::new(&ctx, AccelKind::Lbvh).unwrap();
    let top = builder
        .build_moving(&ctx, &refs, &instances, motion, &flags)
        .unwrap();

    // The build against its CPU twin, bit for bit.
    let (boxes, records) = top.download().unwrap();
    let device_steps = top.download_steps().unwrap();
    let want = instance_boxes(
        &instances,
        motion,
        &infos,
        Some(top.bottom_handles_address()),
    );
    let bits = |v: &[f32]| -> Vec<u32> { v.iter().map(|x| x.to_bits()).collect() };
    assert_eq!(bits(boxes.as_flattened()), bits(want.boxes.as_flattened()));
    assert_eq!(records, want.records);
    for (i, r) in records.iter().enumerate() {
        assert_eq!(
            r.motion[0],
            if i % 5 == 0 { 1 } else { steps },
            "instance {i}"
        );
    }
    assert_eq!(
        bits(device_steps.as_flattened().as_flattened()),
        bits(want.steps.as_flattened().as_flattened())
    );
    assert_eq!(want.invalid, 0);

    // Per time: the twin, the flattened scene at that time, and at step times the static
    // top level of that step.
    let step_of = |time: f32| -> (usize, f32) {
        let u = ((time - 1.0) * motion.scale()).clamp(0.0, (steps - 1) as f32);
        let k = (u as usize).min(steps as usize - 2);
        (k, u - k as f32)
    };
    let mut hits = 0;
    for time in [0.5, 1.0, 1.3, 1.5, 1.77, 2.0, 2.6] {
        let got = probe_at(&ctx, top.handle_address(), &rays, 0, time);
        let (k, f) = step_of(time);
        let placed: Vec<Instance> = (0..n)
            .map(|i| Instance {
                transform: lerp_rows(
                    &instances[k * n + i].transform,
                    &instances[(k + 1) * n + i].transform,
                    f,
                ),
                ..instances[i]
            })
            .collect();
        let (flat, owner) = flattened(&placed, &meshes);
        let mut ties = 0;
        for (j, (g, r)) in got.iter().zip(&rays).enumerate() {
            let (h, inst) = as_hit(g);
            let label = format!("time {time} ray {j}");
            let w = trace_instances(&records, &want.steps, r, time, 0xff, false, |b, ro| {
                (cpu::brute_force(&hosts[b as usize], ro, 0.0, &opt()), false)
            });
            assert_eq!(inst, w.instance, "{label}: instance (twin)");
            assert!(common::same_answer(&h, &w.hit), "{label}: {h:?} vs {w:?}");
            let fh = cpu::brute_force(&flat, r, 0.0, &opt());
            assert_eq!(h.is_hit(), fh.is_hit(), "{label}: hit (flattened)");
            if h.is_hit() {
                hits += 1;
                assert!(
                    (h.t - fh.t).abs() <= 1e-5 * fh.t.abs(),
                    "{label}: t {} vs {}",
                    h.t,
                    fh.t
                );
                ties += usize::from((inst.unwrap(), h.prim) != owner[fh.prim as usize]);
            }
        }
        assert!(ties * 100 <= rays.len(), "time {time}: {ties} ties");
        if f == 0.0 || f == 1.0 {
            let s = k + f as usize;
            let still = builder
                .build(&ctx, &refs, &instances[s * n..(s + 1) * n], &flags)
                .unwrap();
            assert_eq!(
                got,
                probe(&ctx, still.handle_address(), &rays, 0),
                "time {time}: step {s}"
            );
        }
    }
    assert!(hits > 400, "{hits} hits");

    // An update to new motion over a later interval traces as a new build of it.
    let next = moving(&mut rng);
    let mut top = top;
    let later = InstanceMotion::new(steps, 1.1, 2.3);
    top.set_time(later.time).unwrap();
    builder.update(&ctx, &mut top, &next).unwrap();
    let fresh = builder
        .build_moving(&ctx, &refs, &next, later, &flags)
        .unwrap();
    for time in [1.2, 1.9] {
        assert_eq!(
            probe_at(&ctx, top.handle_address(), &rays, 0, time),
            probe_at(&ctx, fresh.handle_address(), &rays, 0, time)
        );
    }

    // Misuse.
    let refused = |r: Result<vkrt::accel::instances::TopLevel, GpuError>| -> String {
        match r {
            Ok(_) => panic!("misuse accepted"),
            Err(e) => e.to_string(),
        }
    };
    for (bad, what) in [
        (InstanceMotion::new(0, 0.0, 1.0), "0 time steps"),
        (InstanceMotion::new(200, 0.0, 1.0), "200 time steps"),
        (
            InstanceMotion::new(2, 1.0, 1.0),
            "not finite and increasing",
        ),
        (
            InstanceMotion::new(2, f32::NAN, 1.0),
            "not finite and increasing",
        ),
    ] {
        let e = refused(builder.build_moving(&ctx, &refs, &instances, bad, &flags));
        assert!(e.contains(what), "{e}");
    }
    let e = refused(builder.build_moving(&ctx, &refs, &instances[1..], motion, &flags));
    assert!(e.contains("not 3 time steps"), "{e}");
    let mut other = instances.clone();
    other[n + 4].bottom ^= 1;
    let e = refused(builder.build_moving(&ctx, &refs, &other, motion, &flags));
    assert!(
        e.contains("instance 4 at step 1") && e.contains("bottom level"),
        "{e}"
    );
    let mut mirrored = instances.clone();
    mirrored[2 * n + 6].transform[0] = mirrored[2 * n + 6].transform[0].map(|x| -x);
    mirrored[2 * n + 6].transform[0][3] *= -1.0;
    let e = refused(builder.build_moving(&ctx, &refs, &mirrored, motion, &flags));
    assert!(
        e.contains("instance 6 at step 2") && e.contains("mirrors"),
        "{e}"
    );
    let mut singular = instances.clone();
    singular[n + 2].transform = [[0.0; 4]; 3];
    let e = refused(builder.build_moving(&ctx, &refs, &singular, motion, &flags));
    assert!(
        e.contains("instance 2 at step 1") && e.contains("singular"),
        "{e}"
    );
    let e = top.set_time([2.0, 1.0]).unwrap_err().to_string();
    assert!(e.contains("not finite and increasing"), "{e}");
    let e = builder
        .build(&ctx, &refs, &instances[..n], &flags)
        .unwrap()
        .set_time([0.0, 1.0])
        .unwrap_err()
        .to_string();
    assert!(e.contains("does not move"), "{e}");
    let e = builder
        .update(&ctx, &mut top, &next[..2 * n])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("48 instance records; the top level holds 24 instances at 3 time steps"),
        "{e}"
    );
    common::assert_silent(&ctx);
}

/// A scene past one level's capacity traces in pieces: its triangles (a mesh named once and
/// a random soup, both left in the world) and spheres cut along a Morton curve into bottom
/// levels of at most 700 primitives, each under an identity instance, answer every ray as
/// brute force over the flat scene does (the identity transform rounds nothing), with the
/// scene's primitive ids, on every structure; `of_within` leaves a scene that fits alone.
#[test]
fn a_scene_cut_into_pieces_answers_as_the_flat_scene() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(11);
    let mut text = String::from(
        "[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\n[[lights]]\ntype = \"point\"\nposition = [0, 5, 5]\n",
    );
    text += "[[meshes]]\ngenerate = \"icosphere\"\nsubdivisions = 3\nscale = 0.8\n";
    text += "[[meshes]]\ngenerate = \"random_soup\"\ncount = 2000\nseed = 5\n";
    for k in 0..3 {
        text += &format!("[[spheres]]\ncenter = [{}, 1.2, 0]\nradius = 0.2\n", k - 1);
    }
    let dir = std::env::temp_dir().join(format!("vkrt-pieces-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("pieces.toml");
    std::fs::write(&path, text).unwrap();
    let scene = vkrt::scene::Scene::load(&path).unwrap().scene;
    std::fs::remove_dir_all(&dir).unwrap();
    let total = scene.triangle_count() + scene.spheres.len();
    assert_eq!(total, 1280 + 2000 + 3);
    assert!(vkrt::accel::two_levels::TwoLevelScene::of_within(&scene, 0.0, total).is_none());
    let two = vkrt::accel::two_levels::TwoLevelScene::of_within(&scene, 0.0, 700).unwrap();
    assert_eq!((two.bottoms.len(), two.rest_first.len()), (5, 5));
    assert_eq!(two.mesh_instances(), 0);
    assert!(two.bottoms.iter().all(|b| b.primitive_count() <= 700));
    let mut ids = two.rest_ids.clone();
    ids.sort_unstable();
    assert!(
        ids.iter().copied().eq(0..total as u32),
        "every primitive once"
    );

    let flat = TraceGeometry::at_time(&scene, 0.0);
    let rays = rays_at(&mut rng, 600, 3.0);
    for any in [false, true] {
        let o = TraceOptions {
            query: if any {
                vkrt::trace::Query::Any
            } else {
                vkrt::trace::Query::Closest
            },
            ..opt()
        };
        let want: Vec<Hit> = rays
            .iter()
            .map(|r| cpu::brute_force(&flat, r, 0.0, &o))
            .collect();
        let mut choices: Vec<vkrt::accel::device::AccelChoice> = [
            AccelKind::KdTree,
            AccelKind::SahBvh,
            AccelKind::Lbvh,
            AccelKind::Ploc,
        ]
        .map(|k| vkrt::accel::device::AccelChoice::new(k, Default::default()))
        .to_vec();
        // The driver's own levels, where it has them (its own triangle test: ties aside,
        // the same answers).
        if ctx.info().features.ray_query {
            choices.push(vkrt::accel::device::AccelChoice::driver(
                vkrt::accel::driver::Prefer::FastTrace,
            ));
        }
        for choice in choices {
            let kind = choice.kind;
            let done = vkrt::trace::instanced::build_and_trace(&ctx, choice, &o, &two, &rays, 0.0)
                .unwrap();
            assert_eq!(done.exhausted, 0);
            for (k, (got, want)) in done.hits.iter().zip(&want).enumerate() {
                if any {
                    assert_eq!(got.is_hit(), want.is_hit(), "{kind:?} any-hit ray {k}");
                } else {
                    assert!(
                        common::same_answer(got, want),
                        "{kind:?} ray {k}: {got:?}, brute force {want:?}"
                    );
                }
            }
        }
    }
    common::assert_silent(&ctx);
}

/// Instance records named by an array of pointers (`arrayOfPointers`) are gathered in the
/// pointers' order, a null pointer giving zeros: the device equals its CPU twin on every
/// edge of the workgroup, over records in a shuffled order.
#[test]
fn instance_pointers_gather_as_their_cpu_twin() {
    let Some(ctx) = common::context() else { return };
    if !ctx.info().features.buffer_device_address {
        return;
    }
    let gather = InstancePointers::new(&ctx).unwrap();
    let sg = ctx.info().subgroup_size as usize;
    let mut rng = common::Rng(41);
    let sizes = common::edge_sizes(sg, 64, 64)
        .into_iter()
        .filter(|&n| n <= 20_000);
    for n in sizes.chain([12_345]) {
        let slots = n.max(1);
        let records: Vec<[u32; 16]> = (0..slots)
            .map(|_| std::array::from_fn(|_| rng.next_u64() as u32))
            .collect();
        let source = Buffer::from_slice(&ctx, "records", &records).unwrap();
        let base = source.device_address().unwrap();
        // Every record named once in a random order; every seventh pointer null.
        let mut order: Vec<usize> = (0..n).collect();
        for k in (1..n).rev() {
            order.swap(k, (rng.next_u64() % (k as u64 + 1)) as usize);
        }
        let pointers: Vec<u64> = order
            .iter()
            .enumerate()
            .map(|(k, &slot)| match k % 7 {
                6 => 0,
                _ => base + 64 * slot as u64,
            })
            .collect();
        let mut stored = pointers.clone();
        stored.resize(n.max(1), 0);
        let pointer_buffer = Buffer::from_slice(&ctx, "pointers", &stored).unwrap();
        let out = Buffer::<[u32; 16]>::new(&ctx, "gathered", slots).unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        gather
            .record(
                &mut rec,
                pointer_buffer.device_address().unwrap(),
                n as u32,
                unsafe { out.as_raw() },
            )
            .unwrap();
        rec.submit_and_wait().unwrap();
        let device = out.download().unwrap();
        let host = instance_pointers_on_host(&pointers, |p| {
            bytemuck::cast(records[((p - base) / 64) as usize])
        });
        for k in 0..n {
            let want: [u32; 16] = bytemuck::cast(host[k]);
            assert_eq!(device[k], want, "n {n} record {k}");
        }
    }
    common::assert_silent(&ctx);
}

/// A top level that lists its bottom levels by borrowing them (`build`, `create_in`) refuses
/// to be updated, rebuilt or handed out once one is dropped — the device would read freed
/// memory — while one that keeps them (`record_build_shared`) goes on.
#[test]
fn a_top_level_refuses_work_once_a_borrowed_bottom_level_is_dropped() {
    let Some(ctx) = common::context() else { return };
    let tris = sphere_tris(1);
    let builder = TopLevelBuilder::new(&ctx, AccelKind::Lbvh).unwrap();
    let flags = BuildFlags {
        allow_update: true,
        ..BuildFlags::default()
    };
    let instances = [Instance::new(0, Instance::IDENTITY)];
    let level = bottom(&ctx, AccelKind::Lbvh, false, &tris);
    let mut top = builder.build(&ctx, &[&level], &instances, &flags).unwrap();
    top.handle_words().unwrap();
    builder.update(&ctx, &mut top, &instances).unwrap();
    drop(level);
    let refused = |r: Result<(), GpuError>, what: &str| match r {
        Err(GpuError::Usage { reason, .. }) => {
            assert!(reason.contains("bottom level 0"), "{what}: {reason}")
        }
        other => panic!("{what}: {other:?}"),
    };
    refused(top.handle_words().map(drop), "the handle");
    refused(builder.update(&ctx, &mut top, &instances), "an update");

    // Kept by the top level: the caller's handle on it may go.
    let level = std::sync::Arc::new(bottom(&ctx, AccelKind::Lbvh, false, &tris));
    let mut rec = Recorder::new(&ctx).unwrap();
    let mut shared = builder
        .record_build_shared(
            &mut rec,
            std::slice::from_ref(&level),
            &instances,
            InstanceMotion::STATIC,
            &flags,
        )
        .unwrap();
    rec.submit_and_wait().unwrap();
    drop(level);
    shared.handle_words().unwrap();
    builder.update(&ctx, &mut shared, &instances).unwrap();
    // Its build's report copied into the renderer's buffer: no invalid instance.
    let caller = Buffer::<u32>::from_slice(&ctx, "caller.status", &[7, 7]).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    shared.record_copy_status_into(&mut rec, &caller).unwrap();
    rec.submit_and_wait().unwrap();
    assert_eq!(caller.download().unwrap(), [0, 7]);
    common::assert_silent(&ctx);
}
