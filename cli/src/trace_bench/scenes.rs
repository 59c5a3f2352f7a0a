//! Where the benchmark's scenes come from: the example scenes as their files set them up,
//! and bare meshes (a mesh file, icospheres) framed by [`BenchScene::from_triangles`].

use std::path::{Path, PathBuf};

use glam::Vec3;

use super::BenchScene;
use vkrt::scene::{Scene, SceneError};

/// The benchmarks' default mesh: the file `$VKRT_MESH` names (`./x` sets it to the Stanford
/// bunny beside the checkout, where that is present). `None`, with a warning, where it is
/// unset or names no file: the benchmarks then use generated meshes.
pub fn default_mesh() -> Option<PathBuf> {
    let Some(path) = std::env::var_os("VKRT_MESH").map(PathBuf::from) else {
        log::warn!("no mesh given (--mesh or VKRT_MESH): generated meshes only");
        return None;
    };
    if path.is_file() {
        Some(path)
    } else {
        log::warn!(
            "VKRT_MESH names no file ({}): generated meshes only",
            path.display()
        );
        None
    }
}

/// Every `*.toml` file in `dir`, in file-name order.
pub fn scene_files(dir: &Path) -> Result<Vec<PathBuf>, SceneError> {
    let entries = std::fs::read_dir(dir).map_err(|source| SceneError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut paths: Vec<_> = entries
        .filter_map(|e| Some(e.ok()?.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    paths.sort();
    Ok(paths)
}

/// Every `*.toml` scene in `dir`, in file-name order, named by file name.
pub fn example_scenes(dir: &Path) -> Result<Vec<BenchScene>, SceneError> {
    scene_files(dir)?
        .iter()
        .map(|p| {
            let name = p.file_name().unwrap_or_default().to_string_lossy();
            Ok(BenchScene::from_scene(name, &Scene::load(p)?.scene))
        })
        .collect()
}

/// Named triangles: a bare mesh before it is framed as a [`BenchScene`].
pub type NamedTriangles = (String, Vec<[Vec3; 3]>);

/// A mesh file's triangles (any format [`Scene::load`] reads), named by its stem.
pub fn mesh_triangles(path: &Path) -> Result<NamedTriangles, SceneError> {
    let scene = Scene::load(path)?.scene;
    let name = path
        .file_stem()
        .map_or("mesh".into(), |s| s.to_string_lossy().into_owned());
    Ok((name, scene.triangles_world(scene.camera.shutter_open)))
}

/// An icosphere of at least `n` triangles, named `icosphere{n/1000}k`.
pub fn icosphere_triangles(n: u64) -> Result<NamedTriangles, SceneError> {
    let m = vkrt::scene::gen::icosphere_with_at_least(n)?;
    let tris = m
        .indices
        .iter()
        .map(|t| t.map(|i| m.positions[i as usize]))
        .collect();
    let name = if n >= 1000 {
        format!("icosphere{}k", n / 1000)
    } else {
        format!("icosphere{n}")
    };
    Ok((name, tris))
}

/// [`mesh_triangles`] framed by [`BenchScene::from_triangles`].
pub fn mesh(path: &Path) -> Result<BenchScene, SceneError> {
    let (name, tris) = mesh_triangles(path)?;
    Ok(BenchScene::from_triangles(name, &tris))
}

/// [`icosphere_triangles`] framed by [`BenchScene::from_triangles`].
pub fn icosphere(n: u64) -> Result<BenchScene, SceneError> {
    let (name, tris) = icosphere_triangles(n)?;
    Ok(BenchScene::from_triangles(name, &tris))
}
