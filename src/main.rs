//! The `vkrt` command line: a thin layer over the library.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand, ValueEnum};

mod cli;
use vkrt::gpu::{Context, ContextOptions, Profile, Validation};

#[derive(Parser)]
#[command(
    name = "vkrt",
    version,
    about = "Vulkan-native ray tracing: GPU-built acceleration structures you can read, embed and profile"
)]
struct Cli {
    /// Enable the Khronos validation layer with synchronization validation (also VKRT_VALIDATION=1).
    #[arg(long, global = true)]
    validate: bool,
    /// More log output on stderr: -v info, -vv debug, -vvv trace (default: warnings).
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
    /// Errors only on stderr (no warnings).
    #[arg(short, long, global = true, conflicts_with = "verbose")]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print the Vulkan device vkrt uses and what it can do.
    Info {
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Check that vkrt computes correctly on this device: every GPU primitive and builder
    /// against its CPU twin, every walk against brute force, the hard cases on every
    /// structure. Exits non-zero when a check fails; the first thing to run on a new GPU.
    Verify {
        /// Print JSON: {"device", "driver", "checks", "failed", "groups": {...}}.
        #[arg(long)]
        json: bool,
        /// Fewer sizes and rays (about a third of the time).
        #[arg(long)]
        quick: bool,
        /// The device whose name contains this (default: as `vkrt info`, or VKRT_DEVICE).
        #[arg(long)]
        device: Option<String>,
    },
    /// Summarise a scene file (.toml, .obj, .scn text): counts, bounds, the effects it calls for.
    Scene {
        /// The scene; omit for the embedded default scene (a Cornell box).
        file: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
    /// Build an acceleration structure and report its time and quality.
    Build {
        /// Scene (.toml, .obj, .scn text); omit for the embedded default scene.
        scene: Option<PathBuf>,
        /// The structure to build: sah-bvh (the SAH BVH, on the CPU's threads; the
        /// default, by measurement: docs/performance.md) or kdtree (the SAH kd-tree after Wu, Zhao & Liu 2011, on
        /// the GPU) or lbvh (LBVH, Karras 2012, on the GPU) or ploc (PLOC, on the GPU) or
        /// driver / driver-fast-build (the driver's own, where it has ray query).
        #[arg(long, default_value = "sah-bvh")]
        accel: String,
        /// kd-tree: also build the CPU twin (must be equal) and the full-clipping CPU
        /// reference; BVH: also build on one thread (must be equal).
        #[arg(long)]
        reference: bool,
        /// Kolodzey's (2014) termination: no SAH leaf test, leaves below 64 primitives.
        #[arg(long)]
        kolodzey_termination: bool,
        #[arg(long)]
        json: bool,
        /// Write a Chrome-trace JSON of every GPU pass (open in ui.perfetto.dev).
        #[arg(long)]
        profile: Option<PathBuf>,
    },
    /// Render a scene to an image (.png, .jpg, .exr or .pfm) with the wavefront renderer.
    Render {
        /// Scene (.toml, .obj, .scn text); omit for the embedded default scene.
        scene: Option<PathBuf>,
        /// Output image, by extension: .png or .jpg/.jpeg (8-bit sRGB), .exr or .pfm (linear
        /// float radiance).
        #[arg(short, long, default_value = "render.png")]
        output: PathBuf,
        /// Samples per pixel (default: the scene's; 1 if no effect of the scene needs more).
        #[arg(long)]
        spp: Option<u32>,
        #[arg(long)]
        width: Option<u32>,
        #[arg(long)]
        height: Option<u32>,
        /// Render frame K of an animated scene (its time K / fps), as `vkrt animate` does.
        #[arg(long)]
        frame: Option<u32>,
        /// Print the render plan (passes, shader variants) and stop.
        #[arg(long)]
        plan: bool,
        /// Force every pass and shader branch on (the image must not change).
        #[arg(long)]
        all_effects: bool,
        /// Ray/triangle test: watertight (default) or moller-trumbore.
        #[arg(long, default_value = "watertight")]
        intersector: String,
        /// The acceleration structure: the SAH BVH built on the CPU's threads (the
        /// default, by measurement: it builds 25-30x and traces 1.3-1.8x faster here), or
        /// the SAH kd-tree built on the GPU. The image is the same.
        #[arg(long, value_enum, default_value_t = AccelArg::SahBvh)]
        accel: AccelArg,
        /// How a BVH is walked: a stack, the stackless bitstack walk with parent links, or
        /// a stack over 4-wide quantized nodes made after the build.
        #[arg(long, value_enum, default_value_t = TraversalArg::Stack)]
        traversal: TraversalArg,
        /// Trace one structure over every primitive even where meshes repeat (by default a
        /// mesh named more than once becomes one bottom-level structure with an instance
        /// per copy, under a top level; the image is the same).
        #[arg(long)]
        flatten: bool,
        #[arg(long)]
        json: bool,
        /// Write a Chrome-trace JSON of every GPU pass (open in ui.perfetto.dev).
        #[arg(long)]
        profile: Option<PathBuf>,
    },
    /// Trace a batch of rays against a scene on the GPU (the structure built and traced in
    /// one submission) and write the hits.
    ///
    /// Rays: `.rays` (little-endian, 8 f32 per ray: ox oy oz tmin dx dy dz tmax) or `.csv`
    /// (`ox,oy,oz,dx,dy,dz[,tmin,tmax]`). Hits: binary, 16 bytes per ray (t f32, prim u32,
    /// u f32, v f32; t = inf and prim = 4294967295 for a miss), or `.csv` by extension.
    /// Rays with NaN/Inf components are misses. Moving geometry is placed at the camera's
    /// shutter-open time.
    Trace {
        /// Scene (.toml, .obj, .scn text).
        scene: PathBuf,
        /// The ray file (.rays or .csv).
        #[arg(long)]
        rays: PathBuf,
        /// Where to write the hits (.csv for text, anything else binary); written atomically.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Any-hit (shadow / visibility) queries instead of closest hit.
        #[arg(long)]
        any_hit: bool,
        /// The ray/triangle test.
        #[arg(long, value_enum, default_value_t = IntersectorArg::Watertight)]
        intersector: IntersectorArg,
        /// Rays per GPU batch (default and maximum: what fits the device's buffer limit).
        #[arg(long, hide = true)]
        batch_rays: Option<usize>,
        /// The acceleration structure: the SAH BVH built on the CPU's threads (the
        /// default, by measurement), or the SAH kd-tree built on the GPU. The hits are the
        /// same.
        #[arg(long, value_enum, default_value_t = AccelArg::SahBvh)]
        accel: AccelArg,
        /// How a BVH is walked: a stack, the stackless bitstack walk with parent links, or
        /// a stack over 4-wide quantized nodes made after the build.
        #[arg(long, value_enum, default_value_t = TraversalArg::Stack)]
        traversal: TraversalArg,
        /// Trace one structure over every triangle even where meshes repeat (by default a
        /// mesh named more than once becomes one bottom-level structure with an instance
        /// per copy, under a top level).
        #[arg(long)]
        flatten: bool,
        #[arg(long)]
        json: bool,
    },
    /// Render the frames of an animated scene (its `[animation]`): per frame the moved
    /// primitives are written on the device, the structure rebuilt or refit, and the frame
    /// rendered, all in one submission; frames are written while the next renders.
    Animate {
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
        #[arg(long, value_enum, default_value_t = AccelArg::SahBvh)]
        accel: AccelArg,
        #[arg(long, value_enum, default_value_t = TraversalArg::Stack)]
        traversal: TraversalArg,
        /// Per frame: build the structure anew, or refit it (BVHs and the driver's). Over
        /// two levels only the top level is rebuilt or refit: rigid motions move instances.
        #[arg(long, value_enum, default_value_t = UpdateArg::Rebuild)]
        update: UpdateArg,
        /// Trace one structure over every primitive even where meshes repeat (by default a
        /// mesh named more than once, and a moving mesh beside it, get instances under a top
        /// level; the frames are the same).
        #[arg(long)]
        flatten: bool,
        /// Also an animated PNG of every frame, for a quick look.
        #[arg(long)]
        preview: Option<PathBuf>,
        /// One JSON object: the frames' numbers and the means.
        #[arg(long)]
        json: bool,
        /// Write a Chrome-trace JSON of every GPU pass (open in ui.perfetto.dev).
        #[arg(long)]
        profile: Option<PathBuf>,
    },
    /// Measure GPU baselines and primitives.
    Bench {
        #[command(subcommand)]
        what: BenchCommand,
    },
}

#[derive(Subcommand)]
enum BenchCommand {
    /// vkCmdCopyBuffer vs the plain copy kernels, on the same bytes.
    Copy {
        /// MiB to copy.
        #[arg(long, default_value_t = 64)]
        mib: u64,
        /// Timed repetitions (the best is reported).
        #[arg(long, default_value_t = 5)]
        reps: u32,
        #[arg(long)]
        json: bool,
        /// Write a Chrome-trace JSON of every GPU pass (open in ui.perfetto.dev).
        #[arg(long)]
        profile: Option<PathBuf>,
    },
    /// Sochora's (2013) Tables 3/4 on this machine: CPU SAH BVH build time of every threading
    /// scheme (single, uneven, even, node queue, rayon) at 1 and all threads, full sweep and
    /// binned (16 bins), over the bunny and icospheres up to --max-n; the speed-up over one
    /// thread, the SAH cost, and the same tree from every scheme asserted.
    Bvh {
        /// Largest icosphere (triangles).
        #[arg(long, default_value_t = 1_000_000)]
        max_n: u64,
        /// Timed repetitions (the best is reported).
        #[arg(long, default_value_t = 3)]
        reps: u32,
        /// Mesh to include (default: ../shared/scenes/stanford-bunny.obj when present).
        #[arg(long)]
        mesh: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
    /// GPU kd-tree build time against N (the bunny when ../shared is present, icospheres of
    /// 100 K, 200 K, 500 K, 1 M, 2 M triangles up to --max-n), per phase, the fitted growth
    /// exponent, and with --ablation the GPU kd-tree thesis's Table 6.2: each optimisation switched back to
    /// its baseline, same tree asserted, time ratio to the default in the same run.
    Kdtree {
        /// Largest icosphere (triangles).
        #[arg(long, default_value_t = 500_000)]
        max_n: u64,
        /// Also build each scene of at most --ablation-max-n triangles with each variant.
        #[arg(long)]
        ablation: bool,
        #[arg(long, default_value_t = 100_000)]
        ablation_max_n: u64,
        /// Timed builds per variant, interleaved round-robin over the variants; the fastest
        /// of each is reported (the machine may be shared).
        #[arg(long, default_value_t = 1)]
        reps: u32,
        /// Kolodzey's (2014) termination: leaves below 64 primitives, no SAH leaf test (much smaller
        /// trees than the default leaves of at most 2 primitives).
        #[arg(long)]
        kolodzey_termination: bool,
        /// Mesh to include (default: ../shared/scenes/stanford-bunny.obj when present).
        #[arg(long)]
        mesh: Option<PathBuf>,
        #[arg(long)]
        json: bool,
        /// Write a Chrome-trace JSON of every GPU pass (open in ui.perfetto.dev).
        #[arg(long)]
        profile: Option<PathBuf>,
    },
    /// What each effect costs and what the plan saves: every example scene (scenes/EFFECT.toml)
    /// as planned, without its effect, and with --all-effects, measured in one run.
    Render {
        /// Folder of the example scenes.
        #[arg(long, default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes"))]
        scenes: PathBuf,
        #[arg(long, default_value_t = 256)]
        width: u32,
        #[arg(long, default_value_t = 192)]
        height: u32,
        /// The structure the renders trace (built on the device, as `vkrt render` does).
        #[arg(long, value_enum, default_value_t = AccelArg::SahBvh)]
        accel: AccelArg,
        /// How a BVH is walked.
        #[arg(long, value_enum, default_value_t = TraversalArg::Stack)]
        traversal: TraversalArg,
        #[arg(long)]
        json: bool,
    },
    /// The robustness suite (watertightness, self-intersection, parallel/in-plane rays,
    /// degenerate geometry, builder stress, bad rays) for both ray/triangle tests on every
    /// structure, and on the driver's own where the device has it: rays, failures and GPU
    /// trace time per case.
    Robustness {
        /// The integration test's smaller sizes (a 100K soup instead of 2M, fewer rays).
        #[arg(long)]
        quick: bool,
        #[arg(long)]
        json: bool,
    },
    /// Ray throughput of every structure and walk (each --accel and --traversal), the
    /// driver's ray query where the device has it and obvhs on one CPU thread, on the same
    /// rays in one run: the bunny (or --mesh), the example scenes and an icosphere of --max-n
    /// triangles; primary, shadow and mirror rays; build ms, trace ms, Mrays/s, hits (any
    /// difference reported) and the ratio to the driver's ray query.
    Trace(BenchTraceArgs),
    /// What accuracy costs in time: every knob (structure and builder parameters, kd-tree
    /// termination, BVH leaf size, traversal, ray/triangle test, samples per pixel, ray depth,
    /// refit vs rebuild) measured in one run against a reference — build and trace ms, SAH
    /// cost, bytes, failures on the robustness suite's hard cases, image RMSE — with each
    /// group's Pareto front and a recommendation per use. Writes OUT/index.html (inline SVG
    /// plots), OUT/report.json and the compared images.
    Accuracy {
        /// Smaller everything (~3 minutes on 2 cores of lavapipe; the CI's check).
        #[arg(long)]
        quick: bool,
        /// Print the report as JSON too.
        #[arg(long)]
        json: bool,
        #[arg(short, long, default_value = "accuracy-report")]
        out: PathBuf,
        /// Mesh whose rays time the structures (default: ../shared/scenes/stanford-bunny.obj
        /// when present, else an icosphere of as many triangles).
        #[arg(long)]
        mesh: Option<PathBuf>,
        /// Folder of the effect scenes.
        #[arg(long, default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes"))]
        scenes: PathBuf,
    },
    /// An animated scene's frames on every structure and update mode in one run (kd-tree,
    /// SAH BVH, LBVH and PLOC rebuilt; the BVHs refit; the driver's both ways where the device
    /// has it): build or refit ms, render ms, frames/s per frame; the refit trees' SAH cost
    /// against a rebuild's; after how many refit frames a rebuild pays off. Writes
    /// OUT/frames.svg (the per-frame plot) and OUT/report.json.
    Animate {
        /// The animated scene (default: scenes/dynamic_demo.toml).
        #[arg(default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/dynamic_demo.toml"))]
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
        #[arg(short, long, default_value = "animate-report")]
        out: PathBuf,
        #[arg(long)]
        json: bool,
    },
    /// Every GPU primitive against the copy baselines of the same bytes, n = 2^16 .. max-n.
    Prims {
        /// Largest n (rounded down to a power of two).
        #[arg(long, default_value_t = 1 << 24)]
        max_n: usize,
        /// Smallest n.
        #[arg(long, default_value_t = 1 << 16)]
        min_n: usize,
        /// Multiply n by 2^step between sizes.
        #[arg(long, default_value_t = 2)]
        step: u32,
        /// Timed repetitions (the best is reported).
        #[arg(long, default_value_t = 3)]
        reps: u32,
        /// Only the primitives whose group name contains this (scan, compact, reduce, ...).
        #[arg(long)]
        only: Option<String>,
        #[arg(long)]
        json: bool,
        /// Write a Chrome-trace JSON of every GPU pass (open in ui.perfetto.dev).
        #[arg(long)]
        profile: Option<PathBuf>,
    },
}

#[derive(Args)]
struct BenchTraceArgs {
    /// Camera image width in pixels, one primary ray per pixel (default 512; 64 with --quick).
    #[arg(long)]
    size: Option<u32>,
    /// Repetitions of each build and trace, the best reported (default 3; 1 with --quick).
    #[arg(long)]
    reps: Option<u32>,
    /// Triangles of the icosphere (default 500000; 10000 with --quick).
    #[arg(long)]
    max_n: Option<u64>,
    /// Mesh to include (default: ../shared/scenes/stanford-bunny.obj when present, except
    /// with --quick).
    #[arg(long)]
    mesh: Option<PathBuf>,
    /// Folder of the example scenes (every .toml in it).
    #[arg(long, default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes"))]
    scenes: PathBuf,
    /// The integration test's run: 64-pixel-wide images, the example scenes and a 10 K
    /// icosphere, one repetition.
    #[arg(long)]
    quick: bool,
    #[arg(long)]
    json: bool,
}

#[derive(Clone, Copy, PartialEq, ValueEnum)]
enum AccelArg {
    Kdtree,
    SahBvh,
    Lbvh,
    Ploc,
    /// The driver's own structure (VK_KHR_acceleration_structure, built preferring fast
    /// trace) through its ray query (VK_KHR_ray_query), where the device has them.
    Driver,
    /// The driver's structure built preferring a fast build.
    DriverFastBuild,
}

#[derive(Clone, Copy, ValueEnum)]
enum UpdateArg {
    Rebuild,
    Refit,
}

#[derive(Clone, Copy, ValueEnum)]
enum TraversalArg {
    /// Binary nodes, far children on a stack.
    Stack,
    /// Binary nodes, no stack: parent links and one bit per level.
    Bitstack,
    /// 4-wide quantized nodes (Ylitie et al. 2017) with a stack.
    Wide,
}

fn accel_traversal(accel: AccelArg, walk: TraversalArg) -> vkrt::accel::device::AccelChoice {
    use vkrt::accel::device::{AccelChoice, AccelKind};
    use vkrt::accel::driver::Prefer;
    use vkrt::trace::bvh_cpu::Traversal;
    let kind = match accel {
        AccelArg::Kdtree => AccelKind::KdTree,
        AccelArg::SahBvh => AccelKind::SahBvh,
        AccelArg::Lbvh => AccelKind::Lbvh,
        AccelArg::Ploc => AccelKind::Ploc,
        AccelArg::Driver => return AccelChoice::driver(Prefer::FastTrace),
        AccelArg::DriverFastBuild => return AccelChoice::driver(Prefer::FastBuild),
    };
    let walk = match walk {
        TraversalArg::Stack => Traversal::Stack,
        TraversalArg::Bitstack => Traversal::Bitstack,
        TraversalArg::Wide => Traversal::Wide,
    };
    AccelChoice::new(kind, walk)
}

#[derive(Clone, Copy, ValueEnum)]
enum IntersectorArg {
    /// Woop, Benthin & Wald 2013 (no ray slips between triangles sharing an edge).
    Watertight,
    /// Möller–Trumbore 1997 (faster, not watertight).
    MollerTrumbore,
}

impl From<IntersectorArg> for vkrt::trace::Intersector {
    fn from(a: IntersectorArg) -> Self {
        match a {
            IntersectorArg::Watertight => Self::Watertight,
            IntersectorArg::MollerTrumbore => Self::MollerTrumbore,
        }
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    init_logging(cli.verbose, cli.quiet);
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("vkrt: error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// Logs go to stderr (stdout stays for results and --json) as `vkrt: LEVEL: message`, the
/// style of the error line at exit; debug and trace also name the module.
fn init_logging(verbose: u8, quiet: bool) {
    use log::{Level, LevelFilter};
    use std::io::Write;
    let level = match (quiet, verbose) {
        (true, _) => LevelFilter::Error,
        (false, 0) => LevelFilter::Warn,
        (false, 1) => LevelFilter::Info,
        (false, 2) => LevelFilter::Debug,
        _ => LevelFilter::Trace,
    };
    env_logger::Builder::new()
        .filter_level(level)
        .target(env_logger::Target::Stderr)
        .format(|buf, record| match record.level() {
            Level::Error => writeln!(buf, "vkrt: error: {}", record.args()),
            Level::Warn => writeln!(buf, "vkrt: warning: {}", record.args()),
            Level::Info => writeln!(buf, "vkrt: info: {}", record.args()),
            l => writeln!(
                buf,
                "vkrt: {}: [{}] {}",
                l.as_str().to_ascii_lowercase(),
                record.target(),
                record.args()
            ),
        })
        .init();
}

fn context(validate: bool) -> Result<Context, Box<dyn std::error::Error>> {
    let env_on = std::env::var("VKRT_VALIDATION").is_ok_and(|v| v.trim() == "1");
    let validation = if validate || env_on {
        Validation::On
    } else {
        Validation::Off
    };
    let ctx = Context::new(&ContextOptions {
        validation,
        device_name: None,
    })?;
    let info = ctx.info();
    log::info!("device {}, driver {}", info.device, info.driver);
    Ok(ctx)
}

fn load_scene(path: &Option<PathBuf>) -> Result<vkrt::scene::Scene, Box<dyn std::error::Error>> {
    Ok(match path {
        Some(path) => {
            let loaded = vkrt::scene::Scene::load(path)?;
            for w in &loaded.warnings {
                log::warn!("{w}");
            }
            loaded.scene
        }
        None => vkrt::scene::Scene::default_scene(),
    })
}

/// `--width`, `--height` and `--spp` within the scene limits.
fn check_resolution(opt: &vkrt::render::RenderOptions) -> Result<(), Box<dyn std::error::Error>> {
    use vkrt::scene::MAX_RESOLUTION;
    for (name, v) in [("--width", opt.width), ("--height", opt.height)] {
        if v.is_some_and(|v| v == 0 || v > MAX_RESOLUTION) {
            return Err(format!("{name} must be 1..={MAX_RESOLUTION}").into());
        }
    }
    if opt.spp.is_some_and(|s| s == 0 || s > vkrt::scene::MAX_SPP) {
        return Err(format!("--spp must be 1..={}", vkrt::scene::MAX_SPP).into());
    }
    Ok(())
}

fn write_profile(
    path: &Option<PathBuf>,
    profile: &Profile,
) -> Result<(), Box<dyn std::error::Error>> {
    if let Some(path) = path {
        profile.write_chrome_trace(path)?;
        eprintln!(
            "vkrt: wrote GPU trace {} (open in ui.perfetto.dev)",
            path.display()
        );
    }
    Ok(())
}

fn parse_intersector(name: &str) -> Result<vkrt::trace::Intersector, Box<dyn std::error::Error>> {
    match name {
        "watertight" => Ok(vkrt::trace::Intersector::Watertight),
        "moller-trumbore" | "moller_trumbore" | "moller" => {
            Ok(vkrt::trace::Intersector::MollerTrumbore)
        }
        _ => Err(format!(
            "unknown --intersector `{name}` (available: watertight, moller-trumbore)"
        )
        .into()),
    }
}

#[allow(clippy::too_many_arguments, reason = "one parameter per CLI flag")]
fn render_command(
    validate: bool,
    scene: &Option<PathBuf>,
    output: &std::path::Path,
    opt: vkrt::render::RenderOptions,
    (frame, plan_only): (Option<u32>, bool),
    intersector: &str,
    json: bool,
    profile: &Option<PathBuf>,
) -> Result<(), Box<dyn std::error::Error>> {
    // An unsupported image extension fails here, before the scene or the device is touched.
    vkrt::render::output::ImageFormat::from_path(output)?;
    let intersector = parse_intersector(intersector)?;
    check_resolution(&opt)?;
    let mut scene = load_scene(scene)?;
    if let Some(k) = frame {
        let frames = scene.animation.map_or(0, |a| a.frames);
        if k >= frames {
            return Err(match frames {
                0 => "--frame: the scene has no [animation]".to_string(),
                n => format!("--frame {k}: the scene has frames 0..{n}"),
            }
            .into());
        }
        scene = scene.at_frame(k);
    }
    if plan_only {
        let plan = vkrt::render::Plan::new(&scene, &opt)?;
        if json {
            println!("{}", serde_json::to_string_pretty(&plan)?);
        } else {
            print!("{plan}");
        }
        return Ok(());
    }
    // Fail before rendering if the image cannot be written there.
    let dir = output
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(std::path::Path::new("."));
    if !dir.is_dir() {
        return Err(format!("{}: no such directory for the output image", dir.display()).into());
    }
    let ctx = context(validate)?;
    let trace = vkrt::trace::TraceOptions {
        intersector,
        ..Default::default()
    };
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} samples {pos}/{len} [{bar:30}] {elapsed_precise} (eta {eta})",
        )
        .map_err(|e| e.to_string())?,
    );
    let (rendered, trace_profile) = vkrt::gpu::capture_profiles(|| {
        vkrt::render::render_scene(&ctx, &scene, &opt, &trace, |done, spp| {
            if spp > 1 {
                bar.set_length(spp as u64);
                bar.set_position(done as u64);
            }
        })
    });
    bar.finish_and_clear();
    let r = rendered.map_err(|e| e.to_string())?;
    let p = &r.plan;
    vkrt::render::output::write_image(output, p.width, p.height, &r.image.rgba, &r.image.radiance)?;
    write_profile(profile, &trace_profile)?;
    if r.image.counts.exhausted > 0 {
        log::warn!(
            "{} rays ran out of traversal steps (counted as misses)",
            r.image.counts.exhausted
        );
    }
    if json {
        let v = serde_json::json!({
            "width": p.width,
            "height": p.height,
            "spp": p.spp,
            "accel": p.accel.label(),
            "levels": p.levels,
            "build_ms": r.build_ms,
            "render_ms": r.render_ms,
            "build_attempts": r.image.build_attempts,
            "submits": r.image.traffic.submits,
            "readback_bytes": r.image.readback_before_trace,
            "readback_bytes_total": r.image.traffic.readback_bytes,
            "passes": r.passes,
            "effects": p.effects,
            "mrays_per_s": r.mrays_per_s(),
            "rays": r.image.counts,
            "output": output.display().to_string(),
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!(
            "{}: {}x{}, {} spp, effects: {}",
            output.display(),
            p.width,
            p.height,
            p.spp,
            if p.effects.is_empty() {
                "none".into()
            } else {
                p.effects.join(", ")
            }
        );
        println!(
            "{} build {:.1} ms, render {:.1} ms, {:.2} Mrays/s",
            p.accel.label(),
            r.build_ms,
            r.render_ms,
            r.mrays_per_s()
        );
        for pass in &r.passes {
            println!(
                "  {:<11} {:>12} rays {:>10.1} ms",
                pass.name, pass.rays, pass.ms
            );
        }
    }
    Ok(())
}

fn run(cli: Cli) -> Result<(), Box<dyn std::error::Error>> {
    match cli.command {
        Command::Render {
            scene,
            output,
            spp,
            width,
            height,
            frame,
            plan,
            all_effects,
            intersector,
            accel,
            traversal,
            flatten,
            json,
            profile,
        } => {
            let opt = vkrt::render::RenderOptions {
                width,
                height,
                spp,
                all_effects,
                accel: accel_traversal(accel, traversal),
                flatten,
            };
            render_command(
                cli.validate,
                &scene,
                &output,
                opt,
                (frame, plan),
                &intersector,
                json,
                &profile,
            )?;
        }
        Command::Verify {
            json,
            quick,
            device,
        } => cli::verify::verify_command(cli.validate, device, quick, json)?,
        Command::Info { json } => {
            let ctx = context(cli.validate)?;
            let info = ctx.info();
            if json {
                println!("{}", serde_json::to_string_pretty(info)?);
            } else {
                println!("device              {} ({})", info.device, info.device_type);
                println!("driver              {}", info.driver);
                println!("vulkan              {}", info.api_version);
                println!(
                    "subgroup size       {} (min {}, max {})",
                    info.subgroup_size, info.min_subgroup_size, info.max_subgroup_size
                );
                println!("subgroup ops        {}", info.subgroup_ops.join(" "));
                println!(
                    "max storage buffer  {} bytes",
                    info.max_storage_buffer_range
                );
                println!("max shared memory   {} bytes", info.max_shared_memory);
                println!(
                    "workgroups          {} invocations, size {:?}, count {:?}",
                    info.max_workgroup_invocations,
                    info.max_workgroup_size,
                    info.max_workgroup_count
                );
                println!(
                    "timestamps          {} (period {} ns)",
                    if info.timestamps { "yes" } else { "no" },
                    info.timestamp_period_ns
                );
                println!(
                    "f32 division        {}",
                    if info.ieee_division {
                        "correctly rounded"
                    } else {
                        "within Vulkan's 2.5 ulp: the exact walks round it correctly"
                    }
                );
                match info.loop_budget {
                    Some(b) => println!("loop budget         {b} iterations per invocation"),
                    None => println!("loop budget         none (loops run to their end)"),
                }
                println!(
                    "walk step cap       {} node visits + primitive tests per ray",
                    info.max_traversal_steps
                );
                println!(
                    "walks read          {} buffers (texel views up to {} texels)",
                    vkrt::trace::gpu::NodeAccess::for_device(&ctx).name(),
                    info.max_texel_buffer_elements
                );
            }
        }
        Command::Bench {
            what:
                BenchCommand::Render {
                    scenes,
                    width,
                    height,
                    accel,
                    traversal,
                    json,
                },
        } => {
            let mut list = Vec::new();
            for effect in vkrt::scene::Effects::ALL_NAMES {
                let path = scenes.join(format!("{effect}.toml"));
                if path.exists() {
                    let scene = vkrt::scene::Scene::load(&path)?.scene;
                    list.push((format!("{effect}.toml"), scene, effect.to_string()));
                }
            }
            if list.is_empty() {
                return Err(
                    format!("no effect scenes (EFFECT.toml) in {}", scenes.display()).into(),
                );
            }
            let ctx = context(cli.validate)?;
            let accel = accel_traversal(accel, traversal);
            let rows = vkrt::render::bench::effect_costs(&ctx, &list, (width, height), accel)
                .map_err(|e| e.to_string())?;
            if json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&serde_json::json!({ "results": rows }))?
                );
            } else {
                println!(
                    "{:<24} {:>4} {:>10} {:>10} {:>10} {:>8} {:>9} {:>8}",
                    "scene", "spp", "plan ms", "w/o ms", "all ms", "Mrays/s", "cost", "saves"
                );
                for r in &rows {
                    println!(
                        "{:<24} {:>4} {:>10.1} {:>10.1} {:>10.1} {:>8.2} {:>8.2}x {:>7.2}x",
                        r.scene,
                        r.spp,
                        r.plan_ms,
                        r.without_ms,
                        r.all_effects_ms,
                        r.mrays_per_s,
                        r.effect_cost,
                        r.planning_saves
                    );
                }
                println!("cost = plan / without the effect (same spp); saves = all-effects / plan");
            }
        }
        Command::Bench {
            what:
                BenchCommand::Copy {
                    mib,
                    reps,
                    json,
                    profile,
                },
        } => {
            let ctx = context(cli.validate)?;
            let (baselines, trace) = vkrt::bench::copy_baselines(&ctx, mib << 20, reps.max(1))?;
            write_profile(&profile, &trace)?;
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
        }
        Command::Bench {
            what:
                BenchCommand::Prims {
                    max_n,
                    min_n,
                    step,
                    reps,
                    only,
                    json,
                    profile,
                },
        } => {
            let ctx = context(cli.validate)?;
            let mut sizes = Vec::new();
            let mut n = min_n.max(1);
            while n <= max_n {
                sizes.push(n);
                n <<= step.max(1);
            }
            let (report, trace) = vkrt::gpu::capture_profiles(|| {
                vkrt::bench::prims_report(&ctx, &sizes, reps.max(1), only.as_deref())
            });
            let report = report?;
            write_profile(&profile, &trace)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&report)?);
            } else {
                println!("{} (subgroup {})", report.device, report.subgroup_size);
                println!(
                    "{:<34} {:>10} {:>10} {:>10} {:>9} {:>13}",
                    "prim", "n", "gpu ms", "Melem/s", "/copy", "/copy kernel"
                );
                for r in &report.results {
                    println!(
                        "{:<34} {:>10} {:>10.3} {:>10.1} {:>9.3} {:>13.3}",
                        r.prim,
                        r.n,
                        r.gpu_ms,
                        r.elements_per_s / 1e6,
                        r.ratio_to_copy,
                        r.ratio_to_copy_kernel
                    );
                }
            }
        }
        Command::Scene { file, json } => {
            let (scene, warnings) = match &file {
                Some(path) => {
                    let loaded = vkrt::scene::Scene::load(path)?;
                    (loaded.scene, loaded.warnings)
                }
                None => (vkrt::scene::Scene::default_scene(), Vec::new()),
            };
            for w in &warnings {
                log::warn!("{w}");
            }
            let summary = scene.summary();
            if json {
                println!("{}", serde_json::to_string_pretty(&summary)?);
            } else {
                println!("{}", summary.to_string().trim_end());
            }
        }
        Command::Build {
            scene,
            accel,
            reference,
            kolodzey_termination,
            json,
            profile,
        } => {
            if accel == "sah-bvh" {
                if kolodzey_termination {
                    return Err(
                        "--kolodzey-termination is the GPU kd-tree thesis's termination rule: add \
                                --accel kdtree"
                            .into(),
                    );
                }
                return bvh_build_command(&load_scene(&scene)?, reference, json);
            }
            let driver = match accel.as_str() {
                "driver" => Some(vkrt::accel::driver::Prefer::FastTrace),
                "driver-fast-build" => Some(vkrt::accel::driver::Prefer::FastBuild),
                _ => None,
            };
            if let Some(prefer) = driver {
                if kolodzey_termination || reference {
                    return Err(
                        "--kolodzey-termination and --reference do not apply to the \
                                driver's structure (it is opaque)"
                            .into(),
                    );
                }
                let ctx = context(cli.validate)?;
                let scene = load_scene(&scene)?;
                return driver_build_command(&ctx, prefer, &scene, json, &profile);
            }
            let gpu_bvh = match accel.as_str() {
                "lbvh" => Some(vkrt::accel::device::AccelKind::Lbvh),
                "ploc" => Some(vkrt::accel::device::AccelKind::Ploc),
                _ => None,
            };
            if let Some(kind) = gpu_bvh {
                if kolodzey_termination {
                    return Err(
                        "--kolodzey-termination is the GPU kd-tree thesis's termination rule: add \
                                --accel kdtree"
                            .into(),
                    );
                }
                let ctx = context(cli.validate)?;
                let scene = load_scene(&scene)?;
                return gpu_bvh_build_command(&ctx, kind, &scene, reference, json, &profile);
            }
            if accel != "kdtree" {
                return Err(format!(
                    "unknown --accel `{accel}` (available: kdtree, sah-bvh, lbvh, ploc, \
                     driver, driver-fast-build)"
                )
                .into());
            }
            let scene = load_scene(&scene)?;
            let triangles = scene.triangles_world(0.0);
            if triangles.is_empty() {
                return Err("the scene has no triangles to build a kd-tree over (spheres are not in the kd-tree yet)".into());
            }
            let mut params = vkrt::accel::kdtree::SahParams::default();
            if kolodzey_termination {
                params.sah_leaf_test = false;
                params.max_leaf_prims = 63;
            }
            let ctx = context(cli.validate)?;
            let before = device_bytes_start(&ctx);
            let (report, trace) =
                vkrt::accel::kdtree::report::build_report(&ctx, &triangles, &params, reference)?;
            write_profile(&profile, &trace)?;
            if json {
                let mut v = serde_json::to_value(&report)?;
                extend_json(&mut v, device_bytes_json(&ctx, before, triangles.len()));
                let kd = vkrt::accel::device::AccelKind::KdTree;
                extend_json(&mut v, levels_json(&ctx, kd, &scene)?);
                println!("{}", serde_json::to_string_pretty(&v)?);
            } else {
                println!(
                    "{} triangles: GPU build {:.2} ms in {} levels",
                    report.primitives, report.build_ms, report.levels
                );
                for (phase, ms) in &report.phases {
                    println!("  {phase:<16} {ms:>9.2} ms");
                }
                println!(
                    "{} nodes, {} leaves, depth {}, {} references ({:.2} per primitive), SAH cost {:.3}, {} bytes",
                    report.nodes,
                    report.leaves,
                    report.max_depth,
                    report.references,
                    report.references as f64 / f64::from(report.primitives.max(1)),
                    report.sah_cost,
                    report.bytes
                );
                if let (Some(eq), Some(twin), Some(cost), Some(full)) = (
                    report.equal_to_cpu_twin,
                    report.cpu_twin_ms,
                    report.full_clip_sah_cost,
                    report.full_clip_ms,
                ) {
                    println!("CPU twin {twin:.1} ms, equal to the GPU tree: {eq}");
                    println!("full-clipping CPU build {full:.1} ms, SAH cost {cost:.3}");
                    if !eq {
                        return Err("the GPU tree differs from its CPU twin".into());
                    }
                }
            }
        }
        Command::Bench {
            what: BenchCommand::Trace(args),
        } => bench_trace_command(cli.validate, &args)?,
        Command::Bench {
            what:
                BenchCommand::Accuracy {
                    quick,
                    json,
                    out,
                    mesh,
                    scenes,
                },
        } => {
            use vkrt::accuracy::{measure, report};
            report::check_target(&out)?;
            let opt = measure::AccuracyOptions {
                quick,
                mesh,
                motion_scene: scenes.join("dynamic_demo.toml"),
                scenes_dir: scenes,
                command: std::env::args().collect::<Vec<_>>().join(" "),
            };
            let ctx = context(cli.validate)?;
            let (r, images) =
                measure::run(&ctx, &opt, |line| eprintln!("{line}")).map_err(|e| e.to_string())?;
            report::write(&out, &r, &images)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&r)?);
            } else {
                print!("{r}");
                println!("report: {}", out.join("index.html").display());
            }
        }
        Command::Animate {
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
            accel,
            traversal,
            update,
            flatten,
            preview,
            json,
            profile,
        } => {
            let render = vkrt::render::RenderOptions {
                width,
                height,
                spp,
                all_effects: false,
                accel: accel_traversal(accel, traversal),
                flatten,
            };
            check_resolution(&render)?;
            let loaded = load_scene(&Some(scene))?;
            let args = cli::animate::AnimateArgs {
                output,
                frames,
                length,
                skip_existing,
                render,
                update: match update {
                    UpdateArg::Rebuild => vkrt::render::gpu::Update::Rebuild,
                    UpdateArg::Refit => vkrt::render::gpu::Update::Refit,
                },
                preview,
            };
            let validate = cli.validate;
            if plan {
                let argv: Vec<String> = std::env::args().collect();
                let v = cli::animate::plan_command(
                    || context(validate),
                    loaded,
                    args,
                    &Default::default(),
                    task_seconds,
                    &argv,
                )?;
                println!("{}", serde_json::to_string_pretty(&v)?);
                return Ok(());
            }
            let (report, trace_profile) = vkrt::gpu::capture_profiles(|| {
                cli::animate::animate_command(
                    || context(validate),
                    loaded,
                    args,
                    &Default::default(),
                )
                .map_err(|e| e.to_string())
            });
            write_profile(&profile, &trace_profile)?;
            cli::animate::print_report(&report?, json)?;
        }
        Command::Bench {
            what:
                BenchCommand::Animate {
                    scene,
                    frames,
                    step,
                    width,
                    height,
                    spp,
                    out,
                    json,
                },
        } => {
            let render = vkrt::render::RenderOptions {
                width: Some(width),
                height: Some(height),
                spp,
                ..Default::default()
            };
            check_resolution(&render)?;
            let scene = cli::animate::animated(load_scene(&Some(scene))?, None)?;
            let ctx = context(cli.validate)?;
            cli::animate::bench_animate(&ctx, &scene, (frames, step), &render, &out, json)?;
        }
        Command::Bench {
            what: BenchCommand::Robustness { quick, json },
        } => {
            use vkrt::trace::robust::{run_all, SuiteSize};
            let ctx = context(cli.validate)?;
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
                    "case",
                    "accel",
                    "intersector",
                    "rays",
                    "failures",
                    "(kind)",
                    "errors",
                    "trace ms"
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
        }
        Command::Trace {
            scene,
            rays,
            out,
            any_hit,
            intersector,
            batch_rays,
            accel,
            traversal,
            flatten,
            json,
        } => {
            let accel = accel_traversal(accel, traversal);
            let opt = vkrt::trace::TraceOptions {
                intersector: intersector.into(),
                query: if any_hit {
                    vkrt::trace::Query::Any
                } else {
                    vkrt::trace::Query::Closest
                },
                ..Default::default()
            };
            trace_command(
                cli.validate,
                &scene,
                &rays,
                out.as_deref(),
                (&opt, accel),
                (batch_rays, flatten),
                json,
            )?;
        }
        Command::Bench {
            what:
                BenchCommand::Bvh {
                    max_n,
                    reps,
                    mesh,
                    json,
                },
        } => {
            let scenes = bench_scenes(mesh, max_n)?;
            let rows = vkrt::accel::bvh::bench::bench(&scenes, reps)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&rows)?);
            } else {
                println!(
                    "{:<16} {:>9} {:<8} {:<7} {:>7} {:>11} {:>8} {:>9}",
                    "scene",
                    "triangles",
                    "sah",
                    "scheme",
                    "threads",
                    "build ms",
                    "speed-up",
                    "SAH cost"
                );
                for r in &rows {
                    println!(
                        "{:<16} {:>9} {:<8} {:<7} {:>7} {:>11.1} {:>8.2} {:>9.2}",
                        r.scene,
                        r.triangles,
                        r.sah,
                        r.scheme,
                        r.threads,
                        r.build_ms,
                        r.speedup,
                        r.sah_cost
                    );
                }
            }
        }
        Command::Bench {
            what:
                BenchCommand::Kdtree {
                    max_n,
                    ablation,
                    ablation_max_n,
                    reps,
                    kolodzey_termination,
                    mesh,
                    json,
                    profile,
                },
        } => {
            let scenes = bench_scenes(mesh, max_n)?;
            let ctx = context(cli.validate)?;
            let mut params = vkrt::accel::kdtree::SahParams::default();
            if kolodzey_termination {
                params.max_leaf_prims = 63;
                params.sah_leaf_test = false;
            }
            let ablation_max_n = if ablation { ablation_max_n as usize } else { 0 };
            let (report, trace) = vkrt::gpu::capture_profiles(|| {
                vkrt::bench::kdtree_report(&ctx, &scenes, &params, ablation_max_n, reps)
            });
            let report = report?;
            write_profile(&profile, &trace)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&report)?);
            } else {
                println!("{}", report.device);
                println!("{:?}", report.params);
                println!(
                    "{:<16} {:>9} {:<22} {:>10} {:>7} {:>9} {:>9} {:>9} {:>9} {:>9} {:>8}",
                    "scene",
                    "tris",
                    "variant",
                    "build ms",
                    "ratio",
                    "phase1",
                    "costs",
                    "argmin",
                    "nodes",
                    "clip",
                    "SAH"
                );
                for r in &report.rows {
                    let p = |k: &str| r.phases.get(k).copied().unwrap_or(0.0);
                    if let Some(e) = &r.error {
                        println!("{:<16} {:>9} {:<22} {e}", r.scene, r.primitives, r.variant);
                        continue;
                    }
                    println!(
                        "{:<16} {:>9} {:<22} {:>10.1} {:>7.2} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>8.2}",
                        r.scene,
                        r.primitives,
                        r.variant,
                        r.build_ms,
                        r.ratio_to_default,
                        p("phase1"),
                        p("split_costs"),
                        p("best_split"),
                        p("nodes"),
                        p("clip_partition"),
                        r.sah_cost
                    );
                }
                if report.rows.iter().any(|r| r.variant != "default") {
                    println!("ratio: variant build ms / default build ms, same scene, same run, same tree");
                    for (label, note) in vkrt::bench::KD_VARIANT_NOTES {
                        println!("  {label}: {note}");
                    }
                }
                if let Some(e) = report.fitted_exponent {
                    println!("fitted exponent of build time over N (icospheres): {e:.3}");
                }
                if let Some(e) = report.fitted_exponent_all {
                    println!("fitted exponent of build time over N (all default rows): {e:.3}");
                }
            }
        }
    }
    Ok(())
}

/// `vkrt trace`: everything is read and checked before the GPU work, the hits are written
/// atomically (no partial file on any error).
fn trace_command(
    validate: bool,
    scene_path: &std::path::Path,
    rays_path: &std::path::Path,
    out: Option<&std::path::Path>,
    (opt, accel): (&vkrt::trace::TraceOptions, vkrt::accel::device::AccelChoice),
    (batch_rays, flatten): (Option<usize>, bool),
    json: bool,
) -> Result<(), Box<dyn std::error::Error>> {
    use vkrt::trace::{files, gpu, instanced, TraceGeometry};
    let rays = files::read_rays(rays_path)?;
    let scene = load_scene(&Some(scene_path.to_path_buf()))?;
    let time = scene.camera.shutter_open;
    let ctx = context(validate)?;
    // Meshes named more than once: bottom levels and instances, unless asked flat (or
    // traced by the driver's structure, which vkrt builds as one level).
    let flatten = flatten || accel.kind == vkrt::accel::device::AccelKind::Driver;
    if let Some(two) = (!flatten)
        .then(|| instanced::TwoLevelScene::of(&scene, time))
        .flatten()
    {
        let done = instanced::build_and_trace(&ctx, accel, opt, &two, &rays, time)?;
        let extra = serde_json::json!({
            "levels": 2,
            "instances": two.mesh_instances(),
            "bottom_levels": two.bottoms.len(),
            "unique_primitives": two.unique_primitives,
            "bottom_build_ms": done.bottom_build_ms,
            "top_build_ms": done.top_build_ms,
            "bottom_bytes": done.bottom_bytes,
            "top_bytes": done.top_bytes,
        });
        let summary = format!(
            "{} primitives as {} bottom levels under {} instances ({} unique primitives)",
            scene.triangle_count() + scene.spheres.len(),
            two.bottoms.len(),
            two.instances.len(),
            two.unique_primitives
        );
        let batch = gpu::TraceBatch {
            hits: done.hits,
            exhausted: done.exhausted,
            profile: Default::default(),
        };
        let report = TraceReport {
            accel,
            build_ms: done.bottom_build_ms + done.top_build_ms,
            trace_ms: done.trace_ms,
            attempts: 1,
            traffic: None,
            extra,
            summary,
        };
        return report_trace(&rays, &batch, out, report, json);
    }
    let geometry = TraceGeometry::at_time(&scene, time);
    let builder = vkrt::accel::device::AccelBuilder::for_choice(&ctx, accel)?;
    let tracer = gpu::Tracer::for_accel(&ctx, opt, accel.traversal())?;
    // Upload, build and the first batch's trace in one submission; nothing read back
    // between build and trace.
    let done = gpu::build_and_trace(&ctx, &builder, &tracer, &geometry, &rays, 0.0, batch_rays)?;
    let report = TraceReport {
        accel,
        build_ms: done.build_ms,
        trace_ms: done.batch.profile.ms("trace").unwrap_or(0.0),
        attempts: done.attempts,
        traffic: Some((
            done.traffic.submits,
            done.readback_before_trace,
            done.traffic.readback_bytes,
        )),
        extra: serde_json::json!({ "levels": 1 }),
        summary: format!("{} primitives", geometry.primitive_count()),
    };
    report_trace(&rays, &done.batch, out, report, json)
}

/// What `vkrt trace` prints besides the hits.
struct TraceReport {
    accel: vkrt::accel::device::AccelChoice,
    build_ms: f64,
    trace_ms: f64,
    attempts: u32,
    /// Submissions, bytes read back before the trace and in all (the flat path's).
    traffic: Option<(u64, u64, u64)>,
    extra: serde_json::Value,
    summary: String,
}

fn report_trace(
    rays: &[vkrt::trace::Ray],
    batch: &vkrt::trace::gpu::TraceBatch,
    out: Option<&std::path::Path>,
    r: TraceReport,
    json: bool,
) -> Result<(), Box<dyn std::error::Error>> {
    use vkrt::trace::files;
    // Invalid rays are answered as misses; say how many and why, never silently.
    let invalid = vkrt::trace::count_invalid(rays);
    let n_invalid: usize = invalid.iter().sum();
    if n_invalid > 0 {
        let why: Vec<String> = vkrt::trace::InvalidRay::ALL
            .iter()
            .zip(invalid)
            .filter(|(_, n)| *n > 0)
            .map(|(r, n)| format!("{n} {}", r.name()))
            .collect();
        log::warn!(
            "{n_invalid} of {} rays are invalid and reported as misses ({}); \
             a valid ray has a finite origin, direction and tmin, a non-zero direction and \
             tmin <= tmax (tmax = inf is unbounded)",
            rays.len(),
            why.join(", ")
        );
    }
    if batch.exhausted > 0 {
        log::warn!(
            "{} rays ran out of traversal steps and are reported as misses",
            batch.exhausted
        );
    }
    if let Some(out) = out {
        vkrt::gpu::write_atomically(out, &files::encode_hits(out, &batch.hits))?;
    }
    let hits = batch.hits.iter().filter(|h| h.is_hit()).count();
    let trace_ms = r.trace_ms;
    let mrays_per_s = if trace_ms > 0.0 {
        rays.len() as f64 / (trace_ms * 1e3)
    } else {
        0.0
    };
    if json {
        let mut v = serde_json::json!({
            "rays": rays.len(),
            "hits": hits,
            "invalid": n_invalid,
            "invalid_by_reason": vkrt::trace::InvalidRay::ALL
                .iter()
                .zip(invalid)
                .map(|(r, n)| (r.name().to_string(), n.into()))
                .collect::<serde_json::Map<_, _>>(),
            "exhausted": batch.exhausted,
            "accel": r.accel.label(),
            "build_ms": r.build_ms,
            "build_attempts": r.attempts,
            "trace_ms": trace_ms,
            "mrays_per_s": mrays_per_s,
        });
        if let Some((submits, before, total)) = r.traffic {
            extend_json(
                &mut v,
                serde_json::json!({
                    "submits": submits,
                    "readback_bytes": before,
                    "readback_bytes_total": total,
                }),
            );
        }
        extend_json(&mut v, r.extra);
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!(
            "{} rays, {} hits, {} misses: trace {:.3} ms on the GPU ({:.2} Mrays/s), {}",
            rays.len(),
            hits,
            rays.len() - hits,
            trace_ms,
            mrays_per_s,
            r.summary
        );
        if let Some(out) = out {
            println!("wrote {}", out.display());
        }
    }
    Ok(())
}

/// `vkrt build --accel sah-bvh`: the parallel node-queue build on every core over the scene's
/// primitives at the shutter-open time; with `reference`, also on one thread (must be equal).
fn bvh_build_command(
    scene: &vkrt::scene::Scene,
    reference: bool,
    json: bool,
) -> Result<(), Box<dyn std::error::Error>> {
    use vkrt::accel::bvh::{self, validate, BvhParams, Threading};
    let g = vkrt::trace::TraceGeometry::at_time(scene, scene.camera.shutter_open);
    let params = BvhParams::default();
    let all_cores = Threading::all_cores();
    let Threading::Queue { threads } = all_cores else {
        unreachable!("all_cores is the node queue")
    };
    let timed = |threading| bvh::build_timed(&g.boxes, &params, threading);
    let (tree, build_ms) = timed(all_cores)?;
    validate::validate(&tree, &g.boxes).map_err(|e| format!("invalid BVH: {e}"))?;
    let single = if reference {
        Some(timed(Threading::Single)?)
    } else {
        None
    };
    let equal = single.as_ref().map(|(t, _)| *t == tree);
    let (shape, shape_line) = bvh_shape(&tree, &params);
    let mut report = serde_json::json!({
        "kind": "sah_bvh",
        "primitives": g.primitive_count(),
        "build_ms": build_ms,
        "threads": threads,
        "scheme": "queue",
        "params": params,
        "equal_to_single_thread": equal,
        "single_thread_ms": single.as_ref().map(|(_, ms)| *ms),
    });
    report.as_object_mut().expect("an object").extend(shape);
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "{} primitives: CPU build {build_ms:.2} ms on {threads} threads (node queue)",
            g.primitive_count()
        );
        println!("{shape_line}");
        if let (Some((_, ms)), Some(eq)) = (&single, equal) {
            println!("one thread {ms:.1} ms, the same tree: {eq}");
        }
    }
    if equal == Some(false) {
        return Err("the multithreaded BVH differs from the single-threaded one".into());
    }
    Ok(())
}

/// `vkrt build --accel lbvh|ploc`: LBVH, Karras 2012 or PLOC built on the device over the
/// scene's primitives at the shutter-open time, read back (this command is a tool),
/// validated; with `reference`, also the CPU twin (must be equal bit for bit).
fn gpu_bvh_build_command(
    ctx: &vkrt::gpu::Context,
    kind: vkrt::accel::device::AccelKind,
    scene: &vkrt::scene::Scene,
    reference: bool,
    json: bool,
    profile: &Option<PathBuf>,
) -> Result<(), Box<dyn std::error::Error>> {
    use vkrt::accel::bvh::{lbvh, ploc, validate, BvhParams};
    use vkrt::accel::device::{AccelBuilder, AccelKind, HostStructure};
    let g = vkrt::trace::TraceGeometry::at_time(scene, scene.camera.shutter_open);
    let builder = AccelBuilder::new(ctx, kind)?;
    let before = device_bytes_start(ctx);
    // Once to compile and warm the pipelines, then the timed build.
    let mut timed = None;
    for _ in 0..2 {
        // The previous build's buffers go before the next is made (the peak is one build).
        drop(timed.take());
        let mut rec = vkrt::gpu::Recorder::new(ctx)?;
        let dev = match vkrt::trace::gpu::GpuGeometry::record_build(&mut rec, &builder, &g, 0) {
            Ok((dev, _)) => dev,
            // A scene too big to build flat may still build as two levels: say both.
            Err(flat) => return levels_only(ctx, kind, scene, flat, json),
        };
        let prof = rec.submit_and_wait()?;
        timed = Some((dev, prof));
    }
    let (dev, prof) = timed.expect("built");
    write_profile(profile, &prof)?;
    let HostStructure::Bvh(tree) = dev.accel.download()? else {
        unreachable!("a GPU BVH")
    };
    validate::validate(&tree, &g.boxes).map_err(|e| format!("invalid {}: {e}", kind.name()))?;
    let passes: serde_json::Map<String, serde_json::Value> = vkrt::accel::bvh::GPU_BUILD_PASSES
        .iter()
        .filter_map(|p| Some((p.to_string(), prof.ms(p)?.into())))
        .collect();
    let build_ms = prof.ms("build").unwrap_or(0.0);
    let bits = builder.lbvh_bits();
    let ploc_params = builder.ploc_params();
    let twin = reference.then(|| {
        let t = std::time::Instant::now();
        let twin = match kind {
            AccelKind::Ploc => ploc::build(&g.boxes, &ploc_params.unwrap_or_default()).0,
            _ => lbvh::build(&g.boxes, bits),
        };
        let twin = vkrt::accel::bvh::collapse::collapse(&twin, &builder.bvh_params);
        (twin, t.elapsed().as_secs_f64() * 1e3)
    });
    let equal = twin.as_ref().map(|(t, _)| *t == tree);
    let params = BvhParams::default();
    let (shape, shape_line) = bvh_shape(&tree, &params);
    let mut report = serde_json::json!({
        "kind": kind.name(),
        "morton_bits": bits.spec(),
        "ploc_radius": ploc_params.map(|p| p.radius),
        "primitives": g.primitive_count(),
        "build_ms": build_ms,
        "passes_ms": passes,
        "equal_to_cpu_twin": equal,
        "cpu_twin_ms": twin.as_ref().map(|(_, ms)| *ms),
    });
    report.as_object_mut().expect("an object").extend(shape);
    extend_json(
        &mut report,
        device_bytes_json(ctx, before, g.primitive_count()),
    );
    if json {
        extend_json(&mut report, levels_json(ctx, kind, scene)?);
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "{} primitives: {} GPU build {build_ms:.2} ms ({}-bit Morton codes)",
            g.primitive_count(),
            kind.name(),
            bits.spec()
        );
        for (name, ms) in &passes {
            println!("  {name:<12} {ms} ms");
        }
        println!("{shape_line}");
        if let (Some((_, ms)), Some(eq)) = (&twin, equal) {
            println!("CPU twin {ms:.1} ms, the same tree: {eq}");
        }
    }
    if equal == Some(false) {
        return Err(format!("the GPU {} differs from its CPU twin", kind.name()).into());
    }
    Ok(())
}

/// `vkrt build --accel driver`: the driver's structure built over the scene's primitives at
/// the shutter-open time, twice (the first warms up), with the build's GPU time from
/// timestamps and the submission's wall time; its bytes as the driver reports them.
fn driver_build_command(
    ctx: &vkrt::gpu::Context,
    prefer: vkrt::accel::driver::Prefer,
    scene: &vkrt::scene::Scene,
    json: bool,
    profile: &Option<PathBuf>,
) -> Result<(), Box<dyn std::error::Error>> {
    use vkrt::accel::device::{AccelBuilder, AccelChoice, DevicePrimitives};
    use vkrt::accel::driver::{DriverAccel, DriverInput};
    let g = vkrt::trace::TraceGeometry::at_time(scene, scene.camera.shutter_open);
    let builder = AccelBuilder::for_choice(ctx, AccelChoice::driver(prefer))?;
    let before = device_bytes_start(ctx);
    let prims = DevicePrimitives::upload(ctx, &g)?;
    let sizes = DriverAccel::sizes(ctx, &DriverInput::counts(&prims), prefer, false)?;
    let mut timed = None;
    for _ in 0..2 {
        // The previous build's buffers go before the next is made (the peak is one build).
        drop(timed.take());
        let (mut accel, scratch) = builder.create(ctx, prims.count(), 0)?;
        let mut rec = vkrt::gpu::Recorder::new(ctx)?;
        rec.scope("build", |rec| {
            builder.record_build(rec, &prims, &g, &scratch, &mut accel)
        })?;
        let t = std::time::Instant::now();
        let prof = rec.submit_and_wait()?;
        timed = Some((prof, t.elapsed().as_secs_f64() * 1e3));
    }
    let (prof, wall_ms) = timed.expect("built");
    write_profile(profile, &prof)?;
    let build_ms = prof.ms("build").unwrap_or(0.0);
    if json {
        let v = serde_json::json!({
            "kind": "driver",
            "prefer": prefer,
            "primitives": g.primitive_count(),
            "build_ms": build_ms,
            "submit_wall_ms": wall_ms,
            "bytes": sizes.structure_bytes,
            "build_scratch_bytes": sizes.build_scratch_bytes,
        });
        let mut v = v;
        extend_json(&mut v, device_bytes_json(ctx, before, g.primitive_count()));
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!(
            "{} primitives: driver build ({}) {build_ms:.2} ms on the GPU, submission \
             {wall_ms:.2} ms wall; {} bytes, {} bytes of scratch",
            g.primitive_count(),
            prefer.name(),
            sizes.structure_bytes,
            sizes.build_scratch_bytes
        );
    }
    Ok(())
}

/// Starts measuring the device memory a build needs: vkrt's live bytes now.
fn device_bytes_start(ctx: &vkrt::gpu::Context) -> u64 {
    ctx.reset_memory_peak();
    ctx.memory().vkrt_bytes
}

/// `device_bytes`: the most device memory vkrt's buffers held at once since `before`
/// (primitives, structure, scratch, the build's read-backs), and per primitive.
fn device_bytes_json(ctx: &vkrt::gpu::Context, before: u64, n: usize) -> serde_json::Value {
    let bytes = ctx.memory().vkrt_peak_bytes.saturating_sub(before);
    serde_json::json!({
        "device_bytes": bytes,
        "device_bytes_per_primitive": bytes as f64 / n.max(1) as f64,
    })
}

/// `levels`: where the scene names a mesh more than once, the bytes of its two levels as
/// `vkrt trace` builds them (bottom levels of `kind`, the top level); absent otherwise.
fn levels_json(
    ctx: &vkrt::gpu::Context,
    kind: vkrt::accel::device::AccelKind,
    scene: &vkrt::scene::Scene,
) -> Result<serde_json::Value, Box<dyn std::error::Error>> {
    use vkrt::trace::instanced::{level_bytes, TwoLevelScene};
    let Some(two) = TwoLevelScene::of(scene, scene.camera.shutter_open) else {
        return Ok(serde_json::json!({}));
    };
    let choice = vkrt::accel::device::AccelChoice::new(kind, Default::default());
    Ok(serde_json::json!({ "levels": level_bytes(ctx, choice, &two)? }))
}

/// `vkrt build` of a scene whose flat build failed with `flat`: where meshes repeat, the
/// bytes of its two levels and why it does not build flat; else the error.
fn levels_only(
    ctx: &vkrt::gpu::Context,
    kind: vkrt::accel::device::AccelKind,
    scene: &vkrt::scene::Scene,
    flat: vkrt::gpu::GpuError,
    json: bool,
) -> Result<(), Box<dyn std::error::Error>> {
    use vkrt::trace::instanced::{level_bytes, TwoLevelScene};
    let Some(two) = TwoLevelScene::of(scene, scene.camera.shutter_open) else {
        return Err(flat.into());
    };
    let choice = vkrt::accel::device::AccelChoice::new(kind, Default::default());
    let levels = level_bytes(ctx, choice, &two)?;
    if json {
        let v = serde_json::json!({
            "kind": kind.name(),
            "primitives": scene.triangle_count() + scene.spheres.len(),
            "flat_error": flat.to_string(),
            "levels": levels,
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!("flat: {flat}");
        println!(
            "as two levels: {} bottom levels ({} unique primitives, {} bytes) under {} \
             instances ({} bytes)",
            levels.bottom_levels,
            levels.unique_primitives,
            levels.bottom_bytes,
            levels.instances,
            levels.top_bytes
        );
    }
    Ok(())
}

fn extend_json(v: &mut serde_json::Value, more: serde_json::Value) {
    if let (Some(v), serde_json::Value::Object(more)) = (v.as_object_mut(), more) {
        v.extend(more);
    }
}

/// What `vkrt build --json` reports of a BVH's shape, and the same as a line of text.
fn bvh_shape(
    tree: &vkrt::accel::bvh::Bvh,
    params: &vkrt::accel::bvh::BvhParams,
) -> (serde_json::Map<String, serde_json::Value>, String) {
    let sah = vkrt::accel::bvh::validate::sah_cost(tree, params);
    let v = serde_json::json!({
        "nodes": tree.nodes.len(),
        "leaves": tree.leaf_count(),
        "max_depth": tree.depth(),
        "sah_cost": sah,
        "references": tree.refs.len(),
        "bytes": tree.bytes(),
    });
    let line = format!(
        "{} nodes, {} leaves, depth {}, SAH cost {sah:.3}, {} bytes",
        tree.nodes.len(),
        tree.leaf_count(),
        tree.depth(),
        tree.bytes()
    );
    let serde_json::Value::Object(map) = v else {
        unreachable!("an object")
    };
    (map, line)
}

/// `vkrt bench trace`: the scenes are loaded before the device is touched.
fn bench_trace_command(
    validate: bool,
    args: &BenchTraceArgs,
) -> Result<(), Box<dyn std::error::Error>> {
    use vkrt::trace::bench::{self, scenes, BenchOptions};
    let quick = args.quick;
    let mut list = Vec::new();
    let default_mesh = scenes::shared_bunny().filter(|_| !quick);
    if let Some(path) = args.mesh.clone().or(default_mesh) {
        list.push(scenes::mesh(&path)?);
    }
    list.extend(scenes::example_scenes(&args.scenes)?);
    let max_n = args.max_n.unwrap_or(if quick { 10_000 } else { 500_000 });
    list.push(scenes::icosphere(max_n)?);
    let opt = BenchOptions {
        size: args.size.unwrap_or(if quick { 64 } else { 512 }).max(1),
        reps: args.reps.unwrap_or(if quick { 1 } else { 3 }).max(1),
    };
    let ctx = context(validate)?;
    let report = bench::run(&ctx, &list, &opt)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{report}");
    }
    Ok(())
}

/// Named triangle lists.
type Meshes = Vec<(String, Vec<[glam::Vec3; 3]>)>;

/// The meshes a build benchmark runs over: `mesh` (default: the bunny in ../shared when
/// present), then icospheres of 100 K, 200 K, 500 K, 1 M and 2 M triangles up to `max_n`.
fn bench_scenes(mesh: Option<PathBuf>, max_n: u64) -> Result<Meshes, Box<dyn std::error::Error>> {
    use vkrt::trace::bench::scenes;
    let mut list = Vec::new();
    if let Some(path) = mesh.or_else(scenes::shared_bunny) {
        list.push(scenes::mesh_triangles(&path)?);
    }
    for n in [100_000u64, 200_000, 500_000, 1_000_000, 2_000_000] {
        if n > max_n {
            break;
        }
        list.push(scenes::icosphere_triangles(n)?);
    }
    Ok(list)
}
