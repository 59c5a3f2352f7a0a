//! `vkrt verify`: the conformance checks of [`vkrt::verify`] on this machine's device, one
//! line per failed check (and, with `-v`, per passed one), a summary, and a non-zero exit
//! status when a required check failed.

use clap::Args;
use vkrt::gpu::{Context, ContextOptions, Validation};
use vkrt::verify::{self, Options};

use super::common::CliResult;

#[derive(Args)]
pub struct VerifyArgs {
    /// Print JSON: {"device", "driver", "checks", "failed", "groups": {...}}.
    #[arg(long)]
    json: bool,
    /// Fewer sizes and rays (about a third of the time).
    #[arg(long)]
    quick: bool,
    /// The device whose name contains this (default: as `vkrt info`, or VKRT_DEVICE).
    #[arg(long)]
    device: Option<String>,
}

/// Runs the checks on the device whose name contains `device` (else the one `vkrt info`
/// names); `Err` when a required check failed.
pub fn run(args: VerifyArgs, validate: bool) -> CliResult<()> {
    let VerifyArgs {
        json,
        quick,
        device,
    } = args;
    let env_on = std::env::var("VKRT_VALIDATION").is_ok_and(|v| v.trim() == "1");
    let ctx = Context::new(&ContextOptions {
        validation: if validate || env_on {
            Validation::On
        } else {
            Validation::Off
        },
        device_name: device,
        ..Default::default()
    })?;
    super::common::apply_profiling(&ctx);
    let info = ctx.info();
    if !json {
        println!("{} ({}), {}", info.device, info.device_type, info.driver);
    }
    let report = verify::run(&ctx, &Options { quick }, &mut |c| {
        if json {
            return;
        }
        if !c.passed {
            let what = if c.required { "FAIL" } else { "note" };
            println!("{what}  {:<12} {}: {}", c.group, c.name, c.detail);
        } else {
            log::info!("ok    {:<12} {}", c.group, c.name);
        }
    });
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        for (group, g) in &report.groups {
            println!("{group:<12} {:>4} checks, {} failed", g.checks, g.failed);
        }
        println!(
            "{} checks, {} failed, in {:.1} s",
            report.checks, report.failed, report.seconds
        );
    }
    if report.failed > 0 {
        return Err(format!(
            "{} of {} checks failed on {}",
            report.failed, report.checks, report.device
        )
        .into());
    }
    Ok(())
}
