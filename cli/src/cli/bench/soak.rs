//! `vkrt bench soak`: a long run that shows nothing grows and nothing goes wrong; many
//! frames of an animated scene, then many random scenes built and traced, every answer
//! checked; device memory and host RSS growth after a warm-up. Fails (non-zero exit) on
//! any mismatch or a growth above 1 %.

use std::path::PathBuf;
use std::time::Instant;

use clap::Args;
use vkrt::render::gpu::Update;
use vkrt::render::RenderOptions;
use vkrt_cli::soak::{self, BuildSoak, BuildSoakOptions, FrameSoak, FrameSoakOptions, Growth};

use crate::cli::animate::animated;
use crate::cli::common::{check_resolution, context, load_scene, CliResult};

#[derive(Args)]
pub struct SoakArgs {
    /// The animated scene (default: scenes/dynamic_demo.toml in the current directory: the
    /// checkout's, run from there).
    #[arg(default_value = "scenes/dynamic_demo.toml")]
    scene: PathBuf,
    /// Frames rendered (the animation wraps around).
    #[arg(long)]
    frames: Option<u32>,
    /// Random scenes built and traced.
    #[arg(long)]
    builds: Option<u32>,
    /// The random scenes' seed (the same seed, the same run).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Check every N-th frame against a fresh render and the CPU twin.
    #[arg(long)]
    check_every: Option<u32>,
    /// The largest random scene, in primitives.
    #[arg(long)]
    max_primitives: Option<u32>,
    /// Rays per random scene (each traced for the closest and for any hit).
    #[arg(long)]
    rays: Option<usize>,
    #[arg(long, default_value_t = 64)]
    width: u32,
    #[arg(long, default_value_t = 48)]
    height: u32,
    /// Trace the scene as one flat structure (its CPU twin then checks the frames too; a
    /// flat rebuild of the demo's 100 K triangles costs about 2 s a frame on lavapipe)
    /// rather than two levels (where repeated meshes are instances).
    #[arg(long)]
    flatten: bool,
    /// Per frame: rebuild the structure or refit it.
    #[arg(long, value_enum, default_value_t = UpdateArg::Rebuild)]
    update: UpdateArg,
    /// The integration test's sizes: 100 frames, 40 builds of at most 4,000 primitives.
    #[arg(long)]
    quick: bool,
    #[arg(long)]
    json: bool,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum UpdateArg {
    Rebuild,
    Refit,
}

pub fn run(args: SoakArgs, validate: bool) -> CliResult<()> {
    let start = Instant::now();
    let q = args.quick;
    let frames = args.frames.unwrap_or(if q { 100 } else { 2_000 });
    let builds = args.builds.unwrap_or(if q { 40 } else { 200 });
    let render = RenderOptions {
        width: Some(args.width),
        height: Some(args.height),
        spp: Some(1),
        flatten: args.flatten,
        ..Default::default()
    };
    check_resolution(&render)?;
    let scene = animated(load_scene(&Some(args.scene.clone()))?, None)?;
    let ctx = context(validate)?;
    let frame_opt = FrameSoakOptions {
        frames,
        check_every: args.check_every.unwrap_or(if q { 25 } else { 200 }),
        render,
        update: match args.update {
            UpdateArg::Rebuild => Update::Rebuild,
            UpdateArg::Refit => Update::Refit,
        },
    };
    let tick = |what: &'static str, n: u32| {
        move |k: u32| {
            if k % (n / 10).max(1) == 0 {
                log::info!("{what}: {k} of {n}");
            }
        }
    };
    let f = soak::soak_frames(&ctx, &scene, &frame_opt, tick("frames", frames))
        .map_err(|e| e.to_string())?;
    let build_opt = BuildSoakOptions {
        builds,
        seed: args.seed,
        max_primitives: args
            .max_primitives
            .unwrap_or(if q { 4_000 } else { 20_000 }),
        rays: args.rays.unwrap_or(if q { 1_024 } else { 4_096 }),
    };
    let b =
        soak::soak_builds(&ctx, &build_opt, tick("builds", builds)).map_err(|e| e.to_string())?;
    let wall_s = start.elapsed().as_secs_f64();
    // The validation layer's own tracking grows host memory by tens of KB a frame: under
    // it, RSS growth is reported, not judged.
    let rss_judged = !ctx.validation_enabled();
    let mut failures = failures(&f, &b, rss_judged);
    let messages = ctx.take_validation_messages().len();
    if messages > 0 {
        failures.push(format!("{messages} validation messages"));
    }
    if args.json {
        let v = serde_json::json!({
            "device": ctx.info().device,
            "frames": f,
            "builds": b,
            "mismatches": f.mismatches + b.mismatches + b.exhausted + b.invalid,
            "max_growth": soak::MAX_GROWTH,
            "host_rss_judged": rss_judged,
            "validation_messages": messages,
            "wall_s": wall_s,
            "passed": failures.is_empty(),
            "failures": failures,
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        print_report(ctx.info().device.as_str(), &f, &b, wall_s);
        if !rss_judged {
            println!("host RSS not judged under the validation layer (its own tracking grows)");
        }
    }
    match failures.is_empty() {
        true => Ok(()),
        false => Err(format!("soak failed: {}", failures.join("; ")).into()),
    }
}

/// What went wrong, one line each.
fn failures(f: &FrameSoak, b: &BuildSoak, rss: bool) -> Vec<String> {
    let mut out = Vec::new();
    if f.non_finite_frames > 0 {
        out.push(format!(
            "{} frames with non-finite radiance",
            f.non_finite_frames
        ));
    }
    for c in f.checks.iter().filter(|c| !c.ok()) {
        out.push(match c.fresh_equal {
            false => format!("frame {} differs from a fresh render", c.frame),
            true => format!(
                "frame {}: {} of {} channels off the CPU twin",
                c.frame,
                c.twin_off.unwrap_or(0),
                c.channels
            ),
        });
    }
    if b.mismatches + b.exhausted + b.invalid > 0 {
        out.push(format!(
            "builds: {} answers unlike brute force, {} rays out of steps, {} invalid structures",
            b.mismatches, b.exhausted, b.invalid
        ));
    }
    for (what, g) in [("frames", &f.memory), ("builds", &b.memory)] {
        if g.grew(rss) {
            out.push(format!("{what}: memory grew ({})", growth_line(g)));
        }
    }
    out
}

fn growth_line(g: &Growth) -> String {
    let mib = |x: u64| x as f64 / (1 << 20) as f64;
    let rss = match (
        g.warm.host_rss_bytes,
        g.end.host_rss_bytes,
        g.host_rss_growth,
    ) {
        (Some(a), Some(b), Some(r)) => {
            format!(
                "host RSS {:.1} → {:.1} MiB ({:+.2} %)",
                mib(a),
                mib(b),
                r * 100.0
            )
        }
        _ => "host RSS not reported by this OS".into(),
    };
    format!(
        "device {:.2} → {:.2} MiB ({:+.2} %), {rss}",
        mib(g.warm.device_bytes),
        mib(g.end.device_bytes),
        g.device_growth * 100.0
    )
}

fn print_report(device: &str, f: &FrameSoak, b: &BuildSoak, wall_s: f64) {
    println!("{device}");
    println!(
        "frames: {} ({}×{}, {} spp, {} {}, {} level{}), {:.1} ms each; {} non-finite; \
         {} checked against a fresh render{}: {} failed",
        f.frames,
        f.width,
        f.height,
        f.spp,
        f.accel,
        f.update.name(),
        f.levels,
        if f.levels == 1 { "" } else { "s" },
        f.mean_frame_ms,
        f.non_finite_frames,
        f.checks.len(),
        if f.levels == 1 {
            " and the CPU twin"
        } else {
            ""
        },
        f.checks.iter().filter(|c| !c.ok()).count()
    );
    println!(
        "  memory after frame {} to the end: {}",
        f.memory.warm_up,
        growth_line(&f.memory)
    );
    println!(
        "builds: {} (seed {}, {} primitives, {} rays checked against brute force): \
         {} mismatches ({} on the driver's, not watertight), {} out of steps, {} invalid",
        b.builds,
        b.seed,
        b.primitives,
        b.rays,
        b.mismatches,
        b.driver_mismatches,
        b.exhausted,
        b.invalid
    );
    println!(
        "  memory after build {} to the end: {}",
        b.memory.warm_up,
        growth_line(&b.memory)
    );
    for c in &b.failed {
        println!(
            "  build {}: {} of {} primitives on {}: {:?}",
            c.build, c.kind, c.primitives, c.accel, c.result
        );
    }
    println!("wall {wall_s:.1} s");
}
