//! Where the benchmark's scenes come from: the example scenes as their files set them up,
//! and bare meshes (a mesh file, icospheres) framed by [`BenchScene::from_triangles`].

use std::path::Path;

use super::BenchScene;
use crate::scene::{Scene, SceneError};

/// Every `*.toml` scene in `dir`, in file-name order, named by file name.
pub fn example_scenes(dir: &Path) -> Result<Vec<BenchScene>, SceneError> {
    let entries = std::fs::read_dir(dir).map_err(|source| SceneError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut paths: Vec<_> = entries
        .filter_map(|e| Some(e.ok()?.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    paths.sort();
    paths
        .iter()
        .map(|p| {
            let name = p.file_name().unwrap_or_default().to_string_lossy();
            Ok(BenchScene::from_scene(name, &Scene::load(p)?.scene))
        })
        .collect()
}

/// A mesh file's triangles (any format [`Scene::load`] reads), named by its stem.
pub fn mesh(path: &Path) -> Result<BenchScene, SceneError> {
    let scene = Scene::load(path)?.scene;
    let name = path
        .file_stem()
        .map_or("mesh".into(), |s| s.to_string_lossy().into_owned());
    Ok(BenchScene::from_triangles(
        name,
        &scene.triangles_world(scene.camera.shutter_open),
    ))
}

/// An icosphere of at least `n` triangles, named `icosphere{n/1000}k`.
pub fn icosphere(n: u64) -> Result<BenchScene, SceneError> {
    let m = crate::scene::gen::icosphere_with_at_least(n)?;
    let tris: Vec<_> = m
        .indices
        .iter()
        .map(|t| t.map(|i| m.positions[i as usize]))
        .collect();
    let name = if n >= 1000 {
        format!("icosphere{}k", n / 1000)
    } else {
        format!("icosphere{n}")
    };
    Ok(BenchScene::from_triangles(name, &tris))
}
