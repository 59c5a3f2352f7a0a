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
    /// Mesh whose rays time the structures (default: $VKRT_MESH, else an icosphere of the
    /// bunny's size; `./x` sets it to the Stanford bunny in ../shared/scenes where that is
    /// present).
    #[arg(long)]
    mesh: Option<PathBuf>,
    /// Folder of the effect scenes (default: `scenes` in the current directory: the
    /// checkout's, run from there).
    #[arg(long, default_value = "scenes")]
    scenes: PathBuf,
}

pub fn run(args: AccuracyArgs, validate: bool) -> CliResult<()> {
    use vkrt_cli::accuracy::{measure, report};
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
