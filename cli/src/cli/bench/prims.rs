//! `vkrt bench prims`: every GPU primitive against the copy baselines of the same bytes,
//! over a range of sizes.

use clap::Args;

use crate::cli::common::{context, CliResult};

#[derive(Args)]
pub struct PrimsArgs {
    /// Largest n (rounded down to a power of two).
    #[arg(long, default_value_t = 1 << 24)]
    max_n: usize,
    /// Smallest n.
    #[arg(long, default_value_t = 1 << 16)]
    min_n: usize,
    /// Multiply n by 2^step between sizes.
    #[arg(long, default_value_t = 2)]
    step: u32,
    /// Timed repetitions (the best is reported).
    #[arg(long, default_value_t = 3)]
    reps: u32,
    /// Only the primitives whose group name contains this (scan, compact, reduce, ...).
    #[arg(long)]
    only: Option<String>,
    #[arg(long)]
    json: bool,
}

pub fn run(args: PrimsArgs, validate: bool) -> CliResult<()> {
    let PrimsArgs {
        max_n,
        min_n,
        step,
        reps,
        only,
        json,
    } = args;
    let ctx = context(validate)?;
    let mut sizes = Vec::new();
    let mut n = min_n.max(1);
    while n <= max_n {
        sizes.push(n);
        n <<= step.max(1);
    }
    let report = vkrt_cli::bench::prims::prims_report(&ctx, &sizes, reps.max(1), only.as_deref())?;
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!("{} (subgroup {})", report.device, report.subgroup_size);
        println!(
            "{:<34} {:>10} {:>10} {:>10} {:>9} {:>13}",
            "prim", "n", "gpu ms", "Melem/s", "/copy", "/copy kernel"
        );
        for r in &report.results {
            println!(
                "{:<34} {:>10} {:>10.3} {:>10.1} {:>9.3} {:>13.3}",
                r.prim,
                r.n,
                r.gpu_ms,
                r.elements_per_s / 1e6,
                r.ratio_to_copy,
                r.ratio_to_copy_kernel
            );
        }
    }
    Ok(())
}
