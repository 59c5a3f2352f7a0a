//! Measured baselines for `vkrt bench`: what moving the same bytes costs on this device.
//!
//! Every kernel in vkrt is reported as a ratio to these, measured in the same run:
//! `vkCmdCopyBuffer` (the driver's copy; memcpy on lavapipe) and the best plain copy
//! kernel (u32, uvec4 or u64vec4 granules, one or four per invocation, several workgroup
//! sizes; the 64-bit ones only where the device has shaderInt64). Buffers are touched
//! once before timing: the first touch of fresh memory on lavapipe costs page faults.

use serde::Serialize;

use vkrt::gpu::{kernels, Buffer, Context, Profile, Recorder, Result, Spec};

pub mod prims;

/// One timed variant of a copy.
#[derive(Clone, Debug, Serialize)]
pub struct CopyResult {
    /// `vkCmdCopyBuffer`, or `copy_kernel.<granule>.wg<workgroup size>`.
    pub method: String,
    /// Bytes copied (read, and as many written).
    pub bytes: u64,
    /// Best of the timed repetitions, milliseconds of GPU time.
    pub gpu_ms: f64,
    /// Bytes read plus bytes written, GiB per second.
    pub gib_per_s: f64,
    /// `copy_ms / gpu_ms` of `vkCmdCopyBuffer` in the same run (1.0 = as fast).
    pub ratio_to_copy: f64,
}

/// The copy baselines for `bytes` bytes (rounded down to a multiple of 16).
#[derive(Clone, Debug, Serialize)]
pub struct CopyBaselines {
    /// The device name the driver reports.
    pub device: String,
    /// The device's default subgroup size (invocations).
    pub subgroup_size: u32,
    /// Bytes each variant copies.
    pub bytes: u64,
    /// Timed repetitions of each variant (after one untimed warm-up).
    pub repetitions: u32,
    /// `vkCmdCopyBuffer` first, then each copy kernel the device can run at each workgroup
    /// size it allows.
    pub results: Vec<CopyResult>,
}

impl CopyBaselines {
    /// The fastest copy kernel.
    pub fn best_kernel(&self) -> Option<&CopyResult> {
        self.results
            .iter()
            .filter(|r| r.method != "vkCmdCopyBuffer")
            .min_by(|a, b| a.gpu_ms.total_cmp(&b.gpu_ms))
    }
}

/// A copy kernel, its u32 words per element (its `ELEM`) and elements per invocation.
type KernelVariant = (std::sync::Arc<vkrt::gpu::Kernel>, u32, u32);

const WORKGROUP_SIZES: [u32; 3] = [64, 256, 1024];

/// The copy kernels: (name, blob, u32 words per element, elements per invocation, needs
/// shaderInt64).
const COPY_KERNELS: [(&str, &vkrt::gpu::ShaderBlob, u32, u32, bool); 6] = [
    ("u32", &kernels::GPU_COPY_U32, 1, 1, false),
    ("uvec4", &kernels::GPU_COPY_UVEC4, 4, 1, false),
    ("uvec4x4", &kernels::GPU_COPY_UVEC4X4, 4, 4, false),
    ("u64vec4", &kernels::GPU_COPY_U64VEC4, 8, 1, true),
    ("u64vec4x4", &kernels::GPU_COPY_U64VEC4X4, 8, 4, true),
    ("u64vec4run16", &kernels::GPU_COPY_U64VEC4RUN16, 8, 16, true),
];

/// Measures `vkCmdCopyBuffer` and the copy kernels over `bytes`, `reps` times each, and
/// returns the baselines plus the profile of every timed pass.
pub fn copy_baselines(ctx: &Context, bytes: u64, reps: u32) -> Result<(CopyBaselines, Profile)> {
    // A whole number of the widest kernel's invocations (32 words).
    let words = (bytes / 128 * 32).max(32) as usize;
    let bytes = words as u64 * 4;
    let src = Buffer::<u32>::new(ctx, "bench.src", words)?;
    let dst = Buffer::<u32>::new(ctx, "bench.dst", words)?;
    // (name, None = vkCmdCopyBuffer | Some(kernel variant))
    let mut variants: Vec<(String, Option<KernelVariant>)> =
        vec![("vkCmdCopyBuffer".to_string(), None)];
    for wg in WORKGROUP_SIZES
        .into_iter()
        .filter(|&w| w <= ctx.info().max_workgroup_invocations)
    {
        let spec = Spec::new().workgroup(wg);
        for (name, blob, words_per_elem, per_invocation, int64) in COPY_KERNELS {
            if int64 && !ctx.info().features.shader_int64 {
                continue;
            }
            variants.push((
                format!("copy_kernel.{name}.wg{wg}"),
                Some((ctx.kernel(blob, &spec)?, words_per_elem, per_invocation)),
            ));
        }
    }
    let mut rec = Recorder::new(ctx)?;
    // Warm-up: touch every page of both buffers once, untimed.
    rec.fill(&src, 0x1234_5678);
    rec.fill(&dst, 0);
    rec.transfer_to_transfer();
    for rep in 0..=reps {
        for (name, kernel) in &variants {
            let label = if rep == 0 {
                format!("warmup.{name}")
            } else {
                name.clone()
            };
            rec.begin_scope(&label);
            match kernel {
                None => rec.copy(&src, &dst, words),
                Some((k, words_per_elem, per_invocation)) => {
                    let n = (words / *words_per_elem as usize) as u32;
                    let invocations = n.div_ceil(*per_invocation);
                    let groups = rec.groups_1d(u64::from(invocations), k.invocations());
                    rec.dispatch(k, groups, &[&src, &dst], &n);
                }
            }
            rec.end_scope();
            // Each copy writes `dst`: order them so timings never overlap.
            rec.compute_to_transfer();
            rec.transfer_to_compute();
            rec.compute_to_compute();
            rec.transfer_to_transfer();
        }
    }
    let profile = rec.submit_and_wait()?;
    let best = |name: &str| {
        profile
            .passes
            .iter()
            .filter(|p| p.name == name)
            .filter_map(|p| p.ms)
            .fold(f64::INFINITY, f64::min)
    };
    let copy_ms = best("vkCmdCopyBuffer");
    let results = variants
        .iter()
        .map(|(name, _)| {
            let ms = best(name);
            CopyResult {
                method: name.clone(),
                bytes,
                gpu_ms: ms,
                gib_per_s: 2.0 * bytes as f64 / (ms / 1e3) / f64::from(1u32 << 30),
                ratio_to_copy: copy_ms / ms,
            }
        })
        .collect();
    let baselines = CopyBaselines {
        device: ctx.info().device.clone(),
        subgroup_size: ctx.info().subgroup_size,
        bytes,
        repetitions: reps,
        results,
    };
    Ok((baselines, profile))
}

/// One row of `vkrt bench prims --json`.
#[derive(Clone, Debug, Serialize)]
pub struct PrimResult {
    /// The primitive's name (e.g. `scan_u32`, `compact_4_arrays`).
    pub prim: String,
    /// Elements processed.
    pub n: u64,
    /// GPU milliseconds of the primitive's passes (best of the repetitions).
    pub gpu_ms: f64,
    /// `n` over `gpu_ms`, elements per second.
    pub elements_per_s: f64,
    /// Bytes the primitive must at least read plus write.
    pub min_bytes: u64,
    /// `vkCmdCopyBuffer` of `min_bytes / 2` bytes (it reads and writes as much).
    pub copy_ms: f64,
    /// The best plain copy kernel on the same bytes.
    pub copy_kernel_ms: f64,
    /// `copy_ms / gpu_ms`: 1.0 = as fast as the driver's copy of the same bytes.
    pub ratio_to_copy: f64,
    /// `copy_kernel_ms / gpu_ms`: 1.0 = as fast as the best copy kernel.
    pub ratio_to_copy_kernel: f64,
}

/// `vkrt bench prims --json`.
#[derive(Clone, Debug, Serialize)]
pub struct PrimsReport {
    /// The device name the driver reports.
    pub device: String,
    /// The device's default subgroup size (invocations).
    pub subgroup_size: u32,
    /// One row per primitive and size.
    pub results: Vec<PrimResult>,
}

/// A primitive's benchmark: times at `n` elements, best of `reps`.
pub type PrimBench = fn(&Context, usize, u32) -> Result<Vec<prims::PrimTiming>>;

/// Every primitive's benchmark, in the order of the report.
pub fn prim_benches() -> Vec<(&'static str, PrimBench)> {
    vec![
        ("scan", prims::scan::bench as PrimBench),
        ("compact", prims::compact::bench),
        ("reduce", prims::reduce::bench),
        ("segmented", prims::segmented::bench),
        // Its rows include `cpu_sort_unstable_by_key`: the CPU sort of the same pairs on one
        // core (its "gpu_ms" is CPU wall time).
        ("radix", prims::radix_sort::bench),
    ]
}

/// Times every primitive at each of `sizes` and sets each against the copy baselines of
/// the same bytes, measured in the same run. `only` keeps the benches whose group name
/// contains it.
pub fn prims_report(
    ctx: &Context,
    sizes: &[usize],
    reps: u32,
    only: Option<&str>,
) -> Result<PrimsReport> {
    let mut results = Vec::new();
    let mut baselines: std::collections::HashMap<u64, (f64, f64)> = Default::default();
    for &n in sizes {
        for (group, bench) in prim_benches() {
            if only.is_some_and(|o| !group.contains(o)) {
                continue;
            }
            for t in bench(ctx, n, reps)? {
                let copy_bytes = (t.min_bytes / 2).max(16);
                let (copy_ms, copy_kernel_ms) = match baselines.get(&copy_bytes) {
                    Some(&b) => b,
                    None => {
                        // Above the largest buffer, time the largest and scale linearly
                        // (copies are bandwidth-bound at that size).
                        let cap = ctx.info().max_storage_buffer_range / 16 * 16;
                        let measured = copy_bytes.min(cap);
                        let scale = copy_bytes as f64 / measured as f64;
                        let (b, _) = copy_baselines(ctx, measured, reps)?;
                        let copy = b
                            .results
                            .iter()
                            .find(|r| r.method == "vkCmdCopyBuffer")
                            .map_or(f64::NAN, |r| r.gpu_ms * scale);
                        let kernel = b.best_kernel().map_or(f64::NAN, |r| r.gpu_ms * scale);
                        baselines.insert(copy_bytes, (copy, kernel));
                        (copy, kernel)
                    }
                };
                results.push(PrimResult {
                    elements_per_s: t.n as f64 / (t.gpu_ms / 1e3),
                    ratio_to_copy: copy_ms / t.gpu_ms,
                    ratio_to_copy_kernel: copy_kernel_ms / t.gpu_ms,
                    prim: t.prim,
                    n: t.n,
                    gpu_ms: t.gpu_ms,
                    min_bytes: t.min_bytes,
                    copy_ms,
                    copy_kernel_ms,
                });
            }
        }
    }
    Ok(PrimsReport {
        device: ctx.info().device.clone(),
        subgroup_size: ctx.info().subgroup_size,
        results,
    })
}

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

/// The exponent `k` of the power law `ms ≈ c·n^k` through `(n, ms)` points: the
/// least-squares slope of log(ms) over log(n); `None` for fewer than two points.
pub fn power_law_exponent(points: &[(f64, f64)]) -> Option<f64> {
    (points.len() >= 2).then(|| {
        let logs: Vec<(f64, f64)> = points.iter().map(|p| (p.0.ln(), p.1.ln())).collect();
        let n = logs.len() as f64;
        let (sx, sy) = logs.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
        let (mx, my) = (sx / n, sy / n);
        let num: f64 = logs.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
        let den: f64 = logs.iter().map(|p| (p.0 - mx).powi(2)).sum();
        num / den
    })
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

#[cfg(test)]
mod tests {
    use super::power_law_exponent;

    #[test]
    fn the_power_law_exponent_of_exact_points_is_their_power() {
        let pts: Vec<(f64, f64)> = [1e3, 1e4, 2e5, 3e6]
            .iter()
            .map(|&n: &f64| (n, 0.25 * n.powf(1.37)))
            .collect();
        let k = power_law_exponent(&pts).unwrap();
        assert!((k - 1.37).abs() < 1e-9, "{k}");
        assert_eq!(power_law_exponent(&pts[..1]), None);
    }
}
