//! Bidmon's (2010) plain-text format: never panics, errors name the file.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use vkrt::scene::scn::parse_scn;
use vkrt::scene::Limits;
use vkrt::scene::SceneError;

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
    let limits = Limits {
        max_triangles: 200_000,
        max_spheres: 20_000,
        ..Limits::default()
    };
    if let Err(e) = parse_scn(text, Path::new("mem/scene.scn"), &limits) {
        assert!(names_a_file(&e), "error names no file: {e}");
    }
});
