//! The `vkrt` command line: a thin layer over the library. This file parses the global
//! flags and picks the command; each command lives in its own file under `cli/`.

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
    let validate = cli.validate;
    match cli.command {
        Command::Info(args) => cli::info::run(&args, validate),
        Command::Verify(args) => cli::verify::run(args, validate),
        Command::Scene(args) => cli::scene::run(&args),
        Command::Build(args) => cli::build::run(args, validate),
        Command::Render(args) => cli::render::run(args, validate),
        Command::Trace(args) => cli::trace::run(args, validate),
        Command::Animate(args) => cli::animate::run(args, validate),
        Command::Bench { what } => cli::bench::run(what, validate),
    }
}
