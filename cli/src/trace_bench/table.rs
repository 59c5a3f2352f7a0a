//! The report as text: one block per scene and ray set, a line under a block for every
//! hit count that differs from the first row's.

use std::fmt;

use super::{RayKind, RaySetReport, SceneReport, TraceBenchReport};

impl fmt::Display for TraceBenchReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{}: camera images {} pixels wide, best of {}",
            self.device, self.size, self.reps
        )?;
        if let Some(note) = &self.driver_note {
            writeln!(f, "{note}")?;
        }
        let accesses: Vec<&str> = self.node_access.iter().map(|a| a.name()).collect();
        writeln!(
            f,
            "vkrt's walks read the structures through {} buffers",
            accesses.join(" and through ")
        )?;
        for scene in &self.scenes {
            for set in &scene.ray_sets {
                writeln!(f)?;
                block(f, scene, set)?;
            }
        }
        writeln!(f)?;
        writeln!(
            f,
            "build ms: kd-tree, LBVH, PLOC and the driver's: GPU passes (timestamps); SAH BVH: \
             host, every core; obvhs (PLOC, medium): host, one thread"
        )?;
        writeln!(
            f,
            "trace ms: GPU timestamps around the trace kernel (vkrt: watertight test); obvhs: \
             wall time, one CPU thread, Möller–Trumbore"
        )?;
        if self.ray_query {
            writeln!(
                f,
                "×driver: Mrays/s over the driver's (fast-trace) structure's"
            )?;
        }
        Ok(())
    }
}

fn block(f: &mut fmt::Formatter<'_>, scene: &SceneReport, set: &RaySetReport) -> fmt::Result {
    let what = match set.kind {
        RayKind::Primary => format!("a {}×{} camera", scene.width, scene.height),
        RayKind::Shadow => format!("from the primary hits to the {}", scene.light),
        RayKind::Mirror => "reflections of the primary hits".to_string(),
    };
    writeln!(
        f,
        "{} ({}, {}): {} {} rays, {} hit — {what}",
        scene.name,
        count(scene.triangles, "triangle"),
        count(scene.spheres, "sphere"),
        set.rays,
        set.kind.name(),
        set.query,
    )?;
    writeln!(
        f,
        "{:<26} {:>10} {:>10} {:>9} {:>9} {:>8}",
        "structure", "build ms", "trace ms", "Mrays/s", "hits", "×driver"
    )?;
    for r in &set.rows {
        let ratio = r.over_driver.map_or("-".to_string(), |x| format!("{x:.2}"));
        let note = r
            .note
            .as_ref()
            .map_or(String::new(), |n| format!("  ({n})"));
        writeln!(
            f,
            "{:<26} {:>10.2} {:>10.2} {:>9.2} {:>9} {:>8}{note}",
            r.structure, r.build_ms, r.trace_ms, r.mrays_per_s, r.hits, ratio
        )?;
    }
    let first = set.rows.first().map_or("", |r| r.structure.as_str());
    let differ: Vec<String> = set
        .rows
        .iter()
        .filter_map(|r| {
            let d = r.hits_vs_first.filter(|&d| d != 0)?;
            let share = d.unsigned_abs() as f64 / set.rays.max(1) as f64 * 100.0;
            Some(format!("{} {d:+} ({share:.3} % of the rays)", r.structure))
        })
        .collect();
    if !differ.is_empty() {
        writeln!(f, "hits differ from {first}'s: {}", differ.join(", "))?;
    }
    Ok(())
}

/// `1 sphere`, `2 spheres`.
fn count(n: usize, noun: &str) -> String {
    format!("{n} {noun}{}", if n == 1 { "" } else { "s" })
}
