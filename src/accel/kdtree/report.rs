//! `vkrt build --accel kdtree`: one GPU build with its per-phase GPU times and tree
//! statistics, optionally against both CPU references (the twin of the same algorithm, which
//! must be equal, and the full-clipping SAH build, the quality reference).

use std::collections::BTreeMap;
use std::time::Instant;

use glam::Vec3;
use serde::Serialize;

use super::gpu::KdTreeBuilder;
use super::{breadth_first, full_clip, stats, SahParams};
use crate::gpu::{Context, Profile, Result, Spread};

/// The phases of Kolodzey (2014) as profiler scopes (summed over all levels).
pub const PHASES: [&str; 5] = [
    "kdtree.phase1",
    "kdtree.split_costs",
    "kdtree.best_split",
    "kdtree.nodes",
    "kdtree.clip_partition",
];

/// The JSON of `vkrt build --json`.
#[derive(Clone, Debug, Serialize)]
pub struct BuildReport {
    /// Input triangles.
    pub primitives: u32,
    /// GPU milliseconds of the whole build (timestamps), buffers warm: the median of
    /// `reps` builds into the same buffers after the first, as a renderer rebuilding every
    /// frame sees it.
    pub build_ms: f64,
    /// The fastest and slowest of the warm builds.
    pub build_ms_min: f64,
    /// See [`BuildReport::build_ms_min`].
    pub build_ms_max: f64,
    /// The first build's GPU milliseconds (its pipelines compiled at their first dispatch
    /// on a driver that compiles then; its successful attempt where the capacity grew).
    pub first_build_ms: f64,
    /// Warm builds timed.
    pub reps: u32,
    /// GPU milliseconds per phase, summed over the levels (levels past the last one with
    /// nodes are recorded too and dispatch nothing; their barriers still cost a little):
    /// each phase's median over the warm builds.
    pub phases: BTreeMap<String, f64>,
    /// Levels that had nodes.
    pub levels: u32,
    /// All nodes of the tree ([`KdStats::nodes`](stats::KdStats::nodes)).
    pub nodes: u32,
    /// Leaves reachable from the root, empty ones included.
    pub leaves: u32,
    /// Depth of the deepest node (root = 0).
    pub max_depth: u32,
    /// SAH cost of the whole tree ([`stats`](mod@stats)).
    pub sah_cost: f64,
    /// Leaf references (primitives counted once per leaf that holds them).
    pub references: u64,
    /// Memory of the layout: 16 bytes per node plus 4 per reference.
    pub bytes: u64,
    /// Build attempts (more than 1 when a capacity overflowed and the build was retried).
    pub attempts: u32,
    /// With the references: whether the CPU twin ([`breadth_first`]) built the same nodes
    /// (split planes bit for bit) and references.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub equal_to_cpu_twin: Option<bool>,
    /// With the references: host milliseconds of the CPU twin's build.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cpu_twin_ms: Option<f64>,
    /// With the references: SAH cost of the full-clipping build (Wald & Havran 2006,
    /// [`full_clip`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub full_clip_sah_cost: Option<f64>,
    /// With the references: host milliseconds of the full-clipping build.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub full_clip_ms: Option<f64>,
}

/// Builds `triangles` on the GPU (and with `reference` on the CPU twice) and reports: the
/// first build, then one timed warm build.
pub fn build_report(
    ctx: &Context,
    triangles: &[[Vec3; 3]],
    params: &SahParams,
    reference: bool,
) -> Result<(BuildReport, Profile)> {
    build_report_repeated(ctx, triangles, params, reference, 1)
}

/// [`build_report`] with `reps` (at least 1) timed warm builds after the first: the times
/// are their medians. The profile is the last build's.
pub fn build_report_repeated(
    ctx: &Context,
    triangles: &[[Vec3; 3]],
    params: &SahParams,
    reference: bool,
    reps: u32,
) -> Result<(BuildReport, Profile)> {
    let builder = KdTreeBuilder::new(ctx)?;
    let capacity = super::gpu::BuildCapacity::for_primitives(triangles.len());
    let result = builder.build_from(ctx, triangles, params, capacity)?;
    let s = stats::stats(&result.tree, params);
    let whole =
        |p: &Profile| p.ms("kdtree.phase1").unwrap_or(0.0) + p.ms("kdtree.phase2").unwrap_or(0.0);
    let mut builds = Vec::new();
    let mut phases: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut timed = Profile::default();
    for _ in 0..reps.max(1) {
        timed = builder.timed_build(ctx, triangles, params, result.capacity)?;
        builds.push(whole(&timed));
        for p in PHASES {
            let name = p.trim_start_matches("kdtree.").to_string();
            phases
                .entry(name)
                .or_default()
                .push(timed.ms(p).unwrap_or(0.0));
        }
    }
    let spread = Spread::of(&builds);
    let mut report = BuildReport {
        primitives: triangles.len() as u32,
        build_ms: spread.median,
        build_ms_min: spread.min,
        build_ms_max: spread.max,
        first_build_ms: whole(&result.profile),
        reps: builds.len() as u32,
        phases: phases
            .into_iter()
            .map(|(name, ms)| (name, Spread::of(&ms).median))
            .collect(),
        levels: result.levels,
        nodes: s.nodes,
        leaves: s.leaves,
        max_depth: s.max_depth,
        sah_cost: s.sah_cost,
        references: s.references,
        bytes: s.bytes,
        attempts: result.attempts,
        equal_to_cpu_twin: None,
        cpu_twin_ms: None,
        full_clip_sah_cost: None,
        full_clip_ms: None,
    };
    if reference {
        let t = Instant::now();
        let (twin, _) = breadth_first::build(triangles, params);
        report.cpu_twin_ms = Some(t.elapsed().as_secs_f64() * 1e3);
        let same_nodes = twin.nodes.len() == result.tree.nodes.len()
            && twin.nodes.iter().zip(&result.tree.nodes).all(|(a, b)| {
                a.split.to_bits() == b.split.to_bits()
                    && a.kind == b.kind
                    && a.a == b.a
                    && a.b == b.b
            });
        report.equal_to_cpu_twin = Some(same_nodes && twin.prim_refs == result.tree.prim_refs);
        let t = Instant::now();
        let full = full_clip::build(triangles, params);
        report.full_clip_ms = Some(t.elapsed().as_secs_f64() * 1e3);
        report.full_clip_sah_cost = Some(stats::stats(&full, params).sah_cost);
    }
    Ok((report, timed))
}
