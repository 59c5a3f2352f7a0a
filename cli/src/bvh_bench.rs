//! `vkrt bench bvh`: Sochora's (2013) build-time tables on this machine.

use glam::Vec3;

use vkrt::accel::bvh::sah::{build_timed, BvhError, BvhParams, Threading};
use vkrt::accel::bvh::validate::sah_cost;
use vkrt::scene::Aabb;

/// One build: scene, SAH variant, scheme and thread count.
#[derive(Clone, Debug, serde::Serialize)]
pub struct BvhBenchRow {
    /// The scene's name.
    pub scene: String,
    /// Triangles in the scene.
    pub triangles: usize,
    /// `sweep` or `binned16`.
    pub sah: String,
    /// The [`Threading`] scheme: `single`, `uneven`, `even`, `queue` or `rayon`.
    pub scheme: String,
    /// Threads the scheme ran with (rayon's pool size for `rayon`).
    pub threads: usize,
    /// Best of the repetitions, wall time.
    pub build_ms: f64,
    /// The single-threaded build's time over this one's (same scene and SAH variant).
    pub speedup: f64,
    /// SAH cost of the built tree ([`sah_cost`]).
    pub sah_cost: f64,
    /// Nodes of the built tree.
    pub nodes: usize,
}

/// Every scheme at 1 and all threads over every scene; every build of a scene and SAH
/// variant must give the single-threaded tree (a panic otherwise: a determinism bug).
pub fn bench(scenes: &[(String, Vec<[Vec3; 3]>)], reps: u32) -> Result<Vec<BvhBenchRow>, BvhError> {
    let all = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut thread_counts = vec![1, all];
    thread_counts.dedup();
    let mut rows = Vec::new();
    for (name, tris) in scenes {
        // Triangle boxes (accel sits below trace, whose TraceGeometry does the same).
        let boxes: Vec<Aabb> = tris
            .iter()
            .map(|t| Aabb {
                min: t[0].min(t[1]).min(t[2]),
                max: t[0].max(t[1]).max(t[2]),
            })
            .collect();
        for (sah, bins) in [("sweep", None), ("binned16", Some(16))] {
            let params = BvhParams {
                bins,
                ..BvhParams::default()
            };
            let mut runs = vec![(Threading::Single, "single", 1)];
            for &t in &thread_counts {
                runs.push((Threading::Uneven { threads: t }, "uneven", t));
                runs.push((Threading::Even { threads: t }, "even", t));
                runs.push((Threading::Queue { threads: t }, "queue", t));
            }
            runs.push((Threading::Rayon, "rayon", rayon::current_num_threads()));
            let mut reference = None;
            let mut single_ms = f64::NAN;
            for (threading, scheme, threads) in runs {
                let mut best = f64::INFINITY;
                let mut tree = None;
                for _ in 0..reps.max(1) {
                    let (t, ms) = build_timed(&boxes, &params, threading)?;
                    best = best.min(ms);
                    tree = Some(t);
                }
                let tree = tree.expect("at least one repetition");
                match &reference {
                    None => reference = Some(tree.clone()),
                    Some(r) => assert!(*r == tree, "{name}: {scheme} built another tree"),
                }
                if threading == Threading::Single {
                    single_ms = best;
                }
                rows.push(BvhBenchRow {
                    scene: name.clone(),
                    triangles: tris.len(),
                    sah: sah.into(),
                    scheme: scheme.into(),
                    threads,
                    build_ms: best,
                    speedup: single_ms / best,
                    sah_cost: sah_cost(&tree, &params),
                    nodes: tree.nodes.len(),
                });
            }
        }
    }
    Ok(rows)
}
