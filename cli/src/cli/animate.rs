//! `vkrt animate`: the frames of an animated scene, each rendered in one submission after
//! its structure was rebuilt or refit on the device; `--plan` sizes render-farm tasks.

use std::path::PathBuf;

use clap::Args;
use vkrt::gpu::Context;
use vkrt::render::animate::{
    self, growth, AnimateOptions, AnimationReport, FramePattern, FrameWriter, Preview,
};
use vkrt::render::gpu::Update;
use vkrt::render::RenderOptions;
use vkrt::scene::Scene;
use vkrt::trace::TraceOptions;

use super::common::{check_resolution, context, load_scene, CliResult, StructureArgs, UpdateArg};

#[derive(Args)]
pub struct AnimateArgs {
    /// The animated scene (.toml with `[animation]`).
    scene: PathBuf,
    /// Frame files: a pattern with one %d or %0Nd; .png or .jpg (8-bit sRGB), .exr or .pfm
    /// (linear radiance, as `render -o x.exr`).
    #[arg(short, long, default_value = "frames/frame_%04d.png")]
    output: PathBuf,
    /// The frames to render, by number: A..B (B excluded), A..=B, A.. (to the end), ..B,
    /// or one frame K (default: all). Any split renders the same frames: a render farm's
    /// tasks each take a range.
    #[arg(long)]
    frames: Option<String>,
    /// The animation's frame count, overriding the scene's.
    #[arg(long)]
    length: Option<u32>,
    /// Leave frames whose files are already complete (a whole image of the right size):
    /// a re-queued farm task does not redo finished frames.
    #[arg(long)]
    skip_existing: bool,
    /// Render nothing: measure the first frames and print (JSON) how to split the
    /// animation into render-farm tasks of about --task-seconds each, with each task's
    /// command.
    #[arg(long)]
    plan: bool,
    /// The wall time a farm task should take, for --plan.
    #[arg(long, default_value_t = 600.0)]
    task_seconds: f64,
    #[arg(long)]
    spp: Option<u32>,
    #[arg(long)]
    width: Option<u32>,
    #[arg(long)]
    height: Option<u32>,
    #[command(flatten)]
    structure: StructureArgs,
    /// Per frame: build the structure anew, or refit it (BVHs and the driver's). Over
    /// two levels only the top level is rebuilt or refit: rigid motions move instances.
    #[arg(long, value_enum, default_value_t = UpdateArg::Rebuild)]
    update: UpdateArg,
    /// Also an animated PNG of every frame, for a quick look.
    #[arg(long)]
    preview: Option<PathBuf>,
    /// One JSON object: the frames' numbers and the means.
    #[arg(long)]
    json: bool,
}

pub fn run(args: AnimateArgs, validate: bool) -> CliResult<()> {
    let AnimateArgs {
        scene,
        output,
        frames,
        length,
        skip_existing,
        plan,
        task_seconds,
        spp,
        width,
        height,
        structure,
        update,
        preview,
        json,
    } = args;
    let render = RenderOptions {
        width,
        height,
        spp,
        all_effects: false,
        accel: structure.choice(None),
        flatten: structure.flatten,
        // (from the device, when it renders)
        max_level_primitives: None,
    };
    check_resolution(&render)?;
    let loaded = load_scene(&Some(scene))?;
    let job = AnimateJob {
        output,
        frames,
        length,
        skip_existing,
        render,
        structure,
        update: match update {
            UpdateArg::Rebuild => Update::Rebuild,
            UpdateArg::Refit => Update::Refit,
        },
        preview,
    };
    if plan {
        let argv: Vec<String> = std::env::args().collect();
        let v = plan_command(
            || context(validate),
            loaded,
            job,
            &Default::default(),
            task_seconds,
            &argv,
        )?;
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    let report = animate_command(|| context(validate), loaded, job, &Default::default())
        .map_err(|e| e.to_string());
    print_report(&report?, json)?;
    Ok(())
}

/// `scene` with `frames` frames (its own count by default): at most
/// [`vkrt::scene::MAX_FRAMES`], and the scene must be animated.
pub fn animated(scene: Scene, frames: Option<u32>) -> CliResult<Scene> {
    animated_as(scene, frames, "--frames")
}

fn animated_as(mut scene: Scene, frames: Option<u32>, flag: &str) -> CliResult<Scene> {
    let Some(anim) = scene.animation.as_mut() else {
        return Err(
            "the scene has no [animation] (fps, and frames or end_time): \
                    see docs/scene-format.md"
                .into(),
        );
    };
    if let Some(n) = frames {
        if n == 0 || n > vkrt::scene::MAX_FRAMES {
            return Err(format!("{flag} must be 1..={}", vkrt::scene::MAX_FRAMES).into());
        }
        anim.frames = n;
    }
    Ok(scene)
}

/// The frames `spec` names among `0..count`: `A..B` (B excluded, as Rust's ranges),
/// `A..=B`, `A..`, `..B`, or one frame `K`. Empty, reversed or outside: an error.
fn frame_range(spec: &str, count: u32) -> CliResult<std::ops::Range<u32>> {
    let bad = || -> Box<dyn std::error::Error> {
        format!("--frames `{spec}`: expected A..B (B excluded), A..=B, A.., ..B or one frame K")
            .into()
    };
    let num = |s: &str| s.trim().parse::<u32>().map_err(|_| bad());
    let (start, end) = match spec.split_once("..") {
        None => {
            let k = num(spec)?;
            (k, k.checked_add(1).ok_or_else(bad)?)
        }
        Some((a, b)) => {
            let start = if a.trim().is_empty() { 0 } else { num(a)? };
            let end = match b.strip_prefix('=') {
                Some(b) => num(b)?.checked_add(1).ok_or_else(bad)?,
                None if b.trim().is_empty() => count,
                None => num(b)?,
            };
            (start, end)
        }
    };
    if end <= start {
        return Err(format!("--frames `{spec}` is empty").into());
    }
    if end > count {
        return Err(format!(
            "--frames `{spec}` is outside the animation's frames 0..{count} (--length sets the count)"
        )
        .into());
    }
    Ok(start..end)
}

/// The scene with `--length` applied, and the frames `--frames` names (all by default).
fn scene_and_range(scene: Scene, args: &AnimateJob) -> CliResult<(Scene, std::ops::Range<u32>)> {
    let scene = animated_as(scene, args.length, "--length")?;
    let range = match &args.frames {
        Some(spec) => frame_range(spec, scene.frame_count())?,
        None => 0..scene.frame_count(),
    };
    Ok((scene, range))
}

/// What `vkrt animate` was asked.
struct AnimateJob {
    pub output: PathBuf,
    /// `--frames`: a range or one frame ([`frame_range`]); all by default.
    pub frames: Option<String>,
    /// `--length`: the animation's frame count.
    pub length: Option<u32>,
    /// `--skip-existing`: leave frames whose files are already complete.
    pub skip_existing: bool,
    pub render: RenderOptions,
    /// `--accel` and `--traversal` (the walk is the device's where `auto`).
    pub structure: StructureArgs,
    pub update: Update,
    pub preview: Option<PathBuf>,
}

/// `vkrt animate`: every input is checked and the output directory probed before the
/// device is touched; frames are written while the next one renders; on any error the
/// files this run wrote are removed.
fn animate_command(
    ctx: impl FnOnce() -> CliResult<Context>,
    scene: Scene,
    args: AnimateJob,
    trace: &TraceOptions,
) -> CliResult<AnimationReport> {
    let (scene, range) = scene_and_range(scene, &args)?;
    let pattern = FramePattern::parse(&args.output)?;
    let pattern_float = pattern.float();
    if let Some(p) = &args.preview {
        if !p
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("png") || e.eq_ignore_ascii_case("apng"))
        {
            return Err(format!("{}: the preview is an animated PNG (.png)", p.display()).into());
        }
    }
    if args.preview.is_some() && args.skip_existing {
        return Err("--preview needs every frame rendered: not with --skip-existing".into());
    }
    let plan = vkrt::render::Plan::new(&scene.at_frame(0), &args.render)?;
    pattern.prepare()?;
    let (todo, skipped): (Vec<u32>, Vec<u32>) = range
        .clone()
        .partition(|&k| !(args.skip_existing && pattern.complete(k, plan.width, plan.height)));
    let ctx = ctx()?;
    let mut args = args;
    args.render.accel = args.structure.choice(Some(&ctx));
    let frames = todo.len() as u32;
    let preview = args.preview.clone().map(|path| Preview {
        path,
        fps: scene.animation.map_or(24.0, |a| a.fps),
        frames,
    });
    let mut writer = FrameWriter::new(pattern, plan.width, plan.height, preview)?;
    let bar = indicatif::ProgressBar::new(frames as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} frames {pos}/{len} [{bar:30}] {elapsed_precise} (eta {eta})",
        )
        .map_err(|e| e.to_string())?,
    );
    let opt = AnimateOptions {
        render: args.render,
        update: args.update,
        frames: todo,
        radiance: pattern_float,
        quality: false,
    };
    let report = animate::run(
        &ctx,
        |k| (scene.frame_time(k), scene.at_frame(k)),
        &opt,
        trace,
        |frame| writer.write(frame),
        |done| bar.set_position(done as u64),
    );
    bar.finish_and_clear();
    match report {
        Ok(mut r) => {
            writer.finish()?;
            r.skipped = skipped;
            Ok(r)
        }
        Err(e) => {
            writer.abandon();
            Err(e.to_string().into())
        }
    }
}

/// Prints a report: one JSON object per frame and a summary, or a table.
fn print_report(r: &AnimationReport, json: bool) -> CliResult<()> {
    if json {
        let v = serde_json::json!({
            "accel": r.accel,
            "levels": r.levels,
            "update": r.update,
            "width": r.width,
            "height": r.height,
            "spp": r.spp,
            "frames": r.frames,
            "skipped": r.skipped,
            "mean_update_ms": r.mean_update_ms(),
            "mean_render_ms": r.mean_render_ms(),
            "fps": r.fps(),
            "mrays_per_s": r.mrays_per_s(),
            "submits": r.traffic_totals().0,
            "readback_bytes": r.traffic_totals().1,
            "upload_bytes": r.traffic_totals().2,
            "memory": memory_summary(r),
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    println!(
        "{} frames {}×{}, {} spp, {} ({}{})",
        r.frames.len(),
        r.width,
        r.height,
        r.spp,
        r.accel,
        r.update.name(),
        match r.levels {
            2 => " of the top level over the instances",
            _ => "",
        }
    );
    println!(
        "{:>6} {:>8} {:>9} {:>11} {:>10} {:>12} {:>9}",
        "frame", "time s", "update", "update ms", "render ms", "rays", "wall ms"
    );
    for f in &r.frames {
        println!(
            "{:>6} {:>8.3} {:>9} {:>11.2} {:>10.2} {:>12} {:>9.1}",
            f.frame,
            f.time,
            if f.built { "build" } else { "refit" },
            f.update_ms,
            f.render_ms,
            f.rays,
            f.wall_ms
        );
    }
    println!(
        "mean: update {:.2} ms (after frame 0), render {:.2} ms, {:.2} frames/s, {:.2} Mrays/s",
        r.mean_update_ms(),
        r.mean_render_ms(),
        r.fps(),
        r.mrays_per_s()
    );
    if !r.skipped.is_empty() {
        println!(
            "skipped {} frames whose files were complete",
            r.skipped.len()
        );
    }
    if let Some(m) = memory_line(r) {
        println!("{m}");
    }
    Ok(())
}

/// The frame a memory comparison starts from: caches and pools settle in the first frames.
const SETTLED_FRAME: usize = 10;

/// Device memory and host RSS at the settled frame and at the last, and their growth.
fn memory_summary(r: &AnimationReport) -> serde_json::Value {
    let from = SETTLED_FRAME.min(r.frames.len().saturating_sub(1));
    let at = |i: usize| r.frames.get(i);
    let last = r.frames.len().saturating_sub(1);
    serde_json::json!({
        "from_frame": from,
        "device_bytes": [at(from).map(|f| f.device_bytes), at(last).map(|f| f.device_bytes)],
        "host_rss_bytes": [at(from).and_then(|f| f.host_rss_bytes), at(last).and_then(|f| f.host_rss_bytes)],
        "device_growth": growth(&r.frames, from, |f| Some(f.device_bytes)),
        "host_rss_growth": growth(&r.frames, from, |f| f.host_rss_bytes),
    })
}

fn memory_line(r: &AnimationReport) -> Option<String> {
    let from = SETTLED_FRAME.min(r.frames.len().checked_sub(1)?);
    let (a, b) = (&r.frames[from], r.frames.last()?);
    let mib = |x: u64| x as f64 / (1 << 20) as f64;
    let pct = |g: Option<f64>| g.map_or("-".into(), |g| format!("{:+.2} %", g * 100.0));
    let rss = match (a.host_rss_bytes, b.host_rss_bytes) {
        (Some(x), Some(y)) => format!(
            "host RSS {:.1} → {:.1} MiB ({})",
            mib(x),
            mib(y),
            pct(growth(&r.frames, from, |f| f.host_rss_bytes))
        ),
        _ => "host RSS not reported by this OS".into(),
    };
    Some(format!(
        "memory from frame {from} to {}: device {:.1} → {:.1} MiB ({}), {rss}",
        b.frame,
        mib(a.device_bytes),
        mib(b.device_bytes),
        pct(growth(&r.frames, from, |f| Some(f.device_bytes))),
    ))
}

/// `vkrt animate --plan`: how to split the animation into render-farm tasks. Renders the
/// first two frames of the range (no files) to measure a task's first frame (pipelines,
/// upload, build) and a following one, then sizes chunks to about `task_seconds` each.
/// Every chunk's command is `argv` with `--frames A..B --skip-existing` (a re-queued task
/// skips what it finished).
fn plan_command(
    ctx: impl FnOnce() -> CliResult<Context>,
    scene: Scene,
    args: AnimateJob,
    trace: &TraceOptions,
    task_seconds: f64,
    argv: &[String],
) -> CliResult<serde_json::Value> {
    if !(task_seconds.is_finite() && task_seconds > 0.0) {
        return Err("--task-seconds must be a positive number".into());
    }
    let (scene, range) = scene_and_range(scene, &args)?;
    FramePattern::parse(&args.output)?;
    let ctx = ctx()?;
    let mut args = args;
    args.render.accel = args.structure.choice(Some(&ctx));
    let probe: Vec<u32> = range.clone().take(2).collect();
    let opt = AnimateOptions {
        render: args.render,
        update: args.update,
        frames: probe,
        radiance: false,
        quality: false,
    };
    let report = animate::run(
        &ctx,
        |k| (scene.frame_time(k), scene.at_frame(k)),
        &opt,
        trace,
        |_| Ok(()),
        |_| {},
    )
    .map_err(|e| e.to_string())?;
    let first_ms = report.frames.first().map_or(0.0, |f| f.wall_ms);
    let next_ms = report
        .frames
        .get(1)
        .map_or(first_ms, |f| f.wall_ms)
        .max(1e-3);
    let budget_ms = task_seconds * 1e3;
    let chunk =
        (((budget_ms - first_ms) / next_ms).floor() as i64 + 1).clamp(1, range.len() as i64) as u32;
    let base = plan_argv(argv);
    let chunks: Vec<serde_json::Value> = range
        .clone()
        .step_by(chunk as usize)
        .map(|a| {
            let b = (a + chunk).min(range.end);
            let mut cmd = base.clone();
            cmd.extend([
                "--frames".into(),
                format!("{a}..{b}"),
                "--skip-existing".into(),
            ]);
            serde_json::json!({ "frames": format!("{a}..{b}"), "command": cmd })
        })
        .collect();
    Ok(serde_json::json!({
        "frames": range.len(),
        "range": format!("{}..{}", range.start, range.end),
        "first_frame_ms": first_ms,
        "frame_ms": next_ms,
        "task_seconds": task_seconds,
        "chunk": chunk,
        "chunks": chunks,
    }))
}

/// The invocation as a task runs it: `vkrt` and the arguments, less the planning ones and
/// those each task sets itself (`--frames`, `--skip-existing`, `--json`, `--preview`).
fn plan_argv(argv: &[String]) -> Vec<String> {
    let mut out = vec!["vkrt".to_string()];
    let mut args = argv.iter().skip(1);
    while let Some(a) = args.next() {
        let flag = a.split('=').next().unwrap_or(a);
        match flag {
            "--plan" | "--skip-existing" | "--json" => {}
            "--frames" | "--task-seconds" | "--preview" => {
                if !a.contains('=') {
                    args.next();
                }
            }
            _ => out.push(a.clone()),
        }
    }
    out
}
