//! The `vkrt` command line: a thin layer over the library. This file parses the global
//! flags and picks the command; each command lives in its own file under `cli/`.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod cli;

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
    /// Write a Chrome trace of the whole command (open in ui.perfetto.dev): the host's spans
    /// (recording, submits, waits, read-backs, uploads, CPU builds) and every GPU pass, on
    /// one calibrated time axis.
    #[arg(long, global = true, value_name = "FILE")]
    profile: Option<PathBuf>,
    /// Time every dispatch too, as a scope named after its kernel inside its pass (costs two
    /// timestamp queries per dispatch).
    #[arg(long, global = true)]
    profile_dispatches: bool,
    /// Count each scope's compute-shader invocations (a pipeline-statistics query around
    /// every dispatch, where the device has them) and the bytes it binds, and weigh its
    /// bandwidth against a copy kernel's measured first: beside its time in `render`'s table
    /// and in the trace.
    #[arg(long, global = true)]
    profile_stats: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print the Vulkan device vkrt uses and what it can do.
    Info(cli::info::InfoArgs),
    /// Check that vkrt computes correctly on this device: every GPU primitive and builder
    /// against its CPU twin, every walk against brute force, the hard cases on every
    /// structure. Exits non-zero when a check fails; the first thing to run on a new GPU.
    Verify(cli::verify::VerifyArgs),
    /// Summarise a scene file (.toml, .obj, .scn text): counts, bounds, the effects it calls for.
    Scene(cli::scene::SceneArgs),
    /// Build an acceleration structure and report its time and quality.
    Build(cli::build::BuildArgs),
    /// Render a scene to an image (.png, .jpg, .exr or .pfm) with the wavefront renderer.
    Render(cli::render::RenderArgs),
    /// Trace a batch of rays against a scene on the GPU (the structure built and traced in
    /// one submission) and write the hits.
    ///
    /// Rays: `.rays` (little-endian, 8 f32 per ray: ox oy oz tmin dx dy dz tmax) or `.csv`
    /// (`ox,oy,oz,dx,dy,dz[,tmin,tmax]`). Hits: binary, 16 bytes per ray (t f32, prim u32,
    /// u f32, v f32; t = inf and prim = 4294967295 for a miss), or `.csv` by extension.
    /// Rays with NaN/Inf components are misses. Moving geometry is placed at the camera's
    /// shutter-open time.
    Trace(cli::trace::TraceArgs),
    /// Render the frames of an animated scene (its `[animation]`): per frame the moved
    /// primitives are written on the device, the structure rebuilt or refit, and the frame
    /// rendered, all in one submission; frames are written while the next renders.
    Animate(cli::animate::AnimateArgs),
    /// Run a renderer's own GL_EXT_ray_query compute shader over a scene and a ray file,
    /// through vkrt and through the driver's own ray query, and compare what it wrote, ray
    /// by ray.
    ///
    /// The shader's interface (binding 0's name is the shader's own):
    ///
    ///   layout(local_size_x = 64) in;  // one invocation per ray, any 1-D size
    ///   layout(set = 0, binding = 0) uniform accelerationStructureEXT scene;
    ///   layout(set = 0, binding = 1, std430) readonly buffer Rays { vec4 rays[]; };
    ///   //   ray i: rays[2i] = (origin, tMin), rays[2i+1] = (direction, tMax)
    ///   layout(set = 0, binding = 2, std430) writeonly buffer Results { uvec4 results[]; };
    ///   layout(push_constant) uniform Count { uint rayCount; };
    ///
    /// The shader includes "vkrt/ext_ray_query.glsl" after its #extension lines; where it
    /// does not, the line is inserted after the last #extension line (after #version where
    /// there is none). It is compiled with glslc (VKRT_GLSLC names another) for Vulkan 1.2,
    /// once through vkrt and once with VKRT_NATIVE_RAY_QUERY=1 for the driver's ray query
    /// (the include is then empty). Through vkrt, binding 0 is a uniform texel buffer
    /// (RGBA32UI) whose first texel's .xy is the top level's handle address.
    ///
    /// The scene's two levels, the same on both paths: each [[meshes]] entry is one
    /// instance (its id: its place among the entries) of a bottom level holding its
    /// triangles as geometry 0 (entries naming the same file share one); all spheres are one
    /// more instance, the last, with the identity transform, of a bottom level of one box
    /// geometry (primitive i: sphere i's box, centre ± radius). A mesh entry's `mask`,
    /// `custom_index`, `sbt_offset`, `flags` and `opaque` keys fill its instance record.
    ///
    /// Two records agree when every 32-bit word is equal, or both words are floats of the
    /// same sign and magnitude at least 2^-60 within 2^-16 of the larger of 1 and their
    /// magnitudes (drivers transform and intersect rays in their own order of operations;
    /// integers below 2^29 read as smaller floats and so are compared exactly). The exit
    /// status is non-zero when any ray differs. A shader that does not compile or breaks the
    /// interface, and a bad scene or ray file, are errors before any GPU work.
    ///
    /// --json prints {"rays", "native" (whether the driver's ray query ran),
    /// "mismatching_rays", "mismatches" (the first ten: {"ray", "driver", "vkrt"}, 4 words
    /// each), "vkrt_ms", "driver_ms" (the dispatches' GPU milliseconds)}.
    #[command(verbatim_doc_comment)]
    ShaderCheck(cli::shader_check::ShaderCheckArgs),
    /// Rewrite a SPIR-V module's ray queries (SPV_KHR_ray_query) into calls of vkrt's walk,
    /// for a device without VK_KHR_ray_query: no include, any compiler.
    ///
    /// Each acceleration-structure binding becomes a uniform texel buffer (RGBA32UI) whose
    /// first texel's .xy is the structure handle's device address, the descriptor
    /// vkrt/ext_ray_query.glsl takes. A module without ray queries is written unchanged.
    ///
    /// --json prints {"changed", "ray_query_instructions", "query_states", "structures",
    /// "functions_linked", "words_in", "words_out", "ms"}.
    #[command(verbatim_doc_comment)]
    Lower(cli::lower::LowerArgs),
    /// Measure GPU baselines and primitives.
    Bench {
        #[command(subcommand)]
        what: cli::bench::BenchCommand,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    cli::common::init_logging(cli.verbose, cli.quiet);
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("vkrt: error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> cli::common::CliResult<()> {
    cli::common::set_profiling(cli::common::Profiling {
        dispatches: cli.profile_dispatches,
        statistics: cli.profile_stats,
    });
    let Some(path) = cli.profile.clone() else {
        return run_command(cli);
    };
    let (result, profile) = vkrt::gpu::capture_profiles(|| run_command(cli));
    result?;
    cli::common::write_profile(&path, &profile)
}

fn run_command(cli: Cli) -> cli::common::CliResult<()> {
    let validate = cli.validate;
    match cli.command {
        Command::Info(args) => cli::info::run(&args, validate),
        Command::Verify(args) => cli::verify::run(args, validate),
        Command::Scene(args) => cli::scene::run(&args),
        Command::Build(args) => cli::build::run(args, validate),
        Command::Render(args) => cli::render::run(args, validate),
        Command::Trace(args) => cli::trace::run(args, validate),
        Command::Animate(args) => cli::animate::run(args, validate),
        Command::ShaderCheck(args) => cli::shader_check::run(args, validate),
        Command::Lower(args) => cli::lower::run(&args),
        Command::Bench { what } => cli::bench::run(what, validate),
    }
}
