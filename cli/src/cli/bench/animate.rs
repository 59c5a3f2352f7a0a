//! `vkrt bench animate`: an animated scene's frames on every structure and update mode in
//! one run; per-frame update and render times, refit trees' SAH cost against a rebuild's,
//! when a rebuild pays off; a plot and a JSON report in `-o/--output`.

use std::path::{Path, PathBuf};

use clap::Args;
use vkrt::accel::device::{AccelChoice, AccelKind};
use vkrt::accel::driver::Prefer;
use vkrt::accel::walk::Traversal;
use vkrt::gpu::Context;
use vkrt::render::animate::{self, AnimateOptions, AnimationReport};
use vkrt::render::gpu::Update;
use vkrt::render::RenderOptions;
use vkrt::scene::Scene;
use vkrt::trace::TraceOptions;

use crate::cli::animate::animated;
use crate::cli::common::{check_resolution, context, load_scene, CliResult};

#[derive(Args)]
pub struct BenchAnimateArgs {
    /// The animated scene (default: scenes/dynamic_demo.toml in the current directory: the
    /// checkout's, run from there).
    #[arg(default_value = "scenes/dynamic_demo.toml")]
    scene: PathBuf,
    /// Frames rendered per run.
    #[arg(long, default_value_t = 8)]
    frames: u32,
    /// Render every STEP-th frame of the animation (the default spans the demo's 48-frame
    /// loop; a refit from one rendered frame to the next is exact whatever the step).
    #[arg(long, default_value_t = 6)]
    step: u32,
    #[arg(long, default_value_t = 1024)]
    width: u32,
    #[arg(long, default_value_t = 768)]
    height: u32,
    #[arg(long)]
    spp: Option<u32>,
    // `--out` was the flag's name before every command's output was `-o/--output`.
    #[arg(short, long, alias = "out", default_value = "animate-report")]
    output: PathBuf,
    #[arg(long)]
    json: bool,
}

pub fn run(args: BenchAnimateArgs, validate: bool) -> CliResult<()> {
    let BenchAnimateArgs {
        scene,
        frames,
        step,
        width,
        height,
        spp,
        output,
        json,
    } = args;
    let render = RenderOptions {
        width: Some(width),
        height: Some(height),
        spp,
        ..Default::default()
    };
    check_resolution(&render)?;
    let scene = animated(load_scene(&Some(scene))?, None)?;
    let ctx = context(validate)?;
    bench_animate(&ctx, &scene, (frames, step), &render, &output, json)
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
fn refit_pays_until(refit: &AnimationReport, rebuild: &AnimationReport) -> Option<u32> {
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
fn bench_animate(
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
    vkrt_cli::animate_plot::frames_svg(&reports, &out.join("frames.svg"))?;
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
