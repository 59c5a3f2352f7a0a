//! `vkrt animate` and `vkrt bench animate`: the frames of an animated scene, each
//! rendered in one submission after its structure was rebuilt or refit on the device.

use std::path::{Path, PathBuf};

use vkrt::accel::device::{AccelChoice, AccelKind};
use vkrt::accel::driver::Prefer;
use vkrt::gpu::Context;
use vkrt::render::animate::{
    self, growth, AnimateOptions, AnimationReport, FramePattern, FrameWriter, Preview,
};
use vkrt::render::gpu::Update;
use vkrt::render::RenderOptions;
use vkrt::scene::Scene;
use vkrt::trace::bvh_cpu::Traversal;
use vkrt::trace::TraceOptions;

type CliResult<T> = Result<T, Box<dyn std::error::Error>>;

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
pub fn frame_range(spec: &str, count: u32) -> CliResult<std::ops::Range<u32>> {
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
fn scene_and_range(scene: Scene, args: &AnimateArgs) -> CliResult<(Scene, std::ops::Range<u32>)> {
    let scene = animated_as(scene, args.length, "--length")?;
    let range = match &args.frames {
        Some(spec) => frame_range(spec, scene.frame_count())?,
        None => 0..scene.frame_count(),
    };
    Ok((scene, range))
}

/// What `vkrt animate` was asked.
pub struct AnimateArgs {
    pub output: PathBuf,
    /// `--frames`: a range or one frame ([`frame_range`]); all by default.
    pub frames: Option<String>,
    /// `--length`: the animation's frame count.
    pub length: Option<u32>,
    /// `--skip-existing`: leave frames whose files are already complete.
    pub skip_existing: bool,
    pub render: RenderOptions,
    pub update: Update,
    pub preview: Option<PathBuf>,
}

/// `vkrt animate`: every input is checked and the output directory probed before the
/// device is touched; frames are written while the next one renders; on any error the
/// files this run wrote are removed.
pub fn animate_command(
    ctx: impl FnOnce() -> CliResult<Context>,
    scene: Scene,
    args: AnimateArgs,
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
pub fn print_report(r: &AnimationReport, json: bool) -> CliResult<()> {
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

/// The structures and update modes `vkrt bench animate` compares: every kind rebuilt, every
/// kind that can be refit refit, the driver's where the device has it.
/// The runs of `vkrt bench animate`: every structure flat (`true`: flatten), and where
/// meshes repeat (`levels`) LBVH bottom levels under a top level rebuilt or refit per frame.
fn bench_runs(ctx: &Context, levels: bool) -> Vec<(AccelChoice, Update, bool)> {
    let walk = Traversal::Stack;
    let mut runs = vec![(
        AccelChoice::new(AccelKind::KdTree, walk),
        Update::Rebuild,
        true,
    )];
    for kind in [AccelKind::SahBvh, AccelKind::Lbvh, AccelKind::Ploc] {
        runs.push((AccelChoice::new(kind, walk), Update::Rebuild, true));
        runs.push((AccelChoice::new(kind, walk), Update::Refit, true));
    }
    if ctx.info().features.ray_query {
        runs.push((
            AccelChoice::driver(Prefer::FastBuild),
            Update::Rebuild,
            true,
        ));
        runs.push((AccelChoice::driver(Prefer::FastTrace), Update::Refit, true));
    }
    if levels {
        for update in [Update::Rebuild, Update::Refit] {
            runs.push((AccelChoice::new(AccelKind::Lbvh, walk), update, false));
        }
    }
    runs
}

/// When refitting stops paying: the frames after a build over which refit's extra render
/// time adds up to more than one rebuild costs over one refit; `None` if it never does
/// within the frames. The extra render time of a refit BVH is the rebuilt run's render ms
/// times (the refit tree's SAH cost ÷ a fresh tree's − 1): the SAH models the trace cost
/// both builders optimise, while per-frame render times swing ±5 % on a shared machine,
/// more than a few frames of refit lose. Without SAH costs (the driver's structure), the
/// measured difference.
pub fn refit_pays_until(refit: &AnimationReport, rebuild: &AnimationReport) -> Option<u32> {
    let later = |r: &AnimationReport| r.frames.iter().skip(1).cloned().collect::<Vec<_>>();
    let (a, b) = (later(refit), later(rebuild));
    let extra_build = rebuild.mean_update_ms() - refit.mean_update_ms();
    let mut lost = 0.0;
    for (i, (fa, fb)) in a.iter().zip(&b).enumerate() {
        lost += match (fa.sah_cost, fa.rebuilt_sah_cost) {
            (Some(now), Some(fresh)) if fresh > 0.0 => fb.render_ms * (now / fresh - 1.0),
            _ => fa.render_ms - fb.render_ms,
        };
        if lost > extra_build {
            return Some(i as u32 + 1);
        }
    }
    None
}

/// `vkrt bench animate`: every structure and update mode over the same frames, in one run;
/// the SAH cost of the refit BVHs against a rebuild per frame; a plot and a JSON report in
/// `out`.
pub fn bench_animate(
    ctx: &Context,
    scene: &Scene,
    (frames, step): (u32, u32),
    render: &RenderOptions,
    out: &Path,
    json: bool,
) -> CliResult<()> {
    if frames == 0 || step == 0 || (frames - 1).saturating_mul(step) >= scene.frame_count() {
        return Err(format!(
            "--frames {frames} --step {step}: the scene has frames 0..{}",
            scene.frame_count()
        )
        .into());
    }
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let mut reports: Vec<AnimationReport> = Vec::new();
    let levels = vkrt::render::Plan::new(scene, render)
        .map_err(|e| e.to_string())?
        .levels
        == 2;
    for (accel, update, flatten) in bench_runs(ctx, levels) {
        let opt = AnimateOptions {
            render: RenderOptions {
                accel,
                flatten,
                ..*render
            },
            update,
            frames: (0..frames).collect(),
            radiance: false,
            quality: true,
        };
        let r = animate::run(
            ctx,
            |k| (scene.frame_time(k * step), scene.at_frame(k * step)),
            &opt,
            &TraceOptions::default(),
            |_| Ok(()),
            |_| {},
        )
        .map_err(|e| e.to_string())?;
        log::info!("{} {}: done", r.accel, r.update.name());
        reports.push(r);
    }
    animate::frames_svg(&reports, &out.join("frames.svg"))?;
    let payoff: Vec<(String, Option<u32>)> = reports
        .iter()
        .filter(|r| r.update == Update::Refit)
        .filter_map(|refit| {
            let rebuild = reports.iter().find(|r| {
                r.update == Update::Rebuild
                    && r.levels == refit.levels
                    && same_kind(&r.accel, &refit.accel)
            })?;
            let label = match refit.levels {
                2 => format!("{} (two levels)", refit.accel),
                _ => refit.accel.clone(),
            };
            Some((label, refit_pays_until(refit, rebuild)))
        })
        .collect();
    let report = serde_json::json!({
        "device": ctx.info().device,
        "runs": reports,
        "refit_pays_until_frame": payoff,
    });
    vkrt::gpu::write_atomically(
        &out.join("report.json"),
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )?;
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    let first = &reports[0];
    println!(
        "{}: {} frames (every {step}th of the animation's) {}×{}, {} spp",
        ctx.info().device,
        first.frames.len(),
        first.width,
        first.height,
        first.spp
    );
    println!(
        "{:<20} {:<8} {:>11} {:>11} {:>8} {:>9} {:>15}",
        "structure", "update", "update ms", "render ms", "frames/s", "Mrays/s", "SAH last/fresh"
    );
    for r in &reports {
        let sah = r
            .frames
            .last()
            .and_then(|f| Some(format!("{:.2}/{:.2}", f.sah_cost?, f.rebuilt_sah_cost?)))
            .unwrap_or_else(|| "-".into());
        println!(
            "{:<20} {:<8} {:>11.2} {:>11.2} {:>8.3} {:>9.2} {:>15}",
            match r.levels {
                2 => format!("{} + top", r.accel),
                _ => r.accel.clone(),
            },
            r.update.name(),
            r.mean_update_ms(),
            r.mean_render_ms(),
            r.fps(),
            r.mrays_per_s(),
            sah
        );
    }
    for (accel, until) in &payoff {
        match until {
            Some(n) => println!("{accel}: after {n} refit frames a rebuild pays off"),
            None => println!(
                "{accel}: refit pays off over all {} frames",
                first.frames.len()
            ),
        }
    }
    println!(
        "update ms: after frame 0 (which builds); wrote {}/frames.svg and report.json",
        out.display()
    );
    Ok(())
}

/// Whether two labels name the same kind (`driver/fast-build` and `driver` do).
fn same_kind(a: &str, b: &str) -> bool {
    a.split('/').next() == b.split('/').next()
}

/// `vkrt animate --plan`: how to split the animation into render-farm tasks. Renders the
/// first two frames of the range (no files) to measure a task's first frame (pipelines,
/// upload, build) and a following one, then sizes chunks to about `task_seconds` each.
/// Every chunk's command is `argv` with `--frames A..B --skip-existing` (a re-queued task
/// skips what it finished).
pub fn plan_command(
    ctx: impl FnOnce() -> CliResult<Context>,
    scene: Scene,
    args: AnimateArgs,
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
