//! The renderer: a plan from the scene ([`plan`]), the scene flattened for the GPU
//! ([`RenderScene`]), the wavefront renderer ([`gpu`]) and its CPU twin ([`cpu`]), and
//! image output ([`output`]).
//!
//! Shading model (Whitted with distributed effects; `scene::material` documents the terms):
//!
//! ```text
//! L = emission + ambient·diffuse            (× unoccluded fraction with ambient occlusion)
//!   + Σ_lights (diffuse·cosθ + specular·max(R·V, 0)^shininess) · E_light · visible
//!   + mirror·L(reflected) + transmission·L(refracted)   (Fresnel-weighted for glass)
//! ```
//!
//! where `E_light` is `I/d²` for point lights, `I` for directional ones and one area sample
//! `L_e·cosθ_l·A/d²` per path vertex for sphere and quad lights (soft over the samples of a
//! pixel). Diffuse albedo is used without 1/π, as in Bidmon (2010).

pub mod animate;
pub mod cpu;
pub mod gpu;
mod levels;
pub mod output;
pub mod plan;
pub mod types;

use glam::Vec3;
use serde::Serialize;

use crate::accel::device::AccelChoice;
use crate::accel::host::HostStructure;
use crate::accel::primitives::TraceGeometry;
use crate::accel::two_levels::TwoLevelScene;
use crate::scene::{Light, Scene};
pub use levels::RenderLevels;

pub use plan::{Plan, RenderOptions};
use types::{GpuLight, GpuMaterial, RenderParams};

/// Rays traced per kind.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct RayCounts {
    /// Camera rays (one per pixel and sample).
    pub primary: u64,
    /// Perfect mirror reflection rays.
    pub reflection: u64,
    /// Refraction rays (glossy ones included).
    pub refraction: u64,
    /// Glossy reflection rays (Cook et al. 1984, distributed ray tracing).
    pub glossy: u64,
    /// Occlusion queries towards lights.
    pub shadow: u64,
    /// Ambient-occlusion queries.
    pub ambient_occlusion: u64,
    /// Rays that ran out of traversal steps (counted as misses).
    pub exhausted: u64,
}

impl RayCounts {
    /// The counts in the `counters` words read back from the device ([`types::counter`]).
    pub fn from_counters(c: &[u32]) -> Self {
        use types::counter as k;
        Self {
            primary: c[k::PRIMARY] as u64,
            reflection: c[k::REFLECTION] as u64,
            refraction: c[k::REFRACTION] as u64,
            glossy: c[k::GLOSSY] as u64,
            shadow: c[k::SHADOW] as u64,
            ambient_occlusion: c[k::AO] as u64,
            exhausted: c[k::EXHAUSTED] as u64,
        }
    }

    /// Secondary rays (reflection, refraction, glossy).
    pub fn secondary(&self) -> u64 {
        self.reflection + self.refraction + self.glossy
    }

    /// Every ray traced: primary, secondary, shadow and ambient occlusion (`exhausted` ones
    /// are among them).
    pub fn total(&self) -> u64 {
        self.primary + self.secondary() + self.shadow + self.ambient_occlusion
    }
}

/// The structure a render traces.
pub enum RenderAccel {
    /// Built on the host (the CPU twins, tests).
    Host(HostStructure),
    /// Built by the GPU renderer in its first submission and traced where it lies (the
    /// CLI's path; the CPU twin builds the same structure on the host first).
    OnDevice(AccelChoice),
}

/// The scene as the renderer reads it: geometry and its structure, materials, lights,
/// constants.
pub struct RenderScene {
    /// The primitives as traced: at shutter open, or over the shutter where the plan blurs
    /// motion; empty over two levels.
    pub geometry: TraceGeometry,
    /// The structure over `geometry`, or which one the device builds.
    pub accel: RenderAccel,
    /// The scene as two levels ([`RenderScene::on_device`] where the plan traces two); then
    /// `geometry` is empty, and `prim_material` and `tri_normals` are the level materials
    /// and normals, only the bottom levels' that need them ([`RenderLevels::new`]).
    pub levels: Option<RenderLevels>,
    /// Material of every primitive (triangles, then spheres).
    pub prim_material: Vec<u32>,
    /// Shading normals, 9 floats per triangle (zero when the mesh has none).
    pub tri_normals: Vec<f32>,
    /// Every material of the scene, packed as the shade kernel reads it.
    pub materials: Vec<GpuMaterial>,
    /// The lights the plan shades with (those with non-zero power).
    pub lights: Vec<GpuLight>,
    /// The render's constants: camera, image, sampling.
    pub params: RenderParams,
}

/// Weight below which a secondary ray is not spawned.
pub const MIN_WEIGHT: f32 = 1e-4;

impl RenderScene {
    /// Flattens `scene` for `plan`; `build` makes the structure of the geometry (the GPU
    /// kd-tree builder or the CPU BVH builder in the renderer, any builder in tests).
    pub fn new<E>(
        scene: &Scene,
        plan: &Plan,
        build: impl FnOnce(&TraceGeometry) -> Result<RenderAccel, E>,
    ) -> Result<Self, E> {
        let scene = &held(scene);
        let cam = &scene.camera;
        let geometry = if plan.motion && cam.shutter_close > cam.shutter_open {
            TraceGeometry::over_interval(scene, cam.shutter_open, cam.shutter_close)
        } else {
            TraceGeometry::at_time(scene, cam.shutter_open)
        };
        let normal_time = if geometry.has_motion() {
            0.0
        } else {
            cam.shutter_open
        };
        let accel = build(&geometry)?;
        let mut prim_material = scene.triangle_materials();
        prim_material.extend(scene.spheres.iter().map(|s| s.material));
        let tri_normals = scene
            .triangle_normals_world(normal_time)
            .iter()
            .zip(
                &scene
                    .meshes
                    .iter()
                    .flat_map(|m| std::iter::repeat_n(m.normals.is_empty(), m.indices.len()))
                    .collect::<Vec<_>>(),
            )
            .flat_map(|(n, &flat)| {
                // Meshes without normals: zeros, so the kernel uses the geometric normal of
                // the triangle at the ray's time.
                let n = if flat { [Vec3::ZERO; 3] } else { *n };
                n.into_iter().flat_map(|v| v.to_array())
            })
            .collect();
        let (materials, lights, params) = constants(scene, plan);
        Ok(Self {
            geometry,
            accel,
            levels: None,
            prim_material,
            tri_normals,
            materials,
            lights,
            params,
        })
    }

    /// `scene` for `plan`, its structures built by the renderer on the device: as two levels
    /// where the plan says so ([`Plan::levels`]; no flat copy of the primitives is made),
    /// else flat, as [`RenderScene::new`] with [`RenderAccel::OnDevice`].
    pub fn on_device(scene: &Scene, plan: &Plan) -> Self {
        let flat = || {
            let on_device = |_: &TraceGeometry| {
                Ok::<_, std::convert::Infallible>(RenderAccel::OnDevice(plan.accel))
            };
            match Self::new(scene, plan, on_device) {
                Ok(rs) => rs,
                Err(never) => match never {},
            }
        };
        if plan.levels != 2 {
            return flat();
        }
        let scene = &held(scene);
        let time = scene.camera.shutter_open;
        let max_per_level = plan.pieces_of.unwrap_or(usize::MAX);
        let Some(two) = TwoLevelScene::of_moving(scene, time, max_per_level) else {
            return flat();
        };
        let (levels, prim_material, tri_normals) =
            RenderLevels::new(scene, two, time, shutter(scene, plan));
        let (materials, lights, params) = constants(scene, plan);
        Self {
            geometry: TraceGeometry::default(),
            accel: RenderAccel::OnDevice(plan.accel),
            levels: Some(levels),
            prim_material,
            tri_normals,
            materials,
            lights,
            params,
        }
    }
}

impl RenderScene {
    /// This scene made `scene` (the same scene, moved: an animation's next frame) for
    /// `plan`: over two levels only the instances, their placements and the constants
    /// change, in place (nothing the size of the scene is made again); flat, everything.
    pub fn move_to(&mut self, scene: &Scene, plan: &Plan) {
        match &mut self.levels {
            Some(levels) => {
                let scene = &held(scene);
                let cam = &scene.camera;
                levels.move_to(scene, [cam.shutter_open, cam.shutter_close]);
                (self.materials, self.lights, self.params) = constants(scene, plan);
            }
            None => *self = Self::on_device(scene, plan),
        }
    }
}

/// The shutter interval where `plan` blurs motion over an open shutter.
fn shutter(scene: &Scene, plan: &Plan) -> Option<[f32; 2]> {
    let cam = &scene.camera;
    (plan.motion && cam.shutter_close > cam.shutter_open)
        .then_some([cam.shutter_open, cam.shutter_close])
}

/// `scene` with its keyframed meshes held at their pose at shutter open for the exposure:
/// the traced motion model is rigid velocity + orbit (scene::animation).
fn held(scene: &Scene) -> std::borrow::Cow<'_, Scene> {
    if scene.has_keyframe_motion() {
        let mut s = scene.clone();
        s.hold_keyframes(scene.camera.shutter_open);
        std::borrow::Cow::Owned(s)
    } else {
        std::borrow::Cow::Borrowed(scene)
    }
}

/// The materials, the lights the plan shades with, and the render's constants.
fn constants(scene: &Scene, plan: &Plan) -> (Vec<GpuMaterial>, Vec<GpuLight>, RenderParams) {
    let cam = &scene.camera;
    let materials = scene
        .materials
        .iter()
        .map(|m| GpuMaterial {
            diffuse: m.diffuse.extend(m.shininess).to_array(),
            specular: m.specular.extend(m.roughness).to_array(),
            mirror: m.mirror.extend(m.transmission).to_array(),
            emission: m.emission.extend(m.ior).to_array(),
            flags: [m.fresnel as u32, 0, 0, 0],
        })
        .collect();
    let lights: Vec<GpuLight> = if plan.lights {
        scene
            .lights
            .iter()
            .filter(|l| l.power().max_element() > 0.0)
            .map(gpu_light)
            .collect()
    } else {
        Vec::new()
    };
    let (forward, right, up) = cam.basis();
    let tan = (cam.fov.to_radians() * 0.5).tan();
    let aspect = plan.width as f32 / plan.height as f32;
    let s = &scene.settings;
    let params = RenderParams {
        cam_pos: cam.position.extend(0.0).to_array(),
        cam_forward: forward.extend(0.0).to_array(),
        cam_right: (right * tan * aspect).extend(0.0).to_array(),
        cam_up: (up * tan).extend(0.0).to_array(),
        background: s.background.extend(0.0).to_array(),
        ambient: scene.ambient.extend(0.0).to_array(),
        width: plan.width,
        height: plan.height,
        spp: plan.spp,
        max_depth: plan.max_depth,
        n_lights: lights.len() as u32,
        ao_samples: plan.ao_samples,
        shadow_slots: lights.len() as u32 + plan.ao_samples,
        jitter: (scene.effects().antialiasing && plan.spp > 1) as u32,
        aperture: cam.aperture_radius,
        focus_distance: cam.focus_distance,
        shutter_open: cam.shutter_open,
        shutter_close: if plan.motion {
            cam.shutter_close
        } else {
            cam.shutter_open
        },
        ao_radius: s.ao.radius,
        min_weight: MIN_WEIGHT,
        pad: [0; 2],
    };
    (materials, lights, params)
}

fn gpu_light(l: &Light) -> GpuLight {
    use types::*;
    let p = l.power().extend(0.0).to_array();
    let v4 = |v: Vec3, w: f32| v.extend(w).to_array();
    match *l {
        Light::Point { position, .. } => GpuLight {
            kind: [LIGHT_POINT, 0, 0, 0],
            p: v4(position, 0.0),
            power: p,
            ..Default::default()
        },
        Light::Directional { direction, .. } => GpuLight {
            kind: [LIGHT_DIRECTIONAL, 0, 0, 0],
            p: v4(direction, 0.0),
            power: p,
            ..Default::default()
        },
        Light::Sphere { center, radius, .. } => GpuLight {
            kind: [LIGHT_SPHERE, 0, 0, 0],
            p: v4(center, 0.0),
            u: [0.0, 0.0, 0.0, radius],
            power: p,
            ..Default::default()
        },
        Light::Quad {
            corner,
            edge_u,
            edge_v,
            ..
        } => GpuLight {
            kind: [LIGHT_QUAD, 0, 0, 0],
            p: v4(corner, 0.0),
            u: v4(edge_u, 0.0),
            v: v4(edge_v, 0.0),
            power: p,
        },
    }
}

/// One pass of a render: rays it handled and GPU time.
#[derive(Clone, Debug, Serialize)]
pub struct PassReport {
    /// The pass, as in [`Plan::passes`].
    pub name: &'static str,
    /// Rays the pass handled (0 for the tone map).
    pub rays: u64,
    /// GPU milliseconds of the pass over every sample (timestamps).
    pub ms: f64,
    /// The pass's milliseconds per sample: count, median and range (the tone map: its one
    /// run). Compilation is not in them: it runs in the `warm-up` scope before sample 0.
    pub per_sample: crate::gpu::Spread,
    /// Compute-shader invocations of the pass over every sample, where counted
    /// ([`crate::gpu::Context::set_pipeline_statistics`]): the work its indirect dispatches
    /// really did.
    pub invocations: Option<u64>,
    /// The bytes the pass read and wrote over every sample, where the host knows them
    /// ([`crate::gpu::PassBytes`]: its dispatches' grids are set on the host); `None` for the
    /// passes whose indirect dispatches take their grids from the device.
    pub bytes: Option<crate::gpu::PassBytes>,
}

/// A finished render with everything `vkrt render --json` reports.
pub struct Rendered {
    /// The plan the render ran.
    pub plan: Plan,
    /// The image, its ray counts and its GPU profile.
    pub image: gpu::GpuRender,
    /// The structure's build: GPU passes (timestamps) or the host builder's time.
    pub build_ms: f64,
    /// GPU time of all samples (timestamps), tone mapping included.
    pub render_ms: f64,
    /// Every pass of the plan, in order.
    pub passes: Vec<PassReport>,
    /// GPU milliseconds of the warm-up before the first sample: the kernels' dispatches on
    /// empty grids, where a driver compiling at first dispatch compiles them.
    pub warm_up_ms: f64,
}

impl Rendered {
    /// Rays per second over the render time, in millions.
    pub fn mrays_per_s(&self) -> f64 {
        let rays = self.image.counts.total() as f64;
        if self.render_ms > 0.0 {
            rays / (self.render_ms * 1e3)
        } else {
            0.0
        }
    }
}

/// Plans, builds the structure on the device and renders `scene`; `progress(done, spp)` after
/// every sample.
///
/// ```
/// use std::path::Path;
/// use vkrt::render::{render_scene, RenderOptions};
/// use vkrt::{Context, ContextOptions, Scene, TraceOptions};
///
/// # fn main() -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
/// let scene = Scene::from_toml_str(
///     r#"
///     [settings]
///     width = 32
///     height = 24
///     [camera]
///     position = [0.0, 0.0, 4.0]
///     look_at = [0.0, 0.0, 0.0]
///     [[lights]]
///     type = "point"
///     position = [2.0, 3.0, 4.0]
///     intensity = 30.0
///     [[spheres]]
///     center = [0.0, 0.0, 0.0]
///     radius = 1.0
///     "#,
///     Path::new("."),
/// )?
/// .scene;
/// # /*
/// let ctx = Context::new(&ContextOptions::default())?;
/// # */
/// # let ctx = Context::new(&ContextOptions::for_tests())?; // validation as the tests run it
/// let opt = RenderOptions::default();
/// let out = render_scene(&ctx, &scene, &opt, &TraceOptions::default(), |_, _| {})?;
/// // RGBA, row-major from the top left: the sphere is lit at the centre, the corner is
/// // background.
/// let px = |x: usize, y: usize| &out.image.rgba[4 * (y * 32 + x)..][..3];
/// assert!(px(16, 12).iter().any(|&c| c > 0));
/// assert_ne!(px(16, 12), px(0, 0));
/// assert!(out.plan.passes.contains(&"shadow"));
/// # let messages = ctx.take_validation_messages();
/// # assert!(messages.is_empty(), "validation: {messages:?}");
/// # Ok(())
/// # }
/// ```
pub fn render_scene(
    ctx: &crate::gpu::Context,
    scene: &Scene,
    opt: &RenderOptions,
    trace: &crate::trace::TraceOptions,
    progress: impl FnMut(u32, u32),
) -> Result<Rendered, Box<dyn std::error::Error + Send + Sync>> {
    let plan = Plan::new(scene, &opt.for_device(ctx))?;
    if plan.levels != 2 {
        crate::accel::primitives::TraceGeometry::check_flat_fits(ctx, scene)?;
    }
    let rs = RenderScene::on_device(scene, &plan);
    render_prepared(ctx, plan, rs, trace, progress)
}

/// [`render_scene`] of a scene it takes: the scene goes once what the render reads is made
/// of it (a large mesh is then never held twice on the host).
pub fn render_scene_owned(
    ctx: &crate::gpu::Context,
    scene: Scene,
    opt: &RenderOptions,
    trace: &crate::trace::TraceOptions,
    progress: impl FnMut(u32, u32),
) -> Result<Rendered, Box<dyn std::error::Error + Send + Sync>> {
    let plan = Plan::new(&scene, &opt.for_device(ctx))?;
    if plan.levels != 2 {
        crate::accel::primitives::TraceGeometry::check_flat_fits(ctx, &scene)?;
    }
    let rs = RenderScene::on_device(&scene, &plan);
    drop(scene);
    render_prepared(ctx, plan, rs, trace, progress)
}

/// [`render_scene`] of `rs`, made for `plan`.
fn render_prepared(
    ctx: &crate::gpu::Context,
    plan: Plan,
    rs: RenderScene,
    trace: &crate::trace::TraceOptions,
    mut progress: impl FnMut(u32, u32),
) -> Result<Rendered, Box<dyn std::error::Error + Send + Sync>> {
    // The structure is built on the device in the render's first submission (a scene in
    // pieces: its bottom levels one after another before it, `Renderer::render_owned`).
    let renderer = gpu::Renderer::new(ctx, &plan, trace)?;
    let spp = plan.spp;
    let image = renderer.render_owned(ctx, rs, &plan, |done| progress(done, spp))?;
    let warm_up_ms = image.profile.ms("warm-up").unwrap_or(0.0);
    let timed = image.profile.without("warm-up");
    let ms = |n: &str| timed.ms(n).unwrap_or(0.0);
    let c = image.counts;
    let traced = c.primary + c.secondary();
    let passes = plan
        .passes
        .iter()
        .map(|&name| PassReport {
            name,
            rays: match name {
                "camera" => c.primary,
                "extend" | "shade" | "accumulate" => traced,
                "shadow" => c.shadow + c.ambient_occlusion,
                "compact" | "gather" => c.secondary(),
                _ => 0,
            },
            ms: ms(&format!("render.{name}")),
            per_sample: crate::gpu::Spread::of(&match name {
                "tonemap" => timed.ms("render.tonemap").into_iter().collect(),
                _ => timed.ms_within(&format!("render.{name}"), "render.sample"),
            }),
            invocations: timed.invocations(&format!("render.{name}")),
            bytes: timed.bytes(&format!("render.{name}")),
        })
        .collect();
    let render_ms = ms("render.sample") + ms("render.tonemap");
    Ok(Rendered {
        warm_up_ms,
        plan,
        build_ms: image.build_ms.unwrap_or(0.0),
        image,
        render_ms,
        passes,
    })
}
