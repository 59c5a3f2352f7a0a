//! The TOML scene format: the example scenes, round trips, and every error
//! class with the file, line and key it must name.

use std::path::{Path, PathBuf};

use glam::Vec3;
use vkrt::scene::{
    Limits, MemoryFiles, MeshMaterials, Scene, SceneError, MAX_DEPTH, MAX_RESOLUTION, MAX_SPP,
};

fn scenes_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes")
}

/// Parse in memory, messages naming `mem/test.toml`; `house.obj` and
/// `house.mtl` from scenes/ are available as `mem/house.obj`.
fn parse(text: &str) -> Result<vkrt::scene::LoadedScene, SceneError> {
    let mut files = MemoryFiles::new();
    for f in ["house.obj", "house.mtl"] {
        files.insert(
            Path::new("mem").join(f),
            std::fs::read_to_string(scenes_dir().join(f)).unwrap(),
        );
    }
    Scene::from_toml_str_with(text, Path::new("mem/test.toml"), &files, &Limits::default())
}

fn parse_err(text: &str) -> SceneError {
    match parse(text) {
        Ok(_) => panic!("expected an error for:\n{text}"),
        Err(e) => e,
    }
}

/// The error message names the file, the line and every `needle`.
#[track_caller]
fn assert_names(e: &SceneError, line: u32, needles: &[&str]) {
    let msg = e.to_string();
    assert!(msg.contains("mem/test.toml"), "no file in: {msg}");
    assert!(
        msg.contains(&format!("test.toml:{line}:")),
        "not line {line}: {msg}"
    );
    for n in needles {
        assert!(msg.contains(n), "`{n}` not in: {msg}");
    }
    assert_eq!(e.origin().and_then(|o| o.line), Some(line), "{msg}");
}

const MINIMAL: &str = r#"
[camera]
position = [0, 0, 5]
look_at = [0, 0, 0]

[materials.red]
diffuse = [0.8, 0.1, 0.1]

[[lights]]
type = "point"
position = [0, 5, 5]

[[spheres]]
center = [0, 0, 0]
radius = 1
material = "red"
"#;

#[test]
fn minimal_scene_and_defaults() {
    let loaded = parse(MINIMAL).unwrap();
    assert!(loaded.warnings.is_empty(), "{:?}", loaded.warnings);
    let s = loaded.scene;
    assert_eq!(s.spheres.len(), 1);
    assert_eq!(s.materials.len(), 1);
    assert_eq!(s.materials[0].name, "red");
    assert_eq!(s.settings.width, 640);
    assert_eq!(s.settings.height, 480);
    assert_eq!(s.camera.fov, 40.0);
    assert_eq!(s.camera.focus_distance, 5.0);
    assert_eq!(s.camera.up, Vec3::Y);
    assert_eq!(s.effects().names(), ["hard_shadows"]);
}

/// Expected effects of every example in scenes/.
const EXAMPLES: &[(&str, &[&str])] = &[
    ("hard_shadows.toml", &["hard_shadows"]),
    ("soft_shadows.toml", &["soft_shadows", "antialiasing"]),
    ("reflection.toml", &["hard_shadows", "reflection"]),
    (
        "glossy.toml",
        &["hard_shadows", "reflection", "glossy", "antialiasing"],
    ),
    (
        "refraction.toml",
        &["hard_shadows", "reflection", "refraction"],
    ),
    ("antialiasing.toml", &["hard_shadows", "antialiasing"]),
    (
        "depth_of_field.toml",
        &["hard_shadows", "antialiasing", "depth_of_field"],
    ),
    (
        "motion_blur.toml",
        &["hard_shadows", "antialiasing", "motion_blur"],
    ),
    (
        "ambient_occlusion.toml",
        &["antialiasing", "ambient_occlusion"],
    ),
    ("emission.toml", &["emission"]),
    (
        "mesh_file.toml",
        &["hard_shadows", "reflection", "refraction", "antialiasing"],
    ),
    (
        "dynamic_demo.toml",
        &["hard_shadows", "reflection", "refraction"],
    ),
    (
        "dynamic_demo_glass.toml",
        &["hard_shadows", "reflection", "refraction"],
    ),
];

#[test]
fn every_example_loads_with_its_effects() {
    let mut seen = Vec::new();
    for entry in std::fs::read_dir(scenes_dir()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            seen.push(path.file_name().unwrap().to_string_lossy().into_owned());
        }
    }
    seen.sort();
    let mut listed: Vec<String> = EXAMPLES.iter().map(|e| e.0.to_owned()).collect();
    listed.sort();
    assert_eq!(
        seen, listed,
        "every example must have its expected effects listed here"
    );
    for (file, effects) in EXAMPLES {
        let loaded = Scene::load(&scenes_dir().join(file)).unwrap_or_else(|e| panic!("{e}"));
        // The one warning an example may give: ../shared's bunny is absent
        // and its stand-in is used (dynamic_demo*.toml).
        assert!(
            loaded
                .warnings
                .iter()
                .all(|w| w.contains("stanford-bunny.obj does not exist")),
            "{file}: {:?}",
            loaded.warnings
        );
        assert_eq!(loaded.scene.effects().names(), *effects, "{file}");
    }
    // Every effect is demonstrated by some example.
    let all: Vec<&str> = EXAMPLES.iter().flat_map(|e| e.1.iter().copied()).collect();
    for name in vkrt::scene::Effects::ALL_NAMES {
        assert!(all.contains(&name), "no example shows {name}");
    }
}

#[test]
fn mesh_file_example_resolves_relative_path_and_materials() {
    let s = Scene::load(&scenes_dir().join("mesh_file.toml"))
        .unwrap()
        .scene;
    assert_eq!(s.meshes.len(), 3);
    assert_eq!(s.meshes[0].indices.len(), 30);
    assert_eq!(s.meshes[1].indices.len(), 30);
    // First copy: the MTL's five materials, appended after the file's own.
    let names: Vec<&str> = s.materials.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(
        names,
        ["grass", "stone", "wall", "roof", "brick", "door", "window"]
    );
    let MeshMaterials::PerTriangle(ids) = &s.meshes[0].materials else {
        panic!("house uses several materials")
    };
    assert!(ids.iter().all(|&i| (2..7).contains(&i)));
    let window = &s.materials[6];
    assert!((window.transmission - 0.8).abs() < 1e-6);
    assert_eq!(window.ior, 1.5);
    assert_eq!(window.mirror, Vec3::splat(0.3));
    // Second copy: material override and its own transform.
    assert_eq!(s.meshes[1].materials, MeshMaterials::Single(1));
    assert_eq!(s.meshes[1].name, "stone house");
    assert_eq!(s.meshes[1].transform.scale, Vec3::splat(0.8));
    assert_eq!(s.meshes[1].transform.rotate, Vec3::new(0.0, -30.0, 0.0));
}

#[test]
fn round_trip_toml_scene_toml() {
    for (file, _) in EXAMPLES {
        let a = Scene::load(&scenes_dir().join(file)).unwrap().scene;
        let text = a.to_toml_string();
        let b = Scene::from_toml_str(&text, &scenes_dir())
            .unwrap_or_else(|e| panic!("{file}: {e}\n{text}"))
            .scene;
        assert_eq!(a, b, "{file}");
        assert_eq!(a.summary(), b.summary(), "{file}");
        assert_eq!(
            text,
            b.to_toml_string(),
            "{file}: writer is not a fixed point"
        );
    }
    for mut s in [
        Scene::default_scene(),
        vkrt::scene::gen::dynamic_ring(vkrt::scene::gen::icosphere(1).unwrap(), 5).unwrap(),
    ] {
        s.validate().unwrap();
        let text = s.to_toml_string();
        let back = Scene::from_toml_str(&text, Path::new(".")).unwrap().scene;
        assert_eq!(s, back);
    }
}

#[test]
fn round_trip_exotic_names_and_floats() {
    let mut s = Scene::default_scene();
    s.materials[0].name = "white \"quoted\" [x]".to_owned();
    s.materials[1].name = "red".to_owned();
    s.materials[2].name = "red".to_owned(); // duplicate: made unique
    s.materials[3].diffuse = Vec3::new(0.1, 1e-7, 3.4028235e38);
    s.camera.fov = 33.333332;
    let text = s.to_toml_string();
    let back = Scene::from_toml_str(&text, Path::new(".")).unwrap().scene;
    assert_eq!(back.materials[0].name, "white \"quoted\" [x]");
    assert_eq!(
        back.materials
            .iter()
            .filter(|m| m.name.starts_with("red"))
            .count(),
        2
    );
    assert_eq!(back.materials[3].diffuse, s.materials[3].diffuse);
    assert_eq!(back.camera.fov, s.camera.fov);
    assert_eq!(back.meshes, s.meshes);
}

#[test]
fn generators_in_toml() {
    let text = r#"
[camera]
position = [0, 0, 10]
look_at = [0, 0, 0]
[[meshes]]
generate = "icosphere"
subdivisions = 2
[[meshes]]
generate = "geodesic_sphere"
min_triangles = 1000
[[meshes]]
generate = "random_soup"
count = 100
seed = 3
[[meshes]]
generate = "integer_grid"
nx = 3
ny = 2
[[meshes]]
generate = "sphere_flake"
depth = 1
subdivisions = 0
"#;
    let s = parse(text).unwrap().scene;
    let counts: Vec<usize> = s.meshes.iter().map(|m| m.indices.len()).collect();
    assert_eq!(counts, [320, 1280, 100, 12, 200]);
    // Objects without a material get the implicit default.
    assert_eq!(s.materials.len(), 1);
    assert_eq!(s.materials[0].name, "default");
}

// --- error classes ---------------------------------------------------------

#[test]
fn missing_scene_file_names_the_path() {
    let p = scenes_dir().join("does_not_exist.toml");
    let e = Scene::load(&p).unwrap_err();
    assert!(matches!(e, SceneError::Io { .. }));
    assert!(e.to_string().contains("does_not_exist.toml"), "{e}");
    // A directory is not a scene file either.
    let e = Scene::load(&scenes_dir().join("dir.toml")).unwrap_err();
    assert!(e.to_string().contains("dir.toml"), "{e}");
}

#[test]
fn unknown_extension_is_an_error() {
    let e = Scene::load(Path::new("scene.yaml")).unwrap_err();
    assert!(matches!(e, SceneError::UnsupportedFormat { .. }), "{e}");
    assert!(e.to_string().contains("scene.yaml"), "{e}");
    let e = Scene::load(Path::new("noext")).unwrap_err();
    assert!(matches!(e, SceneError::UnsupportedFormat { .. }), "{e}");
}

#[test]
fn missing_mesh_file_names_the_path() {
    let e = parse_err(&format!(
        "{MINIMAL}\n[[meshes]]\npath = \"nope/missing.obj\"\n"
    ));
    assert!(matches!(e, SceneError::Io { .. }), "{e}");
    assert!(e.to_string().contains("mem/nope/missing.obj"), "{e}");
    let e = parse_err(&format!("{MINIMAL}\n[[meshes]]\npath = \"model.ply\"\n"));
    assert_names(&e, 19, &["meshes[0].path", "model.ply", ".obj"]);
}

#[test]
fn syntax_error_names_line() {
    let e = parse_err("[camera]\nposition = [0, 0, 5\nlook_at = [0, 0, 0]\n");
    assert!(matches!(e, SceneError::Syntax { .. }));
    let msg = e.to_string();
    assert!(msg.starts_with("mem/test.toml:"), "{msg}");
    assert!(
        msg.contains("test.toml:2:") || msg.contains("test.toml:3:"),
        "{msg}"
    );
}

#[test]
fn unknown_key_names_key_and_line() {
    let text = MINIMAL.replace("radius = 1\n", "radius = 1\ncolour = [1, 0, 0]\n");
    let e = parse_err(&text);
    assert!(matches!(e, SceneError::Syntax { .. }));
    assert_names(&e, 16, &["colour", "spheres[0].colour"]);
    // At top level and in nested tables too.
    let e = parse_err(&format!("ambiant = [0, 0, 0]\n{MINIMAL}"));
    assert_names(&e, 1, &["ambiant"]);
    let e = parse_err(&format!("{MINIMAL}\n[settings.ao]\nraduis = 2\n"));
    assert_names(&e, 19, &["raduis", "settings.ao.raduis"]);
    let e = parse_err(&MINIMAL.replace("[materials.red]\n", "[materials.red]\nglosy = 1\n"));
    assert_names(&e, 7, &["glosy", "materials.red.glosy"]);
}

#[test]
fn wrong_type_names_key_and_line() {
    let e = parse_err(&MINIMAL.replace("radius = 1\n", "radius = \"big\"\n"));
    assert_names(&e, 15, &["spheres[0].radius", "invalid type"]);
    let e = parse_err(&MINIMAL.replace("position = [0, 0, 5]", "position = [0, 0]"));
    assert_names(&e, 3, &["camera.position", "length 2"]);
    let e = parse_err(&format!("{MINIMAL}\n[settings]\nspp = -4\n"));
    assert_names(&e, 19, &["settings.spp", "-4"]);
    let e = parse_err(&format!("{MINIMAL}\n[settings]\nwidth = 1.5\n"));
    assert_names(&e, 19, &["settings.width"]);
    let e = parse_err(&MINIMAL.replace("type = \"point\"", "type = \"spot\""));
    assert_names(&e, 10, &["lights[0].type", "spot"]);
    let e = parse_err(&format!("{MINIMAL}\n[[meshes]]\ngenerate = \"cube\"\n"));
    assert_names(&e, 19, &["meshes[0].generate", "cube"]);
    let e = parse_err(&format!(
        "{MINIMAL}\n[[meshes]]\npositions = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nindices = [[0, 1, \"2\"]]\n"
    ));
    assert_names(&e, 20, &["meshes[0].indices[0][2]"]);
}

/// Every numeric key of a scene, set to `nan` (and to `inf`), is rejected
/// with its key and line.
#[test]
fn nan_and_inf_anywhere() {
    let base = r#"ambient = [0.1, 0.1, 0.1]
[settings]
background = [0, 0, 0]
[settings.ao]
enabled = true
radius = 1.0
samples = 4
[camera]
position = [0, 0, 5]
look_at = [0, 0, 0]
up = [0, 1, 0]
fov = 40
aperture = 0.1
focus_distance = 5
shutter = [0, 0.5]
[materials.m]
diffuse = [0.5, 0.5, 0.5]
specular = [0.5, 0.5, 0.5]
shininess = 10
mirror = 0.5
roughness = 0.1
transmission = 0.5
ior = 1.5
emission = [0, 0, 0]
[[lights]]
type = "point"
position = [0, 5, 0]
color = [1, 1, 1]
intensity = 1
[[lights]]
type = "sphere"
center = [0, 5, 0]
radius = 0.5
[[lights]]
type = "quad"
corner = [0, 5, 0]
edge_u = [1, 0, 0]
edge_v = [0, 0, 1]
[[lights]]
type = "directional"
direction = [0, -1, 0]
[[spheres]]
center = [0, 0, 0]
radius = 1
material = "m"
velocity = [1, 0, 0]
[spheres.orbit]
center = [0, 0, 0]
axis = [0, 1, 0]
degrees_per_second = 10
[[meshes]]
positions = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
normals = [[0, 0, 1], [0, 0, 1], [0, 0, 1]]
indices = [[0, 1, 2]]
material = "m"
translate = [0, 0, 0]
rotate = [0, 0, 0]
scale = [1, 1, 1]
"#;
    parse(base).unwrap();
    let lines: Vec<&str> = base.lines().collect();
    let mut tested = 0;
    for (i, line) in lines.iter().enumerate() {
        let Some((key, value)) = line.split_once(" = ") else {
            continue;
        };
        if !value.starts_with(|c: char| c == '[' || c == '-' || c.is_ascii_digit()) {
            continue;
        }
        if key == "samples" || key == "indices" {
            continue; // integers: nan is a type error there (tested elsewhere)
        }
        for bad in ["nan", "inf", "-inf"] {
            // Replace the first number of the value.
            let new_value = if value.starts_with("[[") {
                value.replacen("[[0", &format!("[[{bad}"), 1)
            } else if let Some(inner) = value.strip_prefix('[') {
                let rest = inner.split_once(',').map_or("]", |r| r.1);
                format!("[{bad},{rest}")
            } else {
                bad.to_owned()
            };
            let mut text_lines = lines.clone();
            let new_line = format!("{key} = {new_value}");
            text_lines[i] = &new_line;
            let text = text_lines.join("\n");
            let e = match parse(&text) {
                Ok(_) => panic!("{bad} accepted in line {}: {new_line}", i + 1),
                Err(e) => e,
            };
            let msg = e.to_string();
            assert!(
                msg.contains(&format!("test.toml:{}:", i + 1)),
                "{bad} in `{new_line}` (line {}) reported as: {msg}",
                i + 1
            );
            assert!(msg.contains(key), "key `{key}` not named in: {msg}");
            tested += 1;
        }
    }
    assert!(tested >= 3 * 35, "only {tested} cases");
}

#[test]
fn out_of_range_values() {
    let cases: &[(&str, &str, u32, &[&str])] = &[
        (
            "radius = 1\n",
            "radius = -2\n",
            15,
            &["spheres[0].radius", "-2", "> 0"],
        ),
        ("radius = 1\n", "radius = 0\n", 15, &["spheres[0].radius"]),
        (
            "look_at = [0, 0, 0]",
            "look_at = [0, 0, 0]\nfov = 180",
            5,
            &["camera.fov", "180"],
        ),
        (
            "look_at = [0, 0, 0]",
            "look_at = [0, 0, 0]\nup = [0, 0, 1]",
            5,
            &["camera.up", "parallel"],
        ),
        (
            "look_at = [0, 0, 0]",
            "look_at = [0, 0, 5]",
            4,
            &["camera.look_at"],
        ),
        (
            "look_at = [0, 0, 0]",
            "look_at = [0, 0, 0]\nshutter = [1, 0]",
            5,
            &["camera.shutter"],
        ),
        (
            "look_at = [0, 0, 0]",
            "look_at = [0, 0, 0]\naperture = -1",
            5,
            &["camera.aperture"],
        ),
        (
            "diffuse = [0.8, 0.1, 0.1]",
            "diffuse = [0.8, -0.1, 0.1]",
            7,
            &["materials.red.diffuse", "≥ 0"],
        ),
        (
            "diffuse = [0.8, 0.1, 0.1]",
            "diffuse = [0.8, 0.1, 0.1]\nior = 0",
            8,
            &["materials.red.ior"],
        ),
        (
            "diffuse = [0.8, 0.1, 0.1]",
            "diffuse = [0.8, 0.1, 0.1]\nmirror = 1.5",
            8,
            &["materials.red.mirror"],
        ),
        (
            "diffuse = [0.8, 0.1, 0.1]",
            "diffuse = [0.8, 0.1, 0.1]\nroughness = 2",
            8,
            &["materials.red.roughness"],
        ),
        (
            "diffuse = [0.8, 0.1, 0.1]",
            "diffuse = [0.8, 0.1, 0.1]\ntransmission = -0.5",
            8,
            &["materials.red.transmission"],
        ),
        (
            "position = [0, 5, 5]",
            "position = [0, 5, 5]\nintensity = -3",
            12,
            &["lights[0].intensity"],
        ),
        (
            "position = [0, 0, 5]",
            "position = [0, 0, 5e10]",
            3,
            &["camera.position", "1e9"],
        ),
    ];
    for (from, to, line, needles) in cases {
        assert!(MINIMAL.contains(from));
        let e = parse_err(&MINIMAL.replacen(from, to, 1));
        assert!(
            matches!(
                e,
                SceneError::OutOfRange { .. } | SceneError::Invalid { .. }
            ),
            "{e}"
        );
        assert_names(&e, *line, needles);
    }
}

#[test]
fn zero_size_image_and_absurd_settings() {
    let with = |settings: &str| format!("{MINIMAL}\n[settings]\n{settings}\n");
    let e = parse_err(&with("width = 0"));
    assert_names(&e, 19, &["settings.width", "0", "1 ..= 16384"]);
    let e = parse_err(&with("height = 0"));
    assert_names(&e, 19, &["settings.height"]);
    let e = parse_err(&with(&format!("width = {}", MAX_RESOLUTION + 1)));
    assert_names(
        &e,
        19,
        &["settings.width", &(MAX_RESOLUTION + 1).to_string()],
    );
    let e = parse_err(&with("width = 16384\nheight = 16384"));
    assert_names(&e, 19, &["settings.width", "pixels"]);
    let e = parse_err(&with(&format!("spp = {}", MAX_SPP + 1)));
    assert_names(&e, 19, &["settings.spp", &MAX_SPP.to_string()]);
    let e = parse_err(&with("spp = 0"));
    assert_names(&e, 19, &["settings.spp"]);
    let e = parse_err(&with(&format!("max_depth = {}", MAX_DEPTH + 1)));
    assert_names(&e, 19, &["settings.max_depth", &MAX_DEPTH.to_string()]);
    let e = parse_err(&format!("{MINIMAL}\n[settings.ao]\nsamples = 100000\n"));
    assert_names(&e, 19, &["settings.ao.samples"]);
    let e = parse_err(&format!("{MINIMAL}\n[settings.ao]\nradius = 0\n"));
    assert_names(&e, 19, &["settings.ao.radius"]);
    // Integers beyond u32 are type errors, still with key and line.
    let e = parse_err(&with("spp = 99999999999"));
    assert_names(&e, 19, &["settings.spp"]);
}

#[test]
fn unknown_material_names_key_line_and_candidates() {
    let e = parse_err(&MINIMAL.replace("material = \"red\"", "material = \"blue\""));
    assert!(matches!(e, SceneError::UnknownName { .. }), "{e}");
    assert_names(&e, 16, &["spheres[0].material", "blue", "red"]);
}

#[test]
fn index_out_of_range_inline_mesh() {
    let e = parse_err(&format!(
        "{MINIMAL}\n[[meshes]]\npositions = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nindices = [\n  [0, 1, 2],\n  [0, 1, 3],\n]\n"
    ));
    assert!(
        matches!(
            e,
            SceneError::IndexOutOfRange {
                index: 3,
                len: 3,
                ..
            }
        ),
        "{e}"
    );
    assert_names(&e, 22, &["meshes[0].indices[1]", "3"]);
    let e = parse_err(&format!(
        "{MINIMAL}\n[[meshes]]\npositions = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nindices = [[0, 1, 2]]\nnormals = [[0, 0, 1]]\n"
    ));
    assert_names(&e, 21, &["meshes[0].normals", "1 normals for 3 positions"]);
    let e = parse_err(&format!(
        "{MINIMAL}\n[[meshes]]\npositions = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nindices = [[0, 1, 2]]\ntriangle_materials = [\"red\", \"red\"]\n"
    ));
    assert_names(
        &e,
        21,
        &["meshes[0].triangle_materials", "2 entries for 1 triangles"],
    );
}

#[test]
fn empty_scene_is_an_error() {
    let e = parse_err("[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\n");
    assert!(matches!(e, SceneError::Empty { .. }), "{e}");
    assert!(e.to_string().contains("mem/test.toml"), "{e}");
    assert!(e.to_string().contains("empty"), "{e}");
    let e = parse_err("");
    assert!(matches!(e, SceneError::Empty { .. }), "{e}");
    // Only degenerate triangles: empty, saying why.
    let e = parse_err(
        "[[meshes]]\npositions = [[0, 0, 0], [1, 0, 0], [2, 0, 0]]\nindices = [[0, 1, 2]]\n",
    );
    assert!(e.to_string().contains("zero area"), "{e}");
}

#[test]
fn zero_area_triangles_are_a_warning_not_an_error() {
    let loaded = parse(&format!(
        "{MINIMAL}\n[[meshes]]\npositions = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]]\nindices = [[0, 1, 2], [0, 1, 3], [2, 2, 1]]\n"
    ))
    .unwrap();
    assert_eq!(*loaded.scene.meshes[0].indices, vec![[0, 1, 2]]);
    assert_eq!(loaded.warnings.len(), 1, "{:?}", loaded.warnings);
    assert!(
        loaded.warnings[0].contains("dropped 2 zero-area triangles"),
        "{:?}",
        loaded.warnings
    );
    assert!(
        loaded.warnings[0].contains("mem/test.toml"),
        "{:?}",
        loaded.warnings
    );
}

#[test]
fn scene_larger_than_the_limits() {
    let limits = Limits {
        max_triangles: 100,
        max_spheres: 2,
        ..Limits::default()
    };
    let files = MemoryFiles::new();
    let name = Path::new("mem/test.toml");
    let e = Scene::from_toml_str_with(
        &format!("{MINIMAL}\n[[meshes]]\ngenerate = \"icosphere\"\nsubdivisions = 2\n"),
        name,
        &files,
        &limits,
    )
    .unwrap_err();
    assert!(
        matches!(
            e,
            SceneError::TooLarge {
                count: 320,
                limit: 100,
                ..
            }
        ),
        "{e}"
    );
    assert_names(&e, 19, &["meshes[0].generate", "320", "100"]);
    let three = format!(
        "{MINIMAL}{}",
        "[[spheres]]\ncenter = [0, 0, 0]\nradius = 1\n".repeat(2)
    );
    let e = Scene::from_toml_str_with(&three, name, &files, &limits).unwrap_err();
    assert!(
        matches!(e, SceneError::TooLarge { what: "sphere", .. }),
        "{e}"
    );
    // The default limit stops absurd generators before they allocate.
    let e = parse_err(&format!(
        "{MINIMAL}\n[[meshes]]\ngenerate = \"icosphere\"\nsubdivisions = 40\n"
    ));
    assert!(matches!(e, SceneError::TooLarge { .. }), "{e}");
    assert_names(&e, 19, &["meshes[0].generate"]);
    let e = parse_err(&format!(
        "{MINIMAL}\n[[meshes]]\ngenerate = \"sphere_flake\"\ndepth = 4000000000\n"
    ));
    assert!(matches!(e, SceneError::TooLarge { .. }), "{e}");
}

/// A mesh named many times is held once: its entries share one geometry (each with its own
/// placement and material) and count once against the triangle limit, every copy against
/// the instanced limit.
#[test]
fn a_repeated_mesh_is_held_once_and_counted_once() {
    let limits = Limits {
        max_triangles: 1_000,
        max_instanced_triangles: 100_000,
        ..Limits::default()
    };
    let files = MemoryFiles::new();
    let name = Path::new("mem/test.toml");
    let entry = |i: usize| {
        format!(
            "\n[[meshes]]\ngenerate = \"icosphere\"\nsubdivisions = 2\ntranslate = [{i}, 0, 0]\n"
        )
    };
    // 320 triangles, named 300 times: 96,000 placed, 320 held.
    let text: String = (0..300).map(entry).collect();
    let loaded =
        Scene::from_toml_str_with(&format!("{MINIMAL}{text}"), name, &files, &limits).unwrap();
    let meshes = &loaded.scene.meshes;
    assert_eq!(meshes.len(), 300);
    assert_eq!(loaded.scene.triangle_count(), 96_000);
    for m in &meshes[1..] {
        assert!(std::sync::Arc::ptr_eq(&m.positions, &meshes[0].positions));
        assert!(std::sync::Arc::ptr_eq(&m.indices, &meshes[0].indices));
    }
    assert_eq!(meshes[299].transform.translate, Vec3::new(299.0, 0.0, 0.0));
    assert_eq!(loaded.scene.mesh_groups().len(), 1);
    // Another generator's parameters: another mesh, counted too.
    let other = "\n[[meshes]]\ngenerate = \"icosphere\"\nsubdivisions = 3\n";
    let e = Scene::from_toml_str_with(&format!("{MINIMAL}{text}{other}"), name, &files, &limits)
        .unwrap_err();
    assert!(
        matches!(
            e,
            SceneError::TooLarge {
                what: "triangle",
                count: 1_600,
                limit: 1_000,
                ..
            }
        ),
        "{e}"
    );
    // Every copy counts against the instanced limit.
    let text: String = (0..313).map(entry).collect();
    let e =
        Scene::from_toml_str_with(&format!("{MINIMAL}{text}"), name, &files, &limits).unwrap_err();
    assert!(
        matches!(
            e,
            SceneError::TooLarge {
                what: "instanced triangle",
                count: 100_160,
                limit: 100_000,
                ..
            }
        ),
        "{e}"
    );
    let msg = e.to_string();
    for needle in [
        "mem/test.toml",
        "meshes[312]",
        "instanced triangle",
        "100160",
        "100000",
    ] {
        assert!(msg.contains(needle), "`{needle}` not in: {msg}");
    }
    // An OBJ file named again is read once and shared, with or without a material of the
    // entry's own.
    let mut files = MemoryFiles::new();
    files.insert(
        "mem/quad.obj",
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n",
    );
    let quads = "\n[[meshes]]\npath = \"quad.obj\"\nmaterial = \"red\"\n\n[[meshes]]\npath = \"quad.obj\"\n";
    let loaded =
        Scene::from_toml_str_with(&format!("{MINIMAL}{quads}{quads}"), name, &files, &limits)
            .unwrap();
    let meshes = &loaded.scene.meshes;
    assert_eq!(meshes.len(), 4);
    for m in &meshes[1..] {
        assert!(std::sync::Arc::ptr_eq(&m.indices, &meshes[0].indices));
    }
}

#[test]
fn structural_mistakes_in_meshes_and_lights() {
    let e = parse_err(&format!("{MINIMAL}\n[[meshes]]\nname = \"nothing\"\n"));
    assert_names(&e, 18, &["meshes[0]", "exactly one of"]);
    let e = parse_err(&format!(
        "{MINIMAL}\n[[meshes]]\ngenerate = \"icosphere\"\n"
    ));
    assert_names(&e, 19, &["meshes[0].generate", "subdivisions"]);
    let e = parse_err(&format!(
        "{MINIMAL}\n[[meshes]]\ngenerate = \"icosphere\"\nsubdivisions = 1\nnx = 3\n"
    ));
    assert_names(&e, 21, &["meshes[0].nx", "icosphere"]);
    let e = parse_err(&format!("{MINIMAL}\n[[meshes]]\npositions = [[0, 0, 0]]\n"));
    assert_names(&e, 18, &["meshes[0].indices"]);
    let e = parse_err(&MINIMAL.replace("position = [0, 5, 5]", "center = [0, 5, 5]"));
    assert_names(&e, 11, &["lights[0].center", "point light"]);
    let e = parse_err(&MINIMAL.replace("position = [0, 5, 5]\n", ""));
    assert_names(&e, 9, &["lights[0]", "needs `position`"]);
    let e = parse_err(&format!(
        "{MINIMAL}\n[[lights]]\ntype = \"quad\"\ncorner = [0, 0, 0]\nedge_u = [1, 0, 0]\nedge_v = [2, 0, 0]\n"
    ));
    assert_names(&e, 22, &["lights[1].edge_v", "parallel"]);
    let e = parse_err(&format!(
        "{MINIMAL}\n[[meshes]]\ngenerate = \"integer_grid\"\nnx = 2\nny = 2\nscale = 0\n"
    ));
    assert_names(&e, 22, &["meshes[0].scale", "zero"]);
}

#[test]
fn camera_is_optional() {
    let loaded = parse("[[spheres]]\ncenter = [1, 2, 3]\nradius = 2\n").unwrap();
    assert!(
        loaded.warnings.iter().any(|w| w.contains("no [camera]")),
        "{:?}",
        loaded.warnings
    );
    let c = loaded.scene.camera;
    assert_eq!(c.look_at, Vec3::new(1.0, 2.0, 3.0));
    assert!((c.position - c.look_at).length() > 2.0);
    assert!(
        loaded.warnings.iter().any(|w| w.contains("no lights")),
        "{:?}",
        loaded.warnings
    );
}

#[test]
fn invalid_utf8_names_line() {
    let dir = std::env::temp_dir().join(format!("vkrt-scene-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("bad.toml");
    let mut bytes = MINIMAL.as_bytes().to_vec();
    bytes.extend_from_slice(b"\n# caf\xe9\n");
    std::fs::write(&p, bytes).unwrap();
    let e = Scene::load(&p).unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains("bad.toml:18:"), "{msg}");
    assert!(msg.contains("UTF-8"), "{msg}");
    std::fs::remove_dir_all(&dir).unwrap();
}
