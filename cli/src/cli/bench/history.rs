//! `vkrt bench history` (measure the fixed quick set, append one JSON line to the history)
//! and `vkrt bench compare` (the newest line against the previous one of the same device).

use std::io::Write;
use std::path::{Path, PathBuf};

use clap::Args;

use vkrt_cli::bench::history::{self, HistoryOptions, HistoryRun, QueryShader};

use crate::cli::common::{context, CliResult};

/// The repository's history, from the checkout's root.
const DEFAULT_FILE: &str = "benches/history.jsonl";
/// The ray-query shader of the set, from the checkout's root.
const DEFAULT_QUERY_SHADER: &str = "examples/ray_queries/closest_hit.comp";

#[derive(Args)]
pub struct HistoryArgs {
    /// The history file the run's line is appended to (created where missing).
    #[arg(long, default_value = DEFAULT_FILE)]
    file: PathBuf,
    /// The mesh whose primary rays are traced and whose structures are built (default:
    /// $VKRT_MESH; `./x` sets it to the Stanford bunny in ../shared/scenes, read in place).
    #[arg(long)]
    mesh: Option<PathBuf>,
    /// Without a mesh, an icosphere of at least this many triangles.
    #[arg(long, default_value_t = 100_000)]
    icosphere: u64,
    /// Camera image width in pixels, one primary ray per pixel.
    #[arg(long, default_value_t = HistoryOptions::default().size)]
    size: u32,
    /// Elements of the scan (u32); the copy baseline moves 4 × this many bytes.
    #[arg(long, default_value_t = HistoryOptions::default().scan_n)]
    scan_n: u64,
    /// Rounds of the whole set, each measuring every item once (each trace three times);
    /// each item keeps its best over the rounds.
    #[arg(long, default_value_t = HistoryOptions::default().reps)]
    reps: u32,
    /// A `GL_EXT_ray_query` compute shader in `vkrt shader-check`'s interface, traced on the
    /// same rays through vkrt/ext_ray_query.glsl (`query.include`) and, where the device has
    /// ray query, through the driver's (`query.driver`); it needs glslc (or VKRT_GLSLC).
    /// Where it cannot be read or compiled, the run leaves the `query.*` metrics out and
    /// says why.
    #[arg(long, default_value = DEFAULT_QUERY_SHADER)]
    query_shader: PathBuf,
    /// Measure and print, but append nothing.
    #[arg(long)]
    dry_run: bool,
    /// Print the run's JSON line instead of the table.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
pub struct CompareArgs {
    /// The history file to read.
    #[arg(long, default_value = DEFAULT_FILE)]
    file: PathBuf,
    /// Percent by which a ratio may grow before it counts as a regression (the default
    /// clears the spread of back-to-back runs on a 2-core lavapipe; lower it on a quieter
    /// device).
    #[arg(long, default_value_t = 25.0)]
    threshold: f64,
    #[arg(long)]
    json: bool,
}

pub fn run_history(args: HistoryArgs, validate: bool) -> CliResult<()> {
    use vkrt_cli::trace_bench::scenes;
    let scene = match args.mesh.or_else(scenes::default_mesh) {
        Some(path) => scenes::mesh(&path)?,
        None => scenes::icosphere(args.icosphere)?,
    };
    let opt = HistoryOptions {
        size: args.size.max(1),
        scan_n: args.scan_n.max(32),
        reps: args.reps.max(1),
    };
    let ctx = context(validate)?;
    let query = QueryShader::compile(&args.query_shader, ctx.info().features.ray_query)
        .map_err(|e| log::warn!("no query.* metrics: {e}"))
        .ok();
    let mut run = history::measure(&ctx, &scene, &opt, query.as_ref())?;
    run.date = history::utc_date(
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)?
            .as_secs(),
    );
    run.commit = git_commit();
    let line = serde_json::to_string(&run)?;
    if args.json {
        println!("{line}");
    } else {
        print_run(&run);
    }
    if !args.dry_run {
        append_line(&args.file, &line)?;
        if !args.json {
            println!("appended to {}", args.file.display());
        }
    }
    Ok(())
}

pub fn run_compare(args: CompareArgs) -> CliResult<()> {
    if !(args.threshold.is_finite() && args.threshold >= 0.0) {
        return Err(format!("--threshold {} is not a percentage ≥ 0", args.threshold).into());
    }
    let text = std::fs::read_to_string(&args.file)
        .map_err(|e| format!("cannot read the history {}: {e}", args.file.display()))?;
    let in_file = |e: history::HistoryError| format!("{}: {e}", args.file.display());
    let runs = history::parse(&text).map_err(in_file)?;
    let cmp = history::compare(&runs, args.threshold / 100.0).map_err(in_file)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&cmp)?);
    } else {
        let at = |(date, commit): &(String, Option<String>)| {
            format!("{date} ({})", commit.as_deref().unwrap_or("no commit"))
        };
        println!("{} ({})", cmp.device, cmp.driver);
        println!("previous {}", at(&cmp.previous));
        println!("newest   {}", at(&cmp.newest));
        println!(
            "{:<28} {:>10} {:>10} {:>9} {:>9}",
            "metric (lower is better)", "previous", "newest", "change", "time"
        );
        let num = |x: Option<f64>| x.map_or("—".to_string(), |x| format!("{x:.4}"));
        let pct = |x: Option<f64>| x.map_or("—".to_string(), |x| format!("{:+.1} %", 100.0 * x));
        for c in &cmp.changes {
            let flag = if c.regressed { "  REGRESSION" } else { "" };
            println!(
                "{:<28} {:>10} {:>10} {:>9} {:>9}{flag}",
                c.name,
                num(c.previous),
                num(c.newest),
                pct(c.change),
                pct(c.ms_change)
            );
        }
    }
    let regressions = cmp.regressions();
    if !regressions.is_empty() {
        let names: Vec<&str> = regressions.iter().map(|c| c.name.as_str()).collect();
        return Err(format!(
            "{} metric(s) more than {} % worse than the previous run, ratio and time: {}",
            names.len(),
            args.threshold,
            names.join(", ")
        )
        .into());
    }
    Ok(())
}

fn print_run(run: &HistoryRun) {
    println!("{} ({})", run.device, run.driver);
    println!(
        "{}: {} triangles, {} primary rays; scan of {} u32; baseline {} over {} bytes: {:.3} ms",
        run.set.scene,
        run.set.triangles,
        run.set.rays,
        run.set.options.scan_n,
        run.copy.kernel,
        run.copy.bytes,
        run.copy.ms
    );
    println!(
        "{:<28} {:>10} {:>12} {:>10}",
        "metric", "ms", "baseline ms", "ratio"
    );
    for (name, m) in &run.metrics {
        println!(
            "{name:<28} {:>10.3} {:>12.4} {:>10.4}",
            m.ms, m.baseline_ms, m.ratio
        );
    }
}

/// The checkout's commit, `-dirty` where the work tree differs from it; `None` where git or
/// a checkout is missing.
fn git_commit() -> Option<String> {
    let git = |args: &[&str]| {
        let out = std::process::Command::new("git").args(args).output().ok()?;
        out.status
            .success()
            .then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
    };
    let commit = git(&["rev-parse", "--short=12", "HEAD"])?;
    let dirty =
        git(&["status", "--porcelain", "--untracked-files=no"]).is_some_and(|s| !s.is_empty());
    Some(if dirty {
        format!("{commit}-dirty")
    } else {
        commit
    })
}

/// Appends `line` and a newline to `path`, creating it (and its folder) where missing.
fn append_line(path: &Path, line: &str) -> CliResult<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .map_err(|e| format!("cannot append to {}: {e}", path.display()))?;
    writeln!(f, "{line}")?;
    Ok(())
}
