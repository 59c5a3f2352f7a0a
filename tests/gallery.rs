//! `docs/gallery.md` shows every example scene: each scene under `scenes/` (and the default
//! scene) has a PNG in `docs/gallery/` that decodes, and the page shows it.

use std::path::Path;

#[test]
fn every_example_scene_has_its_picture_in_the_gallery() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let page = std::fs::read_to_string(root.join("docs/gallery.md")).expect("docs/gallery.md");
    let mut names = vec!["default".to_string()];
    for entry in std::fs::read_dir(root.join("scenes")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml" || e == "scn") {
            names.push(path.file_stem().unwrap().to_string_lossy().into_owned());
        }
    }
    assert!(names.len() > 10, "{names:?}");
    for name in &names {
        let png = root.join("docs/gallery").join(format!("{name}.png"));
        let image = image::open(&png).unwrap_or_else(|e| panic!("{}: {e}", png.display()));
        assert!(
            image.width() >= 128 && image.height() >= 128,
            "{name}: too small"
        );
        assert!(
            page.contains(&format!("(gallery/{name}.png)")),
            "docs/gallery.md does not show {name}.png"
        );
    }
}
