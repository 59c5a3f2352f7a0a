//! OBJ + MTL loader (validator in front of tobj): never panics, errors name
//! a file, loaded meshes pass validation. Input: OBJ text, optionally
//! followed by a NUL byte and the text of `m.mtl` (which the OBJ can load
//! with `mtllib m.mtl`).
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use vkrt::scene::obj::parse_obj_str;
use vkrt::scene::SceneError;
use vkrt::scene::{validate, Limits, MemoryFiles, Scene};

/// Every error says which file it is about (the path may be anything the
/// input names, e.g. an absolute `mtllib`).
fn names_a_file(e: &SceneError) -> bool {
    matches!(
        e,
        SceneError::Io { .. } | SceneError::UnsupportedFormat { .. }
    ) || e.origin().is_some_and(|o| o.file.is_some())
}

fuzz_target!(|data: &[u8]| {
    let (obj, mtl) = match data.iter().position(|&b| b == 0) {
        Some(p) => (&data[..p], &data[p + 1..]),
        None => (data, &[][..]),
    };
    let (Ok(obj), Ok(mtl)) = (std::str::from_utf8(obj), std::str::from_utf8(mtl)) else {
        return;
    };
    let mut files = MemoryFiles::new();
    files.insert("mem/m.mtl", mtl);
    let limits = Limits {
        max_triangles: 200_000,
        max_vertices: 600_000,
        ..Limits::default()
    };
    match parse_obj_str(obj, Path::new("mem/m.obj"), &files, &limits) {
        Err(e) => {
            assert!(names_a_file(&e), "error names no file: {e}");
        }
        Ok(m) => {
            let mut scene = Scene::from_geometry(vec![m.mesh], Vec::new(), m.materials);
            if validate::validate(&mut scene, &limits).is_ok() {
                let back = Scene::from_toml_str_with(
                    &scene.to_toml_string(),
                    Path::new("mem/back.toml"),
                    &files,
                    &limits,
                )
                .expect("a validated OBJ scene writes and reads back");
                assert_eq!(back.scene.summary(), scene.summary());
            }
        }
    }
});
