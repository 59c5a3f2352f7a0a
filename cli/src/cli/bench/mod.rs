//! `vkrt bench ...`: the measurements, one file per subcommand; the build benchmarks'
//! meshes are shared here.

use std::path::PathBuf;

use clap::Subcommand;

use super::common::CliResult;

mod accuracy;
mod animate;
mod bvh;
mod copy;
mod history;
mod kdtree;
mod prims;
mod render;
mod robustness;
mod soak;
mod trace;

#[derive(Subcommand)]
pub enum BenchCommand {
    /// vkCmdCopyBuffer vs the plain copy kernels, on the same bytes.
    Copy(copy::CopyArgs),
    /// Sochora's (2013) Tables 3/4 on this machine: CPU SAH BVH build time of every threading
    /// scheme (single, uneven, even, node queue, rayon) at 1 and all threads, full sweep and
    /// binned (16 bins), over the bunny and icospheres up to --max-n; the speed-up over one
    /// thread, the SAH cost, and the same tree from every scheme asserted.
    Bvh(bvh::BvhArgs),
    /// GPU kd-tree build time against N (the bunny when ../shared is present, icospheres of
    /// 100 K, 200 K, 500 K, 1 M, 2 M triangles up to --max-n), per phase, the fitted growth
    /// exponent, and with --ablation the GPU kd-tree thesis's Table 6.2: each optimisation switched back to
    /// its baseline, same tree asserted, time ratio to the default in the same run.
    Kdtree(kdtree::KdtreeArgs),
    /// What each effect costs and what the plan saves: every example scene (scenes/EFFECT.toml)
    /// as planned, without its effect, and with --all-effects, measured in one run.
    Render(render::BenchRenderArgs),
    /// The robustness suite (watertightness, self-intersection, parallel/in-plane rays,
    /// degenerate geometry, builder stress, bad rays) for both ray/triangle tests on every
    /// structure, and on the driver's own where the device has it: rays, failures and GPU
    /// trace time per case.
    Robustness(robustness::RobustnessArgs),
    /// Ray throughput of every structure and walk (each --accel and --traversal), the
    /// driver's ray query where the device has it and obvhs on one CPU thread, on the same
    /// rays in one run: the bunny (or --mesh), the example scenes and an icosphere of --max-n
    /// triangles; primary, shadow and mirror rays; build ms, trace ms, Mrays/s, hits (any
    /// difference reported) and the ratio to the driver's ray query.
    Trace(trace::BenchTraceArgs),
    /// What accuracy costs in time: every knob (structure and builder parameters, kd-tree
    /// termination, BVH leaf size, traversal, ray/triangle test, samples per pixel, ray depth,
    /// refit vs rebuild) measured in one run against a reference — build and trace ms, SAH
    /// cost, bytes, failures on the robustness suite's hard cases, image RMSE — with each
    /// group's Pareto front and a recommendation per use. Writes OUTPUT/index.html (inline SVG
    /// plots), OUTPUT/report.json and the compared images.
    Accuracy(accuracy::AccuracyArgs),
    /// An animated scene's frames on every structure and update mode in one run (kd-tree,
    /// SAH BVH, LBVH and PLOC rebuilt; the BVHs refit; the driver's both ways where the device
    /// has it): build or refit ms, render ms, frames/s per frame; the refit trees' SAH cost
    /// against a rebuild's; after how many refit frames a rebuild pays off. Writes
    /// OUTPUT/frames.svg (the per-frame plot) and OUTPUT/report.json.
    Animate(animate::BenchAnimateArgs),
    /// Every GPU primitive against the copy baselines of the same bytes, n = 2^16 .. max-n.
    Prims(prims::PrimsArgs),
    /// A long run that shows nothing grows and nothing goes wrong: --frames frames of an
    /// animated scene through `vkrt animate`'s loop (each frame finite; every
    /// --check-every-th equal byte for byte to a fresh render and near the CPU twin), then
    /// --builds random scenes (seeded) on random structures, random closest and any-hit rays
    /// checked against brute force; device bytes and host RSS from the end of a warm-up to
    /// the end. Exits non-zero on any mismatch or a growth above 1 %.
    Soak(soak::SoakArgs),
    /// The fixed quick set that guards against regressions, in one run: the mesh's primary
    /// rays through every walk (and the driver's ray query where the device has it), the
    /// kd-tree, LBVH and PLOC GPU builds, and the chained scan, each as a ratio to the best
    /// copy kernel's time for as many bytes in the same run (lower is better); appends one
    /// JSON line to --file (benches/history.jsonl).
    History(history::HistoryArgs),
    /// The newest line of a history (--file) against the previous one of the same device,
    /// driver and set: each ratio's change; exits non-zero where one grew by more than
    /// --threshold percent (default 25).
    Compare(history::CompareArgs),
}

pub fn run(what: BenchCommand, validate: bool) -> CliResult<()> {
    match what {
        BenchCommand::Copy(args) => copy::run(args, validate),
        BenchCommand::Bvh(args) => bvh::run(args),
        BenchCommand::Kdtree(args) => kdtree::run(args, validate),
        BenchCommand::Render(args) => render::run(args, validate),
        BenchCommand::Robustness(args) => robustness::run(args, validate),
        BenchCommand::Trace(args) => trace::run(&args, validate),
        BenchCommand::Accuracy(args) => accuracy::run(args, validate),
        BenchCommand::Animate(args) => animate::run(args, validate),
        BenchCommand::Prims(args) => prims::run(args, validate),
        BenchCommand::Soak(args) => soak::run(args, validate),
        BenchCommand::History(args) => history::run_history(args, validate),
        BenchCommand::Compare(args) => history::run_compare(args),
    }
}

/// Named triangle lists.
type Meshes = Vec<(String, Vec<[glam::Vec3; 3]>)>;

/// The meshes a build benchmark runs over: `mesh` (default: `$VKRT_MESH`, see
/// [`vkrt_cli::trace_bench::scenes::default_mesh`]), then icospheres of 100 K, 200 K, 500 K, 1 M and 2 M triangles up to `max_n`.
fn bench_scenes(mesh: Option<PathBuf>, max_n: u64) -> CliResult<Meshes> {
    use vkrt_cli::trace_bench::scenes;
    let mut list = Vec::new();
    if let Some(path) = mesh.or_else(scenes::default_mesh) {
        list.push(scenes::mesh_triangles(&path)?);
    }
    for n in [100_000u64, 200_000, 500_000, 1_000_000, 2_000_000] {
        if n > max_n {
            break;
        }
        list.push(scenes::icosphere_triangles(n)?);
    }
    Ok(list)
}
