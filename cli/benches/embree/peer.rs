//! What the trace and BVH-build benches share: their scenes, and Embree 3 as a CPU peer: `embree_trace.c` compiled on first use (it needs
//! a C compiler and Debian's `libembree-dev`; without them the benches print a note and
//! leave Embree's columns empty). Triangles and rays go to it as files.

use std::path::{Path, PathBuf};
use std::process::Command;

use glam::Vec3;
use vkrt::trace::Ray;

/// The bench's context (validation off) and, when it can be had, the Embree peer (else a
/// note on stderr).
pub fn context_and_peer() -> (vkrt::gpu::Context, Option<Embree>) {
    let ctx = vkrt::gpu::Context::new(&vkrt::gpu::ContextOptions {
        validation: vkrt::gpu::Validation::Off,
        device_name: None,
        ..Default::default()
    })
    .expect("a Vulkan device");
    let embree = Embree::new()
        .inspect_err(|why| eprintln!("Embree's columns are empty: {why}"))
        .ok();
    (ctx, embree)
}

/// The benches' mesh: `$VKRT_MESH`, else the Stanford bunny beside the checkout.
pub fn bench_mesh() -> std::path::PathBuf {
    std::env::var_os("VKRT_MESH").map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/scenes/stanford-bunny.obj"),
        std::path::PathBuf::from,
    )
}

/// The benches' mesh ([`bench_mesh`], when present; else a note), then icospheres of at
/// least each of `sizes` triangles.
pub fn bench_scenes(sizes: &[u64]) -> Vec<(String, Vec<[Vec3; 3]>)> {
    let mut scenes = Vec::new();
    let bunny = bench_mesh();
    if bunny.exists() {
        let s = vkrt::scene::Scene::load(&bunny)
            .expect("load the bunny")
            .scene;
        scenes.push(("bunny".to_string(), s.triangles_world(0.0)));
    } else {
        eprintln!("skipped the bunny: {} is absent", bunny.display());
    }
    for &n in sizes {
        let m = vkrt::scene::gen::icosphere_with_at_least(n).expect("icosphere");
        let tris = m
            .indices
            .iter()
            .map(|t| t.map(|i| m.positions[i as usize]))
            .collect();
        scenes.push((format!("icosphere{}k", n / 1000), tris));
    }
    scenes
}

pub struct Embree {
    exe: PathBuf,
    dir: PathBuf,
}

/// What one run of the helper measured.
pub struct EmbreeRun {
    /// `rtcCommitScene`, medium quality, best of 3.
    pub build_ms: f64,
    /// Per ray set: hits and the best of 3 wall times.
    pub traces: Vec<(usize, f64)>,
    /// With instances: the mesh's own commit (`build_ms` is then the top level's).
    #[allow(dead_code, reason = "only the instancing bench reads it")]
    pub blas_ms: Option<f64>,
}

impl Embree {
    /// The compiled helper, or why not.
    pub fn new() -> Result<Self, String> {
        let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/embree/embree_trace.c");
        let dir = std::env::temp_dir().join(format!("vkrt-embree-{}", std::process::id()));
        std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
        let exe = dir.join("embree_trace");
        let out = Command::new("cc")
            .args(["-O2", "-o"])
            .arg(&exe)
            .arg(&src)
            .args(["-lembree3", "-lpthread", "-lm"])
            .output()
            .map_err(|e| format!("no C compiler ({e})"))?;
        if !out.status.success() {
            return Err(format!(
                "could not build {} (apt install libembree-dev): {}",
                src.display(),
                String::from_utf8_lossy(&out.stderr)
                    .lines()
                    .next()
                    .unwrap_or("")
            ));
        }
        Ok(Self { exe, dir })
    }

    /// Builds over `tris` and traces each ray set (`true`: any hit) on `threads` threads.
    pub fn run(&self, tris: &[[Vec3; 3]], threads: usize, sets: &[(&[Ray], bool)]) -> EmbreeRun {
        self.run_instanced(tris, &[], threads, sets)
    }

    /// [`Embree::run`] over instances of `tris` placed by `transforms` (row-major 3×4
    /// object to world; none: the triangles themselves).
    pub fn run_instanced(
        &self,
        tris: &[[Vec3; 3]],
        transforms: &[[[f32; 4]; 3]],
        threads: usize,
        sets: &[(&[Ray], bool)],
    ) -> EmbreeRun {
        let tri_path = self.dir.join("scene.tris");
        let floats: Vec<f32> = tris
            .iter()
            .flat_map(|t| t.iter().flat_map(|p| p.to_array()))
            .collect();
        std::fs::write(&tri_path, bytemuck::cast_slice(&floats)).expect("write triangles");
        let mut cmd = Command::new(&self.exe);
        cmd.arg(&tri_path).arg(threads.to_string());
        if !transforms.is_empty() {
            let p = self.dir.join("instances.xf");
            std::fs::write(&p, bytemuck::cast_slice(transforms)).expect("write transforms");
            cmd.env("EMBREE_INSTANCES", &p);
        } else {
            cmd.env_remove("EMBREE_INSTANCES");
        }
        for (k, (rays, any)) in sets.iter().enumerate() {
            let p = self.dir.join(format!("set{k}.rays"));
            std::fs::write(&p, vkrt::trace::files::encode_rays(rays)).expect("write rays");
            cmd.arg(format!(
                "{}:{}",
                p.display(),
                if *any { "any" } else { "closest" }
            ));
        }
        let out = cmd.output().expect("run embree_trace");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let text = String::from_utf8_lossy(&out.stdout);
        let mut run = EmbreeRun {
            build_ms: f64::NAN,
            traces: Vec::new(),
            blas_ms: None,
        };
        for line in text.lines() {
            let f: Vec<&str> = line.split_whitespace().collect();
            match f.as_slice() {
                ["build_ms", ms] => run.build_ms = ms.parse().unwrap(),
                ["blas_ms", ms] => run.blas_ms = Some(ms.parse().unwrap()),
                ["trace", _, _, hits, ms] => run
                    .traces
                    .push((hits.parse().unwrap(), ms.parse().unwrap())),
                _ => {}
            }
        }
        run
    }
}

impl Drop for Embree {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}
