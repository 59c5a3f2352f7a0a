//! What several commands share: the error type, logging, the device context, scene
//! loading, the render limits, profile writing, JSON merging and the `*Arg` value enums.

use std::path::PathBuf;

use clap::{Args, ValueEnum};
use vkrt::gpu::{Context, ContextOptions, Profile, Validation};

/// A command's result: its error is printed as `vkrt: error: ...` with exit status 1.
pub type CliResult<T> = Result<T, Box<dyn std::error::Error>>;

#[derive(Clone, Copy, PartialEq, ValueEnum)]
pub enum AccelArg {
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
pub enum UpdateArg {
    Rebuild,
    Refit,
}

#[derive(Clone, Copy, PartialEq, ValueEnum)]
pub enum TraversalArg {
    /// The walk that traces fastest on this device, as measured (`vkrt info` says which).
    Auto,
    /// Binary nodes, far children on a stack.
    Stack,
    /// Binary nodes, no stack: parent links and one bit per level.
    Bitstack,
    /// 4-wide quantized nodes (Ylitie et al. 2017) with a stack.
    Wide,
}

/// The structure `render`, `trace` and `animate` answer rays with (one set of flags).
#[derive(Args, Clone, Copy)]
pub struct StructureArgs {
    /// The acceleration structure: the SAH BVH built on the CPU's threads (the default, by
    /// measurement: on lavapipe it builds 25-30x and traces 1.3-1.8x faster than the
    /// kd-tree), the LBVH or PLOC built on the GPU, the SAH kd-tree built on the GPU, or the
    /// driver's own through its ray query. The answers are the same.
    #[arg(long, value_enum, default_value_t = AccelArg::SahBvh)]
    pub accel: AccelArg,
    /// How a BVH is walked: the device's fastest (auto: `vkrt info` says which), a stack,
    /// the stackless bitstack walk with parent links, or a stack over 4-wide quantized nodes
    /// made after the build. The answers are the same.
    #[arg(long, value_enum, default_value_t = TraversalArg::Auto)]
    pub traversal: TraversalArg,
    /// Trace one structure over every primitive even where meshes repeat (by default a
    /// mesh named more than once, and a moving mesh beside it, become instances of one
    /// bottom-level structure under a top level; the answers are the same).
    #[arg(long)]
    pub flatten: bool,
}

impl StructureArgs {
    /// The structure and walk chosen, on `ctx`'s device (`auto`: its fastest walk; the
    /// binary stack walk before there is a device).
    pub fn choice(&self, ctx: Option<&Context>) -> vkrt::accel::device::AccelChoice {
        accel_traversal(self.accel, self.traversal, ctx)
    }
}

pub fn accel_traversal(
    accel: AccelArg,
    walk: TraversalArg,
    ctx: Option<&Context>,
) -> vkrt::accel::device::AccelChoice {
    use vkrt::accel::device::{AccelChoice, AccelKind};
    use vkrt::accel::driver::Prefer;
    let kind = match accel {
        AccelArg::Kdtree => AccelKind::KdTree,
        AccelArg::SahBvh => AccelKind::SahBvh,
        AccelArg::Lbvh => AccelKind::Lbvh,
        AccelArg::Ploc => AccelKind::Ploc,
        AccelArg::Driver => return AccelChoice::driver(Prefer::FastTrace),
        AccelArg::DriverFastBuild => return AccelChoice::driver(Prefer::FastBuild),
    };
    AccelChoice::new(kind, traversal(walk, ctx))
}

/// The walk `--traversal` names, on `ctx`'s device (`auto`: its fastest walk; the binary
/// stack walk before there is a device).
pub fn traversal(walk: TraversalArg, ctx: Option<&Context>) -> vkrt::accel::walk::Traversal {
    use vkrt::accel::walk::Traversal;
    match walk {
        TraversalArg::Auto => ctx.map_or(Traversal::Stack, Traversal::for_device),
        TraversalArg::Stack => Traversal::Stack,
        TraversalArg::Bitstack => Traversal::Bitstack,
        TraversalArg::Wide => Traversal::Wide,
    }
}

#[derive(Clone, Copy, ValueEnum)]
pub enum IntersectorArg {
    /// Woop, Benthin & Wald 2013 (no ray slips between triangles sharing an edge).
    Watertight,
    /// Möller–Trumbore 1997 (faster, not watertight).
    // The spellings `vkrt render` parsed by hand before it took this enum.
    #[value(aliases = ["moller_trumbore", "moller"])]
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

/// Logs go to stderr (stdout stays for results and --json) as `vkrt: LEVEL: message`, the
/// style of the error line at exit; debug and trace also name the module.
pub fn init_logging(verbose: u8, quiet: bool) {
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

/// The global profiling flags: what every context a command makes is set to.
#[derive(Clone, Copy, Default)]
pub struct Profiling {
    /// `--profile-dispatches`: every dispatch a timed scope of its own.
    pub dispatches: bool,
    /// `--profile-stats`: compute-shader invocations counted per scope.
    pub statistics: bool,
}

static PROFILING: std::sync::OnceLock<Profiling> = std::sync::OnceLock::new();

/// Sets the global profiling flags (once, before any command makes a context).
pub fn set_profiling(p: Profiling) {
    let _ = PROFILING.set(p);
}

/// Sets `ctx` to the global profiling flags.
pub fn apply_profiling(ctx: &Context) {
    let p = PROFILING.get().copied().unwrap_or_default();
    ctx.set_dispatch_timestamps(p.dispatches);
    if p.statistics && !ctx.set_pipeline_statistics(true) {
        log::warn!("--profile-stats: the device has no pipeline-statistics queries");
    }
    if p.statistics {
        // The baseline each pass's bandwidth is weighed against, measured here and now.
        match vkrt_cli::bench::copy::copy_bandwidth(ctx) {
            Ok(gib) => ctx.set_copy_baseline(gib),
            Err(e) => log::warn!("--profile-stats: no copy baseline: {e}"),
        }
    }
}

pub fn context(validate: bool) -> CliResult<Context> {
    let env_on = std::env::var("VKRT_VALIDATION").is_ok_and(|v| v.trim() == "1");
    let validation = if validate || env_on {
        Validation::On
    } else {
        Validation::Off
    };
    let ctx = Context::new(&ContextOptions {
        validation,
        device_name: None,
        ..Default::default()
    })?;
    let info = ctx.info();
    log::info!("device {}, driver {}", info.device, info.driver);
    apply_profiling(&ctx);
    Ok(ctx)
}

pub fn load_scene(path: &Option<PathBuf>) -> CliResult<vkrt::scene::Scene> {
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
pub fn check_resolution(opt: &vkrt::render::RenderOptions) -> CliResult<()> {
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

/// Writes `--profile`'s trace.
pub fn write_profile(path: &std::path::Path, profile: &Profile) -> CliResult<()> {
    profile.write_chrome_trace(path)?;
    eprintln!(
        "vkrt: wrote the CPU+GPU trace {} (open in ui.perfetto.dev)",
        path.display()
    );
    Ok(())
}

/// What `--json` reports of memory: the process's peak resident set (on lavapipe it
/// includes the device's memory, which is host memory there), per triangle of the scene,
/// and the most bytes of vkrt's device buffers alive at once.
pub fn memory_json(triangles: usize, device: &vkrt::gpu::MemoryUsage) -> serde_json::Value {
    let peak = vkrt::host::host_peak_rss_bytes();
    serde_json::json!({
        "triangles": triangles,
        "host_peak_rss_bytes": peak,
        "host_peak_rss_bytes_per_triangle": peak.map(|b| b as f64 / triangles.max(1) as f64),
        "device_peak_bytes": device.vkrt_peak_bytes,
    })
}

pub fn extend_json(v: &mut serde_json::Value, more: serde_json::Value) {
    if let (Some(v), serde_json::Value::Object(more)) = (v.as_object_mut(), more) {
        v.extend(more);
    }
}

/// A time measured over repeats: the first run apart (a driver compiles a pipeline at its
/// first dispatch, caches are cold), then the warm runs, whose median is what the command
/// reports and the benches measure.
#[derive(Clone, Debug, Default)]
pub struct Repeated {
    /// The first run's milliseconds.
    pub first: f64,
    /// The warm runs' milliseconds, in order.
    pub warm: Vec<f64>,
}

impl Repeated {
    /// Adds run `i`'s milliseconds (run 0 is the first).
    pub fn push(&mut self, i: usize, ms: f64) {
        match i {
            0 => self.first = ms,
            _ => self.warm.push(ms),
        }
    }

    /// The warm runs' median, fastest and slowest.
    pub fn spread(&self) -> vkrt::gpu::Spread {
        vkrt::gpu::Spread::of(&self.warm)
    }

    /// `{key}` (the warm median), `{key}_min`, `{key}_max` and `first_{key}`.
    pub fn json(&self, key: &str) -> serde_json::Value {
        let s = self.spread();
        let mut v = serde_json::Map::new();
        v.insert(key.into(), s.median.into());
        v.insert(format!("{key}_min"), s.min.into());
        v.insert(format!("{key}_max"), s.max.into());
        v.insert(format!("first_{key}"), self.first.into());
        serde_json::Value::Object(v)
    }

    /// "12.34 ms (median of 3 warm runs, 11.90–13.02; the first 40.10)".
    pub fn text(&self) -> String {
        let s = self.spread();
        match s.count {
            1 => format!("{:.2} ms (warm; the first {:.2})", s.median, self.first),
            n => format!(
                "{:.2} ms (median of {n} warm runs, {:.2}–{:.2}; the first {:.2})",
                s.median, s.min, s.max, self.first
            ),
        }
    }
}
