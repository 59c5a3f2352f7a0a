//! Frames of an animation on the device (`vkrt::render::gpu::FrameLoop`): every frame,
//! rendered in one submission after its primitives moved where they lie and its structure
//! was rebuilt or refit, equals the single render of the scene at that frame's time, bit for
//! bit, on every structure and update mode; a kd-tree cannot be refit.

mod common;

use std::path::Path;

use common::{assert_silent, context};
use vkrt::accel::device::{AccelChoice, AccelKind};
use vkrt::accel::driver::Prefer;
use vkrt::accel::walk::Traversal;
use vkrt::gpu::Context;
use vkrt::render::gpu::{FrameLoop, Renderer, Update};
use vkrt::render::{Plan, RenderAccel, RenderOptions, RenderScene};
use vkrt::scene::Scene;
use vkrt::trace::TraceOptions;

/// The motion-blur example with its shutter closed: its meshes and sphere move from frame to
/// frame, each frame sharp.
fn moving_scene() -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/motion_blur.toml");
    let mut s = Scene::load(&path).unwrap().scene;
    s.camera.shutter_close = s.camera.shutter_open;
    s
}

/// `scene` at `time`: what a frame renders.
fn at(scene: &Scene, time: f32) -> Scene {
    let mut s = scene.clone();
    s.camera.shutter_open += time;
    s.camera.shutter_close += time;
    s
}

fn options(accel: AccelChoice, spp: u32) -> RenderOptions {
    RenderOptions {
        width: Some(48),
        height: Some(36),
        spp: Some(spp),
        all_effects: false,
        accel,
        flatten: false,
        max_level_primitives: None,
    }
}

/// The plan of `scene` as one structure, with `opt`'s other settings.
fn flat_plan(scene: &Scene, opt: RenderOptions) -> Plan {
    let plan = Plan::new(
        scene,
        &RenderOptions {
            flatten: true,
            ..opt
        },
    )
    .unwrap();
    assert_eq!(plan.levels, 1);
    plan
}

/// Channels of two 8-bit images that differ by more than 1/255.
fn channels_off(a: &[u8], b: &[u8]) -> usize {
    a.iter().zip(b).filter(|(x, y)| x.abs_diff(**y) > 1).count()
}

fn flatten(scene: &Scene, plan: &Plan, accel: AccelChoice) -> RenderScene {
    RenderScene::new(scene, plan, |_| Ok::<_, ()>(RenderAccel::OnDevice(accel))).unwrap()
}

fn choices(ctx: &Context) -> Vec<(AccelChoice, Update)> {
    let mut v = vec![
        (
            AccelChoice::new(AccelKind::KdTree, Traversal::Stack),
            Update::Rebuild,
        ),
        (
            AccelChoice::new(AccelKind::SahBvh, Traversal::Stack),
            Update::Rebuild,
        ),
        (
            AccelChoice::new(AccelKind::SahBvh, Traversal::Bitstack),
            Update::Refit,
        ),
        (
            AccelChoice::new(AccelKind::Lbvh, Traversal::Stack),
            Update::Rebuild,
        ),
        (
            AccelChoice::new(AccelKind::Lbvh, Traversal::Bitstack),
            Update::Refit,
        ),
        (
            AccelChoice::new(AccelKind::Ploc, Traversal::Stack),
            Update::Refit,
        ),
    ];
    if ctx.info().features.ray_query {
        v.push((AccelChoice::driver(Prefer::FastBuild), Update::Rebuild));
        v.push((AccelChoice::driver(Prefer::FastTrace), Update::Refit));
    }
    v
}

#[test]
fn every_frame_equals_the_single_render_at_its_time() {
    let Some(ctx) = context() else { return };
    let scene = moving_scene();
    let spp = 2;
    for (accel, update) in choices(&ctx) {
        let what = format!("{} {}", accel.label(), update.name());
        let plan = Plan::new(&scene, &options(accel, spp)).unwrap();
        let renderer = Renderer::new(&ctx, &plan, &TraceOptions::default()).unwrap();
        let mut frames = FrameLoop::new(&ctx, &renderer, &plan, accel, update).unwrap();
        let mut previous: Option<Vec<u8>> = None;
        for k in 0..4 {
            let s = at(&scene, 0.3 * k as f32);
            let rs = flatten(&s, &plan, accel);
            let frame = frames.render(&ctx, &rs, &plan).unwrap();
            let single = renderer.render(&ctx, &rs, &plan, |_| {}).unwrap();
            assert!(frame.rgba == single.rgba, "{what}: frame {k} differs");
            assert_eq!(frame.counts, single.counts, "{what}: frame {k}");
            // One submission; back come the image, the counters (and a kd-tree's report).
            assert_eq!(frame.redone, 0, "{what}");
            assert_eq!(frame.traffic.submits, 1, "{what}: frame {k}");
            let report = if accel.kind == AccelKind::KdTree {
                16
            } else {
                0
            };
            let counters = 4 * vkrt::render::types::counter::WORDS as u64;
            assert_eq!(
                frame.traffic.readback_bytes,
                frame.rgba.len() as u64 + counters + report,
                "{what}: frame {k}"
            );
            assert_eq!(frame.built, k == 0 || update == Update::Rebuild, "{what}");
            assert!(frame.update_ms > 0.0, "{what}: frame {k}");
            assert!(frame.render_ms > 0.0, "{what}: frame {k}");
            if let Some(p) = &previous {
                assert!(p != &frame.rgba, "{what}: frame {k} did not move");
            }
            previous = Some(frame.rgba);
        }
    }
    assert_silent(&ctx);
}

#[test]
fn a_kd_tree_cannot_be_refit() {
    let Some(ctx) = context() else { return };
    let scene = moving_scene();
    let accel = AccelChoice::new(AccelKind::KdTree, Traversal::Stack);
    let plan = Plan::new(&scene, &options(accel, 1)).unwrap();
    let renderer = Renderer::new(&ctx, &plan, &TraceOptions::default()).unwrap();
    let Err(err) = FrameLoop::new(&ctx, &renderer, &plan, accel, Update::Refit) else {
        panic!("a kd-tree refit");
    };
    assert!(err.to_string().contains("cannot be refit"), "{err}");
    assert_silent(&ctx);
}

/// Kolodzey's dynamic demo (24 icospheres orbiting a turning bunny in a room) as an
/// animation: over two levels every later frame refits or rebuilds the top level only (the
/// 26 instances), and each frame equals the single two-level render of its time bit for bit
/// (the hits do not depend on the top level's tree), and the flat render of its time but for
/// rounding: the two-level walk intersects in object space (t and the barycentrics round
/// differently, within about 1e-6 relative), which moves a reflection or a shadow edge by a
/// pixel here and there.
#[test]
fn two_level_frames_update_the_top_level_and_match_the_flat_renders() {
    let Some(ctx) = context() else { return };
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/dynamic_demo.toml");
    let scene = Scene::load(&path).unwrap().scene;
    let cases = [
        (
            AccelChoice::new(AccelKind::Lbvh, Traversal::Stack),
            Update::Refit,
        ),
        (
            AccelChoice::new(AccelKind::SahBvh, Traversal::Wide),
            Update::Rebuild,
        ),
        // a kd-tree bottom level is never refit: only the top level is
        (
            AccelChoice::new(AccelKind::KdTree, Traversal::Stack),
            Update::Refit,
        ),
        (
            AccelChoice::new(AccelKind::Ploc, Traversal::Bitstack),
            Update::Refit,
        ),
        // the driver's own levels: its TLAS rebuilt over the moved instances, BLASes kept
        (AccelChoice::driver(Prefer::FastTrace), Update::Refit),
    ];
    for (accel, update) in cases {
        if accel.kind == AccelKind::Driver && !ctx.info().features.ray_query {
            eprintln!(
                "skipped the driver's levels: {} has no ray query",
                ctx.info().driver
            );
            continue;
        }
        let what = format!("{} {}", accel.label(), update.name());
        let plan = Plan::new(&scene, &options(accel, 1)).unwrap();
        assert_eq!(plan.levels, 2, "{what}: the demo's spheres repeat");
        let flat_plan = flat_plan(&scene, options(accel, 1));
        let renderer = Renderer::new(&ctx, &plan, &TraceOptions::default()).unwrap();
        let flat_renderer = Renderer::new(&ctx, &flat_plan, &TraceOptions::default()).unwrap();
        let mut frames = FrameLoop::new(&ctx, &renderer, &plan, accel, update).unwrap();
        for k in [0, 6, 12] {
            let s = scene.at_frame(k);
            let rs = RenderScene::on_device(&s, &plan);
            let two = &rs.levels.as_ref().expect("two levels").scene;
            assert_eq!(two.mesh_instances(), 25, "{what}: 24 spheres and the bunny");
            let frame = frames.render(&ctx, &rs, &plan).unwrap();
            let single = renderer.render(&ctx, &rs, &plan, |_| {}).unwrap();
            assert!(frame.rgba == single.rgba, "{what}: frame {k} differs");
            assert_eq!(frame.counts, single.counts, "{what}: frame {k}");
            assert_eq!(frame.counts.exhausted, 0, "{what}: frame {k}");
            assert_eq!(frame.built, k == 0 || update == Update::Rebuild, "{what}");
            assert!(frame.update_ms > 0.0, "{what}: frame {k}");
            assert_eq!(frame.traffic.submits, 1, "{what}: frame {k}");
            let flat_rs = RenderScene::on_device(&s, &flat_plan);
            assert!(flat_rs.levels.is_none());
            let flat = flat_renderer
                .render(&ctx, &flat_rs, &flat_plan, |_| {})
                .unwrap();
            let n = frame.rgba.len();
            let off = channels_off(&frame.rgba, &flat.rgba);
            eprintln!("{what}: frame {k}: {off} of {n} channels differ from flat by > 1/255");
            assert!(
                off * 200 <= n,
                "{what}: frame {k}: {off} of {n} channels off"
            );
        }
    }
    assert_silent(&ctx);
}

/// The dynamic demo with an open shutter (the ring turns 4.5° while it is open): over two
/// levels the moving spheres' instances move in time steps (one per degree, interpolated at
/// each ray's time), and every frame, refit from the last, equals the single two-level render
/// of its time bit for bit and the flat motion-blurred render (whose triangles turn exactly)
/// but for rounding and the steps' chords.
#[test]
fn motion_blurred_instances_match_the_flat_motion_blur() {
    let Some(ctx) = context() else { return };
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/dynamic_demo.toml");
    let mut scene = Scene::load(&path).unwrap().scene;
    scene.camera.shutter_close = 0.1;
    let accel = AccelChoice::new(AccelKind::Lbvh, Traversal::Stack);
    let plan = Plan::new(&scene, &options(accel, 4)).unwrap();
    assert!(plan.motion, "the demo blurs with an open shutter");
    assert_eq!(plan.levels, 2);
    let flat_plan = flat_plan(&scene, options(accel, 4));
    let renderer = Renderer::new(&ctx, &plan, &TraceOptions::default()).unwrap();
    let flat_renderer = Renderer::new(&ctx, &flat_plan, &TraceOptions::default()).unwrap();
    let mut frames = FrameLoop::new(&ctx, &renderer, &plan, accel, Update::Refit).unwrap();
    for k in [0, 6] {
        let s = scene.at_frame(k);
        let rs = RenderScene::on_device(&s, &plan);
        let levels = rs.levels.as_ref().expect("two levels");
        // 45°/s for 0.1 s: 4.5°, five steps of at most 1°.
        assert_eq!(levels.motion.steps, 6, "frame {k}");
        let frame = frames.render(&ctx, &rs, &plan).unwrap();
        let single = renderer.render(&ctx, &rs, &plan, |_| {}).unwrap();
        assert!(frame.rgba == single.rgba, "frame {k} differs");
        assert_eq!(frame.counts.exhausted, 0, "frame {k}");
        let flat_rs = RenderScene::on_device(&s, &flat_plan);
        let flat = flat_renderer
            .render(&ctx, &flat_rs, &flat_plan, |_| {})
            .unwrap();
        let still = renderer
            .render(
                &ctx,
                &RenderScene::on_device(&scene_still(&s), &plan),
                &plan,
                |_| {},
            )
            .unwrap();
        let n = frame.rgba.len();
        let off = channels_off;
        let (blur_off, still_off) = (off(&frame.rgba, &flat.rgba), off(&still.rgba, &flat.rgba));
        eprintln!(
            "frame {k}: {blur_off} of {n} channels differ from the flat blur by > 1/255 \
             ({still_off} for the unblurred frame)"
        );
        assert!(
            blur_off * 200 <= n,
            "frame {k}: {blur_off} of {n} channels off"
        );
        // The blur shows: the unblurred frame differs from the flat blur far more.
        assert!(
            still_off > 4 * blur_off.max(10),
            "frame {k}: {still_off} vs {blur_off}"
        );
    }
    assert_silent(&ctx);
}

/// Moving analytic spheres over two levels: each an instance of a bottom level holding one
/// sphere at the origin (one level per radius, shared), moved from frame to frame and in time
/// steps over an open shutter. Frames refit from the last equal the single render of their
/// time bit for bit, and the flat renders (whose spheres move exactly) but for rounding and
/// the orbit's chords; the still sphere stays in the world.
#[test]
fn moving_spheres_are_instances_that_match_the_flat_renders() {
    use vkrt::accel::two_levels::REST;
    use vkrt::scene::{Motion, Orbit, Sphere};
    let Some(ctx) = context() else { return };
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/dynamic_demo.toml");
    let mut scene = Scene::load(&path).unwrap().scene;
    let material = scene.spheres.first().map_or(0, |s| s.material);
    let ball = |x: f32, radius: f32, motion: Motion| Sphere {
        motion,
        ..Sphere::new(glam::Vec3::new(x, 0.5, 1.0), radius, material)
    };
    let sliding = Motion {
        velocity: glam::Vec3::new(0.0, 0.0, 2.0),
        orbit: None,
    };
    let circling = Motion {
        velocity: glam::Vec3::ZERO,
        orbit: Some(Orbit {
            center: glam::Vec3::ZERO,
            axis: glam::Vec3::Y,
            degrees_per_second: 60.0,
        }),
    };
    let first_sphere = scene.spheres.len();
    scene.spheres.extend([
        ball(-1.0, 0.3, sliding),
        ball(1.0, 0.3, circling),
        ball(0.0, 0.2, Motion::STATIC),
    ]);
    let accel = AccelChoice::new(AccelKind::Lbvh, Traversal::Stack);
    for shutter in [0.0, 0.05] {
        let mut scene = scene.clone();
        scene.camera.shutter_close = scene.camera.shutter_open + shutter;
        let plan = Plan::new(&scene, &options(accel, 2)).unwrap();
        assert_eq!(plan.levels, 2, "moving spheres no longer flatten the scene");
        let flat_plan = flat_plan(&scene, options(accel, 2));
        let renderer = Renderer::new(&ctx, &plan, &TraceOptions::default()).unwrap();
        let flat_renderer = Renderer::new(&ctx, &flat_plan, &TraceOptions::default()).unwrap();
        let mut frames = FrameLoop::new(&ctx, &renderer, &plan, accel, Update::Refit).unwrap();
        for k in [0, 6] {
            let s = scene.at_frame(k);
            let rs = RenderScene::on_device(&s, &plan);
            let two = &rs.levels.as_ref().expect("two levels").scene;
            // The two moving spheres are instances of one level (their radius), each naming
            // its sphere; the still one stays in the rest.
            let sphere_ids = |c: u32| two.piece_ids(REST - c).unwrap_or_default().to_vec();
            let n_tris = s.triangle_count() as u32;
            let movers: Vec<u32> = (0..two.rest_first.len() as u32)
                .filter(|&c| {
                    let inst = two.instances.iter().find(|i| i.custom_index() == REST - c);
                    inst.is_some_and(|i| two.bottoms[i.bottom as usize].triangle_count() == 0)
                })
                .flat_map(sphere_ids)
                .collect();
            let want = [0, 1].map(|j| n_tris + (first_sphere + j) as u32);
            assert_eq!(movers, want, "shutter {shutter}: frame {k}");
            let frame = frames.render(&ctx, &rs, &plan).unwrap();
            let single = renderer.render(&ctx, &rs, &plan, |_| {}).unwrap();
            assert!(
                frame.rgba == single.rgba,
                "shutter {shutter}: frame {k} differs"
            );
            assert_eq!(frame.counts.exhausted, 0);
            let flat_rs = RenderScene::on_device(&s, &flat_plan);
            let flat = flat_renderer
                .render(&ctx, &flat_rs, &flat_plan, |_| {})
                .unwrap();
            let n = frame.rgba.len();
            let off = channels_off(&frame.rgba, &flat.rgba);
            eprintln!("shutter {shutter}: frame {k}: {off} of {n} channels differ from flat");
            assert!(
                off * 200 <= n,
                "shutter {shutter}: frame {k}: {off} of {n} off"
            );
            // The spheres are in view: without them the image is another.
            let mut without = s.clone();
            without.spheres.truncate(first_sphere);
            let bare_plan = Plan::new(&without, &options(accel, 2)).unwrap();
            let bare = Renderer::new(&ctx, &bare_plan, &TraceOptions::default())
                .unwrap()
                .render(
                    &ctx,
                    &RenderScene::on_device(&without, &bare_plan),
                    &bare_plan,
                    |_| {},
                )
                .unwrap();
            let seen = frame
                .rgba
                .iter()
                .zip(&bare.rgba)
                .filter(|(a, b)| a != b)
                .count();
            assert!(
                seen > 20 * off.max(10),
                "shutter {shutter}: frame {k}: {seen} channels"
            );
        }
    }
    assert_silent(&ctx);
}

/// `scene` with its shutter closed.
fn scene_still(scene: &Scene) -> Scene {
    let mut s = scene.clone();
    s.camera.shutter_close = s.camera.shutter_open;
    s
}
