//! TOML scene loader: never panics; a scene that loads writes back to TOML
//! and reads again with the same summary. Referenced meshes come from an
//! in-memory file set (house.obj/.mtl), so the fuzzer never touches disk.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use vkrt::scene::SceneError;
use vkrt::scene::{Limits, MemoryFiles, Scene};

fn limits() -> Limits {
    // Small enough that generators cannot make an iteration slow.
    Limits {
        max_triangles: 200_000,
        max_instanced_triangles: 2_000_000,
        max_vertices: 600_000,
        max_spheres: 20_000,
        max_file_bytes: 1 << 20,
        ..Limits::default()
    }
}

/// Every error says which file it is about (the path may be anything the
/// input names, e.g. an absolute `mtllib`).
fn names_a_file(e: &SceneError) -> bool {
    matches!(
        e,
        SceneError::Io { .. } | SceneError::UnsupportedFormat { .. }
    ) || e.origin().is_some_and(|o| o.file.is_some())
}

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let mut files = MemoryFiles::new();
    files.insert("mem/house.obj", include_str!("../../scenes/house.obj"));
    files.insert("mem/house.mtl", include_str!("../../scenes/house.mtl"));
    let limits = limits();
    match Scene::from_toml_str_with(text, Path::new("mem/scene.toml"), &files, &limits) {
        Err(e) => {
            assert!(names_a_file(&e), "error names no file: {e}");
        }
        Ok(loaded) => {
            let s = loaded.scene;
            let _ = s.effects().names();
            let _ = s.triangles_world(s.camera.shutter_close);
            let written = s.to_toml_string();
            let back =
                Scene::from_toml_str_with(&written, Path::new("mem/back.toml"), &files, &limits)
                    .unwrap_or_else(|e| panic!("written scene does not read back: {e}\n{written}"));
            assert_eq!(back.scene.summary(), s.summary());
        }
    }
});
