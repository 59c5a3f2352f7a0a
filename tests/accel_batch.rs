//! Several structures over the caller's geometry built by one record call
//! (`AccelBuilder::record_builds_from`): each the same, bit for bit, as its twin built by a
//! call of its own, with the gathers' and the end's barriers paid once; every bad target
//! refused, by its index, before anything is recorded. Sizes asked from counts alone
//! (`GeometryShape`) equal to those asked from the geometry. And compaction: a built
//! kd-tree copied into the bytes it uses traces as the original, hit for hit (the LBVH's
//! and PLOC's: `tests/accel_compact.rs`).

mod common;

use glam::{Vec3, Vec4};
use vkrt::accel::batch::BuildTarget;
use vkrt::accel::compact::CompactedSize;
use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::embedded::BuildFlags;
use vkrt::accel::geometry::{Aabbs, Geometry, IndexType, Spheres, Triangles};
use vkrt::accel::geometry_shape::GeometryShape;
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::gpu::{Buffer, Context, GpuError, RawBuffer, RecordCounts, Recorder};
use vkrt::trace::gpu::Tracer;
use vkrt::trace::{Hit, Ray, TraceOptions};

/// Where ranges of one caller buffer start (any storage-buffer offset alignment divides it).
const ALIGN: u64 = 256;

/// The caller's geometry buffers, kept alive.
struct Caller(Vec<Buffer<u32>>);

impl Caller {
    fn put(&mut self, ctx: &Context, bytes: &[u8]) -> RawBuffer {
        let mut words = bytes.to_vec();
        words.resize(words.len().next_multiple_of(4).max(4), 0);
        let b = Buffer::from_slice(ctx, "caller", bytemuck::cast_slice::<u8, u32>(&words)).unwrap();
        let raw =
            unsafe { RawBuffer::new(b.as_raw().buffer(), b.as_raw().offset(), bytes.len() as u64) };
        self.0.push(b);
        raw
    }
}

/// Lists of geometries, one list per structure: soups of several sizes (none, one and two
/// triangles among them), an indexed and transformed mesh, spheres and boxes, a mixed list.
fn structures(ctx: &Context, caller: &mut Caller) -> Vec<Vec<Geometry>> {
    let mesh = vkrt::scene::gen::icosphere(2).unwrap();
    let tris = common::mesh_triangles(&mesh);
    let soup = |caller: &mut Caller, n: usize, shift: f32| {
        let flat: Vec<Vec3> = tris[..n]
            .iter()
            .flatten()
            .map(|&p| p * 0.7 + Vec3::X * shift)
            .collect();
        let v = caller.put(ctx, bytemuck::cast_slice(&flat));
        Geometry::Triangles(Triangles::soup(v, flat.len() as u32))
    };
    let mut out = vec![
        vec![soup(caller, tris.len(), 0.0)],
        vec![soup(caller, 0, 0.0)],
        vec![soup(caller, 1, 0.1)],
        vec![soup(caller, 2, -0.1)],
        vec![soup(caller, 37, 0.2), soup(caller, 90, -0.3)],
    ];
    let positions: Vec<Vec3> = mesh.positions.to_vec();
    let indices: Vec<u16> = mesh.indices.iter().flatten().map(|&i| i as u16).collect();
    let v = caller.put(ctx, bytemuck::cast_slice(&positions));
    let ix = caller.put(ctx, bytemuck::cast_slice(&indices));
    let mut indexed = Triangles::indexed(
        v,
        positions.len() as u32,
        ix,
        IndexType::U16,
        mesh.indices.len() as u32,
    );
    indexed.transform = Some(
        [
            [0.5, 0.0, 0.0, 0.3],
            [0.0, 0.6, 0.1, -0.2],
            [0.0, 0.0, 0.4, 0.0],
        ]
        .into(),
    );
    let mut rng = common::Rng(7);
    let spheres: Vec<Vec4> = (0..40)
        .map(|_| (rng.next_vec3() * 2.0 - 1.0).extend(0.05 + 0.1 * rng.next_f32()))
        .collect();
    let boxes: Vec<[f32; 6]> = (0..50)
        .map(|_| {
            let c = rng.next_vec3() * 2.0 - 1.0;
            let h = Vec3::splat(0.02) + rng.next_vec3() * 0.1;
            let (lo, hi) = (c - h, c + h);
            [lo.x, lo.y, lo.z, hi.x, hi.y, hi.z]
        })
        .collect();
    let spheres = Geometry::Spheres(Spheres {
        data: caller.put(ctx, bytemuck::cast_slice(&spheres)).into(),
        stride: 16,
        count: 40,
        opaque: true,
    });
    let boxes = Geometry::Aabbs(Aabbs {
        data: caller.put(ctx, bytemuck::cast_slice(&boxes)).into(),
        stride: 24,
        count: 50,
        opaque: true,
    });
    out.push(vec![Geometry::Triangles(indexed)]);
    out.push(vec![boxes, spheres]);
    out.push(vec![spheres, soup(caller, 60, 0.0), boxes]);
    out
}

fn kinds(ctx: &Context) -> Vec<AccelKind> {
    let mut kinds = vec![AccelKind::KdTree, AccelKind::Lbvh, AccelKind::Ploc];
    if ctx.info().features.ray_query {
        kinds.push(AccelKind::Driver);
    }
    kinds
}

fn flags_of(kind: AccelKind) -> BuildFlags {
    BuildFlags {
        allow_update: kind != AccelKind::KdTree,
        ..BuildFlags::default()
    }
}

/// Ranges of `sizes` bytes laid out in one buffer, `ALIGN`-aligned, and the buffer.
fn ranges(ctx: &Context, name: &str, sizes: &[u64]) -> (Buffer<u8>, Vec<RawBuffer>) {
    let mut at = Vec::new();
    let mut end = 0u64;
    for &s in sizes {
        at.push(end);
        end = (end + s.max(4)).next_multiple_of(ALIGN);
    }
    let buffer = Buffer::<u8>::arena(ctx, name, end.max(ALIGN) as usize).unwrap();
    let whole = unsafe { buffer.as_raw() };
    let ranges = at
        .iter()
        .zip(sizes)
        .map(|(&offset, &size)| unsafe {
            RawBuffer::new(whole.buffer(), whole.offset() + offset, size.max(4))
        })
        .collect();
    (buffer, ranges)
}

/// The structures of `lists`, created in one caller buffer, with their scratch ranges in
/// another.
struct Created {
    structures: Vec<GpuGeometry>,
    scratch: Vec<RawBuffer>,
    _memory: [Buffer<u8>; 2],
}

fn create(ctx: &Context, builder: &AccelBuilder, lists: &[Vec<Geometry>]) -> Created {
    let flags = flags_of(builder.kind());
    let sizes: Vec<_> = lists
        .iter()
        .map(|g| builder.sizes_for(ctx, g, &flags).unwrap())
        .collect();
    let bytes: Vec<u64> = sizes.iter().map(|s| s.structure_bytes).collect();
    let (memory, at) = ranges(ctx, "caller.structures", &bytes);
    let scratch_bytes: Vec<u64> = sizes.iter().map(|s| s.build_scratch_bytes).collect();
    let (scratch_memory, scratch) = ranges(ctx, "caller.scratch", &scratch_bytes);
    let structures = lists
        .iter()
        .zip(at)
        .map(|(g, m)| builder.create_in(ctx, g, &flags, m).unwrap())
        .collect();
    Created {
        structures,
        scratch,
        _memory: [memory, scratch_memory],
    }
}

fn targets<'a>(lists: &'a [Vec<Geometry>], c: &'a mut Created) -> Vec<BuildTarget<'a>> {
    c.structures
        .iter_mut()
        .zip(lists)
        .zip(&c.scratch)
        .map(|((out, geometries), &scratch)| BuildTarget {
            geometries,
            out,
            scratch,
        })
        .collect()
}

fn rays(n: usize) -> Vec<Ray> {
    let mut rng = common::Rng(11);
    (0..n)
        .map(|_| {
            let o = (rng.next_vec3() * 2.0 - 1.0).normalize_or(Vec3::X) * 3.0;
            let t = (rng.next_vec3() * 2.0 - 1.0) * 0.8;
            Ray::new(o, t - o, 0.0, f32::INFINITY)
        })
        .collect()
}

fn trace(ctx: &Context, kind: AccelKind, g: &GpuGeometry, rays: &[Ray]) -> Vec<Hit> {
    let tracer = Tracer::for_accel(
        ctx,
        &TraceOptions::default(),
        kind.walked(Default::default()),
    )
    .unwrap();
    tracer.trace(ctx, g, rays, 0.0).unwrap().hits
}

fn hit_bits(h: &[Hit]) -> Vec<[u32; 4]> {
    h.iter()
        .map(|h| [h.t.to_bits(), h.prim, h.u.to_bits(), h.v.to_bits()])
        .collect()
}

#[test]
fn a_batch_builds_each_structure_as_its_own_call_does_sharing_its_barriers() {
    let Some(ctx) = common::context() else { return };
    let mut caller = Caller(Vec::new());
    let lists = structures(&ctx, &mut caller);
    let rays = rays(400);
    for kind in kinds(&ctx) {
        let builder = AccelBuilder::new(&ctx, kind).unwrap();

        // One call over every structure.
        let mut batch = create(&ctx, &builder, &lists);
        let mut rec = Recorder::new(&ctx).unwrap();
        builder
            .record_builds_from(&mut rec, &mut targets(&lists, &mut batch))
            .unwrap();
        let batched = rec.counts();
        rec.submit_and_wait().unwrap();

        // A call each.
        let mut separate = create(&ctx, &builder, &lists);
        let mut rec = Recorder::new(&ctx).unwrap();
        let mut each = Vec::new();
        for t in targets(&lists, &mut separate) {
            let before = rec.counts().barriers;
            builder
                .record_build_from(&mut rec, t.out, t.geometries, t.scratch)
                .unwrap();
            each.push(rec.counts().barriers - before);
        }
        let one_by_one = rec.counts();
        rec.submit_and_wait().unwrap();

        // The same dispatches. A call's barriers: its gather's (one after the header and
        // one after each geometry with data), its builder's, one at the end. A batch pays
        // the gathers' for the longest list only, the builders' of the build with the
        // most passes (vkrt's builders, interleaved; the driver's follow one another), and
        // one end.
        assert_eq!(batched.dispatches, one_by_one.dispatches, "{kind:?}");
        let with_data = |g: &Vec<Geometry>| g.iter().filter(|g| g.primitive_count() > 0).count();
        let builds: Vec<u64> = lists
            .iter()
            .zip(&each)
            .map(|(g, &n)| n - 2 - with_data(g) as u64)
            .collect();
        let gathers = 1 + lists.iter().map(with_data).max().unwrap() as u64;
        let expected = match kind {
            AccelKind::Driver => gathers + builds.iter().sum::<u64>() + 1,
            _ => gathers + builds.iter().max().unwrap() + 1,
        };
        assert!(
            batched.barriers <= expected,
            "{kind:?}: {batched:?}, expected at most {expected} (separately {each:?})"
        );
        if kind != AccelKind::Driver {
            assert!(batched.barriers * 2 < one_by_one.barriers, "{kind:?}");
        }

        for (k, (a, b)) in batch
            .structures
            .iter()
            .zip(&separate.structures)
            .enumerate()
        {
            if kind != AccelKind::Driver {
                assert_eq!(
                    a.structure().download().unwrap(),
                    b.structure().download().unwrap(),
                    "{kind:?} structure {k}"
                );
            }
            assert_eq!(
                hit_bits(&trace(&ctx, kind, a, &rays)),
                hit_bits(&trace(&ctx, kind, b, &rays)),
                "{kind:?} structure {k}"
            );
        }
        // Rebuilt in place by a second batch: the same again.
        let mut rec = Recorder::new(&ctx).unwrap();
        builder
            .record_builds_from(&mut rec, &mut targets(&lists, &mut batch))
            .unwrap();
        rec.submit_and_wait().unwrap();
        if kind != AccelKind::Driver {
            for (a, b) in batch.structures.iter().zip(&separate.structures) {
                assert_eq!(
                    a.structure().download().unwrap(),
                    b.structure().download().unwrap()
                );
            }
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn a_bad_target_is_an_error_naming_it_before_anything_is_recorded() {
    let Some(ctx) = common::context() else { return };
    let mut caller = Caller(Vec::new());
    let lists: Vec<Vec<Geometry>> = structures(&ctx, &mut caller).into_iter().take(4).collect();
    let builder = AccelBuilder::new(&ctx, AccelKind::Lbvh).unwrap();
    let mut c = create(&ctx, &builder, &lists);
    let nothing = RecordCounts::default();
    let mut rec = Recorder::new(&ctx).unwrap();
    let usage = |e: GpuError| match e {
        GpuError::Usage { reason, .. } => reason,
        e => panic!("{e}"),
    };

    // Geometry other than the structure's.
    let mut t = targets(&lists, &mut c);
    t[2].geometries = &lists[0];
    let e = builder.record_builds_from(&mut rec, &mut t).unwrap_err();
    assert!(usage(e).starts_with("target 2: "));
    assert_eq!(rec.counts(), nothing);

    // Two targets on one scratch range.
    let mut t = targets(&lists, &mut c);
    t[3].scratch = t[0].scratch;
    let e = builder.record_builds_from(&mut rec, &mut t).unwrap_err();
    let reason = usage(e);
    assert!(
        reason.starts_with("target 3: ") && reason.contains("target 0"),
        "{reason}"
    );
    assert_eq!(rec.counts(), nothing);

    // Too little scratch.
    let mut t = targets(&lists, &mut c);
    t[1].scratch = t[1].scratch.slice(0, 4).unwrap();
    match builder.record_builds_from(&mut rec, &mut t).unwrap_err() {
        GpuError::Placement { what, .. } => assert!(what.starts_with("target 1: "), "{what}"),
        e => panic!("{e}"),
    }
    assert_eq!(rec.counts(), nothing);

    // Another builder's structure; a builder of another kind.
    let ploc = AccelBuilder::new(&ctx, AccelKind::Ploc).unwrap();
    let e = ploc
        .record_builds_from(&mut rec, &mut targets(&lists, &mut c))
        .unwrap_err();
    match e {
        GpuError::Target { index: 0, error } => match *error {
            GpuError::KindMismatch {
                built, expected, ..
            } => {
                assert_eq!(
                    (built.as_str(), expected.as_str()),
                    ("lbvh", "ploc builder")
                )
            }
            e => panic!("{e}"),
        },
        e => panic!("{e}"),
    }
    assert_eq!(rec.counts(), nothing);

    // Nothing to build records nothing; the recorder still takes a good batch.
    builder.record_builds_from(&mut rec, &mut []).unwrap();
    assert_eq!(rec.counts(), nothing);
    builder
        .record_builds_from(&mut rec, &mut targets(&lists, &mut c))
        .unwrap();
    rec.submit_and_wait().unwrap();
    common::assert_silent(&ctx);
}

#[test]
fn sizes_from_counts_alone_equal_sizes_from_the_geometry() {
    let Some(ctx) = common::context() else { return };
    let mut caller = Caller(Vec::new());
    let lists = structures(&ctx, &mut caller);
    for kind in kinds(&ctx) {
        let builder = AccelBuilder::new(&ctx, kind).unwrap();
        let bvh = matches!(kind, AccelKind::Lbvh | AccelKind::Ploc);
        let all_flags = [
            BuildFlags::default(),
            BuildFlags {
                allow_update: kind != AccelKind::KdTree,
                wide: bvh,
                ..BuildFlags::default()
            },
            BuildFlags {
                kd_capacity_doublings: 2,
                ..BuildFlags::default()
            },
        ];
        for flags in all_flags {
            for (k, geometries) in lists.iter().enumerate() {
                let from_data = builder.sizes_for(&ctx, geometries, &flags).unwrap();
                let shapes: Vec<GeometryShape> = geometries.iter().map(|g| g.shape()).collect();
                let from_counts = builder.sizes_for(&ctx, &shapes, &flags).unwrap();
                assert_eq!(from_data, from_counts, "{kind:?} {flags:?} list {k}");
            }
        }
        // Described by hand: the icosphere's 320 triangles, indexed over 162 vertices.
        let mesh = vkrt::scene::gen::icosphere(2).unwrap();
        let (v, t) = (mesh.positions.len() as u32, mesh.indices.len() as u32);
        let flags = BuildFlags::default();
        assert_eq!(
            builder
                .sizes_for(
                    &ctx,
                    &[GeometryShape::triangles(v, Some(IndexType::U16), t)],
                    &flags
                )
                .unwrap(),
            builder.sizes_for(&ctx, &lists[5], &flags).unwrap(),
            "{kind:?}"
        );
        let by_hand = [GeometryShape::aabbs(50), GeometryShape::spheres(40)];
        assert_eq!(
            builder.sizes_for(&ctx, &by_hand, &flags).unwrap(),
            builder.sizes_for(&ctx, &lists[6], &flags).unwrap(),
            "{kind:?}"
        );
    }

    // What the counts alone can refuse, they refuse.
    let lbvh = AccelBuilder::new(&ctx, AccelKind::Lbvh).unwrap();
    let kd = AccelBuilder::new(&ctx, AccelKind::KdTree).unwrap();
    let flags = BuildFlags::default();
    let bad = [
        (
            &lbvh,
            GeometryShape::Triangles {
                format: Default::default(),
                stride: 10,
                vertex_count: 3,
                index_type: None,
                triangle_count: 1,
                opaque: true,
            },
        ),
        (&lbvh, GeometryShape::triangles(5, None, 2)),
        (&lbvh, GeometryShape::triangles(0, Some(IndexType::U32), 2)),
        (
            &lbvh,
            GeometryShape::Spheres {
                stride: 12,
                count: 1,
                opaque: true,
            },
        ),
        (
            &lbvh,
            GeometryShape::triangles(3, Some(IndexType::U32), u32::MAX / 2),
        ),
        (&kd, GeometryShape::spheres(4).with_opaque(false)),
    ];
    for (k, (builder, shape)) in bad.iter().enumerate() {
        let r = builder.sizes_for(&ctx, &[*shape], &flags);
        assert!(matches!(r, Err(GpuError::Usage { .. })), "{k}: {r:?}");
    }
    assert!(lbvh
        .sizes_for(
            &ctx,
            &[GeometryShape::spheres(4).with_opaque(false)],
            &flags
        )
        .is_ok());
    common::assert_silent(&ctx);
}

/// The compacted sizes of `structures` (built), queried as a renderer does.
fn compacted_sizes(ctx: &Context, structures: &[GpuGeometry]) -> Vec<CompactedSize> {
    let mut rec = Recorder::new(ctx).unwrap();
    rec.compute_to_transfer();
    let queries: Vec<_> = structures
        .iter()
        .map(|g| g.record_compacted_size(&mut rec).unwrap())
        .collect();
    rec.transfer_to_host();
    rec.submit_and_wait().unwrap();
    queries.into_iter().map(|q| q.read().unwrap()).collect()
}

#[test]
fn a_compacted_kd_tree_traces_as_the_original_in_fewer_bytes() {
    let Some(ctx) = common::context() else { return };
    let mut caller = Caller(Vec::new());
    let lists = structures(&ctx, &mut caller);
    let rays = rays(400);
    let kd = AccelBuilder::new(&ctx, AccelKind::KdTree).unwrap();
    let mut built = create(&ctx, &kd, &lists);
    let mut rec = Recorder::new(&ctx).unwrap();
    kd.record_builds_from(&mut rec, &mut targets(&lists, &mut built))
        .unwrap();
    rec.submit_and_wait().unwrap();

    let sizes = compacted_sizes(&ctx, &built.structures);
    let (memory, at) = ranges(
        &ctx,
        "caller.compacted",
        &sizes.iter().map(|s| s.bytes).collect::<Vec<_>>(),
    );
    let mut compacted: Vec<GpuGeometry> = built
        .structures
        .iter()
        .zip(&sizes)
        .zip(&at)
        .map(|((g, s), &m)| g.create_compacted_in(&ctx, s, m).unwrap())
        .collect();
    let mut rec = Recorder::new(&ctx).unwrap();
    for (g, c) in built.structures.iter().zip(&mut compacted) {
        g.record_compact_into(&mut rec, c, None).unwrap();
    }
    rec.submit_and_wait().unwrap();

    let flags = flags_of(AccelKind::KdTree);
    for (k, ((g, c), s)) in built
        .structures
        .iter()
        .zip(&compacted)
        .zip(&sizes)
        .enumerate()
    {
        let full = kd
            .sizes_for(&ctx, &lists[k], &flags)
            .unwrap()
            .structure_bytes;
        assert!(s.bytes <= full, "structure {k}: {s:?} of {full}");
        if lists[k].iter().map(|g| g.primitive_count()).sum::<u32>() > 100 {
            assert!(s.bytes * 2 < full, "structure {k}: {s:?} of {full}");
        }
        assert_eq!(
            g.structure().download().unwrap(),
            c.structure().download().unwrap(),
            "structure {k}"
        );
        assert_eq!(
            hit_bits(&trace(&ctx, AccelKind::KdTree, g, &rays)),
            hit_bits(&trace(&ctx, AccelKind::KdTree, c, &rays)),
            "structure {k}"
        );
    }
    // The compacted structures' handles point into the new memory.
    if let (Ok(base), Ok(_)) = (memory.device_address(), compacted[0].handle_words()) {
        let end = base + unsafe { memory.as_raw() }.size();
        for (c, r) in compacted.iter().zip(&at) {
            let start = base + r.offset() - unsafe { memory.as_raw() }.offset();
            for a in c.handle_words().unwrap() {
                assert!(a >= start && a < start + r.size() && a < end, "{a:#x}");
            }
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn compaction_refuses_what_it_cannot_copy() {
    let Some(ctx) = common::context() else { return };
    let mut caller = Caller(Vec::new());
    let lists: Vec<Vec<Geometry>> = structures(&ctx, &mut caller).into_iter().take(1).collect();
    let is_usage = |r: Result<(), GpuError>, what: &str| match r {
        Err(GpuError::Usage { .. }) => {}
        other => panic!("{what}: {other:?}"),
    };
    let kd = AccelBuilder::new(&ctx, AccelKind::KdTree).unwrap();
    let lbvh = AccelBuilder::new(&ctx, AccelKind::Lbvh).unwrap();

    // Not built yet; then built.
    let mut c = create(&ctx, &kd, &lists);
    let mut rec = Recorder::new(&ctx).unwrap();
    let unbuilt = c.structures[0].record_compacted_size(&mut rec).map(drop);
    assert!(
        matches!(unbuilt, Err(GpuError::NotBuilt { .. })),
        "an unbuilt structure: {unbuilt:?}"
    );
    kd.record_builds_from(&mut rec, &mut targets(&lists, &mut c))
        .unwrap();
    rec.submit_and_wait().unwrap();
    let size = compacted_sizes(&ctx, &c.structures)[0];

    // Too little memory.
    let memory = Buffer::<u8>::arena(&ctx, "compacted", size.bytes as usize).unwrap();
    let short = unsafe {
        RawBuffer::new(
            memory.as_raw().buffer(),
            memory.as_raw().offset(),
            size.bytes - 4,
        )
    };
    match c.structures[0].create_compacted_in(&ctx, &size, short) {
        Err(GpuError::Placement { .. }) => {}
        other => panic!("too little memory: {:?}", other.map(drop)),
    }
    let mut dst = c.structures[0]
        .create_compacted_in(&ctx, &size, unsafe { memory.as_raw() })
        .unwrap();

    // Building into a compacted structure; compacting into one made for another.
    let mut rec = Recorder::new(&ctx).unwrap();
    is_usage(
        kd.record_build_from(&mut rec, &mut dst, &lists[0], c.scratch[0]),
        "a build into a compacted structure",
    );
    let mut other_caller = Caller(Vec::new());
    let others: Vec<Vec<Geometry>> = structures(&ctx, &mut other_caller)
        .into_iter()
        .skip(5)
        .take(1)
        .collect();
    let mut o = create(&ctx, &kd, &others);
    kd.record_builds_from(&mut rec, &mut targets(&others, &mut o))
        .unwrap();
    is_usage(
        o.structures[0].record_compact_into(&mut rec, &mut dst, None),
        "a destination made for another structure",
    );

    // A structure over host geometry (its layout is not the caller's to copy).
    let tris = common::mesh_triangles(&vkrt::scene::gen::icosphere(1).unwrap());
    let host = vkrt::accel::primitives::TraceGeometry::from_triangles(&tris);
    let (b, _) = GpuGeometry::record_build(&mut rec, &lbvh, &host, 0).unwrap();
    is_usage(
        b.record_compacted_size(&mut rec).map(drop),
        "a structure over host geometry",
    );
    c.structures[0]
        .record_compact_into(&mut rec, &mut dst, None)
        .unwrap();
    rec.submit_and_wait().unwrap();
    common::assert_silent(&ctx);
}
