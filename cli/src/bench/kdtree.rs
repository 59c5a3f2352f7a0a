//! `vkrt bench kdtree`: Kolodzey's GPU kd-tree build timed per scene, with the Table 6.2
//! ablation (each optimisation switched back to its baseline) and the fitted growth.

use serde::Serialize;

use vkrt::gpu::{Context, Result};

use super::power_law_exponent;

/// One row of `vkrt bench kdtree`.
#[derive(Clone, Debug, Serialize)]
pub struct KdBenchRow {
    /// The scene's name (the mesh's, or an icosphere's).
    pub scene: String,
    /// Triangles of the scene.
    pub primitives: u32,
    /// The build variant: `default`, or the one optimisation switched back to its baseline
    /// (Kolodzey's Table 6.2 ablation).
    pub variant: String,
    /// GPU ms of the build (`kdtree.phase1` + `kdtree.phase2`), the fastest repetition.
    pub build_ms: f64,
    /// `build_ms` of this variant over `build_ms` of the default on the same scene, in the
    /// same run (> 1: the optimisation pays).
    pub ratio_to_default: f64,
    /// GPU ms of each of Kolodzey's phases in the fastest build, by name without the
    /// `kdtree.` prefix.
    pub phases: std::collections::BTreeMap<String, f64>,
    /// Nodes of the built tree.
    pub nodes: u32,
    /// The built tree's SAH cost.
    pub sah_cost: f64,
    /// Why the scene has no timing (e.g. its tree does not fit the device's buffer limit).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// `vkrt bench kdtree --json`.
#[derive(Clone, Debug, Serialize)]
pub struct KdBenchReport {
    /// The device name the driver reports.
    pub device: String,
    /// The SAH parameters and termination every build used.
    pub params: vkrt::accel::kdtree::SahParams,
    /// One row per scene and variant.
    pub rows: Vec<KdBenchRow>,
    /// Least-squares slope of log(build_ms) over log(N), default builds of the icospheres:
    /// O(N log N) shows as slightly above 1.
    pub fitted_exponent: Option<f64>,
    /// The same over every default row (the bunny's 69 K and the icospheres).
    pub fitted_exponent_all: Option<f64>,
}

/// What each ablation variant of `vkrt bench kdtree --ablation` switches back (label, the
/// baseline it runs, Kolodzey's Table 6.2 row).
pub const KD_VARIANT_NOTES: [(&str, &str); 5] = [
    (
        "workgroup_per_segment",
        "one workgroup per node for the best split in every level, no device-wide \
         reduction for the first big nodes (Table 6.2: Hybrid-Reduction, 2.25)",
    ),
    (
        "shared_memory_argmin",
        "workgroup argmin through shared memory instead of subgroup shuffles \
         (Table 6.2: SAH Shuffle-Reduction, 1.03)",
    ),
    (
        "u32_event_scan",
        "START counts by a u32 scan over widened event types (an extra pass) instead of \
         the byte-flag scan (Table 6.2: Binary-Scan, 1.11; here only ComputeBestSplits)",
    ),
    (
        "full_record_scatter",
        "classify also writes each event's complete clipped record (plane, type, prim, \
         node, 6 box floats) into its valid below/above slots of a temporary list twice as \
         long, then the same flag scan and a second pass moves every kept record to its \
         place: each record written twice, instead of 1-byte flags and one move (Table \
         6.2: Clip-Mask, 1.32)",
    ),
    (
        "narrow_moves",
        "classify, scatter and split costs move the event boxes and read the node fields \
         as 32-bit components instead of 64-bit pairs (the path of devices without \
         shaderInt64; not in Table 6.2)",
    ),
];

/// The ablation variants: (label, builder switches, best-split mode or the default hybrid).
fn kd_variants() -> Vec<(
    &'static str,
    vkrt::accel::kdtree::gpu::Ablation,
    Option<vkrt::prims::segmented::SegmentedMode>,
)> {
    use vkrt::accel::kdtree::gpu::Ablation;
    use vkrt::prims::segmented::SegmentedMode;
    vec![
        ("default", Ablation::default(), None),
        (
            "workgroup_per_segment",
            Ablation::default(),
            Some(SegmentedMode::WorkgroupPerSegment),
        ),
        (
            "shared_memory_argmin",
            Ablation {
                shared_memory_argmin: true,
                ..Ablation::default()
            },
            None,
        ),
        (
            "u32_event_scan",
            Ablation {
                u32_event_scan: true,
                ..Ablation::default()
            },
            None,
        ),
        (
            "full_record_scatter",
            Ablation {
                full_record_scatter: true,
                ..Ablation::default()
            },
            None,
        ),
        (
            "narrow_moves",
            Ablation {
                narrow_moves: true,
                ..Ablation::default()
            },
            None,
        ),
    ]
}

/// Builds each scene with the default builder and, for scenes of at most `ablation_max_n`
/// primitives, with each of Kolodzey's optimisations switched back to its baseline (Table
/// 6.2): one workgroup per segment instead of the hybrid reduction, a shared-memory instead
/// of a shuffle argmin, a u32 instead of a byte-flag scan, full event records written to a
/// temporary slot list and compacted from there (each record moved twice) instead of the
/// 1-byte clip-mask and one move (see [`vkrt::accel::kdtree::gpu::Ablation`]). Every variant must build the
/// default's tree (an error otherwise). A scene whose build fails (e.g. above the device's
/// buffer limit) gets a row with the error.
pub fn kdtree_report(
    ctx: &Context,
    scenes: &[(String, Vec<[glam::Vec3; 3]>)],
    params: &vkrt::accel::kdtree::SahParams,
    ablation_max_n: usize,
    reps: u32,
) -> Result<KdBenchReport> {
    use vkrt::accel::kdtree::gpu::{BuildCapacity, KdTreeBuilder};
    use vkrt::accel::kdtree::{report::PHASES, stats};
    let variants = kd_variants();
    let mut builders = Vec::new();
    for (_, ablation, mode) in &variants {
        let mut b = KdTreeBuilder::with_ablation(ctx, *ablation)?;
        if let Some(mode) = mode {
            b.segmented_mode = *mode;
        }
        builders.push(b);
    }
    let mut rows = Vec::new();
    for (name, tris) in scenes {
        // Build every variant once (capacity found, tree checked against the default's) ...
        let mut built = Vec::new();
        for ((label, _, _), builder) in variants.iter().zip(&builders) {
            if *label != "default" && tris.len() > ablation_max_n {
                continue;
            }
            match builder.build_from(ctx, tris, params, BuildCapacity::for_primitives(tris.len())) {
                Ok(b) => {
                    if let Some((_, _, first)) = built.first() {
                        let first: &vkrt::accel::kdtree::gpu::BuildResult = first;
                        if first.tree.nodes != b.tree.nodes
                            || first.tree.prim_refs != b.tree.prim_refs
                        {
                            return Err(vkrt::gpu::GpuError::Kernel {
                                kernel: "accel.kdtree",
                                reason: format!("{name}: variant {label} built a different tree"),
                            });
                        }
                    }
                    built.push((*label, builder, b));
                }
                Err(e) => {
                    rows.push(KdBenchRow {
                        scene: name.clone(),
                        primitives: tris.len() as u32,
                        variant: label.to_string(),
                        build_ms: f64::NAN,
                        ratio_to_default: f64::NAN,
                        phases: Default::default(),
                        nodes: 0,
                        sah_cost: f64::NAN,
                        error: Some(e.to_string()),
                    });
                    break;
                }
            }
        }
        // ... then time them round-robin, `reps` rounds, keeping each variant's fastest build
        // (the machine is shared: interleaving spreads other load over all variants).
        let mut best: Vec<Option<(f64, vkrt::gpu::Profile)>> = vec![None; built.len()];
        for _ in 0..reps.max(1) {
            for ((_, builder, b), best) in built.iter().zip(&mut best) {
                let profile = builder.timed_build(ctx, tris, params, b.capacity)?;
                let ms = |p: &str| profile.ms(p).unwrap_or(0.0);
                let build_ms = ms("kdtree.phase1") + ms("kdtree.phase2");
                if best.as_ref().is_none_or(|(t, _)| build_ms < *t) {
                    *best = Some((build_ms, profile));
                }
            }
        }
        let default_ms = best.first().and_then(|b| b.as_ref()).map(|b| b.0);
        for ((label, _, b), best) in built.iter().zip(best) {
            let (build_ms, profile) = best.expect("timed at least once");
            let ms = |p: &str| profile.ms(p).unwrap_or(0.0);
            let s = stats::stats(&b.tree, params);
            rows.push(KdBenchRow {
                scene: name.clone(),
                primitives: tris.len() as u32,
                variant: label.to_string(),
                build_ms,
                ratio_to_default: default_ms.map_or(f64::NAN, |d| build_ms / d),
                phases: PHASES
                    .iter()
                    .map(|p| (p.trim_start_matches("kdtree.").to_string(), ms(p)))
                    .collect(),
                nodes: s.nodes,
                sah_cost: s.sah_cost,
                error: None,
            });
        }
    }
    let points = |all: bool| -> Vec<(f64, f64)> {
        rows.iter()
            .filter(|r| r.variant == "default" && r.error.is_none())
            .filter(|r| all || r.scene.starts_with("icosphere"))
            .map(|r| (r.primitives as f64, r.build_ms))
            .collect()
    };
    Ok(KdBenchReport {
        device: ctx.info().device.clone(),
        params: *params,
        fitted_exponent: power_law_exponent(&points(false)),
        fitted_exponent_all: power_law_exponent(&points(true)),
        rows,
    })
}
