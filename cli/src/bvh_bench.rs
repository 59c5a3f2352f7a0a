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

/// The rows as one table, a line each, under one header: what `vkrt bench bvh` and
/// `cargo bench --bench bvh_build` both print.
pub fn table(rows: &[BvhBenchRow]) -> String {
    let mut out = format!(
        "{:<16} {:>9} {:<8} {:<7} {:>7} {:>11} {:>8} {:>9}\n",
        "scene", "triangles", "sah", "scheme", "threads", "build ms", "speed-up", "SAH cost"
    );
    for r in rows {
        out += &format!(
            "{:<16} {:>9} {:<8} {:<7} {:>7} {:>11.1} {:>8.2} {:>9.2}\n",
            r.scene, r.triangles, r.sah, r.scheme, r.threads, r.build_ms, r.speedup, r.sah_cost
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_has_one_header_and_a_line_per_row() {
        let row = |scheme: &str, threads| BvhBenchRow {
            scene: "bunny".into(),
            triangles: 69_451,
            sah: "sweep".into(),
            scheme: scheme.into(),
            threads,
            build_ms: 12.25,
            speedup: 1.5,
            sah_cost: 80.0,
            nodes: 9,
        };
        let text = table(&[row("single", 1), row("queue", 2)]);
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 3);
        assert!(lines[0].starts_with("scene") && lines[0].ends_with("SAH cost"));
        assert!(lines[2].contains("queue") && lines[2].contains("12.2"));
        // The columns line up under the header.
        assert!(lines.iter().all(|l| l.len() == lines[0].len()));
    }
}
