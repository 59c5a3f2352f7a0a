//! The render plan: which passes run and which shader variants exist, decided from what
//! the scene calls for ([`Effects`]) — no shadow pass without lights, no refraction code
//! without glass, no glossy sampling without rough mirrors or glass, a pinhole without an
//! aperture, one sample and no jitter when nothing needs more, no time sampling without
//! motion. `vkrt render --plan` prints it; `--all-effects` compiles and runs everything
//! (the data still decides, so a scene that uses none of the extras renders the same image).

use std::fmt;

use serde::Serialize;

use crate::accel::device::AccelChoice;

use crate::scene::{Effects, Scene};

/// What the caller asks for on top of the scene.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RenderOptions {
    /// Image width in pixels (default: the scene's).
    pub width: Option<u32>,
    /// Image height in pixels (default: the scene's).
    pub height: Option<u32>,
    /// Samples per pixel (default: the scene's; 1 where no effect needs more).
    pub spp: Option<u32>,
    /// Force every pass and shader branch on (for the plan's equality test and for
    /// measuring what the plan saves).
    pub all_effects: bool,
    /// The structure the renderer traces and how it is walked.
    pub accel: AccelChoice,
    /// Trace one structure over every primitive even where meshes repeat (else such a
    /// scene is traced as two levels where it can be: [`Plan::levels`]).
    pub flatten: bool,
    /// The most primitives one structure may hold (`None`: no limit). A larger scene is
    /// traced as two levels, what no repeated mesh holds cut into pieces of at most this
    /// many ([`TwoLevelScene::of_within`](crate::accel::two_levels::TwoLevelScene::of_within)).
    /// [`RenderOptions::for_device`] sets it from the device's binding limit.
    pub max_level_primitives: Option<usize>,
}

impl RenderOptions {
    /// These options with [`RenderOptions::max_level_primitives`], where unset, what one
    /// binding of `ctx`'s device holds of this structure
    /// ([`max_level_primitives`](crate::accel::two_levels::max_level_primitives)).
    pub fn for_device(self, ctx: &crate::gpu::Context) -> Self {
        let max = crate::accel::two_levels::max_level_primitives(ctx, self.accel.kind);
        Self {
            max_level_primitives: self.max_level_primitives.or(Some(max)),
            ..self
        }
    }
}

/// Pixels × samples × bounce tree bounded by this many rays per wave (queue capacity).
pub const WAVE_RAYS: usize = 1 << 19;
/// Largest occlusion-query buffer per wave, bytes (under lavapipe's 128 MiB per buffer).
pub const WAVE_SHADOW_BYTES: usize = 96 << 20;

/// What a render runs, decided from the scene and the options: image, samples, passes
/// and shader switches (`vkrt render --plan` prints it).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Plan {
    /// The effects the scene calls for (`Scene::effects`).
    pub effects: Vec<&'static str>,
    /// Every pass and shader branch forced on ([`RenderOptions::all_effects`]).
    pub all_effects: bool,
    /// The structure traced and its walk (the `ACCEL_KIND` of the tracing kernels).
    pub accel: AccelChoice,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Samples per pixel (1 where no effect of the scene needs more).
    pub spp: u32,
    /// Bounces after the camera hit (0 when no effect needs secondary rays).
    pub max_depth: u32,
    /// Shader switches (specialization constants).
    pub lights: bool,
    /// Sphere and quad lights sampled over their area and seen by rays (`AREA_LIGHTS`).
    pub area_lights: bool,
    /// Perfect mirror reflection (`REFLECTION`).
    pub reflection: bool,
    /// Refraction, Fresnel-weighted where the material asks (`REFRACTION`).
    pub refraction: bool,
    /// Reflection and refraction sampled in a cone that widens with roughness (`GLOSSY`;
    /// Cook et al. 1984, distributed ray tracing).
    pub glossy: bool,
    /// Ambient-occlusion queries in place of the unoccluded ambient term (`AO`).
    pub ambient_occlusion: bool,
    /// Emissive surfaces (`EMISSION`).
    pub emission: bool,
    /// Secondary rays spawned, compacted and gathered (`BOUNCES`): `max_depth > 0`.
    pub bounces: bool,
    /// Thin-lens camera rays: depth of field (`THIN_LENS`).
    pub thin_lens: bool,
    /// Camera samples jittered over the pixel: antialiasing (`JITTER`).
    pub jitter: bool,
    /// Ray times sampled over the open shutter: motion blur (`MOTION`).
    pub motion: bool,
    /// Shining lights and ambient-occlusion rays: occlusion queries per path vertex.
    pub n_lights: u32,
    /// Ambient-occlusion queries per path vertex (0 without ambient occlusion).
    pub ao_samples: u32,
    /// Occlusion-query slots per queue ray: `n_lights + ao_samples`.
    pub shadow_slots: u32,
    /// Children one ray can spawn (2 with refraction: reflected + refracted).
    pub branching: u32,
    /// Pixels traced together (one sample each) at first; smaller after an overflow.
    pub wave_pixels: u32,
    /// Rays a wave's queue holds at any bounce.
    pub queue_capacity: usize,
    /// The passes that run, in order.
    pub passes: Vec<&'static str>,
    /// Notes for the user (e.g. a requested spp that the scene does not need).
    pub notes: Vec<String>,
    /// 2: the scene is traced as two levels (a mesh repeats: one bottom level per repeated
    /// or moving mesh, an instance per copy, `trace::instanced`); 1: one structure.
    pub levels: u32,
    /// Over two levels, where the scene is larger than one structure may hold: the most
    /// primitives in each piece the rest is cut into ([`RenderOptions::max_level_primitives`]).
    pub pieces_of: Option<usize>,
}

/// Why a scene cannot be rendered.
#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    /// The image has no pixels: the width and height asked for.
    #[error("image size {0}x{1}: width and height must be at least 1")]
    EmptyImage(u32, u32),
}

impl Plan {
    /// Plans the render of `scene` with `opt`; errors when the image would have no pixels.
    pub fn new(scene: &Scene, opt: &RenderOptions) -> Result<Self, PlanError> {
        let fx: Effects = scene.effects();
        let all = opt.all_effects;
        let s = &scene.settings;
        let mut notes = Vec::new();
        let requested_spp = opt.spp.unwrap_or(s.spp).max(1);
        let spp = if fx.needs_multiple_samples() {
            requested_spp
        } else {
            if requested_spp > 1 {
                notes.push(format!(
                    "{requested_spp} samples per pixel requested, but no effect of this scene \
                     needs more than one: rendering 1"
                ));
            }
            1
        };
        let secondary = fx.reflection || fx.refraction || fx.glossy;
        let max_depth = if secondary || all { s.max_depth } else { 0 };
        let shining = scene
            .lights
            .iter()
            .filter(|l| l.power().max_element() > 0.0)
            .count() as u32;
        let lights = fx.hard_shadows || fx.soft_shadows || (all && shining > 0);
        let n_lights = if lights { shining } else { 0 };
        let ao = fx.ambient_occlusion;
        let ao_samples = if ao { s.ao.samples } else { 0 };
        let shadow_slots = n_lights + ao_samples;
        let refraction = fx.refraction || all;
        let branching = if refraction { 2u32 } else { 1 };
        let bounces = max_depth > 0 && (secondary || all);
        let queue_capacity =
            (WAVE_SHADOW_BYTES / (48 * shadow_slots.max(1) as usize)).clamp(1, WAVE_RAYS);
        let (width, height) = (opt.width.unwrap_or(s.width), opt.height.unwrap_or(s.height));
        // Waves start with room for the queue to grow 4× (two branching bounces); a wave that
        // outgrows its queue stops, and the renderer redoes the sample with smaller waves.
        if width == 0 || height == 0 {
            return Err(PlanError::EmptyImage(width, height));
        }
        // Without bounces a wave's queue holds its camera rays only: no more than the image.
        let queue_capacity = match bounces {
            true => queue_capacity,
            false => queue_capacity.min(width as usize * height as usize),
        };
        let depth = if bounces { max_depth } else { 0 };
        let growth = (branching as usize).pow(depth.min(2));
        let wave_pixels = (queue_capacity / growth)
            .min(width as usize * height as usize)
            .max(1) as u32;
        let levels = levels(scene, opt, fx.motion_blur || all, &mut notes);
        let pieces_of = opt
            .max_level_primitives
            .filter(|&max| levels == 2 && scene.triangle_count() + scene.spheres.len() > max);
        let mut passes = vec!["camera", "extend", "shade"];
        if shadow_slots > 0 {
            passes.push("shadow");
        }
        passes.push("accumulate");
        if bounces {
            passes.extend(["compact", "gather"]);
        }
        passes.push("tonemap");
        Ok(Self {
            effects: fx.names(),
            all_effects: all,
            accel: opt.accel,
            width,
            height,
            spp,
            max_depth: if bounces { max_depth } else { 0 },
            lights,
            area_lights: fx.soft_shadows || (all && lights),
            reflection: fx.reflection || all,
            refraction,
            glossy: fx.glossy || all,
            ambient_occlusion: ao || all,
            emission: fx.emission || all,
            bounces,
            thin_lens: fx.depth_of_field || all,
            jitter: (fx.antialiasing && spp > 1) || all,
            motion: fx.motion_blur || all,
            n_lights,
            ao_samples,
            shadow_slots,
            branching,
            wave_pixels,
            queue_capacity,
            passes,
            notes,
            levels,
            pieces_of,
        })
    }

    /// Waves per sample with waves of `wave_pixels`.
    pub fn waves_of(&self, wave_pixels: u32) -> u32 {
        ((self.width as u64 * self.height as u64).div_ceil(wave_pixels.max(1) as u64)) as u32
    }

    /// Waves per sample at the plan's wave size.
    pub fn waves(&self) -> u32 {
        self.waves_of(self.wave_pixels)
    }
}

/// How many levels the scene is traced as: two where a mesh repeats or the scene is larger
/// than one structure may hold, and the two levels can serve the render, with a note where
/// they cannot.
fn levels(scene: &Scene, opt: &RenderOptions, motion: bool, notes: &mut Vec<String>) -> u32 {
    use crate::accel::device::AccelKind;
    let repeats = scene.mesh_groups().iter().any(|g| g.len() > 1);
    let max = opt.max_level_primitives.unwrap_or(usize::MAX);
    let too_large = scene.triangle_count() + scene.spheres.len() > max;
    if opt.flatten || !(repeats || too_large) {
        return 1;
    }
    let why_flat = (opt.accel.kind == AccelKind::Driver && motion)
        .then_some("the driver's levels do not move over the shutter");
    match why_flat {
        Some(why) => {
            let what = match repeats {
                true => "meshes repeat",
                false => "the scene is larger than one structure may hold",
            };
            notes.push(format!("{what}, but {why}: one structure"));
            1
        }
        None => 2,
    }
}

impl fmt::Display for Plan {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let on = |b: bool| if b { "on" } else { "off" };
        writeln!(
            f,
            "effects the scene calls for: {}",
            if self.effects.is_empty() {
                "none".to_string()
            } else {
                self.effects.join(", ")
            }
        )?;
        if self.all_effects {
            writeln!(f, "--all-effects: every pass and shader branch forced on")?;
        }
        writeln!(
            f,
            "image {}x{}, {} sample(s)/pixel, {} bounce(s), waves of {} pixels ({} per sample, \
             queues of {} rays)",
            self.width,
            self.height,
            self.spp,
            self.max_depth,
            self.wave_pixels,
            self.waves(),
            self.queue_capacity
        )?;
        writeln!(f, "passes: {}", self.passes.join(" → "))?;
        if self.levels == 2 {
            writeln!(
                f,
                "structure: two levels (a bottom level per repeated or moving mesh, an \
                 instance per copy{}{})",
                match self.pieces_of {
                    Some(n) => format!("; the rest in pieces of at most {n} primitives"),
                    None => String::new(),
                },
                if self.effects.contains(&"motion_blur") {
                    "; moving instances in time steps over the shutter, at most 1° of turn apart"
                } else {
                    ""
                }
            )?;
        }
        writeln!(
            f,
            "camera: {}, jitter {}, time sampling {}",
            if self.thin_lens {
                "thin lens"
            } else {
                "pinhole"
            },
            on(self.jitter),
            on(self.motion)
        )?;
        writeln!(
            f,
            "shading: lights {} ({} shining, area sampling {}), ambient occlusion {} ({} rays), \
             emission {}",
            on(self.lights),
            self.n_lights,
            on(self.area_lights),
            on(self.ambient_occlusion),
            self.ao_samples,
            on(self.emission)
        )?;
        writeln!(
            f,
            "secondary rays: reflection {}, refraction {}, glossy {}",
            on(self.reflection),
            on(self.refraction),
            on(self.glossy)
        )?;
        for n in &self.notes {
            writeln!(f, "note: {n}")?;
        }
        Ok(())
    }
}
