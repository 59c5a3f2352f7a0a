//! `vkrt bench accuracy`: what accuracy costs in time, every knob against a reference, with
//! Pareto fronts and recommendations; an HTML and JSON report in `-o/--output`.

use std::path::PathBuf;

use clap::Args;

use crate::cli::common::{context, CliResult};

#[derive(Args)]
pub struct AccuracyArgs {
    /// Smaller everything (~3 minutes on 2 cores of lavapipe; the CI's check).
    #[arg(long)]
    quick: bool,
    /// Print the report as JSON too.
    #[arg(long)]
    json: bool,
    // `--out` was the flag's name before every command's output was `-o/--output`.
    #[arg(short, long, alias = "out", default_value = "accuracy-report")]
    output: PathBuf,
    /// Mesh whose rays time the structures (default: ../shared/scenes/stanford-bunny.obj
    /// when present, else an icosphere of as many triangles).
    #[arg(long)]
    mesh: Option<PathBuf>,
    /// Folder of the effect scenes.
    #[arg(long, default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes"))]
    scenes: PathBuf,
}

pub fn run(args: AccuracyArgs, validate: bool) -> CliResult<()> {
    use vkrt::accuracy::{measure, report};
    let AccuracyArgs {
        quick,
        json,
        output,
        mesh,
        scenes,
    } = args;
    report::check_target(&output)?;
    let opt = measure::AccuracyOptions {
        quick,
        mesh,
        motion_scene: scenes.join("dynamic_demo.toml"),
        scenes_dir: scenes,
        command: std::env::args().collect::<Vec<_>>().join(" "),
    };
    let ctx = context(validate)?;
    let (r, images) =
        measure::run(&ctx, &opt, |line| eprintln!("{line}")).map_err(|e| e.to_string())?;
    report::write(&output, &r, &images)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        print!("{r}");
        println!("report: {}", output.join("index.html").display());
    }
    Ok(())
}
