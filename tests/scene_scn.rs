//! Bidmon's (2010) plain-text scene format.

use std::path::{Path, PathBuf};

use glam::Vec3;
use vkrt::scene::scn::parse_scn;
use vkrt::scene::{Light, Limits, MeshMaterials, Scene, SceneError};

fn example() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/whitted_example.scn")
}

fn parse(text: &str) -> Result<vkrt::scene::LoadedScene, SceneError> {
    parse_scn(text, Path::new("mem/t.scn"), &Limits::default())
}

#[track_caller]
fn assert_err(text: &str, line: u32, needles: &[&str]) {
    let e = match parse(text) {
        Ok(_) => panic!("expected an error for:\n{text}"),
        Err(e) => e,
    };
    let msg = e.to_string();
    assert!(
        msg.contains(&format!("mem/t.scn:{line}")),
        "not line {line}: {msg}"
    );
    for n in needles {
        assert!(msg.contains(n), "`{n}` not in: {msg}");
    }
}

#[test]
fn example_loads_with_seed_materials() {
    let loaded = Scene::load(&example()).unwrap();
    assert!(loaded.warnings.is_empty(), "{:?}", loaded.warnings);
    let s = loaded.scene;
    assert_eq!(s.triangle_count(), 2);
    assert_eq!(s.spheres.len(), 2);
    assert_eq!(s.lights.len(), 2);
    assert_eq!(
        (s.settings.width, s.settings.height, s.settings.max_depth),
        (700, 700, 4)
    );
    // zoom 3400 at 700 px: 2·atan(350/3400).
    let fov = 2.0 * (350.0f32 / 3400.0).atan().to_degrees();
    assert!((s.camera.fov - fov).abs() < 1e-4);
    assert_eq!(s.camera.look_at, Vec3::new(0.0, 0.0, 999.0));
    // Per-object colour × shared material: the two triangles share material 2
    // with different colours → two materials; two spheres → two more.
    assert_eq!(s.materials.len(), 4);
    let MeshMaterials::PerTriangle(ids) = &s.meshes[0].materials else {
        panic!()
    };
    let (a, b) = (&s.materials[ids[0] as usize], &s.materials[ids[1] as usize]);
    assert_eq!(a.diffuse, Vec3::new(0.12, 0.57, 0.87));
    assert_eq!(b.diffuse, Vec3::new(0.24, 0.4, 0.5));
    assert_eq!((a.mirror, a.shininess), (Vec3::splat(0.6), 50.0));
    let glass = &s.materials[s.spheres[1].material as usize];
    assert_eq!(
        (glass.transmission, glass.ior, glass.fresnel),
        (0.8, 1.5, false)
    );
    assert_eq!(glass.mirror, Vec3::splat(0.1));
    // Light intensity makes the irradiance at the scene centre equal to the
    // colour (the thesis has no falloff).
    let c = s.bounds().center();
    let Light::Point {
        position,
        intensity,
        ..
    } = s.lights[0]
    else {
        panic!()
    };
    assert!((intensity - (c - position).length_squared()).abs() < 1e-2);
    assert_eq!(
        s.effects().names(),
        ["hard_shadows", "reflection", "refraction"],
        "Bidmon 2010: no AA, no area lights"
    );
}

fn example_text() -> String {
    std::fs::read_to_string(example()).unwrap()
}

#[test]
fn header_errors() {
    let t = example_text();
    assert_err(
        &t.replace("scene file version 1.0", "scene version 1.0"),
        1,
        &["scene file version"],
    );
    assert_err(
        &t.replace("Number of objects: 4", "Number of objects: 5"),
        3,
        &["5 objects", "defines 4"],
    );
    assert_err(
        &t.replace("Number of lights: 2", "Number of lights: two"),
        2,
        &["two"],
    );
    assert_err(
        &t.replace("Number of materials: 3", "Number of materials: 2"),
        4,
        &["2 materials"],
    );
    assert_err(
        "scene file version 1.0\nNumber of lights: 0\n",
        2,
        &["incomplete"],
    );
}

#[test]
fn block_errors() {
    let t = example_text();
    assert_err(
        &t.replace("  material: 2\n<next>", "  material: 7\n<next>"),
        51,
        &["index 7", "numbered from 1"],
    );
    assert_err(
        &t.replace("  material: 1\n", "  material: 0\n"),
        62,
        &["index 0"],
    );
    assert_err(
        &t.replace("  radius: 45", "  radius: -45"),
        60,
        &["radius", "-45"],
    );
    assert_err(&t.replace("  radius: 45", "  radius: nan"), 60, &["nan"]);
    assert_err(&t.replace("  zoom: 3400", "  zoom: 0"), 17, &["zoom"]);
    assert_err(
        &t.replace("  radius: 45", "  radious: 45"),
        60,
        &["unknown key `radious`"],
    );
    assert_err(
        &t.replace("  color: 1, 1, 1\n<next>", "  color: 1, 1\n<next>"),
        22,
        &["3 comma-separated"],
    );
    assert_err(&t.replace("<Sphere>", "<Cube>"), 58, &["unknown block"]);
    assert_err(t.trim_end().trim_end_matches("<end>"), 58, &["no <end>"]);
    assert_err(
        &t.replace("  up direction: 0, 1, 0", "  up direction: 0, 1, 1"),
        15,
        &["perpendicular"],
    );
    assert_err(
        &t.replace(
            "vertices: 30, -100, -150; 100",
            "vertices: 30, -100, -150, 100",
        ),
        49,
        &["3 points"],
    );
    assert_err(
        &t.replace("  position: -40, -50, -120\n", ""),
        58,
        &["missing `position:`"],
    );
    assert_err(
        &t.replace("  width: 700\n", "  width: 700\n  width: 800\n"),
        8,
        &["duplicate"],
    );
    assert_err(
        &t.replace("  width: 700", "  width: 0"),
        7,
        &["settings.width"],
    );
}

#[test]
fn round_trips_through_toml() {
    let s = Scene::load(&example()).unwrap().scene;
    let back = Scene::from_toml_str(&s.to_toml_string(), Path::new("."))
        .unwrap()
        .scene;
    assert_eq!(s, back);
}
