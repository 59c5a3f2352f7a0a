//! `vkrt bench robustness`: the robustness suite for both ray/triangle tests on every
//! structure (and the driver's): rays, failures and GPU trace time per case.

use clap::Args;

use crate::cli::common::{context, CliResult};

#[derive(Args)]
pub struct RobustnessArgs {
    /// The integration test's smaller sizes (a 100K soup instead of 2M, fewer rays).
    #[arg(long)]
    quick: bool,
    #[arg(long)]
    json: bool,
}

pub fn run(args: RobustnessArgs, validate: bool) -> CliResult<()> {
    use vkrt::trace::robust::{run_all, SuiteSize};
    let RobustnessArgs { quick, json } = args;
    let ctx = context(validate)?;
    let size = if quick {
        SuiteSize::test()
    } else {
        SuiteSize::default()
    };
    let mut cases = Vec::new();
    // vkrt's structures, and the driver's where the device has it.
    for accel in vkrt::accel::device::AccelChoice::all_on(&ctx) {
        cases.extend(run_all(&ctx, &size, &vkrt::trace::Intersector::ALL, accel)?);
    }
    // Cost of NaN/Inf rays relative to valid rays into the same scene.
    let ratio = |name: &str| {
        let ms = |case: &str| {
            cases
                .iter()
                .find(|c| c.case == case && c.intersector == name && c.accel == "kdtree")
                .map(|c| c.trace_ms)
        };
        Some(ms("bad-rays/nan-inf-zero-inverted")? / ms("bad-rays/baseline-valid")?)
    };
    let ratios: serde_json::Map<String, serde_json::Value> = vkrt::trace::Intersector::ALL
        .iter()
        .filter_map(|i| Some((i.name().to_string(), ratio(i.name())?.into())))
        .collect();
    if json {
        let v = serde_json::json!({ "cases": cases, "bad_ray_cost_ratio": ratios });
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!("{}", ctx.info().device);
        println!(
            "{:<52} {:<17} {:<16} {:>9} {:>9} {:<13} {:>7} {:>10}",
            "case", "accel", "intersector", "rays", "failures", "(kind)", "errors", "trace ms"
        );
        for c in &cases {
            println!(
                "{:<52} {:<17} {:<16} {:>9} {:>9} {:<13} {:>7} {:>10.2}{}{}",
                c.case,
                c.accel,
                c.intersector,
                c.rays,
                c.failures,
                c.failure_kind,
                c.errors,
                c.trace_ms,
                if c.known_limit { "  (known limit)" } else { "" },
                if c.note.is_empty() {
                    String::new()
                } else {
                    format!("  [{}]", c.note)
                }
            );
        }
        for (name, r) in &ratios {
            println!(
                "bad rays cost {:.3}x valid rays ({name})",
                r.as_f64().unwrap_or(0.0)
            );
        }
    }
    Ok(())
}
