//! Two levels against one: the Stanford bunny (../shared/scenes) as one bottom level (PLOC,
//! built from a device buffer in memory the caller allocates), instanced on a square grid
//! (64 and 1,024 copies, each turned about its vertical axis and scaled), under a top level
//! (LBVH over the instances' boxes), against the bunny alone and against Embree 3 with
//! instancing (`RTC_GEOMETRY_TYPE_INSTANCE`, 2 threads) on the same rays.
//!
//! Per scene: the top level's build (GPU ms of `accel.instance_boxes` and the tree, best of
//! 3), its bytes and the bottom level's, the bytes a flat structure over every copy would
//! need, and closest hits of `--size`² primary rays from a camera framing the scene
//! (`gpu.handle_probe` through `vkrt/ray_query.glsl` at device addresses: GPU ms, best of
//! 3 interleaved rounds), as Mrays/s, ÷ the bunny alone, and ÷ Embree's.
//!
//! Then the dynamic demo (`scenes/dynamic_demo.toml`: a room, a bunny turning on keyframes,
//! 24 orbiting copies of one icosphere) per frame: the update as two levels (the 25
//! instances' records written and the top level refit, `TopLevelBuilder::record_update_from`;
//! the bottom levels do not change) against the flat
//! scene's (its moved triangles uploaded and the LBVH rebuilt, or refit), GPU ms, best of 3
//! per frame over 8 frames.
//!
//! `cargo bench --bench instances [-- --json] [-- --quick] [-- --size N]` (`--quick`: 64
//! copies only, 128² rays)

#[path = "common/args.rs"]
mod args;
#[path = "embree/peer.rs"]
mod embree;

use glam::{Affine3A, Quat, Vec3};
use vkrt::accel::device::{AccelBuilder, AccelKind};
use vkrt::accel::embedded::BuildFlags;
use vkrt::accel::geometry::{Geometry, Triangles};
use vkrt::accel::gpu_geometry::GpuGeometry;
use vkrt::accel::instances::{Instance, TopLevel, TopLevelBuilder};
use vkrt::gpu::{kernels, Buffer, BufferArg, Context, Recorder, Spec};
use vkrt::trace::Ray;

#[derive(serde::Serialize)]
struct UpdateRow {
    frames: u32,
    instances: usize,
    triangles: usize,
    /// Mean GPU ms per frame: the two-level update, the flat LBVH's rebuild and refit (each
    /// with its upload of the moved data).
    two_level_ms: f64,
    flat_rebuild_ms: f64,
    flat_refit_ms: f64,
    rebuild_over_two_level: f64,
    refit_over_two_level: f64,
}

#[derive(serde::Serialize)]
struct Row {
    scene: String,
    instances: usize,
    triangles: usize,
    top_build_ms: f64,
    top_bytes: u64,
    bottom_bytes: u64,
    /// A flat structure over every copy (`None`: more than this device can bind).
    flat_bytes: Option<u64>,
    rays: usize,
    hits: usize,
    trace_ms: f64,
    mrays_per_s: f64,
    /// This scene's rate ÷ the bunny alone's.
    vs_one_bunny: f64,
    embree_top_build_ms: Option<f64>,
    embree_mrays_per_s: Option<f64>,
    /// vkrt's rate ÷ Embree's.
    vs_embree: Option<f64>,
}

/// `side`² copies of a mesh of extent `size`, on a grid in the x-y plane, each turned
/// about y and scaled by 0.8–1.2 (deterministic).
fn grid(side: usize, size: f32) -> Vec<[[f32; 4]; 3]> {
    let mut state = 0x9e37_79b9_7f4a_7c15_u64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    let mut out = Vec::new();
    for j in 0..side {
        for i in 0..side {
            let angle = next() * std::f32::consts::TAU;
            let scale = 0.8 + 0.4 * next();
            let at = Vec3::new(i as f32, j as f32, 0.0) * size * 1.3;
            let a = Affine3A::from_scale_rotation_translation(
                Vec3::splat(scale),
                Quat::from_rotation_y(angle),
                at,
            );
            out.push(Instance::rows_of(&a));
        }
    }
    out
}

/// `n`² pinhole rays from +z looking at the box `[lo, hi]`'s centre, framing it.
fn camera_rays(lo: Vec3, hi: Vec3, n: u32) -> Vec<Ray> {
    let c = (lo + hi) * 0.5;
    let half = (hi - lo).max_element() * 0.55;
    let eye = c + Vec3::Z * half * 3.0;
    let mut rays = Vec::with_capacity((n * n) as usize);
    for y in 0..n {
        for x in 0..n {
            let u = ((x as f32 + 0.5) / n as f32 * 2.0 - 1.0) * half;
            let v = ((y as f32 + 0.5) / n as f32 * 2.0 - 1.0) * half;
            let target = Vec3::new(c.x + u, c.y + v, c.z);
            rays.push(Ray::new(eye, target - eye, 0.0, f32::INFINITY));
        }
    }
    rays
}

fn bounds(points: impl Iterator<Item = Vec3>) -> (Vec3, Vec3) {
    points.fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), p| (lo.min(p), hi.max(p)),
    )
}

/// The bunny's PLOC in memory this bench allocates, from its vertices in a device buffer.
fn bottom(ctx: &Context, tris: &[[Vec3; 3]]) -> (GpuGeometry, u64, Vec<Buffer<u8>>, Buffer<Vec3>) {
    let flat: Vec<Vec3> = tris.iter().flatten().copied().collect();
    let vertices = Buffer::from_slice(ctx, "renderer.vertices", &flat).unwrap();
    let geometry = [Geometry::Triangles(Triangles::soup(
        unsafe { vertices.as_raw() },
        flat.len() as u32,
    ))];
    let builder = AccelBuilder::new(ctx, AccelKind::Ploc).unwrap();
    let flags = BuildFlags::default();
    let sizes = builder.sizes_for(ctx, &geometry, &flags).unwrap();
    let memory = Buffer::<u8>::arena(ctx, "bench.bottom", sizes.structure_bytes as usize).unwrap();
    let scratch =
        Buffer::<u8>::arena(ctx, "bench.scratch", sizes.build_scratch_bytes as usize).unwrap();
    let mut g = builder
        .create_in(ctx, &geometry, &flags, unsafe { memory.as_raw() })
        .unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    builder
        .record_build_from(&mut rec, &mut g, &geometry, unsafe { scratch.as_raw() })
        .unwrap();
    rec.submit_and_wait().unwrap();
    (g, sizes.structure_bytes, vec![memory, scratch], vertices)
}

/// Bytes of one flat structure over `copies` copies of `tris` (PLOC), if the device can
/// place it.
fn flat_bytes(ctx: &Context, tris: usize, copies: usize) -> Option<u64> {
    let n = (tris * copies * 3) as u32;
    let vertices = Buffer::<Vec3>::new(ctx, "bench.flat", 3).unwrap();
    let raw = unsafe {
        vkrt::gpu::RawBuffer::new(
            vertices.as_raw().buffer(),
            vertices.as_raw().offset(),
            12 * u64::from(n),
        )
    };
    let geometry = [Geometry::Triangles(Triangles::soup(raw, n))];
    let builder = AccelBuilder::new(ctx, AccelKind::Ploc).unwrap();
    builder
        .sizes_for(ctx, &geometry, &BuildFlags::default())
        .ok()
        .map(|s| s.structure_bytes)
}

/// The top level over `transforms`, built in this bench's memory; its bytes and the
/// best GPU ms of 3 rebuilds.
fn top_level(
    ctx: &Context,
    bottom: &GpuGeometry,
    transforms: &[[[f32; 4]; 3]],
) -> (TopLevel, u64, f64, Vec<Buffer<u8>>, Buffer<Instance>) {
    let instances: Vec<Instance> = transforms.iter().map(|m| Instance::new(0, *m)).collect();
    let builder = TopLevelBuilder::new(ctx, AccelKind::Lbvh).unwrap();
    let flags = BuildFlags::default();
    let n = instances.len() as u32;
    let sizes = builder.sizes_for(ctx, n, 1, &flags).unwrap();
    let memory = Buffer::<u8>::arena(ctx, "bench.top", sizes.structure_bytes as usize).unwrap();
    let scratch =
        Buffer::<u8>::arena(ctx, "bench.top_scratch", sizes.build_scratch_bytes as usize).unwrap();
    let input = Buffer::from_slice(ctx, "renderer.instances", &instances).unwrap();
    let mut top = builder
        .create_in(ctx, &[bottom], n, &flags, unsafe { memory.as_raw() })
        .unwrap();
    let mut best = f64::INFINITY;
    for round in 0..4 {
        let mut rec = Recorder::new(ctx).unwrap();
        builder
            .record_build_from(&mut rec, &mut top, unsafe { input.as_raw() }, n, unsafe {
                scratch.as_raw()
            })
            .unwrap();
        let p = rec.submit_and_wait().unwrap();
        if round > 0 {
            best = best.min(p.ms("top level").unwrap_or(f64::NAN));
        }
    }
    (
        top,
        sizes.structure_bytes,
        best,
        vec![memory, scratch],
        input,
    )
}

/// Closest hits of each ray set through the structure at each handle: (hits, best GPU ms
/// of 3 interleaved rounds) per set.
fn trace(ctx: &Context, sets: &[(u64, &[Ray])]) -> Vec<(usize, f64)> {
    let kernel = ctx
        .kernel(
            &kernels::GPU_HANDLE_PROBE_ADDRESS,
            &Spec::new().workgroup(64),
        )
        .unwrap();
    let bufs: Vec<_> = sets
        .iter()
        .map(|(_, rays)| {
            (
                Buffer::from_slice(ctx, "probe.rays", rays).unwrap(),
                Buffer::<[u32; 4]>::zeroed(ctx, "probe.hits", rays.len()).unwrap(),
            )
        })
        .collect();
    let mut best = vec![f64::INFINITY; sets.len()];
    for round in 0..4 {
        let mut rec = Recorder::new(ctx).unwrap();
        for (k, ((handle, rays), (ray_buf, out))) in sets.iter().zip(&bufs).enumerate() {
            let push = [
                rays.len() as u32,
                0,
                *handle as u32,
                (*handle >> 32) as u32,
                0,
                0,
            ];
            let groups = rec.groups_1d(rays.len() as u64, 64);
            let b: [&dyn BufferArg; 2] = [ray_buf, out];
            rec.scope(&format!("set{k}"), |rec| {
                rec.dispatch(&kernel, groups, &b, &push)
            });
            rec.compute_to_compute();
        }
        let p = rec.submit_and_wait().unwrap();
        if round > 0 {
            for (k, b) in best.iter_mut().enumerate() {
                *b = b.min(p.ms(&format!("set{k}")).unwrap_or(f64::NAN));
            }
        }
    }
    bufs.iter()
        .zip(best)
        .map(|((_, out), ms)| {
            let hits = out.download().unwrap();
            assert!(hits.iter().all(|h| h[0] != 0xffff_fffe), "a walk gave up");
            (hits.iter().filter(|h| h[0] != u32::MAX).count(), ms)
        })
        .collect()
}

/// The dynamic demo's per-frame updates, two levels against flat (see the module docs).
fn dynamic_demo(ctx: &Context) -> Option<UpdateRow> {
    use vkrt::accel::two_levels::TwoLevelScene;
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/dynamic_demo.toml");
    let scene = vkrt::scene::Scene::load(&path).ok()?.scene;
    let anim = scene.animation?;
    let frames = 8.min(anim.frames);
    let two = TwoLevelScene::of(&scene, 0.0)?;
    // Two levels: bottom levels built once, the top level built at frame 0 to be updated.
    let builder = AccelBuilder::new(ctx, AccelKind::Lbvh).unwrap();
    let levels: Vec<GpuGeometry> = two
        .bottoms
        .iter()
        .map(|g| {
            let mut rec = Recorder::new(ctx).unwrap();
            let (l, _) = GpuGeometry::record_build(&mut rec, &builder, g, 0).unwrap();
            rec.submit_and_wait().unwrap();
            l
        })
        .collect();
    let refs: Vec<&GpuGeometry> = levels.iter().collect();
    let top_builder = TopLevelBuilder::new(ctx, AccelKind::Lbvh).unwrap();
    let flags = BuildFlags {
        allow_update: true,
        ..BuildFlags::default()
    };
    let n = two.instances.len() as u32;
    let sizes = top_builder.sizes_for(ctx, n, refs.len(), &flags).unwrap();
    let memory = Buffer::<u8>::arena(ctx, "bench.top", sizes.structure_bytes as usize).unwrap();
    let scratch_bytes = sizes
        .build_scratch_bytes
        .max(sizes.update_scratch_bytes.unwrap());
    let scratch = Buffer::<u8>::arena(ctx, "bench.top_scratch", scratch_bytes as usize).unwrap();
    let input = Buffer::from_slice(ctx, "renderer.instances", &two.instances).unwrap();
    let mut top = top_builder
        .create_in(ctx, &refs, n, &flags, unsafe { memory.as_raw() })
        .unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    top_builder
        .record_build_from(&mut rec, &mut top, unsafe { input.as_raw() }, n, unsafe {
            scratch.as_raw()
        })
        .unwrap();
    rec.submit_and_wait().unwrap();
    // Flat: the LBVH over every triangle, built at frame 0 to be refit.
    let mut flat_builder = AccelBuilder::new(ctx, AccelKind::Lbvh).unwrap();
    flat_builder = flat_builder.with_allow_update(true);
    let g0 = vkrt::accel::primitives::TraceGeometry::at_time(&scene, 0.0);
    let mut rec = Recorder::new(ctx).unwrap();
    let (mut flat, _) = GpuGeometry::record_build(&mut rec, &flat_builder, &g0, 0).unwrap();
    rec.submit_and_wait().unwrap();
    let visits = flat_builder
        .update_scratch(ctx, g0.primitive_count())
        .unwrap()
        .unwrap();
    let best = |f: &mut dyn FnMut(&mut Recorder)| -> f64 {
        (0..3)
            .map(|_| {
                let mut rec = Recorder::new(ctx).unwrap();
                rec.begin_scope("all");
                f(&mut rec);
                rec.end_scope();
                rec.submit_and_wait().unwrap().ms("all").unwrap_or(f64::NAN)
            })
            .fold(f64::INFINITY, f64::min)
    };
    let (mut two_ms, mut rebuild_ms, mut refit_ms) = (0.0, 0.0, 0.0);
    for k in 1..=frames {
        let t = anim.frame_time(k);
        let moved = TwoLevelScene::of(&scene, t)?.instances;
        two_ms += best(&mut |rec| {
            rec.upload(&input, &moved).unwrap();
            rec.transfer_to_compute();
            top_builder
                .record_update_from(rec, &mut top, unsafe { input.as_raw() }, unsafe {
                    scratch.as_raw()
                })
                .unwrap();
        });
        let g = vkrt::accel::primitives::TraceGeometry::at_time(&scene, t);
        rebuild_ms += best(&mut |rec| {
            let (built, _) = GpuGeometry::record_build(rec, &builder, &g, 0).unwrap();
            rec.keep_alive(built);
        });
        refit_ms += best(&mut |rec| {
            flat.primitives().record_update(rec, &g).unwrap();
            flat_builder.record_refit(rec, &mut flat, &visits).unwrap();
        });
    }
    let f = f64::from(frames);
    Some(UpdateRow {
        frames,
        instances: two.mesh_instances(),
        triangles: g0.primitive_count(),
        two_level_ms: two_ms / f,
        flat_rebuild_ms: rebuild_ms / f,
        flat_refit_ms: refit_ms / f,
        rebuild_over_two_level: rebuild_ms / two_ms,
        refit_over_two_level: refit_ms / two_ms,
    })
}

fn main() {
    let a = args::parse();
    let size = if a.quick { 128 } else { a.size };
    let (ctx, embree) = embree::context_and_peer();
    let Some((_, tris)) = embree::bench_scenes(&[])
        .into_iter()
        .find(|(name, _)| name == "bunny")
    else {
        eprintln!("no bunny: nothing to measure");
        return;
    };
    let (bunny, bottom_bytes, _bottom_memory, _vertices) = bottom(&ctx, &tris);
    let handle = Buffer::from_slice(&ctx, "bench.handle", &bunny.handle_words().unwrap()).unwrap();
    let (lo, hi) = bounds(tris.iter().flatten().copied());
    let extent = (hi - lo).max_element();
    let sides: &[usize] = if a.quick { &[8] } else { &[8, 32] };

    // The bunny alone, then each grid: rays, and the structures they trace.
    let one = camera_rays(lo, hi, size);
    let mut grids = Vec::new();
    for &side in sides {
        let transforms = grid(side, extent);
        let corners = transforms.iter().flat_map(|m| {
            (0..8).map(move |k| {
                let p = Vec3::new(
                    if k & 1 != 0 { hi.x } else { lo.x },
                    if k & 2 != 0 { hi.y } else { lo.y },
                    if k & 4 != 0 { hi.z } else { lo.z },
                );
                vkrt::accel::geometry::transform_point(m, p)
            })
        });
        let (glo, ghi) = bounds(corners);
        grids.push((side, transforms.clone(), camera_rays(glo, ghi, size)));
    }
    let tops: Vec<_> = grids
        .iter()
        .map(|(_, transforms, _)| top_level(&ctx, &bunny, transforms))
        .collect();
    let mut sets: Vec<(u64, &[Ray])> = vec![(handle.device_address().unwrap(), &one[..])];
    for (top, (_, _, rays)) in tops.iter().zip(&grids) {
        sets.push((top.0.handle_address(), &rays[..]));
    }
    let traced = trace(&ctx, &sets);

    let mut rows = Vec::new();
    let base_rate = one.len() as f64 / (traced[0].1 * 1e3);
    let e_one = embree.as_ref().map(|e| e.run(&tris, 2, &[(&one, false)]));
    rows.push(Row {
        scene: "bunny".into(),
        instances: 1,
        triangles: tris.len(),
        top_build_ms: 0.0,
        top_bytes: 0,
        bottom_bytes,
        flat_bytes: Some(bottom_bytes),
        rays: one.len(),
        hits: traced[0].0,
        trace_ms: traced[0].1,
        mrays_per_s: base_rate,
        vs_one_bunny: 1.0,
        embree_top_build_ms: None,
        embree_mrays_per_s: e_one
            .as_ref()
            .map(|e| one.len() as f64 / (e.traces[0].1 * 1e3)),
        vs_embree: None,
    });
    for (k, ((side, transforms, rays), top)) in grids.iter().zip(&tops).enumerate() {
        let (hits, ms) = traced[k + 1];
        let rate = rays.len() as f64 / (ms * 1e3);
        let e = embree
            .as_ref()
            .map(|e| e.run_instanced(&tris, transforms, 2, &[(rays, false)]));
        if let Some(e) = &e {
            assert_eq!(e.traces[0].0, hits, "Embree and vkrt disagree on hits");
        }
        let n = side * side;
        rows.push(Row {
            scene: format!("{n} bunnies"),
            instances: n,
            triangles: n * tris.len(),
            top_build_ms: top.2,
            top_bytes: top.1,
            bottom_bytes,
            flat_bytes: flat_bytes(&ctx, tris.len(), n),
            rays: rays.len(),
            hits,
            trace_ms: ms,
            mrays_per_s: rate,
            vs_one_bunny: rate / base_rate,
            embree_top_build_ms: e.as_ref().map(|e| e.build_ms),
            embree_mrays_per_s: e
                .as_ref()
                .map(|e| rays.len() as f64 / (e.traces[0].1 * 1e3)),
            vs_embree: None,
        });
    }
    for r in &mut rows {
        r.vs_embree = r.embree_mrays_per_s.map(|e| r.mrays_per_s / e);
    }
    let update = dynamic_demo(&ctx);
    if a.json {
        let v = serde_json::json!({ "scenes": rows, "dynamic_demo": update });
        println!("{}", serde_json::to_string_pretty(&v).unwrap());
        return;
    }
    println!(
        "{:<14} {:>10} {:>9} {:>10} {:>10} {:>12} {:>8} {:>9} {:>8} {:>9} {:>8}",
        "scene",
        "triangles",
        "top ms",
        "top KiB",
        "bottom KiB",
        "flat KiB",
        "Mrays/s",
        "÷ bunny",
        "Embree",
        "top ms E",
        "÷ Embree"
    );
    let opt = |v: Option<f64>, p: usize| v.map_or("-".to_string(), |v| format!("{v:.p$}"));
    for r in &rows {
        println!(
            "{:<14} {:>10} {:>9.3} {:>10} {:>10} {:>12} {:>8.2} {:>9.2} {:>8} {:>9} {:>8}",
            r.scene,
            r.triangles,
            r.top_build_ms,
            r.top_bytes / 1024,
            r.bottom_bytes / 1024,
            r.flat_bytes
                .map_or("too large".to_string(), |b| (b / 1024).to_string()),
            r.mrays_per_s,
            r.vs_one_bunny,
            opt(r.embree_mrays_per_s, 2),
            opt(r.embree_top_build_ms, 3),
            opt(r.vs_embree, 2),
        );
    }
    println!(
        "{size}² primary rays per scene; vkrt: PLOC bottom level, LBVH top level, \
         vkrt/ray_query.glsl at device addresses (GPU ms, best of 3); Embree 3: 2 threads, \
         wall time"
    );
    if let Some(u) = update {
        println!(
            "\ndynamic demo, {} frames ({} instances, {} triangles), mean GPU ms per frame: \
             two levels (records + top-level refit) {:.3}; flat LBVH rebuild {:.3} ({:.1}×), \
             flat refit {:.3} ({:.1}×)",
            u.frames,
            u.instances,
            u.triangles,
            u.two_level_ms,
            u.flat_rebuild_ms,
            u.rebuild_over_two_level,
            u.flat_refit_ms,
            u.refit_over_two_level
        );
    }
}
