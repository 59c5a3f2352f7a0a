//! `vkrt bench render`: what each effect costs and what the plan saves, measured in one
//! run. For every example scene: the scene as planned, the scene with its effect taken out
//! (lights removed, mirrors dulled, glass made opaque, roughness 0, one pinhole sample, a
//! closed shutter, no occlusion rays, no emission), and the scene with `--all-effects`.

use serde::Serialize;

use vkrt::gpu::Context;
use vkrt::render::{render_scene, RenderOptions};
use vkrt::scene::Scene;
use vkrt::trace::TraceOptions;

/// One example scene's render times: as planned, without its effect, and with every pass
/// forced on.
#[derive(Clone, Debug, Serialize)]
pub struct EffectRow {
    /// The example scene's name.
    pub scene: String,
    /// The effect taken out for `without_ms`.
    pub effect: String,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Samples per pixel as planned (the render without the effect uses as many).
    pub spp: u32,
    /// GPU ms as planned, without the effect, and with every pass forced on.
    pub plan_ms: f64,
    /// GPU ms without the effect, scaled to the planned sample count.
    pub without_ms: f64,
    /// GPU ms with `--all-effects`.
    pub all_effects_ms: f64,
    /// Rays the planned render traced.
    pub rays: u64,
    /// Rays per second of the planned render, in millions.
    pub mrays_per_s: f64,
    /// plan_ms / without_ms: what the effect costs.
    pub effect_cost: f64,
    /// all_effects_ms / plan_ms: what planning saves.
    pub planning_saves: f64,
}

/// `scene` without the named effect (see the module docs).
pub fn without_effect(scene: &Scene, effect: &str) -> Scene {
    let mut s = scene.clone();
    match effect {
        "hard_shadows" | "soft_shadows" => s.lights.clear(),
        "reflection" => s.materials.iter_mut().for_each(|m| {
            m.mirror = glam::Vec3::ZERO;
            m.fresnel = false;
        }),
        "refraction" => s.materials.iter_mut().for_each(|m| m.transmission = 0.0),
        "glossy" => s.materials.iter_mut().for_each(|m| m.roughness = 0.0),
        "antialiasing" => s.settings.antialias = false,
        "depth_of_field" => s.camera.aperture_radius = 0.0,
        "motion_blur" => s.camera.shutter_close = s.camera.shutter_open,
        "ambient_occlusion" => s.settings.ao.enabled = false,
        "emission" => s
            .materials
            .iter_mut()
            .for_each(|m| m.emission = glam::Vec3::ZERO),
        _ => {}
    }
    s
}

/// Renders each `(name, scene, effect)` three ways at `width`×`height`, on `accel`.
pub fn effect_costs(
    ctx: &Context,
    scenes: &[(String, Scene, String)],
    (width, height): (u32, u32),
    accel: vkrt::accel::device::AccelChoice,
) -> Result<Vec<EffectRow>, Box<dyn std::error::Error + Send + Sync>> {
    let trace = TraceOptions::default();
    let opt = RenderOptions {
        width: Some(width),
        height: Some(height),
        spp: None,
        all_effects: false,
        accel,
        flatten: false,
        max_level_primitives: None,
    };
    let mut rows = Vec::new();
    for (name, scene, effect) in scenes {
        // The first render compiles the pipelines and touches the memory: not timed.
        render_scene(ctx, scene, &opt, &trace, |_, _| {})?;
        let planned = render_scene(ctx, scene, &opt, &trace, |_, _| {})?;
        // Same sample count without the effect, so the difference is the effect's own work.
        let without_opt = RenderOptions {
            spp: Some(planned.plan.spp),
            ..opt
        };
        let mut stripped = without_effect(scene, effect);
        if planned.plan.spp > 1 {
            // keep the samples (another effect may need them): jitter stays as planned
            stripped.settings.spp = planned.plan.spp;
        }
        let without = render_scene(ctx, &stripped, &without_opt, &trace, |_, _| {})?;
        let all = render_scene(
            ctx,
            scene,
            &RenderOptions {
                all_effects: true,
                ..opt
            },
            &trace,
            |_, _| {},
        )?;
        let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { 0.0 };
        rows.push(EffectRow {
            scene: name.clone(),
            effect: effect.clone(),
            width,
            height,
            spp: planned.plan.spp,
            plan_ms: planned.render_ms,
            without_ms: without.render_ms * ratio(planned.plan.spp as f64, without.plan.spp as f64),
            all_effects_ms: all.render_ms,
            rays: planned.image.counts.total(),
            mrays_per_s: planned.mrays_per_s(),
            effect_cost: ratio(
                planned.render_ms,
                without.render_ms * ratio(planned.plan.spp as f64, without.plan.spp as f64),
            ),
            planning_saves: ratio(all.render_ms, planned.render_ms),
        });
    }
    Ok(rows)
}
