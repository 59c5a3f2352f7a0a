//! `vkrt bench bvh`: CPU SAH BVH build time of every threading scheme (Sochora 2013,
//! Tables 3/4), the speed-up over one thread and the SAH cost; no device needed.

use std::path::PathBuf;

use clap::Args;

use super::bench_scenes;
use crate::cli::common::CliResult;

#[derive(Args)]
pub struct BvhArgs {
    /// Largest icosphere (triangles).
    #[arg(long, default_value_t = 1_000_000)]
    max_n: u64,
    /// Timed repetitions (the best is reported).
    #[arg(long, default_value_t = 3)]
    reps: u32,
    /// Mesh to include (default: $VKRT_MESH; `./x` sets it to the Stanford bunny in
    /// ../shared/scenes where that is present).
    #[arg(long)]
    mesh: Option<PathBuf>,
    #[arg(long)]
    json: bool,
}

pub fn run(args: BvhArgs) -> CliResult<()> {
    let BvhArgs {
        max_n,
        reps,
        mesh,
        json,
    } = args;
    let scenes = bench_scenes(mesh, max_n)?;
    let rows = vkrt_cli::bvh_bench::bench(&scenes, reps)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        print!("{}", vkrt_cli::bvh_bench::table(&rows));
    }
    Ok(())
}
