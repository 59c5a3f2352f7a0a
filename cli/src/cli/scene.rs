//! `vkrt scene`: a scene file's summary (counts, bounds, the effects it calls for), as text
//! or JSON; no device needed.

use std::path::PathBuf;

use clap::Args;

use super::common::CliResult;

#[derive(Args)]
pub struct SceneArgs {
    /// The scene; omit for the embedded default scene (a Cornell box).
    file: Option<PathBuf>,
    #[arg(long)]
    json: bool,
}

pub fn run(args: &SceneArgs) -> CliResult<()> {
    let (scene, warnings) = match &args.file {
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
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!("{}", summary.to_string().trim_end());
    }
    Ok(())
}
