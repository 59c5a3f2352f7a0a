//! `vkrt bench copy`: vkCmdCopyBuffer against the plain copy kernels on the same bytes, the
//! baselines the primitives are measured against.

use clap::Args;

use crate::cli::common::{context, CliResult};

#[derive(Args)]
pub struct CopyArgs {
    /// MiB to copy.
    #[arg(long, default_value_t = 64)]
    mib: u64,
    /// Timed repetitions (the best is reported).
    #[arg(long, default_value_t = 5)]
    reps: u32,
    #[arg(long)]
    json: bool,
}

pub fn run(args: CopyArgs, validate: bool) -> CliResult<()> {
    let CopyArgs { mib, reps, json } = args;
    let ctx = context(validate)?;
    let (baselines, _) = vkrt_cli::bench::copy::copy_baselines(&ctx, mib << 20, reps.max(1))?;
    if json {
        println!("{}", serde_json::to_string_pretty(&baselines)?);
    } else {
        println!(
            "{} (subgroup {}), {} MiB, best of {}",
            baselines.device, baselines.subgroup_size, mib, baselines.repetitions
        );
        println!(
            "{:<26} {:>10} {:>10} {:>14}",
            "method", "ms", "GiB/s r+w", "copy_ms / ms"
        );
        for r in &baselines.results {
            println!(
                "{:<26} {:>10.3} {:>10.2} {:>14.3}",
                r.method, r.gpu_ms, r.gib_per_s, r.ratio_to_copy
            );
        }
    }
    Ok(())
}
