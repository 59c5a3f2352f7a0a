//! Which rendering effects a scene calls for, and its summary.
//!
//! The renderer builds only the passes and shader variants a scene needs: no
//! refraction kernel without glass, no shadow rays without lights, a pinhole
//! camera without depth of field. [`Effects`] is that decision, made once here
//! from the scene data so the CLI (`vkrt scene`) and the renderer agree. Only
//! materials actually used by some triangle or sphere count, and
//! reflection/refraction need `max_depth ≥ 1` to be traced at all.

use std::fmt;

use serde::Serialize;

use super::model::MeshMaterials;
use super::Scene;

/// The effects a scene calls for. Names (see [`Effects::names`]) are
/// stable: the CLI prints them and tests match on them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Effects {
    /// Point or directional lights with non-zero power: shadow rays to a
    /// point.
    pub hard_shadows: bool,
    /// Sphere or quad lights with non-zero power: shadow rays sampled over
    /// an area.
    pub soft_shadows: bool,
    /// Mirror reflection (perfect), or glass with Fresnel reflection.
    pub reflection: bool,
    /// Blurred reflection or refraction (roughness > 0).
    pub glossy: bool,
    /// Refraction through transmissive materials.
    pub refraction: bool,
    /// Several jittered samples per pixel (`antialias` and `spp > 1`).
    pub antialiasing: bool,
    /// Thin-lens camera (`aperture > 0`).
    pub depth_of_field: bool,
    /// Moving objects and an open shutter (`shutter_close > shutter_open`).
    pub motion_blur: bool,
    /// Ambient occlusion.
    pub ambient_occlusion: bool,
    /// Emissive surfaces.
    pub emission: bool,
}

impl Effects {
    /// All effect names, in a fixed order.
    pub const ALL_NAMES: [&'static str; 10] = [
        "hard_shadows",
        "soft_shadows",
        "reflection",
        "glossy",
        "refraction",
        "antialiasing",
        "depth_of_field",
        "motion_blur",
        "ambient_occlusion",
        "emission",
    ];

    fn flags(&self) -> [bool; 10] {
        [
            self.hard_shadows,
            self.soft_shadows,
            self.reflection,
            self.glossy,
            self.refraction,
            self.antialiasing,
            self.depth_of_field,
            self.motion_blur,
            self.ambient_occlusion,
            self.emission,
        ]
    }

    /// Names of the effects that are on, in the order of
    /// [`Effects::ALL_NAMES`].
    pub fn names(&self) -> Vec<&'static str> {
        Self::ALL_NAMES
            .iter()
            .zip(self.flags())
            .filter(|(_, on)| *on)
            .map(|(n, _)| *n)
            .collect()
    }

    /// Whether the named effect is on (false for unknown names).
    pub fn has(&self, name: &str) -> bool {
        Self::ALL_NAMES
            .iter()
            .zip(self.flags())
            .any(|(n, on)| *n == name && on)
    }

    /// Whether the renderer needs more than one sample per pixel.
    pub fn needs_multiple_samples(&self) -> bool {
        self.soft_shadows
            || self.glossy
            || self.antialiasing
            || self.depth_of_field
            || self.motion_blur
            || self.ambient_occlusion
    }
}

impl Scene {
    /// Ids of materials used by at least one triangle or sphere.
    pub fn used_materials(&self) -> Vec<bool> {
        let mut used = vec![false; self.materials.len()];
        let mut mark = |id: u32| {
            if let Some(u) = used.get_mut(id as usize) {
                *u = true;
            }
        };
        for s in &self.spheres {
            mark(s.material);
        }
        for m in &self.meshes {
            if m.indices.is_empty() {
                continue;
            }
            match &m.materials {
                MeshMaterials::Single(id) => mark(*id),
                MeshMaterials::PerTriangle(ids) => ids.iter().for_each(|&id| mark(id)),
            }
        }
        used
    }

    /// Which effects this scene calls for.
    pub fn effects(&self) -> Effects {
        let used = self.used_materials();
        let mats = || {
            self.materials
                .iter()
                .zip(&used)
                .filter(|(_, u)| **u)
                .map(|(m, _)| m)
        };
        let bounces = self.settings.max_depth >= 1;
        let shining = |l: &&super::Light| l.power().max_element() > 0.0;
        let moving = self
            .meshes
            .iter()
            .any(|m| !m.motion.is_static() && !m.indices.is_empty())
            || self.spheres.iter().any(|s| !s.motion.is_static());
        Effects {
            hard_shadows: self.lights.iter().filter(shining).any(|l| !l.is_area()),
            soft_shadows: self.lights.iter().filter(shining).any(|l| l.is_area()),
            reflection: bounces && mats().any(|m| m.reflects() && m.roughness == 0.0),
            glossy: bounces && mats().any(|m| m.is_glossy()),
            refraction: bounces && mats().any(|m| m.refracts()),
            antialiasing: self.settings.antialias && self.settings.spp > 1,
            depth_of_field: self.camera.aperture_radius > 0.0,
            motion_blur: moving && self.camera.shutter_close > self.camera.shutter_open,
            ambient_occlusion: self.settings.ao.enabled
                && self.settings.ao.samples > 0
                && self.settings.ao.radius > 0.0,
            emission: mats().any(|m| m.emits()),
        }
    }

    /// Counts, bounds and effects: the JSON of `vkrt scene FILE --json`.
    pub fn summary(&self) -> SceneSummary {
        let b = self.bounds();
        let (min, max) = if b.is_empty() {
            ([0.0; 3], [0.0; 3])
        } else {
            (b.min.to_array(), b.max.to_array())
        };
        let s = &self.settings;
        let groups = self.mesh_groups();
        SceneSummary {
            triangles: self.triangle_count() as u64,
            spheres: self.spheres.len() as u64,
            lights: self.lights.len() as u64,
            materials: self.materials.len() as u64,
            meshes: self.meshes.len() as u64,
            instances: groups
                .iter()
                .filter(|g| g.len() > 1)
                .map(|g| g.len() as u64)
                .sum(),
            unique_triangles: groups
                .iter()
                .map(|g| self.meshes[g[0]].indices.len() as u64)
                .sum(),
            bounds: BoundsSummary { min, max },
            effects: self
                .effects()
                .names()
                .into_iter()
                .map(str::to_owned)
                .collect(),
            width: s.width,
            height: s.height,
            spp: s.spp,
            max_depth: s.max_depth,
            animation: self.animation.map(|a| AnimationSummary {
                fps: a.fps,
                frames: a.frames,
                duration: a.duration(),
            }),
        }
    }
}

/// World bounds as plain arrays (for JSON).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct BoundsSummary {
    /// Lower corner.
    pub min: [f32; 3],
    /// Upper corner.
    pub max: [f32; 3],
}

/// Frames of an animated scene (for JSON).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct AnimationSummary {
    /// Frames per second.
    pub fps: f32,
    /// Number of frames.
    pub frames: u32,
    /// `frames / fps`, seconds.
    pub duration: f32,
}

/// What `vkrt scene FILE` prints. Serializes to JSON with these field
/// names; `Display` gives the human version.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SceneSummary {
    /// Triangles over all meshes.
    pub triangles: u64,
    /// Analytic spheres.
    pub spheres: u64,
    /// Lights.
    pub lights: u64,
    /// Materials.
    pub materials: u64,
    /// Meshes.
    pub meshes: u64,
    /// Meshes placed as instances of a shared bottom level: those whose geometry another
    /// mesh repeats ([`Scene::mesh_groups`]).
    pub instances: u64,
    /// Triangles with every repeated mesh counted once: what the structures hold.
    pub unique_triangles: u64,
    /// World bounds at shutter open (zeros for an empty scene).
    pub bounds: BoundsSummary,
    /// [`Effects::names`].
    pub effects: Vec<String>,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Samples per pixel.
    pub spp: u32,
    /// Maximum ray depth.
    pub max_depth: u32,
    /// Frames, when the scene is animated (absent from the JSON otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub animation: Option<AnimationSummary>,
}

impl SceneSummary {
    /// The human-readable summary (same as `Display`).
    pub fn to_text(&self) -> String {
        self.to_string()
    }
}

impl fmt::Display for SceneSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "triangles: {}", self.triangles)?;
        writeln!(f, "spheres:   {}", self.spheres)?;
        writeln!(f, "meshes:    {}", self.meshes)?;
        if self.instances > 0 {
            writeln!(
                f,
                "instances: {} (unique triangles: {})",
                self.instances, self.unique_triangles
            )?;
        }
        writeln!(f, "lights:    {}", self.lights)?;
        writeln!(f, "materials: {}", self.materials)?;
        let [a, b, c] = self.bounds.min;
        let [x, y, z] = self.bounds.max;
        writeln!(f, "bounds:    [{a}, {b}, {c}] .. [{x}, {y}, {z}]")?;
        writeln!(
            f,
            "image:     {}x{}, {} spp, max depth {}",
            self.width, self.height, self.spp, self.max_depth
        )?;
        if let Some(a) = &self.animation {
            writeln!(
                f,
                "animation: {} frames at {} fps ({} s)",
                a.frames, a.fps, a.duration
            )?;
        }
        let effects = if self.effects.is_empty() {
            "none".to_owned()
        } else {
            self.effects.join(", ")
        };
        write!(f, "effects:   {effects}")
    }
}
