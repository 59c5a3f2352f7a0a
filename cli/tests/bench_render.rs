//! `vkrt bench render`'s scenes without their effect.

use std::path::Path;

use vkrt::scene::Scene;

fn scene_file(name: &str) -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../scenes")
        .join(name);
    Scene::load(&path).unwrap().scene
}

/// `vkrt bench render` compares each example scene with its effect taken out: the stripped
/// scene must really lack that effect (and keep the others).
#[test]
fn bench_strips_exactly_the_effect() {
    for effect in vkrt::scene::Effects::ALL_NAMES {
        let scene = scene_file(&format!("{effect}.toml"));
        let fx = scene.effects();
        assert!(fx.has(effect), "{effect}.toml does not call for {effect}");
        let stripped = vkrt_cli::render_bench::without_effect(&scene, effect).effects();
        assert!(!stripped.has(effect), "{effect} still on after stripping");
        for other in fx.names() {
            // glass's Fresnel reflection goes with its refraction
            let coupled = (effect.ends_with("shadows") && other.ends_with("shadows"))
                || (effect == "refraction" && other == "reflection");
            if other != effect && !coupled {
                assert!(
                    stripped.has(other),
                    "stripping {effect} also removed {other}"
                );
            }
        }
    }
}
