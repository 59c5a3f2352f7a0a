//! Animated scenes: `[animation]`, keyframed meshes, frames as stills
//! (`Scene::at_frame`), optional mesh files (`fallback`), the dynamic demo
//! example, and every bad animation input as an error naming its line.

use std::path::{Path, PathBuf};

use glam::{Affine3A, Quat, Vec3};
use vkrt::accel::primitives::TraceGeometry;
use vkrt::scene::animation::pose_at;
use vkrt::scene::gen;
use vkrt::scene::{
    Animation, Keyframe, Limits, LoadedScene, MemoryFiles, Motion, Orbit, Scene, SceneError,
    Transform, MAX_FRAMES,
};

fn scenes_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes")
}

/// Parse in memory as `mem/test.toml`; `mem/house.obj` (+ `.mtl`) exist,
/// nothing else does.
fn parse(text: &str) -> Result<LoadedScene, SceneError> {
    let mut files = MemoryFiles::new();
    for f in ["house.obj", "house.mtl"] {
        files.insert(
            Path::new("mem").join(f),
            std::fs::read_to_string(scenes_dir().join(f)).unwrap(),
        );
    }
    Scene::from_toml_str_with(text, Path::new("mem/test.toml"), &files, &Limits::default())
}

#[track_caller]
fn parse_err(text: &str) -> SceneError {
    match parse(text) {
        Ok(_) => panic!("expected an error for:\n{text}"),
        Err(e) => e,
    }
}

/// 1-based line of the first line of `text` containing `needle`.
#[track_caller]
fn line_of(text: &str, needle: &str) -> u32 {
    text.lines()
        .position(|l| l.contains(needle))
        .unwrap_or_else(|| panic!("`{needle}` not in the text")) as u32
        + 1
}

/// The message names the file, the line of `at` (a needle in `text`), and
/// every one of `needles`.
#[track_caller]
fn assert_at(e: &SceneError, text: &str, at: &str, needles: &[&str]) {
    let msg = e.to_string();
    let line = line_of(text, at);
    assert!(
        msg.starts_with(&format!("mem/test.toml:{line}:")),
        "not at line {line} ({at}): {msg}"
    );
    for n in needles {
        assert!(msg.contains(n), "`{n}` not in: {msg}");
    }
}

const BASE: &str = r#"
[camera]
position = [0, 1, 6]
look_at = [0, 0, 0]

[[lights]]
type = "point"
position = [0, 5, 5]

[[spheres]]
center = [2, 0, 0]
radius = 0.5
"#;

/// `BASE` plus `[animation]` with the given body.
fn with_animation(body: &str) -> String {
    format!("{BASE}\n[animation]\n{body}\n")
}

/// `BASE` plus an icosphere with the given keyframes (TOML after the mesh).
fn with_keys(keys: &str) -> String {
    format!("{BASE}\n[[meshes]]\ngenerate = \"icosphere\"\nsubdivisions = 0\n{keys}")
}

fn key(time: f32, translate: Vec3, rotate: Vec3, scale: Vec3) -> Keyframe {
    Keyframe {
        time,
        transform: Transform {
            translate,
            rotate,
            scale,
        },
    }
}

#[track_caller]
fn assert_close(a: Affine3A, b: Affine3A, tol: f32) {
    assert!(a.abs_diff_eq(b, tol), "\n{a:?}\n!=\n{b:?}");
}

// --- frames ------------------------------------------------------------------

#[test]
fn animation_with_frames_or_end_time() {
    let s = parse(&with_animation("fps = 24\nframes = 48"))
        .unwrap()
        .scene;
    assert_eq!(
        s.animation,
        Some(Animation {
            fps: 24.0,
            frames: 48
        })
    );
    assert_eq!(s.frame_count(), 48);
    // end_time: ⌈end_time · fps⌉ frames covering [0, end_time).
    for (body, frames) in [
        ("fps = 24\nend_time = 2", 48),
        ("fps = 24\nend_time = 2.01", 49),
        ("fps = 30\nend_time = 0.1", 3), // 0.1f32 · 30 is a hair above 3
        ("fps = 24\nend_time = 0.001", 1),
        ("fps = 1000\nend_time = 100", MAX_FRAMES),
    ] {
        let s = parse(&with_animation(body)).unwrap().scene;
        assert_eq!(s.animation.unwrap().frames, frames, "{body}");
    }
    // A still scene is one frame.
    let s = parse(BASE).unwrap().scene;
    assert_eq!(
        (s.animation, s.frame_count(), s.frame_time(0)),
        (None, 1, 0.0)
    );
}

#[test]
fn frame_times() {
    let a = Animation {
        fps: 24.0,
        frames: 48,
    };
    assert_eq!(a.frame_time(0), 0.0);
    assert_eq!(a.frame_time(12), 0.5);
    assert_eq!(a.frame_time(24), 1.0);
    assert_eq!(a.frame_time(47), (47.0f64 / 24.0) as f32);
    assert_eq!(a.duration(), 2.0);
    let a = Animation {
        fps: 29.97,
        frames: MAX_FRAMES,
    };
    let exact = f64::from(MAX_FRAMES - 1) / f64::from(29.97f32);
    assert_eq!(a.frame_time(MAX_FRAMES - 1), exact as f32);
    assert_eq!(Animation::frames_for_end_time(0.0, 24.0), None);
    assert_eq!(Animation::frames_for_end_time(1.0, f32::NAN), None);
    assert_eq!(Animation::frames_for_end_time(1.5, 2.0), Some(3));
    assert_eq!(Animation::frames_for_end_time(1.6, 2.0), Some(4));
}

// --- keyframes ---------------------------------------------------------------

#[test]
fn keyframes_interpolate_and_clamp() {
    let keys = [
        key(1.0, Vec3::ZERO, Vec3::ZERO, Vec3::ONE),
        key(
            3.0,
            Vec3::new(4.0, 2.0, 0.0),
            Vec3::new(0.0, 90.0, 0.0),
            Vec3::splat(3.0),
        ),
        key(4.0, Vec3::new(4.0, 2.0, -8.0), Vec3::ZERO, Vec3::ONE),
    ];
    assert_eq!(pose_at(&[], 1.0), None);
    // At a key: that key exactly.
    for k in &keys {
        let p = pose_at(&keys, k.time).unwrap();
        assert_eq!(p.matrix(), k.transform.matrix(), "t = {}", k.time);
    }
    // Clamped outside the keys (and the first key for NaN).
    for (t, k) in [(-5.0, 0), (0.999, 0), (f32::NAN, 0), (4.001, 2), (1e6, 2)] {
        let p = pose_at(&keys, t).unwrap();
        assert_eq!(p.matrix(), keys[k].transform.matrix(), "t = {t}");
    }
    // Midway between the first two: halfway translation and scale, 45° slerp.
    let p = pose_at(&keys, 2.0).unwrap();
    assert_eq!(p.translate, Vec3::new(2.0, 1.0, 0.0));
    assert_eq!(p.scale, Vec3::splat(2.0));
    let q45 = Quat::from_rotation_y(45f32.to_radians());
    assert!(p.rotation.abs_diff_eq(q45, 1e-6), "{:?}", p.rotation);
    // A quarter of the way through the second segment picks that segment.
    let p = pose_at(&keys, 3.25).unwrap();
    assert_eq!(p.translate, Vec3::new(4.0, 2.0, -2.0));
    assert_eq!(p.scale, Vec3::splat(2.5));
    let q67 = Quat::from_rotation_y(67.5f32.to_radians());
    assert!(p.rotation.abs_diff_eq(q67, 1e-6), "{:?}", p.rotation);
}

#[test]
fn slerp_takes_the_shorter_arc_at_constant_speed() {
    let y = |deg: f32| Vec3::new(0.0, deg, 0.0);
    // 0° → 270° about Y is −90° the short way: a quarter of the way is −22.5°.
    let keys = [
        key(0.0, Vec3::ZERO, y(0.0), Vec3::ONE),
        key(1.0, Vec3::ZERO, y(270.0), Vec3::ONE),
    ];
    let p = pose_at(&keys, 0.25).unwrap();
    let expect = Quat::from_rotation_y(-22.5f32.to_radians());
    assert!(
        p.rotation.abs_diff_eq(expect, 1e-6) || p.rotation.abs_diff_eq(-expect, 1e-6),
        "{:?}",
        p.rotation
    );
    // Four 90° keys turn once, at constant angular speed.
    let keys: Vec<Keyframe> = (0..=4)
        .map(|i| key(i as f32, Vec3::ZERO, y(90.0 * i as f32), Vec3::ONE))
        .collect();
    for step in 0..=40 {
        let t = step as f32 / 10.0;
        let m = pose_at(&keys, t).unwrap().matrix();
        let expect = Affine3A::from_rotation_y((90.0 * t).to_radians());
        assert_close(m, expect, 1e-5);
    }
}

#[test]
fn keyframes_compose_with_transform_and_motion() {
    // Placed (scale 2), then keyed (translate x by 1 per second), then
    // orbited (90°/s about Y): the world matrix is motion · keys · transform.
    let mut mesh = gen::icosphere(0).unwrap();
    mesh.transform.scale = Vec3::splat(2.0);
    mesh.keyframes = vec![
        key(0.0, Vec3::ZERO, Vec3::ZERO, Vec3::ONE),
        key(2.0, Vec3::new(2.0, 0.0, 0.0), Vec3::ZERO, Vec3::ONE),
    ];
    mesh.motion = Motion {
        velocity: Vec3::new(0.0, 0.5, 0.0),
        orbit: Some(Orbit {
            center: Vec3::ZERO,
            axis: Vec3::Y,
            degrees_per_second: 90.0,
        }),
    };
    let p = Vec3::new(1.0, 0.0, 0.0);
    // t = 1: scale → (2, 0, 0); key → (3, 0, 0); orbit 90° about +Y takes +X
    // to −Z → (0, 0, −3); velocity → (0, 0.5, −3).
    let q = mesh.world_matrix(1.0).transform_point3(p);
    assert!(q.abs_diff_eq(Vec3::new(0.0, 0.5, -3.0), 1e-5), "{q}");
    assert_eq!(
        mesh.placement(1.0).transform_point3(p),
        Vec3::new(3.0, 0.0, 0.0)
    );
    // triangles_world honours the keys.
    let mut s = Scene::from_geometry(vec![mesh.clone()], vec![], vec![Default::default()]);
    s.validate().unwrap();
    let tris = s.triangles_world(1.0);
    let m = mesh.world_matrix(1.0);
    let p0 = mesh.positions[mesh.indices[0][0] as usize];
    assert_eq!(tris[0][0], m.transform_point3(p0));
}

#[test]
fn pose_to_transform_round_trips() {
    let mut rng = gen::Rng::new(7);
    // Near gimbal lock (Y = ±90°) too, where X and Z are ill-defined.
    for rotate in [
        Vec3::new(30.0, 90.0, -20.0),
        Vec3::new(10.0, -89.99, 75.0),
        Vec3::new(0.0, 270.0, 0.0),
        Vec3::new(180.0, 0.0, 180.0),
    ] {
        let t = Transform {
            rotate,
            ..Transform::IDENTITY
        };
        let back = vkrt::scene::Pose::from(&t).to_transform();
        assert_close(back.matrix(), t.matrix(), 1e-6);
    }
    for _ in 0..200 {
        let mut r = || rng.next_f32() * 720.0 - 360.0;
        let t = Transform {
            translate: Vec3::new(1.0, -2.0, 3.0),
            rotate: Vec3::new(r(), r(), r()),
            scale: Vec3::new(0.5, 2.0, 1.5),
        };
        let back = vkrt::scene::Pose::from(&t).to_transform();
        assert_close(back.matrix(), t.matrix(), 1e-5);
    }
}

// --- frames as stills ----------------------------------------------------------

fn animated_scene() -> Scene {
    let text = format!(
        "{BASE}\n[animation]\nfps = 24\nframes = 48\n\
         [[meshes]]\ngenerate = \"icosphere\"\nsubdivisions = 1\n\
         orbit = {{ center = [1, 0, 0], degrees_per_second = 30 }}\n\
         [[meshes.keyframes]]\ntime = 0\n\
         [[meshes.keyframes]]\ntime = 2\ntranslate = [0, 1, 0]\nrotate = [0, 90, 0]\nscale = 0.5\n"
    )
    .replace(
        "look_at = [0, 0, 0]",
        "look_at = [0, 0, 0]\nshutter = [0, 0.02]",
    );
    parse(&text).unwrap().scene
}

#[test]
fn at_frame_shifts_the_shutter_and_holds_keyframes() {
    let s = animated_scene();
    assert_eq!(s.frame_count(), 48);
    let f = s.at_frame(12);
    assert_eq!(f.animation, None);
    assert_eq!(f.camera.shutter_open, 0.5);
    assert_eq!(f.camera.shutter_close, 0.52);
    assert!(f.effects().motion_blur, "the orbit still blurs in a frame");
    // The keyed mesh is held at its pose at the frame's shutter open ...
    let mesh = &f.meshes[0];
    assert_eq!(mesh.keyframes.len(), 1);
    assert_eq!(mesh.keyframes[0].time, 0.5);
    for t in [0.5, 0.51, 0.52] {
        assert_close(mesh.placement(t), s.meshes[0].placement(0.5), 1e-5);
    }
    // ... while velocity and orbit keep moving it.
    assert_close(
        mesh.world_matrix(0.52),
        s.meshes[0].motion.at(0.52) * s.meshes[0].placement(0.5),
        1e-5,
    );
    // Spheres move by their motion as before, and frame 0 is the scene.
    assert_eq!(f.spheres, s.spheres);
    let f0 = s.at_frame(0);
    assert_eq!(f0.camera, s.camera);
    // The renderer's geometry for the frame: moving meshes at the held pose
    // and time-0 motion, their boxes swept over the frame's shutter.
    let g = TraceGeometry::over_interval(&f, f.camera.shutter_open, f.camera.shutter_close);
    assert!(g.has_motion());
    let tris = f.triangles_world(0.51);
    for (i, tri) in tris.iter().enumerate() {
        let moved = g.triangle_at(i, 0.51);
        for c in 0..3 {
            assert!(moved[c].abs_diff_eq(tri[c], 1e-4), "{i}: {moved:?} {tri:?}");
        }
    }
    // A still scene has one frame.
    let still = parse(BASE).unwrap().scene;
    assert_eq!(still.at_frame(0), still);
}

#[test]
#[should_panic(expected = "frame 48 of a scene with 48 frames")]
fn at_frame_past_the_end_panics() {
    let _ = animated_scene().at_frame(48);
}

#[test]
fn summary_shows_the_animation() {
    let s = animated_scene();
    let text = s.summary().to_string();
    assert!(
        text.contains("animation: 48 frames at 24 fps (2 s)"),
        "{text}"
    );
    let json = serde_json::to_value(s.summary()).unwrap();
    assert_eq!(json["animation"]["frames"], 48);
    let still = serde_json::to_value(parse(BASE).unwrap().scene.summary()).unwrap();
    assert!(still.get("animation").is_none(), "{still}");
}

// --- writing ---------------------------------------------------------------------

#[test]
fn round_trip_with_animation_and_keyframes() {
    let a = animated_scene();
    let text = a.to_toml_string();
    assert!(text.contains("[animation]"), "{text}");
    assert!(text.contains("[[meshes.keyframes]]"), "{text}");
    let b = Scene::from_toml_str(&text, Path::new("."))
        .unwrap_or_else(|e| panic!("{e}\n{text}"))
        .scene;
    assert_eq!(a, b);
    assert_eq!(text, b.to_toml_string(), "writer is not a fixed point");
    // end_time is kept as its frame count.
    let c = parse(&with_animation("fps = 24\nend_time = 2"))
        .unwrap()
        .scene;
    let back = Scene::from_toml_str(&c.to_toml_string(), Path::new("."))
        .unwrap()
        .scene;
    assert_eq!(back.animation, c.animation);
    // A held frame writes and reads back too.
    let f = a.at_frame(30);
    let back = Scene::from_toml_str(&f.to_toml_string(), Path::new("."))
        .unwrap()
        .scene;
    assert_eq!(back, f);
}

// --- optional mesh files -----------------------------------------------------------

const FALLBACK: &str = r#"
[[meshes]]
name = "house or ball"
path = "PATH"
scale = 2

[meshes.fallback]
name = "stand-in"
generate = "icosphere"
subdivisions = 1
translate = [0, 1, 0]
"#;

#[test]
fn fallback_stands_in_for_a_missing_file_only() {
    let present = format!("{BASE}{}", FALLBACK.replace("PATH", "house.obj"));
    let l = parse(&present).unwrap();
    assert!(l.warnings.is_empty(), "{:?}", l.warnings);
    assert_eq!(l.scene.meshes[0].name, "house or ball");
    assert_eq!(l.scene.meshes[0].transform.scale, Vec3::splat(2.0));

    let missing = format!("{BASE}{}", FALLBACK.replace("PATH", "nope/bunny.obj"));
    let l = parse(&missing).unwrap();
    let m = &l.scene.meshes[0];
    assert_eq!(m.name, "stand-in");
    assert_eq!(m.triangle_count(), 80);
    // Nothing is inherited from the entry it replaces.
    assert_eq!(m.transform.scale, Vec3::ONE);
    assert_eq!(m.transform.translate, Vec3::Y);
    assert_eq!(l.warnings.len(), 1, "{:?}", l.warnings);
    let w = &l.warnings[0];
    assert!(
        w.contains("mem/nope/bunny.obj") && w.contains("meshes[0].fallback"),
        "{w}"
    );

    // A chain: the fallback's own path is missing too.
    let chain = format!(
        "{BASE}{}",
        FALLBACK
            .replace("PATH", "a.obj")
            .replace(
                "[meshes.fallback]\n",
                "[meshes.fallback]\npath = \"b.obj\"\n"
            )
            .replace(
                "name = \"stand-in\"\ngenerate = \"icosphere\"\nsubdivisions = 1\n",
                "[meshes.fallback.fallback]\ngenerate = \"icosphere\"\nsubdivisions = 0\n"
            )
    );
    let l = parse(&chain).unwrap();
    assert_eq!(l.scene.meshes[0].triangle_count(), 20);
    assert_eq!(l.warnings.len(), 2, "{:?}", l.warnings);
}

#[test]
fn fallback_errors_name_their_own_keys() {
    // A bad value in a fallback that is used names the fallback's line ...
    let text = format!(
        "{BASE}{}",
        FALLBACK
            .replace("PATH", "missing.obj")
            .replace("translate = [0, 1, 0]", "scale = [1, 0, 1]")
    );
    let e = parse_err(&text);
    assert_at(
        &e,
        &text,
        "scale = [1, 0, 1]",
        &["meshes[0].fallback.scale"],
    );
    // ... also for keyframes validated on the model.
    let text = format!(
        "{BASE}{}[[meshes.fallback.keyframes]]\ntime = 1\n[[meshes.fallback.keyframes]]\ntime = 1\n",
        FALLBACK.replace("PATH", "missing.obj")
    );
    let e = parse_err(&text);
    let msg = e.to_string();
    assert!(
        msg.contains("meshes[0].fallback.keyframes[1].time"),
        "{msg}"
    );
    // A fallback needs a `path` to stand in for.
    let text = format!(
        "{BASE}\n[[meshes]]\ngenerate = \"icosphere\"\nsubdivisions = 0\n[meshes.fallback]\ngenerate = \"icosphere\"\nsubdivisions = 1\n"
    );
    let e = parse_err(&text);
    assert_at(
        &e,
        &text,
        "[meshes.fallback]",
        &["meshes[0].fallback", "`path`"],
    );
    // A misspelt key in an unused fallback is still an error.
    let text = format!(
        "{BASE}{}",
        FALLBACK
            .replace("PATH", "house.obj")
            .replace("subdivisions = 1", "subdivision = 1")
    );
    let e = parse_err(&text);
    assert_at(&e, &text, "subdivision = 1", &["subdivision"]);
    // A file that exists but is broken is an error, not a fallback.
    let mut files = MemoryFiles::new();
    files.insert("mem/broken.obj", "v 0 0 0\nf 1 2 9\n");
    let text = format!("{BASE}{}", FALLBACK.replace("PATH", "broken.obj"));
    let r = Scene::from_toml_str_with(
        &text,
        Path::new("mem/test.toml"),
        &files,
        &Limits::default(),
    );
    assert!(r.is_err());
}

// --- the dynamic demo ------------------------------------------------------------

fn shared_bunny() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes/stanford-bunny.obj")
}

#[test]
fn dynamic_demo_loads_animates_and_has_a_glass_twin() {
    let metal = Scene::load(&scenes_dir().join("dynamic_demo.toml")).unwrap();
    let glass = Scene::load(&scenes_dir().join("dynamic_demo_glass.toml")).unwrap();
    let bunny_tris = if shared_bunny().exists() {
        assert!(metal.warnings.is_empty(), "{:?}", metal.warnings);
        assert_eq!(metal.scene.meshes[1].name, "bunny");
        69_451
    } else {
        assert_eq!(metal.warnings.len(), 1, "{:?}", metal.warnings);
        assert_eq!(metal.scene.meshes[1].name, "bunny stand-in");
        69_620
    };
    let s = &metal.scene;
    // About 100 K triangles: the bunny (or its stand-in), 24 icospheres, the room.
    assert_eq!(s.triangle_count(), bunny_tris + 24 * 1280 + 10);
    assert_eq!(
        s.animation,
        Some(Animation {
            fps: 24.0,
            frames: 48
        })
    );
    let e = s.effects();
    assert!(e.reflection && e.refraction && e.hard_shadows, "{e:?}");
    assert!(!e.motion_blur);
    // The bunny stands on the floor at the centre, inside the ring.
    let b = &s.meshes[1];
    let ob = b.object_bounds();
    let placed = b.world_matrix(0.0);
    let (lo, hi) = (
        placed.transform_point3(ob.min),
        placed.transform_point3(ob.max),
    );
    assert!(lo.y.abs() < 1e-3, "{lo} {hi}");
    assert!(lo.x.abs().max(hi.x.abs()).max(lo.z.abs()).max(hi.z.abs()) < 1.0);
    // The ring turns 45°/s: after 24 frames (1 s) each sphere is 45° on,
    // and the bunny half a turn on its keyframes at 1 s.
    let f = s.at_frame(24);
    assert_eq!(f.camera.shutter_open, 1.0);
    let ring_center = |scene: &Scene, i: usize, t: f32| {
        let m = &scene.meshes[i];
        m.world_matrix(t).transform_point3(Vec3::ZERO)
    };
    for i in 2..26 {
        let (a, b) = (ring_center(s, i, 0.0), ring_center(&f, i, 1.0));
        let angle = a.with_y(0.0).angle_between(b.with_y(0.0)).to_degrees();
        assert!((angle - 45.0).abs() < 1e-3, "ring {i}: {angle}°");
        assert!((a.y - b.y).abs() < 1e-6);
    }
    let half = f.meshes[1].placement(1.0) * s.meshes[1].transform.matrix().inverse();
    if bunny_tris == 69_451 {
        assert_close(half, Affine3A::from_rotation_y(180f32.to_radians()), 1e-4);
    }
    // The glass file is the metal one with the bunny in glass.
    let glass = glass.scene;
    let glass_id = s.materials.iter().position(|m| m.name == "glass").unwrap() as u32;
    let mut expect = s.clone();
    expect.meshes[1].materials = vkrt::scene::MeshMaterials::Single(glass_id);
    assert_eq!(glass, expect);
}

#[test]
fn dynamic_demo_falls_back_without_shared() {
    // The example parsed where ../shared does not exist: the stand-in.
    let text = std::fs::read_to_string(scenes_dir().join("dynamic_demo.toml")).unwrap();
    let l = Scene::from_toml_str_with(
        &text,
        Path::new("mem/scenes/dynamic_demo.toml"),
        &MemoryFiles::new(),
        &Limits::default(),
    )
    .unwrap();
    assert_eq!(l.warnings.len(), 1, "{:?}", l.warnings);
    assert!(
        l.warnings[0].contains("stanford-bunny.obj"),
        "{:?}",
        l.warnings
    );
    let m = &l.scene.meshes[1];
    assert_eq!(
        (m.name.as_str(), m.triangle_count()),
        ("bunny stand-in", 69_620)
    );
    assert!(m.keyframes.is_empty());
}

// --- bad input --------------------------------------------------------------------

#[test]
fn bad_frame_rates_and_counts() {
    let cases: &[(&str, &str, &[&str])] = &[
        (
            "fps = 0\nframes = 10",
            "fps",
            &["animation.fps", "(0, 1000]"],
        ),
        ("fps = -24\nframes = 10", "fps", &["animation.fps", "-24"]),
        ("fps = nan\nframes = 10", "fps", &["animation.fps", "NaN"]),
        ("fps = inf\nframes = 10", "fps", &["animation.fps", "inf"]),
        ("fps = 1001\nframes = 10", "fps", &["animation.fps", "1001"]),
        (
            "fps = 24\nframes = 0",
            "frames",
            &["animation.frames", "1 ..= 100000"],
        ),
        (
            "fps = 24\nframes = 100001",
            "frames",
            &["animation.frames", "100001"],
        ),
        ("fps = 24\nframes = -3", "frames", &["animation.frames"]),
        ("fps = 24\nframes = 2.5", "frames", &["animation.frames"]),
        (
            "fps = 24\nframes = 48\nend_time = 2",
            "end_time",
            &["animation.end_time", "not both"],
        ),
        (
            "fps = 24",
            "[animation]",
            &["animation", "`frames`", "`end_time`"],
        ),
        ("frames = 24", "[animation]", &["fps"]),
        (
            "fps = 24\nend_time = 0",
            "end_time",
            &["animation.end_time", "(0,"],
        ),
        (
            "fps = 24\nend_time = -1",
            "end_time",
            &["animation.end_time", "-1"],
        ),
        (
            "fps = 24\nend_time = nan",
            "end_time",
            &["animation.end_time", "NaN"],
        ),
        ("fps = 0\nend_time = 1", "fps", &["animation.fps"]),
        (
            "fps = 1000\nend_time = 1000",
            "end_time",
            &["animation.end_time", "1000000 frames", "1 ..= 100000"],
        ),
        ("fps = 24\nframes = 10\nloop = true", "loop", &["loop"]),
        // The last frame's time is past MAX_TIME.
        (
            "fps = 0.01\nframes = 100000",
            "frames",
            &["animation.frames", "last frame"],
        ),
    ];
    for (body, at, needles) in cases {
        let text = with_animation(body);
        let e = parse_err(&text);
        assert_at(&e, &text, at, needles);
    }
    // Hand-built scenes get the same checks.
    let mut s = parse(BASE).unwrap().scene;
    s.animation = Some(Animation {
        fps: f32::NAN,
        frames: 3,
    });
    assert!(matches!(s.validate(), Err(SceneError::NonFinite { .. })));
}

#[test]
fn bad_keyframes() {
    let k = |body: &str| format!("[[meshes.keyframes]]\n{body}\n");
    let cases: Vec<(String, &str, &[&str])> = vec![
        (
            k("time = 1") + &k("time = 1 # second"),
            "# second",
            &[
                "meshes[0].keyframes[1].time",
                "increase strictly",
                "1 s follows 1 s",
            ],
        ),
        (
            k("time = 2") + &k("time = 1 # second"),
            "# second",
            &["meshes[0].keyframes[1].time", "increase strictly"],
        ),
        (
            k("time = 0") + &k("time = 2") + &k("time = 1.5 # third"),
            "# third",
            &["meshes[0].keyframes[2].time"],
        ),
        (k("time = nan"), "time = nan", &["keyframes[0].time", "NaN"]),
        (k("time = 1e7"), "time = 1e7", &["keyframes[0].time", "1e6"]),
        (
            k("time = 0\ntranslate = [0, inf, 0]"),
            "translate",
            &["keyframes[0].translate", "inf"],
        ),
        (
            k("time = 0\ntranslate = [0, 2e9, 0]"),
            "translate",
            &["keyframes[0].translate", "±1e9"],
        ),
        (
            k("time = 0\nrotate = [nan, 0, 0]"),
            "rotate",
            &["keyframes[0].rotate", "NaN"],
        ),
        (
            k("time = 0\nscale = -inf"),
            "scale",
            &["keyframes[0].scale", "inf"],
        ),
        (
            k("time = 0\nscale = [1, 0, 1]"),
            "scale",
            &["keyframes[0].scale", "zero"],
        ),
        (
            k("time = 0") + &k("time = 1\nscale = [1, -1, 1]"),
            "scale",
            &["keyframes[1].scale", "sign", "zero scale"],
        ),
        (
            k("time = 0\nrotation = [0, 1, 0]"),
            "rotation",
            &["rotation"],
        ),
        (
            k("translate = [0, 1, 0]"),
            "[[meshes.keyframes]]",
            &["time"],
        ),
    ];
    for (keys, at, needles) in &cases {
        let text = with_keys(keys);
        let e = parse_err(&text);
        assert_at(&e, &text, at, needles);
    }
    // Keys that carry the mesh past the coordinate limit: the whole scene.
    let text = with_keys(&(k("time = 0\ntranslate = [1e9, 0, 0]") + &k("time = 1\nscale = 1000")));
    let msg = parse_err(&text).to_string();
    assert!(
        msg.starts_with("mem/test.toml: ") && msg.contains("±1e9") && msg.contains("every frame"),
        "{msg}"
    );
    // A single key, and an empty list, are fine.
    parse(&with_keys(&k("time = 3\ntranslate = [1, 0, 0]"))).unwrap();
    parse(&with_keys("keyframes = []\n")).unwrap();
}
