//! `vkrt bench kdtree`: GPU kd-tree build time against N per phase, the fitted growth
//! exponent, and with `--ablation` each optimisation switched back to its baseline.

use std::path::PathBuf;

use clap::Args;

use super::bench_scenes;
use crate::cli::common::{context, CliResult};

#[derive(Args)]
pub struct KdtreeArgs {
    /// Largest icosphere (triangles).
    #[arg(long, default_value_t = 500_000)]
    max_n: u64,
    /// Also build each scene of at most --ablation-max-n triangles with each variant.
    #[arg(long)]
    ablation: bool,
    #[arg(long, default_value_t = 100_000)]
    ablation_max_n: u64,
    /// Timed builds per variant, interleaved round-robin over the variants; the fastest
    /// of each is reported (the machine may be shared).
    #[arg(long, default_value_t = 1)]
    reps: u32,
    /// Kolodzey's (2014) termination: leaves below 64 primitives, no SAH leaf test (much smaller
    /// trees than the default leaves of at most 2 primitives).
    #[arg(long)]
    kolodzey_termination: bool,
    /// Mesh to include (default: $VKRT_MESH; `./x` sets it to the Stanford bunny in
    /// ../shared/scenes where that is present).
    #[arg(long)]
    mesh: Option<PathBuf>,
    #[arg(long)]
    json: bool,
}

pub fn run(args: KdtreeArgs, validate: bool) -> CliResult<()> {
    let KdtreeArgs {
        max_n,
        ablation,
        ablation_max_n,
        reps,
        kolodzey_termination,
        mesh,
        json,
    } = args;
    let scenes = bench_scenes(mesh, max_n)?;
    let ctx = context(validate)?;
    let mut params = vkrt::accel::kdtree::SahParams::default();
    if kolodzey_termination {
        params.max_leaf_prims = 63;
        params.sah_leaf_test = false;
    }
    let ablation_max_n = if ablation { ablation_max_n as usize } else { 0 };
    let report =
        vkrt_cli::bench::kdtree::kdtree_report(&ctx, &scenes, &params, ablation_max_n, reps)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!("{}", report.device);
        println!("{:?}", report.params);
        println!(
            "{:<16} {:>9} {:<22} {:>10} {:>7} {:>9} {:>9} {:>9} {:>9} {:>9} {:>8}",
            "scene",
            "tris",
            "variant",
            "build ms",
            "ratio",
            "phase1",
            "costs",
            "argmin",
            "nodes",
            "clip",
            "SAH"
        );
        for r in &report.rows {
            let p = |k: &str| r.phases.get(k).copied().unwrap_or(0.0);
            if let Some(e) = &r.error {
                println!("{:<16} {:>9} {:<22} {e}", r.scene, r.primitives, r.variant);
                continue;
            }
            println!(
                "{:<16} {:>9} {:<22} {:>10.1} {:>7.2} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>8.2}",
                r.scene,
                r.primitives,
                r.variant,
                r.build_ms,
                r.ratio_to_default,
                p("phase1"),
                p("split_costs"),
                p("best_split"),
                p("nodes"),
                p("clip_partition"),
                r.sah_cost
            );
        }
        if report.rows.iter().any(|r| r.variant != "default") {
            println!("ratio: variant build ms / default build ms, same scene, same run, same tree");
            for (label, note) in vkrt_cli::bench::kdtree::KD_VARIANT_NOTES {
                println!("  {label}: {note}");
            }
        }
        if let Some(e) = report.fitted_exponent {
            println!("fitted exponent of build time over N (icospheres): {e:.3}");
        }
        if let Some(e) = report.fitted_exponent_all {
            println!("fitted exponent of build time over N (all default rows): {e:.3}");
        }
    }
    Ok(())
}
