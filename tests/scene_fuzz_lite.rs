//! Deterministic "fuzz-lite": mutate every example scene file tens of
//! thousands of times (bit flips, byte substitutions, deletions,
//! duplications, truncations, dictionary insertions) and feed the result to
//! the matching loader. Properties checked on every input:
//!
//! - no panic (a panic fails the test and prints the seed and the input);
//! - every error names a file (its origin has one, or it is an I/O error);
//! - every scene that loads is valid by construction: it survives
//!   `validate` again unchanged, and (up to 2000 triangles) writing it to
//!   TOML and reading that back gives the same summary.
//!
//! This complements the cargo-fuzz targets in `fuzz/` (which need nightly)
//! and runs on stable in every `cargo test`. `VKRT_FUZZ_ITERS` sets the
//! number of mutants per file (default 2000, an eighth of that for scenes
//! over 20 K triangles; 28.5 k in total).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};

use vkrt::scene::gen::Rng;
use vkrt::scene::obj::parse_obj_str;
use vkrt::scene::scn::parse_scn;
use vkrt::scene::{Limits, LoadedScene, MemoryFiles, Scene, SceneError};

const DICTIONARY: &[&str] = &[
    "[",
    "]",
    "[[",
    "]]",
    "{",
    "}",
    "=",
    "\"",
    "'",
    "\n",
    "#",
    ",",
    ".",
    "-",
    "0",
    "1",
    "9",
    "e",
    "nan",
    "inf",
    "-inf",
    "1e39",
    "-0",
    "4294967296",
    "-1",
    "1e9",
    "99999999999",
    "true",
    "\"\"\"",
    "'''",
    "\\u0000",
    "\u{feff}",
    "é",
    "/",
    "//",
    " ",
    "\t",
    "\r\n",
    // TOML keys and values
    "radius",
    "center",
    "material",
    "type",
    "\"quad\"",
    "\"sphere\"",
    "generate",
    "\"icosphere\"",
    "\"sphere_flake\"",
    "\"random_soup\"",
    "subdivisions",
    "depth",
    "count",
    "nx",
    "ny",
    "positions",
    "indices",
    "normals",
    "path",
    "\"house.obj\"",
    "[settings]",
    "[settings.ao]",
    "[camera]",
    "[[spheres]]",
    "[[meshes]]",
    "[[lights]]",
    "[materials.x]",
    "orbit",
    "velocity",
    "shutter",
    "[animation]",
    "fps",
    "frames",
    "end_time",
    "[[meshes.keyframes]]",
    "time",
    "[meshes.fallback]",
    "aperture",
    "spp",
    "width",
    "max_depth",
    // OBJ / MTL
    "v ",
    "vn ",
    "vt ",
    "f ",
    "l ",
    "o ",
    "g ",
    "usemtl ",
    "mtllib ",
    "newmtl ",
    "Kd ",
    "Ks ",
    "Ni ",
    "d ",
    "Tr ",
    "illum ",
    "1/1/1",
    "-4",
    "0/0",
    "1//1",
    // .scn (Bidmon 2010)
    "<Sphere>",
    "<Triangle>",
    "<end>",
    "<next>",
    "<Camera>",
    "material: ",
    "radius: ",
    ";",
];

fn mutate(input: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut data = input.to_vec();
    // Half the mutants get a single edit, so that many still load and the
    // success paths (validation, writing, reading back) are exercised too.
    let n_ops = if rng.below(2) == 0 {
        1
    } else {
        1 + rng.below(4)
    };
    for _ in 0..n_ops {
        let len = data.len() as u32;
        let at = if len == 0 { 0 } else { rng.below(len) } as usize;
        match rng.below(7) {
            0 if !data.is_empty() => data[at] ^= 1 << rng.below(8),
            1 if !data.is_empty() => {
                let tok = DICTIONARY[rng.below(DICTIONARY.len() as u32) as usize];
                data[at] = tok.as_bytes()[0];
            }
            2 if !data.is_empty() => {
                let n = (1 + rng.below(16)) as usize;
                data.drain(at..(at + n).min(data.len()));
            }
            3 if !data.is_empty() => {
                let n = (1 + rng.below(64)) as usize;
                let chunk: Vec<u8> = data[at..(at + n).min(data.len())].to_vec();
                let to = rng.below(data.len() as u32 + 1) as usize;
                data.splice(to..to, chunk);
            }
            4 => data.truncate(at),
            5 => {
                // Replace a number-looking run with an interesting number.
                let tok = ["nan", "-1", "0", "1e39", "4294967296", "-0", "7", "1e-45"]
                    [rng.below(8) as usize];
                let end = data[at..]
                    .iter()
                    .position(|b| !(b.is_ascii_digit() || *b == b'.' || *b == b'-'))
                    .map_or(data.len(), |p| at + p);
                data.splice(at..end, tok.bytes());
            }
            _ => {
                let tok = DICTIONARY[rng.below(DICTIONARY.len() as u32) as usize];
                data.splice(at..at, tok.bytes());
            }
        }
    }
    data
}

fn scenes_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes")
}

fn small_limits() -> Limits {
    Limits {
        max_triangles: 200_000,
        max_instanced_triangles: 2_000_000,
        max_vertices: 600_000,
        max_spheres: 20_000,
        ..Limits::default()
    }
}

/// The properties every outcome must have.
fn check(result: Result<LoadedScene, SceneError>, limits: &Limits) {
    match result {
        Err(e) => {
            // Every error says which file it is about (the path may be
            // anything the input names, e.g. an absolute `mtllib`).
            let names_file = matches!(
                e,
                SceneError::Io { .. } | SceneError::UnsupportedFormat { .. }
            ) || e.origin().is_some_and(|o| o.file.is_some());
            assert!(names_file, "error names no file: {e}");
            assert!(!e.to_string().is_empty());
        }
        Ok(loaded) => {
            let mut s = loaded.scene;
            let before = s.clone();
            let again = vkrt::scene::validate::validate(&mut s, limits);
            assert!(
                again.is_ok(),
                "a loaded scene fails validation: {:?}",
                again.err()
            );
            assert_eq!(s, before, "validation is not idempotent");
            let _ = s.effects().names();
            let _ = s.summary().to_text();
            let _ = s.triangles_world(s.camera.shutter_close);
            let _ = s.swept_bounds();
            if s.triangle_count() > 2_000 {
                return; // writing and re-parsing big inline meshes only costs time
            }
            let text = s.to_toml_string();
            let files = MemoryFiles::new();
            let back = Scene::from_toml_str_with(&text, Path::new("mem/back.toml"), &files, limits)
                .unwrap_or_else(|e| panic!("written scene does not read back: {e}\n{text}"));
            assert_eq!(back.scene.summary(), s.summary());
        }
    }
}

#[test]
fn mutated_example_files_never_panic() {
    let iters: u32 = std::env::var("VKRT_FUZZ_ITERS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2000);
    let limits = small_limits();
    let house_obj = std::fs::read(scenes_dir().join("house.obj")).unwrap();
    let house_mtl = std::fs::read(scenes_dir().join("house.mtl")).unwrap();
    let mut inputs: Vec<(String, Vec<u8>)> = Vec::new();
    for entry in std::fs::read_dir(scenes_dir()).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        inputs.push((name, std::fs::read(&path).unwrap()));
    }
    inputs.sort();
    assert!(inputs.len() >= 14, "{} inputs", inputs.len());
    let start = std::time::Instant::now();
    let mut total = 0u64;
    let mut loaded_ok = 0u64;
    for (file_no, (name, bytes)) in inputs.iter().enumerate() {
        // Kolodzey's (2014) demo loads ~100 K triangles (its bunny's stand-in is
        // generated here), ~100× a small scene per mutant: an eighth of the
        // mutants keeps the suite fast and still covers its keys.
        let big = name.ends_with(".toml")
            && Scene::from_toml_str_with(
                &String::from_utf8_lossy(bytes),
                Path::new("mem/scene.toml"),
                &MemoryFiles::new(),
                &limits,
            )
            .is_ok_and(|l| l.scene.triangle_count() > 20_000);
        let iters = if big { (iters / 8).max(1) } else { iters };
        for i in 0..iters {
            let seed = (file_no as u64) << 32 | u64::from(i);
            let mut rng = Rng::new(seed);
            let mutant = mutate(bytes, &mut rng);
            let text = String::from_utf8_lossy(&mutant).into_owned();
            let outcome = catch_unwind(AssertUnwindSafe(|| {
                let _ = vkrt::scene::files::text_from_bytes(mutant.clone(), Path::new("mem/raw"));
                let mut files = MemoryFiles::new();
                files.insert(
                    "mem/house.obj",
                    String::from_utf8_lossy(&house_obj).into_owned(),
                );
                files.insert(
                    "mem/house.mtl",
                    String::from_utf8_lossy(&house_mtl).into_owned(),
                );
                let result = if name.ends_with(".toml") {
                    Scene::from_toml_str_with(&text, Path::new("mem/scene.toml"), &files, &limits)
                } else if name.ends_with(".obj") {
                    parse_obj_str(&text, Path::new("mem/house.obj"), &files, &limits)
                        .map(|o| LoadedScene {
                            scene: Scene::from_geometry(vec![o.mesh], vec![], o.materials),
                            warnings: o.warnings,
                        })
                        .and_then(|mut l| {
                            vkrt::scene::validate::validate(&mut l.scene, &limits)
                                .map(|_| l)
                                .map_err(|mut e| {
                                    if let Some(o) = e.origin_mut() {
                                        o.file.get_or_insert_with(|| "mem/house.obj".into());
                                    }
                                    e
                                })
                        })
                } else if name.ends_with(".mtl") {
                    files.insert("mem/house.mtl", text.clone());
                    let obj = files.files[Path::new("mem/house.obj")].clone();
                    parse_obj_str(&obj, Path::new("mem/house.obj"), &files, &limits).map(|o| {
                        LoadedScene {
                            scene: Scene::from_geometry(vec![o.mesh], vec![], o.materials),
                            warnings: o.warnings,
                        }
                    })
                } else {
                    parse_scn(&text, Path::new("mem/scene.scn"), &limits)
                };
                let ok = result.is_ok();
                check(result, &limits);
                ok
            }));
            match outcome {
                Ok(ok) => loaded_ok += u64::from(ok),
                Err(_) => {
                    let dump = std::env::temp_dir().join(format!("vkrt-fuzz-{name}-{seed}"));
                    let _ = std::fs::write(&dump, &mutant);
                    panic!(
                        "panic on a mutant of {name} (seed {seed}); input written to {}",
                        dump.display()
                    );
                }
            }
            total += 1;
        }
    }
    println!(
        "fuzz-lite: {total} mutants of {} files in {:.1} s, {loaded_ok} loaded, {} rejected with an error",
        inputs.len(),
        start.elapsed().as_secs_f64(),
        total - loaded_ok
    );
    // The mutator must leave a fair share of inputs loadable, or the
    // loaders' success paths go unexercised.
    assert!(
        loaded_ok * 20 > total,
        "only {loaded_ok} of {total} mutants loaded"
    );
}
