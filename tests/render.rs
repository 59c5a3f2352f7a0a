//! The renderer: GPU image vs its CPU twin for every effect's example scene, the plan
//! (passes that must not run, ray counts that must be zero, `--all-effects` bit-identical),
//! and the default scene.

mod common;

use std::path::Path;

use common::{assert_silent, context};
use glam::Vec3;
use vkrt::accel::device::{AccelChoice, AccelKind};
use vkrt::accel::driver::Prefer;
use vkrt::accel::host::HostStructure;
use vkrt::accel::kdtree::{breadth_first, SahParams};
use vkrt::accel::walk::Traversal;
use vkrt::gpu::Context;
use vkrt::render::gpu::{GpuRender, Renderer};
use vkrt::render::output::srgb8;
use vkrt::render::{cpu, Plan, RenderAccel, RenderOptions, RenderScene};
use vkrt::scene::{Light, Scene};
use vkrt::trace::TraceOptions;

fn scene_file(name: &str) -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(name);
    Scene::load(&path).unwrap().scene
}

/// Every effect's example scene and the samples per pixel its tests render.
const EFFECT_SCENES: [(&str, u32); 11] = [
    ("hard_shadows.toml", 1),
    ("soft_shadows.toml", 4),
    ("reflection.toml", 1),
    ("refraction.toml", 1),
    ("glossy.toml", 4),
    ("antialiasing.toml", 4),
    ("depth_of_field.toml", 4),
    ("motion_blur.toml", 4),
    ("ambient_occlusion.toml", 2),
    ("emission.toml", 2),
    ("mesh_file.toml", 1),
];

/// The structure [`prepare`] builds: the kd-tree on the host.
const KD_TREE: AccelChoice = AccelChoice {
    kind: AccelKind::KdTree,
    walk: Traversal::Stack,
    prefer: Prefer::FastTrace,
};

fn small(spp: u32) -> RenderOptions {
    RenderOptions {
        width: Some(64),
        height: Some(48),
        spp: Some(spp),
        all_effects: false,
        accel: KD_TREE,
        flatten: false,
        max_level_primitives: None,
    }
}

fn prepare(scene: &Scene, opt: &RenderOptions) -> (Plan, RenderScene) {
    let plan = Plan::new(scene, opt).unwrap();
    let rs = RenderScene::new(scene, &plan, |g| {
        Ok::<_, ()>(RenderAccel::Host(HostStructure::KdTree(
            breadth_first::build_boxes(&g.boxes, &SahParams::default()).0,
        )))
    })
    .unwrap();
    (plan, rs)
}

fn gpu_render(ctx: &Context, plan: &Plan, rs: &RenderScene) -> GpuRender {
    let r = Renderer::new(ctx, plan, &TraceOptions::default())
        .unwrap()
        .render(ctx, rs, plan, |_| {})
        .unwrap();
    assert_eq!(r.counts.exhausted, 0);
    assert_silent(ctx);
    r
}

/// GPU vs CPU twin per pixel, in 8-bit sRGB: the images may differ only where a
/// transcendental's last bit or a traversal tie flips a sample.
#[test]
fn every_effect_matches_the_cpu_twin() {
    let Some(ctx) = context() else { return };
    for (file, spp) in EFFECT_SCENES {
        let scene = scene_file(file);
        let (plan, rs) = prepare(&scene, &small(spp));
        let gpu = gpu_render(&ctx, &plan, &rs);
        let twin = cpu::render(&rs, &plan, &TraceOptions::default());
        assert_eq!(gpu.counts, twin.counts, "{file}: ray counts");
        let mut off = 0;
        let mut worst = 0i32;
        let mut lit = 0;
        for (i, (g, c)) in gpu.radiance.iter().zip(&twin.radiance).enumerate() {
            for ch in 0..3 {
                let (a, b) = (srgb8(g[ch]) as i32, srgb8(c[ch]) as i32);
                assert_eq!(gpu.rgba[4 * i + ch] as i32, a, "{file}: tone map pixel {i}");
                worst = worst.max((a - b).abs());
                if (a - b).abs() > 1 {
                    off += 1;
                }
                lit += (a > 8) as usize;
            }
        }
        let n = gpu.radiance.len() * 3;
        eprintln!("{file}: {off} of {n} channels differ by more than 1/255 (worst {worst})");
        assert!(
            off * 200 <= n,
            "{file}: {off} of {n} channels differ by more than 1/255 from the CPU twin"
        );
        assert!(
            lit * 10 > n,
            "{file}: image nearly black ({lit} of {n} lit channels)"
        );
    }
}

#[test]
fn the_plan_runs_only_what_the_scene_needs() {
    let Some(ctx) = context() else { return };
    // Diffuse + Phong and a point light: no secondary rays, one shadow ray per hit.
    let scene = scene_file("hard_shadows.toml");
    let (plan, rs) = prepare(&scene, &small(8));
    assert_eq!(
        plan.spp, 1,
        "nothing in this scene needs more than one sample"
    );
    assert!(!plan.bounces && !plan.reflection && !plan.refraction && !plan.glossy);
    assert!(!plan.thin_lens && !plan.jitter && !plan.motion);
    assert!(!plan.passes.contains(&"compact"));
    let r = gpu_render(&ctx, &plan, &rs);
    assert_eq!(r.counts.secondary(), 0);
    assert!(r.counts.shadow > 0);
    assert_eq!(r.counts.primary, 64 * 48);

    // No lights: no shadow pass at all.
    let mut dark = scene.clone();
    dark.lights.clear();
    let (plan, rs) = prepare(&dark, &small(1));
    assert!(!plan.passes.contains(&"shadow") && plan.shadow_slots == 0);
    let r = gpu_render(&ctx, &plan, &rs);
    assert_eq!(r.counts.shadow + r.counts.ambient_occlusion, 0);
    assert!(r.profile.ms("render.shadow").is_none());
}

#[test]
fn all_effects_forced_on_gives_the_same_image() {
    let Some(ctx) = context() else { return };
    let scene = scene_file("hard_shadows.toml");
    let (plan, rs) = prepare(&scene, &small(1));
    let forced_opt = RenderOptions {
        all_effects: true,
        ..small(1)
    };
    let (forced, rs_forced) = prepare(&scene, &forced_opt);
    assert!(forced.bounces && forced.refraction && forced.glossy && forced.thin_lens);
    assert!(forced.passes.len() > plan.passes.len());
    let a = gpu_render(&ctx, &plan, &rs);
    let b = gpu_render(&ctx, &forced, &rs_forced);
    assert_eq!(a.rgba, b.rgba, "--all-effects changed the image");
    let bits =
        |r: &GpuRender| -> Vec<u32> { r.radiance.iter().flatten().map(|x| x.to_bits()).collect() };
    assert_eq!(bits(&a), bits(&b), "--all-effects changed the radiance");
    assert!(
        b.profile.ms("render.compact").is_some(),
        "forced passes must run"
    );
}

#[test]
fn default_scene_renders() {
    let Some(ctx) = context() else { return };
    let scene = Scene::default_scene();
    let r =
        vkrt::render::render_scene(&ctx, &scene, &small(2), &TraceOptions::default(), |_, _| {})
            .unwrap();
    assert_silent(&ctx);
    let lit = r
        .image
        .rgba
        .chunks(4)
        .filter(|p| p[0] > 20 || p[1] > 20)
        .count();
    assert!(
        lit * 2 > 64 * 48,
        "default scene mostly black: {lit} lit pixels"
    );
    assert!(r.image.counts.reflection > 0 && r.image.counts.refraction > 0);
    assert!(r.passes.iter().any(|p| p.name == "shadow" && p.rays > 0));
}

/// A wave whose children outgrow the queue stops, and the sample is redone with smaller
/// waves: the image is the same as with room to spare (waves never change the image).
#[test]
fn queue_overflow_redoes_the_sample_with_the_same_result() {
    let Some(ctx) = context() else { return };
    // Glass and a mirror make the queue grow; two bounces bound a pixel's tree by 4 rays.
    let mut scene = Scene::default_scene();
    scene.settings.max_depth = 2;
    let (plan, rs) = prepare(&scene, &small(2));
    let roomy = gpu_render(&ctx, &plan, &rs);
    let mut tight = plan.clone();
    // 16 pixels per wave fill a 16-ray queue; the waves over the glass sphere overflow.
    tight.queue_capacity = 16;
    tight.wave_pixels = 16;
    let retried = gpu_render(&ctx, &tight, &rs);
    assert_eq!(roomy.rgba, retried.rgba);
    assert_eq!(roomy.counts, retried.counts);
    assert_eq!(roomy.redone_samples, 0);
    assert!(retried.redone_samples > 0, "the overflow path did not run");
}

/// One renderer serves every structure: Sochora's (2013) BVH, walked with a stack or the
/// bitstack, gives the kd-tree's image byte for byte (the closest hit is the same hit, ties
/// to the lowest id), and its CPU twin counts the same rays.
#[test]
fn the_bvh_renders_the_kdtree_image() {
    use vkrt::accel::bvh::{self, BvhParams, Threading};
    use vkrt::accel::walk::Traversal;
    let Some(ctx) = context() else { return };
    for (file, spp) in [
        ("hard_shadows.toml", 1),
        ("refraction.toml", 1),
        ("motion_blur.toml", 2),
        ("ambient_occlusion.toml", 1),
        ("mesh_file.toml", 1),
    ] {
        let scene = scene_file(file);
        let (plan, rs) = prepare(&scene, &small(spp));
        let kd = gpu_render(&ctx, &plan, &rs);
        for walk in Traversal::ALL {
            let opt = RenderOptions {
                accel: vkrt::accel::device::AccelChoice::new(
                    vkrt::accel::device::AccelKind::SahBvh,
                    walk,
                ),
                ..small(spp)
            };
            let plan = Plan::new(&scene, &opt).unwrap();
            let rs = RenderScene::new(&scene, &plan, |g| {
                bvh::build(&g.boxes, &BvhParams::default(), Threading::Single)
                    .map(|b| RenderAccel::Host(HostStructure::Bvh(b)))
            })
            .unwrap();
            let b = gpu_render(&ctx, &plan, &rs);
            assert_eq!(b.counts, kd.counts, "{file} {walk:?}: ray counts");
            assert!(b.rgba == kd.rgba, "{file} {walk:?}: the BVH image differs");
            let twin = cpu::render(&rs, &plan, &TraceOptions::default());
            assert_eq!(
                twin.counts, b.counts,
                "{file} {walk:?}: CPU twin ray counts"
            );
        }
    }
}

/// The renderer builds the structure on the device in its first submission (what `vkrt
/// render` does): the image equals the one rendered from the host-built twin, byte for byte,
/// for every structure and walk; nothing is read back before the first rays are traced; and
/// the CPU twin, building the same structure on the host, counts the same rays.
#[test]
fn structures_built_on_the_device_render_the_host_twins_image() {
    let Some(ctx) = context() else { return };
    for (file, spp) in [("motion_blur.toml", 2), ("mesh_file.toml", 1)] {
        let scene = scene_file(file);
        let (plan, rs) = prepare(&scene, &small(spp));
        let host = gpu_render(&ctx, &plan, &rs);
        for accel in AccelChoice::all() {
            let opt = RenderOptions {
                accel,
                ..small(spp)
            };
            let plan = Plan::new(&scene, &opt).unwrap();
            let rs = RenderScene::new(&scene, &plan, |_| Ok::<_, ()>(RenderAccel::OnDevice(accel)))
                .unwrap();
            let d = gpu_render(&ctx, &plan, &rs);
            let what = format!("{file} on {}", accel.label());
            assert!(d.rgba == host.rgba, "{what}: the image differs");
            assert_eq!(d.counts, host.counts, "{what}");
            assert_eq!(d.readback_before_trace, 0, "{what}");
            assert!(d.build_ms.is_some_and(|ms| ms > 0.0), "{what}");
            // One submission per sample (the first also uploads and builds; it is redone
            // when a kd-tree build ran out of references), the tone map, and the three
            // read-backs of the result.
            let redone = u64::from(d.build_attempts - 1);
            assert_eq!(d.traffic.submits, u64::from(spp) + 4 + redone, "{what}");
            let twin = cpu::render(&rs, &plan, &TraceOptions::default());
            assert_eq!(twin.counts, d.counts, "{what}: CPU twin ray counts");
        }
    }
}

/// Area lights are emitting shapes the camera sees, as in pbrt: camera rays at the default
/// scene's quad light return its radiance exactly; from behind (edges swapped) the quad is
/// invisible; a sphere light in its place is seen too; GPU and CPU twin see the same pixels.
#[test]
fn camera_rays_see_area_lights_as_their_radiance() {
    let Some(ctx) = context() else { return };
    let base = Scene::default_scene();
    let Light::Quad {
        corner,
        edge_u,
        edge_v,
        color,
        intensity,
    } = base.lights[0]
    else {
        panic!("the default scene's light is a quad")
    };
    let power = (color * intensity).to_array();
    let mut back = base.clone();
    back.lights[0] = Light::Quad {
        corner,
        edge_u: edge_v,
        edge_v: edge_u,
        color,
        intensity,
    };
    let mut sphere = base.clone();
    sphere.lights[0] = Light::Sphere {
        center: corner + 0.5 * (edge_u + edge_v) - Vec3::new(0.0, 0.2, 0.0),
        radius: 0.15,
        color,
        intensity,
    };
    for (what, scene, visible) in [
        ("front", base, true),
        ("back", back, false),
        ("sphere", sphere, true),
    ] {
        let (plan, rs) = prepare(&scene, &small(1));
        assert!(plan.area_lights, "{what}: the plan samples area lights");
        let gpu = gpu_render(&ctx, &plan, &rs);
        let twin = cpu::render(&rs, &plan, &TraceOptions::default());
        let seen =
            |r: &[[f32; 3]]| -> Vec<usize> { (0..r.len()).filter(|&i| r[i] == power).collect() };
        let (g, c) = (seen(&gpu.radiance), seen(&twin.radiance));
        eprintln!(
            "{what}: {} pixels see the light (twin {})",
            g.len(),
            c.len()
        );
        if visible {
            assert!(g.len() >= 4, "{what}: the light is not seen");
            let differ = g.iter().filter(|i| !c.contains(i)).count()
                + c.iter().filter(|i| !g.contains(i)).count();
            assert!(
                differ <= 2,
                "{what}: GPU and twin see the light in {differ} different pixels"
            );
        } else {
            assert!(
                g.is_empty() && c.is_empty(),
                "{what}: a quad's back is seen"
            );
        }
    }
}

/// The driver's structure (where the device has ray query) renders every example scene as
/// the kd-tree does, within the renderer's tolerance: its triangle test is its own, so a few
/// samples may take another path (a hit at an edge, a tie); ray counts within 1 %, and at
/// most 1 % of the 8-bit channels more than 1/255 off.
#[test]
fn the_driver_renders_the_kdtree_image_within_tolerance() {
    use vkrt::accel::driver::Prefer;
    let Some(ctx) = context() else { return };
    if !ctx.info().features.ray_query {
        eprintln!("skipped: {} has no ray query", ctx.info().driver);
        return;
    }
    for (file, spp) in EFFECT_SCENES {
        let scene = scene_file(file);
        let (plan, rs) = prepare(&scene, &small(spp));
        let kd = gpu_render(&ctx, &plan, &rs);
        for prefer in [Prefer::FastTrace, Prefer::FastBuild] {
            let accel = AccelChoice::driver(prefer);
            let opt = RenderOptions {
                accel,
                ..small(spp)
            };
            let plan = Plan::new(&scene, &opt).unwrap();
            let rs = RenderScene::new(&scene, &plan, |_| Ok::<_, ()>(RenderAccel::OnDevice(accel)))
                .unwrap();
            let d = gpu_render(&ctx, &plan, &rs);
            let what = format!("{file} on {}", accel.label());
            assert_eq!(d.readback_before_trace, 0, "{what}");
            let (a, b) = (
                d.counts.primary + d.counts.secondary(),
                kd.counts.primary + kd.counts.secondary(),
            );
            assert!(
                a.abs_diff(b) * 100 <= b,
                "{what}: {a} rays, the kd-tree's {b}"
            );
            let n = d.rgba.len() / 4 * 3;
            let off = (0..d.rgba.len())
                .filter(|i| i % 4 != 3 && d.rgba[*i].abs_diff(kd.rgba[*i]) > 1)
                .count();
            eprintln!("{what}: {off} of {n} channels differ by more than 1/255");
            assert!(off * 100 <= n, "{what}: {off} of {n} channels off");
        }
    }
}

/// Frames of an animated scene render as stills of their time: Kolodzey's demo with its
/// shutter opened for half a frame (so the orbiting ring also blurs within the frame), at
/// frames 0 and 24. Each GPU image matches its CPU twin as every effect's does (the frame's
/// shutter is shifted to 1 s, the keyframed bunny held at its pose then), and frame 24 is not
/// frame 0: the ring has turned 45° and the bunny half a turn.
#[test]
fn animation_frames_match_the_cpu_twin() {
    let Some(ctx) = context() else { return };
    let mut scene = scene_file("dynamic_demo.toml");
    scene.camera.shutter_close = 0.5 / 24.0;
    let mut frames = Vec::new();
    for k in [0, 24] {
        let frame = scene.at_frame(k);
        let (plan, rs) = prepare(&frame, &small(2));
        assert!(plan.motion, "frame {k}: the ring blurs");
        let gpu = gpu_render(&ctx, &plan, &rs);
        let twin = cpu::render(&rs, &plan, &TraceOptions::default());
        assert_eq!(gpu.counts, twin.counts, "frame {k}: ray counts");
        let n = gpu.radiance.len() * 3;
        let off = gpu
            .radiance
            .iter()
            .zip(&twin.radiance)
            .flat_map(|(g, c)| (0..3).map(move |ch| (srgb8(g[ch]), srgb8(c[ch]))))
            .filter(|(a, b)| a.abs_diff(*b) > 1)
            .count();
        eprintln!("frame {k}: {off} of {n} channels differ by more than 1/255");
        assert!(off * 200 <= n, "frame {k}: {off} of {n} channels off");
        frames.push(gpu.rgba);
    }
    let moved = frames[0]
        .iter()
        .zip(&frames[1])
        .filter(|(a, b)| a.abs_diff(**b) > 8)
        .count();
    assert!(
        moved * 20 > frames[0].len(),
        "frame 24 looks like frame 0 ({moved} channels changed)"
    );
}

/// Which scenes the plan traces as two levels: one that repeats a mesh (the dynamic demo's
/// icospheres, with or without motion blur), unless asked to flatten, or where the two levels
/// cannot serve the render yet (the driver's structure), said in a note; a scene whose
/// meshes are all different stays one level.
#[test]
fn the_plan_traces_repeated_meshes_as_two_levels() {
    use vkrt::accel::device::{AccelChoice, AccelKind};
    use vkrt::accel::driver::Prefer;
    use vkrt::accel::walk::Traversal;
    let demo = scene_file("dynamic_demo.toml");
    let plan = |scene: &Scene, opt: RenderOptions| Plan::new(scene, &opt).unwrap();
    assert_eq!(plan(&demo, small(1)).levels, 2);
    let flat = plan(
        &demo,
        RenderOptions {
            flatten: true,
            ..small(1)
        },
    );
    assert_eq!((flat.levels, flat.notes.len()), (1, 0));
    // Motion blur too: the moving instances move over the shutter.
    let mut blurred = demo.clone();
    blurred.camera.shutter_close = 0.02;
    assert_eq!(plan(&blurred, small(1)).levels, 2);
    // Every walk of vkrt's own structures.
    let bitstack = RenderOptions {
        accel: AccelChoice::new(AccelKind::Lbvh, Traversal::Bitstack),
        ..small(1)
    };
    assert_eq!(plan(&demo, bitstack).levels, 2);
    // The driver's own levels, where nothing moves over the shutter.
    let driver = RenderOptions {
        accel: AccelChoice::driver(Prefer::FastTrace),
        ..small(1)
    };
    assert_eq!(plan(&demo, driver).levels, 2);
    let cases = [(blurred.clone(), driver, "driver")];
    for (scene, opt, why) in cases {
        let p = plan(&scene, opt);
        assert_eq!(p.levels, 1, "{why}");
        assert!(
            p.notes.iter().any(|n| n.contains(why)),
            "{why}: {:?}",
            p.notes
        );
    }
    assert_eq!(plan(&scene_file("hard_shadows.toml"), small(1)).levels, 1);
}

/// A scene larger than one structure may hold renders as two levels with the rest cut into
/// pieces, each a bottom level under an identity instance, and gives the image of the scene
/// in one structure (the hits are the same; shading reads the pieces' world-space
/// primitives at device addresses, placed by identities). With repeated meshes too (the
/// dynamic demo: its icospheres instanced, the rest in pieces), against the same scene's
/// two levels in one piece.
#[test]
fn a_scene_in_pieces_renders_the_image_of_one_structure() {
    use vkrt::accel::two_levels::TwoLevelScene;
    let Some(ctx) = context() else { return };
    let cases = [
        ("hard_shadows.toml", KD_TREE, 1),
        (
            "reflection.toml",
            AccelChoice::new(AccelKind::Lbvh, Traversal::Bitstack),
            1,
        ),
        (
            "dynamic_demo.toml",
            AccelChoice::new(AccelKind::Ploc, Traversal::Stack),
            2,
        ),
    ];
    for (name, accel, whole_levels) in cases {
        let scene = scene_file(name);
        let whole = RenderOptions { accel, ..small(1) };
        // A quarter of what stays in the world (everything, where no mesh repeats).
        let total = scene.triangle_count() + scene.spheres.len();
        let rest = TwoLevelScene::of(&scene, 0.0).map_or(total, |two| two.rest_ids.len());
        let max = rest / 4 + 1;
        let pieces = RenderOptions {
            max_level_primitives: Some(max),
            ..whole
        };
        let plan = Plan::new(&scene, &pieces).unwrap();
        assert_eq!((plan.levels, plan.pieces_of), (2, Some(max)), "{name}");
        let rs = RenderScene::on_device(&scene, &plan);
        let two = &rs.levels.as_ref().expect("two levels").scene;
        assert!(
            two.rest_first.len() >= 2,
            "{name}: {} pieces",
            two.rest_first.len()
        );
        let got = gpu_render(&ctx, &plan, &rs);
        // Taken, the scene's pieces are built one after another ahead of the first sample,
        // their host copies let go: the same image, bit for bit.
        let taken = Renderer::new(&ctx, &plan, &TraceOptions::default())
            .unwrap()
            .render_owned(&ctx, RenderScene::on_device(&scene, &plan), &plan, |_| {})
            .unwrap();
        assert_silent(&ctx);
        assert!(taken.rgba == got.rgba, "{name}: taken, the image differs");
        assert_eq!(taken.radiance, got.radiance, "{name}");
        assert_eq!(taken.counts, got.counts, "{name}");
        assert!(taken.build_ms.is_some_and(|ms| ms > 0.0), "{name}");

        let want_plan = Plan::new(&scene, &whole).unwrap();
        assert_eq!(want_plan.levels, whole_levels, "{name}");
        let want = gpu_render(
            &ctx,
            &want_plan,
            &RenderScene::on_device(&scene, &want_plan),
        );
        let differ = got
            .rgba
            .iter()
            .zip(&want.rgba)
            .filter(|(a, b)| a.abs_diff(**b) > 1)
            .count();
        eprintln!(
            "{name}: {} pieces, {differ} of {} channels differ",
            two.rest_first.len(),
            got.rgba.len()
        );
        assert_eq!(got.counts.total(), want.counts.total(), "{name}");
        assert_eq!(differ, 0, "{name}");
    }
}

/// A scene that repeats a mesh (the dynamic demo: 24 icospheres and the bunny or its
/// stand-in in a mirrored room) over the driver's own two levels (a BLAS per bottom level, a
/// TLAS instance per instance, hits mapped to instances by `render.driver_hits`) renders the
/// image of vkrt's two levels but for the driver's own triangle test.
#[test]
fn the_driver_renders_two_levels_as_vkrt_does() {
    use vkrt::accel::device::{AccelChoice, AccelKind};
    use vkrt::accel::driver::Prefer;
    use vkrt::accel::walk::Traversal;
    let Some(ctx) = context() else { return };
    if !ctx.info().features.ray_query {
        eprintln!("skipped: {} has no ray query", ctx.info().driver);
        return;
    }
    let demo = scene_file("dynamic_demo.toml");
    let own = RenderOptions {
        accel: AccelChoice::new(AccelKind::Lbvh, Traversal::Stack),
        ..small(1)
    };
    let own_plan = Plan::new(&demo, &own).unwrap();
    let want = gpu_render(&ctx, &own_plan, &RenderScene::on_device(&demo, &own_plan));
    for prefer in [Prefer::FastTrace, Prefer::FastBuild] {
        let accel = AccelChoice::driver(prefer);
        let plan = Plan::new(&demo, &RenderOptions { accel, ..small(1) }).unwrap();
        assert_eq!(plan.levels, 2, "{}", accel.label());
        let rs = RenderScene::on_device(&demo, &plan);
        assert!(rs.levels.is_some());
        let got = gpu_render(&ctx, &plan, &rs);
        assert_eq!(got.readback_before_trace, 0);
        assert_eq!(got.counts.primary, want.counts.primary);
        let (a, b) = (got.counts.secondary(), want.counts.secondary());
        assert!(
            a.abs_diff(b) * 100 <= b.max(100),
            "{a} secondary rays, vkrt's {b}"
        );
        let n = got.rgba.len() / 4 * 3;
        let off = (0..got.rgba.len())
            .filter(|i| i % 4 != 3 && got.rgba[*i].abs_diff(want.rgba[*i]) > 1)
            .count();
        eprintln!(
            "{}: {off} of {n} channels differ by more than 1/255",
            accel.label()
        );
        assert!(
            off * 100 <= n,
            "{}: {off} of {n} channels off",
            accel.label()
        );
        // Not a blank image: the demo's room and spheres are lit.
        assert!(got.rgba.chunks(4).filter(|p| p[..3] != [0, 0, 0]).count() * 2 > n / 3);
    }
}

/// `render.driver_hits` against its CPU twin (`instance_primitive_in`): tables of 0, 1, 7, 8,
/// 9, 63, 64, 65 and 1,000 instances with gaps, empty instances and ids past the last, every
/// id of each range's edges and random ones, misses kept; rays past the queue's live count
/// untouched.
#[test]
fn driver_hits_map_ids_as_their_cpu_twin() {
    use vkrt::accel::driver::instance_primitive_in;
    use vkrt::gpu::{kernels, Buffer, BufferArg, Recorder, Spec};
    let Some(ctx) = context() else { return };
    let kernel = ctx
        .kernel(&kernels::RENDER_DRIVER_HITS, &Spec::new().workgroup(64))
        .unwrap();
    let mut rng = vkrt::scene::gen::Rng::new(7);
    for n in [0usize, 1, 7, 8, 9, 63, 64, 65, 1000] {
        // Instances in a shuffled order of first ids, some empty, some with gaps between.
        let mut starts = Vec::with_capacity(n);
        let mut first = 0u32;
        for i in 0..n {
            let count = (rng.next_u64() % 5) as u32 * (rng.next_u64() % 40) as u32;
            let index = ((i * 7919) % n.max(1)) as u32;
            starts.push([first, count, index, 0]);
            first += count + (rng.next_u64() % 3) as u32;
        }
        let mut ids: Vec<u32> = starts
            .iter()
            .flat_map(|s| [s[0], s[0] + s[1], (s[0] + s[1]).wrapping_sub(1)])
            .collect();
        ids.extend((0..300).map(|_| (rng.next_u64() % (u64::from(first) + 10)) as u32));
        ids.extend([0, first, first + 1, u32::MAX - 1, u32::MAX]);
        let live = ids.len() - 3;
        let hits: Vec<[u32; 4]> = ids.iter().map(|&id| [1, id, 2, 3]).collect();
        let hit_buf = Buffer::from_slice(&ctx, "test.hits", &hits).unwrap();
        let mut counters = [0u32; 16];
        counters[0] = live as u32;
        let counter_buf = Buffer::from_slice(&ctx, "test.counters", &counters).unwrap();
        let table = if starts.is_empty() {
            vec![[0u32; 4]]
        } else {
            starts.clone()
        };
        let start_buf = Buffer::from_slice(&ctx, "test.starts", &table).unwrap();
        let instance_buf = Buffer::<u32>::zeroed(&ctx, "test.instances", ids.len()).unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        let groups = rec.groups_1d(ids.len() as u64, 64);
        let b: [&dyn BufferArg; 4] = [&hit_buf, &counter_buf, &start_buf, &instance_buf];
        rec.dispatch(&kernel, groups, &b, &(starts.len() as u32));
        rec.compute_to_transfer();
        rec.submit_and_wait().unwrap();
        let (got, got_instance) = (
            hit_buf.download().unwrap(),
            instance_buf.download().unwrap(),
        );
        for (r, &id) in ids.iter().enumerate() {
            let want = match (r < live, id) {
                (false, _) | (true, u32::MAX) => ([1, id, 2, 3], 0),
                (true, _) => match instance_primitive_in(&starts, id) {
                    Some((instance, prim)) => ([1, prim, 2, 3], instance),
                    None => ([f32::INFINITY.to_bits(), u32::MAX, 0, 0], 0),
                },
            };
            assert_eq!(
                (got[r], got_instance[r]),
                want,
                "{n} instances: ray {r}, id {id}"
            );
        }
    }
    assert_silent(&ctx);
}
