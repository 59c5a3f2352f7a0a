//! `vkrt bench render`: what each effect costs and what the render plan saves, over the
//! example scenes (scenes/EFFECT.toml).

use std::path::PathBuf;

use clap::Args;

use crate::cli::common::{accel_traversal, context, AccelArg, CliResult, TraversalArg};

#[derive(Args)]
pub struct BenchRenderArgs {
    /// Folder of the example scenes (default: `scenes` in the current directory: the
    /// checkout's, run from there).
    #[arg(long, default_value = "scenes")]
    scenes: PathBuf,
    #[arg(long, default_value_t = 256)]
    width: u32,
    #[arg(long, default_value_t = 192)]
    height: u32,
    /// The structure the renders trace (built on the device, as `vkrt render` does).
    #[arg(long, value_enum, default_value_t = AccelArg::SahBvh)]
    accel: AccelArg,
    /// How a BVH is walked (auto: the device's fastest walk, as `vkrt render`).
    #[arg(long, value_enum, default_value_t = TraversalArg::Auto)]
    traversal: TraversalArg,
    #[arg(long)]
    json: bool,
}

pub fn run(args: BenchRenderArgs, validate: bool) -> CliResult<()> {
    let BenchRenderArgs {
        scenes,
        width,
        height,
        accel,
        traversal,
        json,
    } = args;
    let mut list = Vec::new();
    for effect in vkrt::scene::Effects::ALL_NAMES {
        let path = scenes.join(format!("{effect}.toml"));
        if path.exists() {
            let scene = vkrt::scene::Scene::load(&path)?.scene;
            list.push((format!("{effect}.toml"), scene, effect.to_string()));
        }
    }
    if list.is_empty() {
        return Err(format!("no effect scenes (EFFECT.toml) in {}", scenes.display()).into());
    }
    let ctx = context(validate)?;
    let accel = accel_traversal(accel, traversal, Some(&ctx));
    let rows = vkrt_cli::render_bench::effect_costs(&ctx, &list, (width, height), accel)
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
    Ok(())
}
