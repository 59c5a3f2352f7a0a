//! OBJ + MTL loading (through tobj, behind the line-numbered validator) and
//! `Scene::load` dispatch.

use std::path::{Path, PathBuf};

use glam::Vec3;
use vkrt::scene::obj::parse_obj_str;
use vkrt::scene::{Limits, MemoryFiles, MeshMaterials, Scene, SceneError};

fn scenes_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes")
}

const MTL: &str =
    "newmtl red\nKd 0.8 0.1 0.1\nnewmtl glass\nKd 0 0 0\nKs 0.1 0.1 0.1\nNi 1.5\nd 0.1\nillum 7\n";

/// Parse `obj` as `mem/m.obj` with `mem/m.mtl` = `mtl`.
fn obj(text: &str, mtl: &str) -> Result<vkrt::scene::obj::ObjMesh, SceneError> {
    let mut files = MemoryFiles::new();
    files.insert("mem/m.mtl", mtl);
    parse_obj_str(text, Path::new("mem/m.obj"), &files, &Limits::default())
}

fn obj_err(text: &str, mtl: &str) -> SceneError {
    match obj(text, mtl) {
        Ok(_) => panic!("expected an error for:\n{text}"),
        Err(e) => e,
    }
}

#[track_caller]
fn assert_at(e: &SceneError, file: &str, line: u32, needles: &[&str]) {
    let msg = e.to_string();
    assert!(
        msg.contains(&format!("{file}:{line}")),
        "not {file}:{line}: {msg}"
    );
    assert!(
        !msg.contains(&format!("{file}:{line}0")),
        "not {file}:{line}: {msg}"
    );
    for n in needles {
        assert!(msg.contains(n), "`{n}` not in: {msg}");
    }
}

const QUAD: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n";

#[test]
fn quads_polygons_and_relative_indices() {
    let m = obj(QUAD, "").unwrap();
    assert_eq!(m.mesh.indices.len(), 2);
    assert_eq!(m.materials.len(), 1, "the default material");
    let pentagon = "v 0 0 0\nv 2 0 0\nv 3 1 0\nv 1 2 0\nv -1 1 0\nf -5 -4 -3 -2 -1\n";
    let m = obj(pentagon, "").unwrap();
    assert_eq!(m.mesh.indices.len(), 3);
    let mut area = 0.0;
    for t in m.mesh.indices.iter() {
        let [a, b, c] = t.map(|i| m.mesh.positions[i as usize]);
        area += (b - a).cross(c - a).z * 0.5;
    }
    assert!((area - 5.0).abs() < 1e-6, "fan triangulation area {area}");
    // v/vt/vn forms, w weights, vertex colours.
    let text = "v 0 0 0 2\nv 2 0 0 1 0 0\nv 0 2 0\nvt 0 0\nvt 1\nvn 0 0 1\nf 1/1/1 2/2/1 3//1\n";
    let m = obj(text, "").unwrap();
    assert_eq!(m.mesh.indices.len(), 1);
    assert_eq!(*m.mesh.normals, vec![Vec3::Z; 3]);
}

#[test]
fn materials_from_mtl() {
    let text = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl red\nf 1 2 3\nusemtl glass\nf 2 4 3\nf 1 3 4\n";
    let m = obj(text, MTL).unwrap();
    let names: Vec<&str> = m.materials.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(names, ["red", "glass"]);
    assert_eq!(
        m.mesh.materials,
        MeshMaterials::PerTriangle(vec![0, 1, 1].into())
    );
    let glass = &m.materials[1];
    assert!((glass.transmission - 0.9).abs() < 1e-6);
    assert_eq!(glass.ior, 1.5);
    assert_eq!(glass.mirror, Vec3::splat(0.1), "illum 7 reflects with Ks");
    assert_eq!(m.materials[0].diffuse, Vec3::new(0.8, 0.1, 0.1));
    // Tr is 1 − d; Ke is emission; Pr roughness; a single Kd number is grey.
    let mtl =
        "newmtl lamp\nKd 0.5\nKe 2 2 1\nTr 0.25\nPr 0.3\nillum 3\nKs 0.5 0.5 0.5\nmap_Kd tex.png\n";
    let m = obj(&format!("mtllib m.mtl\nusemtl lamp\n{QUAD}"), mtl).unwrap();
    let lamp = &m.materials[0];
    assert_eq!(lamp.diffuse, Vec3::splat(0.5));
    assert_eq!(lamp.emission, Vec3::new(2.0, 2.0, 1.0));
    assert!((lamp.transmission - 0.25).abs() < 1e-6);
    assert!((lamp.roughness - 0.3).abs() < 1e-6);
    assert_eq!(lamp.mirror, Vec3::splat(0.5));
    assert!(
        m.warnings
            .iter()
            .any(|w| w.contains("map_Kd") && w.contains("mem/m.mtl:8")),
        "{:?}",
        m.warnings
    );
}

#[test]
fn house_example() {
    let loaded = Scene::load(&scenes_dir().join("house.obj")).unwrap();
    assert!(loaded.warnings.is_empty(), "{:?}", loaded.warnings);
    let s = loaded.scene;
    assert_eq!(s.triangle_count(), 30);
    assert_eq!(s.materials.len(), 5);
    assert_eq!(s.lights.len(), 1, "a default light");
    // The default camera looks at the bounds' centre from the front.
    let b = s.bounds();
    assert!((s.camera.look_at - b.center()).length() < 1e-5);
    assert!(s.camera.position.z > b.max.z);
    // Every vertex is inside the view frustum.
    let (f, r, u) = s.camera.basis();
    let half_v = (s.camera.fov.to_radians() * 0.5).tan();
    let half_h = half_v * s.settings.width as f32 / s.settings.height as f32;
    for p in s.triangles_world(0.0).iter().flatten() {
        let d = *p - s.camera.position;
        let z = d.dot(f);
        assert!(z > 0.0);
        assert!(
            d.dot(r).abs() / z <= half_h && d.dot(u).abs() / z <= half_v,
            "{p} outside"
        );
    }
    assert!(s.effects().has("refraction"));
}

#[test]
fn stanford_bunny() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes/stanford-bunny.obj");
    if !path.exists() {
        println!("SKIP stanford_bunny: {} not found", path.display());
        return;
    }
    let t0 = std::time::Instant::now();
    let loaded = Scene::load(&path).unwrap();
    println!("bunny loaded in {:.0} ms", t0.elapsed().as_secs_f64() * 1e3);
    assert_eq!(
        loaded.scene.triangle_count(),
        69_451,
        "{:?}",
        loaded.warnings
    );
    assert!(loaded.warnings.is_empty(), "{:?}", loaded.warnings);
    let sum = loaded.scene.summary();
    assert_eq!(sum.triangles, 69_451);
    assert!(sum.bounds.max[1] > sum.bounds.min[1]);
}

#[test]
fn malformed_obj_lines_name_file_and_line() {
    let cases: &[(&str, u32, &[&str])] = &[
        ("v 0 0 0\nv 1 0\n", 2, &["`v`", "found 2"]),
        ("v 0 0 0\nv 1 zero 0\n", 2, &["zero", "not a number"]),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", 4, &["at least 3"]),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", 4, &["`x`"]),
        (
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1/1/1 2 3\n",
            4,
            &["1/1/1/1"],
        ),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf /1 2 3\n", 4, &["/1"]),
        ("vn 0 0\n", 1, &["`vn`"]),
        ("vt\n", 1, &["`vt`"]),
        ("v 0 0 0 0\n", 1, &["w is 0"]),
        ("# ok\nbogus 1 2 3\n", 2, &["unknown OBJ statement `bogus`"]),
        ("usemtl\n", 1, &["needs a material name"]),
        ("mtllib\n", 1, &["needs a file name"]),
    ];
    for (text, line, needles) in cases {
        let e = obj_err(text, "");
        assert!(
            matches!(e, SceneError::Syntax { .. } | SceneError::NonFinite { .. }),
            "{e}"
        );
        assert_at(&e, "mem/m.obj", *line, needles);
    }
}

#[test]
fn nan_and_inf_in_obj() {
    for bad in ["nan", "NaN", "inf", "-inf", "1e39"] {
        let e = obj_err(&format!("v 0 0 0\nv 1 {bad} 0\nv 0 1 0\nf 1 2 3\n"), "");
        assert!(matches!(e, SceneError::NonFinite { .. }), "{bad}: {e}");
        assert_at(&e, "mem/m.obj", 2, &[bad]);
        let e = obj_err(&format!("{QUAD}vn 0 {bad} 1\n"), "");
        assert_at(&e, "mem/m.obj", 6, &[bad]);
    }
    // Finite but absurd coordinates are out of range.
    let e = obj_err("v 0 0 1e20\n", "");
    assert!(matches!(e, SceneError::OutOfRange { .. }), "{e}");
    assert_at(&e, "mem/m.obj", 1, &["1e9"]);
}

#[test]
fn obj_index_out_of_range() {
    let e = obj_err("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", "");
    assert!(
        matches!(
            e,
            SceneError::IndexOutOfRange {
                index: 4,
                len: 3,
                ..
            }
        ),
        "{e}"
    );
    assert_at(&e, "mem/m.obj", 4, &["index 4", "vertex"]);
    let e = obj_err("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "");
    assert!(
        matches!(e, SceneError::IndexOutOfRange { index: 0, .. }),
        "{e}"
    );
    let e = obj_err("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -4 1 2\n", "");
    assert!(
        matches!(e, SceneError::IndexOutOfRange { index: -4, .. }),
        "{e}"
    );
    // Forward references: the vertex is defined after the face.
    let e = obj_err("v 0 0 0\nv 1 0 0\nf 1 2 3\nv 0 1 0\n", "");
    assert_at(&e, "mem/m.obj", 3, &["index 3"]);
    let e = obj_err(
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//2 3//1\n",
        "",
    );
    assert_at(&e, "mem/m.obj", 5, &["normal"]);
    let e = obj_err("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/1 3/1\n", "");
    assert_at(&e, "mem/m.obj", 4, &["texture coordinate"]);
    let e = obj_err("v 0 0 0\nf 1 1 99999999999999999999\n", "");
    assert_at(&e, "mem/m.obj", 2, &["not an integer"]);
}

#[test]
fn mtl_errors_name_the_mtl_file_and_line() {
    let with = |mtl: &str| obj_err(&format!("# x\nmtllib m.mtl\n{QUAD}"), mtl);
    let cases: &[(&str, u32, &[&str])] = &[
        ("Kd 1 1 1\n", 1, &["before the first `newmtl`"]),
        ("newmtl a\nKd 1 2\n", 2, &["`Kd` needs 1 or 3 numbers"]),
        ("newmtl a\nKd 1 x 1\n", 2, &["`x`"]),
        ("newmtl a\nKd 1 nan 1\n", 2, &["nan"]),
        ("newmtl a\nKs -1 0 0\n", 2, &["≥ 0"]),
        ("newmtl a\nNs\n", 2, &["exactly one number"]),
        ("newmtl a\nd 1.5\n", 2, &["[0, 1]"]),
        ("newmtl a\nillum 11\n", 2, &["illum"]),
        ("newmtl a\nKa spectral file.rfl\n", 2, &["spectral"]),
        ("newmtl\n", 1, &["needs a name"]),
        ("newmtl a\nd 0.5\nNi -1\n", 3, &["Ni"]),
        ("newmtl a\nd 0.5\nNi 20\n", 3, &["index of refraction"]),
        ("newmtl a\nKs 2 2 2\nillum 3\n", 2, &["mirror reflectance"]),
    ];
    for (mtl, line, needles) in cases {
        let e = with(mtl);
        assert_at(&e, "mem/m.mtl", *line, needles);
    }
}

#[test]
fn missing_mtl_and_unknown_material() {
    // A missing library is what OBJ loaders warn about and go on without: the warning names
    // its path, and a material it would have defined is the default.
    let mut files = MemoryFiles::new();
    files.insert("mem/m.mtl", MTL);
    let m = parse_obj_str(
        &format!("mtllib other.mtl\n{QUAD}usemtl red\nf 1 2 3\n"),
        Path::new("mem/m.obj"),
        &files,
        &Limits::default(),
    )
    .unwrap();
    assert!(
        m.warnings
            .iter()
            .any(|w| w.contains("mem/other.mtl") && w.contains("not found")),
        "{:?}",
        m.warnings
    );
    assert!(
        m.warnings
            .iter()
            .any(|w| w.contains("`red`") && w.contains("default")),
        "{:?}",
        m.warnings
    );
    let names: Vec<&str> = m.materials.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(names, ["default"]);
    assert!(!m.mesh.indices.is_empty());
    let e = obj_err(&format!("mtllib m.mtl\n{QUAD}usemtl blue\nf 1 2 3\n"), MTL);
    assert!(matches!(e, SceneError::UnknownName { .. }), "{e}");
    assert_at(&e, "mem/m.obj", 7, &["blue"]);
    let e = obj_err(&format!("{QUAD}usemtl red\n"), MTL);
    assert_at(&e, "mem/m.obj", 6, &["no `mtllib`"]);
    // An absolute path is used as given, and named when it is missing
    // (found by the obj_scene fuzz target: the error names that path, not
    // the OBJ's directory).
    let mut files = MemoryFiles::new();
    files.insert("mem/m.mtl", MTL);
    let m = parse_obj_str(
        &format!("mtllib //abs/x.mtl\n{QUAD}"),
        Path::new("mem/m.obj"),
        &files,
        &Limits::default(),
    )
    .unwrap();
    assert!(
        m.warnings
            .iter()
            .any(|w| w.contains("mtllib `//abs/x.mtl` not found")),
        "{:?}",
        m.warnings
    );
    // Several libraries on one line.
    let mut files = MemoryFiles::new();
    files.insert("mem/a.mtl", "newmtl a\nKd 1 0 0\n");
    files.insert("mem/b.mtl", "newmtl b\nKd 0 1 0\n");
    let m = parse_obj_str(
        &format!("mtllib a.mtl b.mtl\n{QUAD}usemtl b\nf 1 2 3\n"),
        Path::new("mem/m.obj"),
        &files,
        &Limits::default(),
    )
    .unwrap();
    assert_eq!(
        m.materials
            .iter()
            .map(|m| m.name.as_str())
            .collect::<Vec<_>>(),
        ["a", "b", "default"]
    );
}

#[test]
fn tobj_panic_inputs_are_errors() {
    // tobj 4 unwraps a short colour array: `Kd 1 2` would panic inside it.
    let e = obj_err(&format!("mtllib m.mtl\n{QUAD}"), "newmtl a\nKd 1 2\n");
    assert_at(&e, "mem/m.mtl", 2, &["Kd"]);
    // tobj turns `l 1 2 3` into a triangle; we drop polylines and say so.
    let m = obj(&format!("{QUAD}l 1 2 3\nl 1 3\np 1\n"), "").unwrap();
    assert_eq!(m.mesh.indices.len(), 2);
    assert!(
        m.warnings
            .iter()
            .any(|w| w.contains("mem/m.obj:6") && w.contains("2 `l (polyline)` statements")),
        "{:?}",
        m.warnings
    );
    assert!(
        m.warnings.iter().any(|w| w.contains("`p (point)`")),
        "{:?}",
        m.warnings
    );
}

#[test]
fn normals_only_on_some_faces_are_dropped_with_a_warning() {
    let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\nf 2 4 3\n";
    let m = obj(text, "").unwrap();
    assert!(m.mesh.normals.is_empty());
    assert!(
        m.warnings
            .iter()
            .any(|w| w.contains("only some face vertices have normals")),
        "{:?}",
        m.warnings
    );
}

#[test]
fn obj_zero_area_and_empty() {
    let dir = std::env::temp_dir().join(format!("vkrt-obj-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("deg.obj");
    std::fs::write(&p, format!("{QUAD}f 1 1 2\nf 1 2 2\n")).unwrap();
    let loaded = Scene::load(&p).unwrap();
    assert_eq!(loaded.scene.triangle_count(), 2);
    assert!(
        loaded
            .warnings
            .iter()
            .any(|w| w.contains("dropped 2 zero-area triangles") && w.contains("deg.obj")),
        "{:?}",
        loaded.warnings
    );
    let p = dir.join("empty.obj");
    std::fs::write(&p, "# nothing\nv 0 0 0\n").unwrap();
    let e = Scene::load(&p).unwrap_err();
    assert!(matches!(e, SceneError::Empty { .. }), "{e}");
    assert!(e.to_string().contains("empty.obj"), "{e}");
    let p = dir.join("missing.obj");
    let e = Scene::load(&p).unwrap_err();
    assert!(matches!(e, SceneError::Io { .. }), "{e}");
    assert!(e.to_string().contains("missing.obj"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn obj_triangle_limit() {
    let limits = Limits {
        max_triangles: 3,
        ..Limits::default()
    };
    let files = MemoryFiles::new();
    let text = format!("{QUAD}f 1 2 3\nf 1 3 4\n");
    let e = parse_obj_str(&text, Path::new("mem/m.obj"), &files, &limits).unwrap_err();
    assert!(
        matches!(
            e,
            SceneError::TooLarge {
                count: 4,
                limit: 3,
                ..
            }
        ),
        "{e}"
    );
    assert_at(&e, "mem/m.obj", 7, &["triangle"]);
}

#[test]
fn load_dispatches_on_extension() {
    assert!(Scene::load(&scenes_dir().join("house.obj")).is_ok());
    assert!(Scene::load(&scenes_dir().join("hard_shadows.toml")).is_ok());
    assert!(Scene::load(&scenes_dir().join("whitted_example.scn")).is_ok());
    let e = Scene::load(&scenes_dir().join("house.mtl")).unwrap_err();
    assert!(matches!(e, SceneError::UnsupportedFormat { .. }), "{e}");
}
