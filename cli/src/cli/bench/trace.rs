//! `vkrt bench trace`: ray throughput of every structure and walk, the driver's ray query
//! and obvhs on one CPU thread, on the same rays in one run.

use std::path::PathBuf;

use clap::Args;

use crate::cli::common::{context, CliResult};

#[derive(Args)]
pub struct BenchTraceArgs {
    /// Camera image width in pixels, one primary ray per pixel (default 512; 64 with --quick).
    #[arg(long)]
    size: Option<u32>,
    /// Repetitions of each build and trace, the best reported (default 3; 1 with --quick).
    #[arg(long)]
    reps: Option<u32>,
    /// Triangles of the icosphere (default 500000; 10000 with --quick).
    #[arg(long)]
    max_n: Option<u64>,
    /// Mesh to include (default: $VKRT_MESH, except with --quick; `./x` sets it to the
    /// Stanford bunny in ../shared/scenes where that is present).
    #[arg(long)]
    mesh: Option<PathBuf>,
    /// Folder of the example scenes, every .toml in it (default: `scenes` in the current
    /// directory: the checkout's, run from there).
    #[arg(long, default_value = "scenes")]
    scenes: PathBuf,
    /// The integration test's run: 64-pixel-wide images, the example scenes and a 10 K
    /// icosphere, one repetition.
    #[arg(long)]
    quick: bool,
    /// How vkrt's walks read the structures (default: the device's way, as `vkrt trace`
    /// does): `storage` or `texel` buffers, or `both`, every walk twice (rows `WALK
    /// (storage)` and `WALK (texel)`, their hits compared ray by ray, bit for bit)
    #[arg(long, value_enum)]
    node_access: Option<NodeAccessArg>,
    #[arg(long)]
    json: bool,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum NodeAccessArg {
    Storage,
    Texel,
    Both,
}

/// `vkrt bench trace`: the scenes are loaded before the device is touched.
pub fn run(args: &BenchTraceArgs, validate: bool) -> CliResult<()> {
    use vkrt_cli::trace_bench::{self as bench, scenes, AccessRows, BenchOptions};
    let quick = args.quick;
    let mut list = Vec::new();
    let default_mesh = scenes::default_mesh().filter(|_| !quick);
    if let Some(path) = args.mesh.clone().or(default_mesh) {
        list.push(scenes::mesh(&path)?);
    }
    list.extend(scenes::example_scenes(&args.scenes)?);
    let max_n = args.max_n.unwrap_or(if quick { 10_000 } else { 500_000 });
    list.push(scenes::icosphere(max_n)?);
    let opt = BenchOptions {
        size: args.size.unwrap_or(if quick { 64 } else { 512 }).max(1),
        reps: args.reps.unwrap_or(if quick { 1 } else { 3 }).max(1),
        node_access: args.node_access.map(|a| match a {
            NodeAccessArg::Storage => AccessRows::Storage,
            NodeAccessArg::Texel => AccessRows::Texel,
            NodeAccessArg::Both => AccessRows::Both,
        }),
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
