//! Compaction of the LBVH and PLOC (`GpuGeometry::record_compacted_size`,
//! `create_compacted_in`, `record_compact_into`): the live-node count their leaf collapse
//! writes is the size query's, the device's renumbering equals its CPU twin
//! (`bvh::compact::renumber`) slot for slot at every edge of its kernels and the scan, the
//! compacted structure traces hit for hit as the original (binary and wide walks), in fewer
//! bytes, and an update of a compacted structure built to be updated equals the update of
//! the original.

mod common;

use glam::Vec3;
use vkrt::accel::bvh::collapse::DEAD;
use vkrt::accel::bvh::compact::{renumber, BvhSlots};
use vkrt::accel::compact::CompactedSize;
use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::embedded::BuildFlags;
use vkrt::accel::geometry::{Geometry, Triangles};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::walk::Traversal;
use vkrt::gpu::{Buffer, Context, GpuError, RawBuffer, Recorder};
use vkrt::prims::scan::{Scan, ScanInput};
use vkrt::prims::PrimConfig;
use vkrt::trace::gpu::Tracer;
use vkrt::trace::{Hit, Ray, TraceOptions};

/// A structure built over the caller's vertex buffer, in the caller's memory.
struct Built {
    g: GpuGeometry,
    geometries: Vec<Geometry>,
    vertices: Buffer<f32>,
    structure_bytes: u64,
    update_scratch_bytes: u64,
    _memory: [Buffer<u8>; 2],
}

fn soup(tris: &[[Vec3; 3]]) -> Vec<f32> {
    tris.iter().flatten().flat_map(|p| p.to_array()).collect()
}

fn build(ctx: &Context, kind: AccelKind, tris: &[[Vec3; 3]], flags: &BuildFlags) -> Built {
    let words = soup(tris);
    // (a buffer of at least one element: none cannot be made)
    let held = if words.is_empty() {
        vec![0.0]
    } else {
        words.clone()
    };
    let vertices = Buffer::from_slice(ctx, "caller.vertices", &held).unwrap();
    let raw = unsafe {
        RawBuffer::new(
            vertices.as_raw().buffer(),
            vertices.as_raw().offset(),
            4 * words.len() as u64,
        )
    };
    let geometries = vec![Geometry::Triangles(Triangles::soup(
        raw,
        3 * tris.len() as u32,
    ))];
    let builder = AccelBuilder::new(ctx, kind).unwrap();
    let sizes = builder.sizes_for(ctx, &geometries, flags).unwrap();
    let memory = arena(ctx, "caller.structure", sizes.structure_bytes);
    let scratch = arena(ctx, "caller.scratch", sizes.build_scratch_bytes);
    let mut g = builder
        .create_in(ctx, &geometries, flags, unsafe { memory.as_raw() })
        .unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    builder
        .record_build_from(&mut rec, &mut g, &geometries, unsafe { scratch.as_raw() })
        .unwrap();
    rec.submit_and_wait().unwrap();
    Built {
        g,
        geometries,
        vertices,
        structure_bytes: sizes.structure_bytes,
        update_scratch_bytes: sizes.update_scratch_bytes.unwrap_or(0),
        _memory: [memory, scratch],
    }
}

fn arena(ctx: &Context, name: &str, bytes: u64) -> Buffer<u8> {
    Buffer::<u8>::arena(ctx, name, bytes.max(4) as usize).unwrap()
}

fn compacted_size(ctx: &Context, g: &GpuGeometry) -> CompactedSize {
    let mut rec = Recorder::new(ctx).unwrap();
    rec.compute_to_transfer();
    let query = g.record_compacted_size(&mut rec).unwrap();
    rec.transfer_to_host();
    rec.submit_and_wait().unwrap();
    query.read().unwrap()
}

/// The compacted copy of `g` in memory of exactly the sizes it reports, and that memory.
fn compact(ctx: &Context, g: &GpuGeometry) -> (GpuGeometry, CompactedSize, [Buffer<u8>; 2]) {
    let size = compacted_size(ctx, g);
    let memory = arena(ctx, "caller.compacted", size.bytes);
    let exact = unsafe {
        RawBuffer::new(
            memory.as_raw().buffer(),
            memory.as_raw().offset(),
            size.bytes,
        )
    };
    let mut dst = g.create_compacted_in(ctx, &size, exact).unwrap();
    let scratch = arena(ctx, "caller.compact_scratch", size.scratch_bytes);
    let scratch_range = (size.scratch_bytes > 0).then(|| unsafe {
        RawBuffer::new(
            scratch.as_raw().buffer(),
            scratch.as_raw().offset(),
            size.scratch_bytes,
        )
    });
    let mut rec = Recorder::new(ctx).unwrap();
    g.record_compact_into(&mut rec, &mut dst, scratch_range)
        .unwrap();
    rec.submit_and_wait().unwrap();
    (dst, size, [memory, scratch])
}

fn rays(tris: &[[Vec3; 3]], n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = common::Rng(seed);
    let centre = tris
        .iter()
        .flatten()
        .fold(Vec3::ZERO, |a, &p| a + p / (3 * tris.len().max(1)) as f32);
    (0..n)
        .map(|k| {
            let o = centre + (rng.next_vec3() * 2.0 - 1.0).normalize_or(Vec3::X) * 3.0;
            let target = match tris.get(k % tris.len().max(1)) {
                Some(t) if k % 2 == 0 => (t[0] + t[1] + t[2]) / 3.0,
                _ => centre + (rng.next_vec3() * 2.0 - 1.0) * 0.8,
            };
            Ray::new(o, target - o, 0.0, f32::INFINITY)
        })
        .collect()
}

fn hit_bits(hits: &[Hit]) -> Vec<[u32; 4]> {
    hits.iter()
        .map(|h| [h.t.to_bits(), h.prim, h.u.to_bits(), h.v.to_bits()])
        .collect()
}

fn trace(
    ctx: &Context,
    kind: AccelKind,
    wide: bool,
    g: &GpuGeometry,
    rays: &[Ray],
) -> Vec<[u32; 4]> {
    let walk = match wide {
        true => Traversal::Wide,
        false => Traversal::Stack,
    };
    let tracer = Tracer::for_accel(ctx, &TraceOptions::default(), kind.walked(walk)).unwrap();
    hit_bits(&tracer.trace(ctx, g, rays, 0.0).unwrap().hits)
}

fn slots(g: &GpuGeometry) -> BvhSlots {
    g.structure().download_slots().unwrap().expect("a BVH")
}

/// A fine icosphere's first `n` triangles, shuffled a little (PLOC's and the LBVH's trees
/// differ then), or the bunny's.
fn triangles(n: usize, rng: &mut common::Rng) -> Vec<[Vec3; 3]> {
    let sphere = vkrt::scene::gen::icosphere(6).unwrap();
    let all = common::mesh_triangles(&sphere);
    let mut tris: Vec<[Vec3; 3]> = all.iter().copied().cycle().take(n).collect();
    for (k, t) in tris.iter_mut().enumerate() {
        // Repeats (n past the sphere's) moved apart.
        let shift = (k / all.len()) as f32 * 0.01;
        *t = t.map(|p| p * (1.0 + shift) + (rng.next_vec3() - 0.5) * 1e-3);
    }
    tris
}

#[test]
fn the_renumbering_equals_its_cpu_twin_at_every_edge_and_traces_as_the_original() {
    let Some(ctx) = common::context() else { return };
    let subgroup = ctx.info().subgroup_size.max(1) as usize;
    let tile = Scan::new(&ctx, PrimConfig::default_for(&ctx), ScanInput::U32)
        .unwrap()
        .tile_elements();
    let mut rng = common::Rng(17);
    // Primitive counts; the kernels run over `n - 1` node slots, in workgroups of 64.
    let mut sizes = vec![0, 1, 2, 3, 4, 5, 17];
    for edge in [subgroup, 64, tile, 2 * tile] {
        sizes.extend([edge, edge + 1, edge + 2]);
    }
    for _ in 0..3 {
        sizes.push(100 + (rng.next_u64() % 3000) as usize);
    }
    let mut meshes: Vec<Vec<[Vec3; 3]>> = sizes.iter().map(|&n| triangles(n, &mut rng)).collect();
    if !common::quick() {
        meshes.extend(common::bunny());
    }
    let mut collapsed = 0;
    for kind in [AccelKind::Lbvh, AccelKind::Ploc] {
        for (k, tris) in meshes.iter().enumerate() {
            let n = tris.len();
            let flags = BuildFlags {
                allow_update: k % 2 == 0,
                wide: k % 3 == 0,
                ..BuildFlags::default()
            };
            let what = format!("{kind:?}, {n} triangles, {flags:?}");
            let built = build(&ctx, kind, tris, &flags);
            let src = slots(&built.g);
            let live = src.parents.iter().filter(|&&p| p != DEAD).count();
            assert_eq!(src.live, live, "{what}: the collapse's count");

            let (dst, size, _memory) = compact(&ctx, &built.g);
            assert_eq!(size.nodes as usize, live, "{what}");
            assert_eq!(size.refs as usize, n, "{what}");
            assert!(size.bytes <= built.structure_bytes, "{what}: {size:?}");
            if live < src.nodes.len() {
                collapsed += 1;
                assert!(size.bytes < built.structure_bytes, "{what}: {size:?}");
            }
            let got = slots(&dst);
            let (nodes, parents) = renumber(&src.nodes, &src.parents);
            assert_eq!(got.nodes, nodes, "{what}: the nodes");
            assert_eq!(got.parents, parents, "{what}: the parent links");
            assert_eq!(got.refs, src.refs, "{what}: the references");
            assert_eq!(
                dst.structure().download().unwrap(),
                built.g.structure().download().unwrap(),
                "{what}"
            );
            if flags.wide {
                let (binary, wide) = dst.structure().download_wide().unwrap().unwrap();
                assert_eq!(
                    wide,
                    vkrt::accel::bvh::wide::widen(&binary, binary.len()),
                    "{what}"
                );
            }
            let rays = rays(tris, 200, n as u64);
            let want = trace(&ctx, kind, flags.wide, &built.g, &rays);
            assert_eq!(trace(&ctx, kind, flags.wide, &dst, &rays), want, "{what}");
            if n > 16 {
                assert!(want.iter().any(|h| h[1] != u32::MAX), "{what}: no hit");
            }
        }
    }
    assert!(collapsed > 10, "{collapsed} structures had freed slots");
    common::assert_silent(&ctx);
}

#[test]
fn a_compacted_structure_updates_as_the_original_does() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(5);
    let tris = triangles(3000, &mut rng);
    let moved: Vec<[Vec3; 3]> = tris
        .iter()
        .enumerate()
        .map(|(k, t)| t.map(|p| p * 1.2 + Vec3::new(0.1, (k % 7) as f32 * 1e-3, -0.05)))
        .collect();
    let rays = rays(&moved, 300, 9);
    for kind in [AccelKind::Lbvh, AccelKind::Ploc] {
        for wide in [false, true] {
            let flags = BuildFlags {
                allow_update: true,
                wide,
                ..BuildFlags::default()
            };
            let mut built = build(&ctx, kind, &tris, &flags);
            let (mut dst, _, _memory) = compact(&ctx, &built.g);
            // The caller moves its vertices where they lie; both are updated.
            built.vertices.upload(&soup(&moved)).unwrap();
            let builder = AccelBuilder::new(&ctx, kind).unwrap();
            let scratch = arena(&ctx, "caller.update", built.update_scratch_bytes);
            let mut rec = Recorder::new(&ctx).unwrap();
            for g in [&mut built.g, &mut dst] {
                builder
                    .record_update_from(&mut rec, g, &built.geometries, unsafe { scratch.as_raw() })
                    .unwrap();
            }
            rec.submit_and_wait().unwrap();
            let what = format!("{kind:?}, wide: {wide}");
            let (a, b) = (
                built.g.structure().download().unwrap(),
                dst.structure().download().unwrap(),
            );
            assert_eq!(a, b, "{what}");
            let want = trace(&ctx, kind, wide, &built.g, &rays);
            assert_eq!(trace(&ctx, kind, wide, &dst, &rays), want, "{what}");
            assert!(
                want.iter().filter(|h| h[1] != u32::MAX).count() > 100,
                "{what}"
            );
        }
    }
    common::assert_silent(&ctx);
}

#[test]
fn compaction_refuses_what_it_cannot_renumber() {
    let Some(ctx) = common::context() else { return };
    let mut rng = common::Rng(3);
    let tris = triangles(500, &mut rng);
    let usage = |r: Result<(), GpuError>, what: &str| match r {
        Err(GpuError::Usage { .. }) => {}
        other => panic!("{what}: {other:?}"),
    };
    let flags = BuildFlags::default();
    let built = build(&ctx, AccelKind::Ploc, &tris, &flags);
    let size = compacted_size(&ctx, &built.g);
    assert!(size.scratch_bytes > 0);
    let memory = arena(&ctx, "caller.compacted", size.bytes);
    let mut dst = built
        .g
        .create_compacted_in(&ctx, &size, unsafe { memory.as_raw() })
        .unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    // Without scratch, or with too little.
    usage(
        built.g.record_compact_into(&mut rec, &mut dst, None),
        "no scratch",
    );
    let scratch = arena(&ctx, "caller.scratch", size.scratch_bytes);
    let short = unsafe {
        RawBuffer::new(
            scratch.as_raw().buffer(),
            scratch.as_raw().offset(),
            size.scratch_bytes - 4,
        )
    };
    match built.g.record_compact_into(&mut rec, &mut dst, Some(short)) {
        Err(GpuError::Placement { .. }) => {}
        other => panic!("too little scratch: {other:?}"),
    }
    // A size that was not this structure's.
    let other = CompactedSize {
        refs: size.refs + 1,
        ..size
    };
    usage(
        built
            .g
            .create_compacted_in(&ctx, &other, unsafe { memory.as_raw() })
            .map(drop),
        "another structure's size",
    );
    // A build into the compacted structure (an update of one not built to be updated is
    // refused as the original's is).
    let builder = AccelBuilder::new(&ctx, AccelKind::Ploc).unwrap();
    usage(
        builder.record_build_from(&mut rec, &mut dst, &built.geometries, unsafe {
            scratch.as_raw()
        }),
        "a build into a compacted structure",
    );
    let update = builder.record_update_from(&mut rec, &mut dst, &built.geometries, unsafe {
        scratch.as_raw()
    });
    assert!(
        matches!(update, Err(GpuError::NotBuilt { .. })),
        "an update of a structure not built to be updated: {update:?}"
    );
    drop(rec);
    common::assert_silent(&ctx);
}
