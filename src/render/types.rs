//! Records shared byte for byte with `glsl/render/common.glsl` (keep in sync; sizes are
//! asserted below and the render tests exercise every field).

use bytemuck::{Pod, Zeroable};

/// A ray of the wavefront queue (64 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PathRay {
    /// Origin (world space).
    pub o: [f32; 3],
    /// Start of the ray's interval along `d` (the kernels emit 0 and move the origin off the
    /// surface instead).
    pub tmin: f32,
    /// Direction, unit length.
    pub d: [f32; 3],
    /// End of the ray's interval along `d` (`+inf`: unbounded).
    pub tmax: f32,
    /// Throughput (RGB): what the radiance arriving along this ray is multiplied by.
    pub weight: [f32; 3],
    /// The pixel this path adds to, row-major from the top-left (`y · width + x`).
    pub pixel: u32,
    /// Time within the shutter at which the ray sees the scene (seconds).
    pub time: f32,
    /// Bounces before this ray (0: camera ray).
    pub depth: u32,
    /// State of this path's random stream ([`rnd`]); each child derives its own from it.
    pub seed: u32,
    /// Which kind of ray it is (`RAY_*`), for the per-kind ray counters.
    pub kind: u32,
}

/// An occlusion query and the radiance it adds when unoccluded (48 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ShadowRay {
    /// Origin: the shading point, moved off the surface.
    pub o: [f32; 3],
    /// Start of the query's interval along `d` (0).
    pub tmin: f32,
    /// Direction towards the light sample or the ambient-occlusion sample, unit length.
    pub d: [f32; 3],
    /// End of the interval: the distance to the light sample, `+inf` for a directional
    /// light, the occlusion radius for ambient occlusion.
    pub tmax: f32,
    /// Radiance (RGB) the query adds to its pixel when unoccluded, the path's throughput
    /// included; the shadow pass zeroes it when occluded.
    pub contrib: [f32; 3],
    /// [`SHADOW_NONE`] (an empty slot), [`SHADOW_LIGHT`] or [`SHADOW_AO`].
    pub kind: u32,
}

/// A material (80 bytes); see `Material` in `common.glsl` for the packing.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuMaterial {
    /// Lambertian albedo (xyz) and Phong shininess (w).
    pub diffuse: [f32; 4],
    /// Phong highlight colour (xyz) and roughness (w).
    pub specular: [f32; 4],
    /// Mirror reflectance (xyz) and transmission (w).
    pub mirror: [f32; 4],
    /// Emitted radiance (xyz) and index of refraction (w).
    pub emission: [f32; 4],
    /// x: 1 where the reflect/refract split follows the Fresnel equations; the rest 0.
    pub flags: [u32; 4],
}

/// A light (80 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuLight {
    /// x: the light's kind (`LIGHT_*`); the rest 0.
    pub kind: [u32; 4],
    /// Position (point), centre (sphere), corner (quad) or direction of travel
    /// (directional); w unused.
    pub p: [f32; 4],
    /// A quad's first edge; a sphere's radius in w.
    pub u: [f32; 4],
    /// A quad's second edge.
    pub v: [f32; 4],
    /// Colour · intensity (xyz).
    pub power: [f32; 4],
}

/// An instance as shading reads it, over two levels (128 bytes, `glsl/render/shade.comp`):
/// its bottom level, its transforms, its material, and how it moves over the shutter.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Placement {
    /// Rows of the object-to-world transform.
    pub object_to_world: [[f32; 4]; 3],
    /// Rows of its inverse (normals move by its transpose).
    pub world_to_object: [[f32; 4]; 3],
    /// Its bottom level (the index of its [`BottomShading`]), the bottom level's triangles,
    /// 0, and the instance's material (`u32::MAX`: each primitive's, in the level
    /// materials).
    pub info: [u32; 4],
    /// As the top level's record has it ([`crate::accel::instances::InstanceRecord::motion`]):
    /// steps (1: still; the transforms above), where its steps start among the levels'
    /// steps, the first step's time and `(steps - 1) / shutter` (as bits).
    pub motion: [u32; 4],
}

/// Where shading reads one bottom level's primitives and what it adds to them, over two
/// levels (32 bytes, `glsl/render/shade.comp`): device addresses of its triangles' vertices
/// and its spheres (the bottom level's own, as its walk reads them), and of its part of the
/// level normals and of the level materials (0: it has none, its triangles have no shading
/// normals; its primitives share the material of its instances' placements).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct BottomShading {
    /// 9 floats per triangle.
    pub verts: u64,
    /// Centre and radius per sphere (0 where it has none).
    pub spheres: u64,
    /// 9 floats per triangle.
    pub normals: u64,
    /// One per primitive, its triangles then its spheres.
    pub materials: u64,
}

/// Per-render constants (160 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct RenderParams {
    /// Camera position (lens centre).
    pub cam_pos: [f32; 4],
    /// Unit view direction.
    pub cam_forward: [f32; 4],
    /// Right axis scaled by `tan(fov / 2) · aspect`: the image's half-width at distance 1.
    pub cam_right: [f32; 4],
    /// Up axis scaled by `tan(fov / 2)`: the image's half-height at distance 1.
    pub cam_up: [f32; 4],
    /// Radiance (RGB) of rays that hit nothing.
    pub background: [f32; 4],
    /// The scene's ambient light (RGB), scaled by the diffuse albedo.
    pub ambient: [f32; 4],
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Samples per pixel.
    pub spp: u32,
    /// Bounces after the camera hit; a ray at this depth spawns no children.
    pub max_depth: u32,
    /// Lights in the lights buffer (those the plan shades with).
    pub n_lights: u32,
    /// Ambient-occlusion queries per path vertex (0: the ambient term is unoccluded).
    pub ao_samples: u32,
    /// Occlusion-query slots per queue ray: `n_lights + ao_samples`.
    pub shadow_slots: u32,
    /// 1: camera samples jittered over the pixel (antialiasing, `spp > 1`); 0: pixel centres.
    pub jitter: u32,
    /// Lens radius (world units); 0 is a pinhole.
    pub aperture: f32,
    /// Distance from the lens to the plane in focus, along the view direction.
    pub focus_distance: f32,
    /// Shutter opening time (seconds): the time of every ray without motion blur.
    pub shutter_open: f32,
    /// Shutter closing time (seconds); `shutter_open` where the plan does not blur motion.
    pub shutter_close: f32,
    /// Length of the ambient-occlusion queries (world units).
    pub ao_radius: f32,
    /// Throughput below which a child ray is not spawned ([`crate::render::MIN_WEIGHT`]).
    pub min_weight: f32,
    /// Padding to 160 bytes (zero).
    pub pad: [u32; 2],
}

const _: () = assert!(std::mem::size_of::<PathRay>() == 64);
const _: () = assert!(std::mem::size_of::<ShadowRay>() == 48);
const _: () = assert!(std::mem::size_of::<GpuMaterial>() == 80);
const _: () = assert!(std::mem::size_of::<GpuLight>() == 80);
const _: () = assert!(std::mem::size_of::<RenderParams>() == 160);
const _: () = assert!(std::mem::size_of::<Placement>() == 128);
const _: () = assert!(std::mem::size_of::<BottomShading>() == 32);

/// [`PathRay::kind`]: a camera ray.
pub const RAY_PRIMARY: u32 = 0;
/// [`PathRay::kind`]: a perfect mirror reflection.
pub const RAY_REFLECTION: u32 = 1;
/// [`PathRay::kind`]: a refraction (glossy ones included).
pub const RAY_REFRACTION: u32 = 2;
/// [`PathRay::kind`]: a reflection sampled in a cone that widens with roughness
/// (Cook et al. 1984, distributed ray tracing).
pub const RAY_GLOSSY: u32 = 3;

/// [`ShadowRay::kind`]: an empty slot (no query).
pub const SHADOW_NONE: u32 = 0;
/// [`ShadowRay::kind`]: a query towards a light (sample).
pub const SHADOW_LIGHT: u32 = 1;
/// [`ShadowRay::kind`]: an ambient-occlusion query.
pub const SHADOW_AO: u32 = 2;

/// [`GpuLight::kind`]: a point light.
pub const LIGHT_POINT: u32 = 0;
/// [`GpuLight::kind`]: a spherical area light.
pub const LIGHT_SPHERE: u32 = 1;
/// [`GpuLight::kind`]: a parallelogram area light.
pub const LIGHT_QUAD: u32 = 2;
/// [`GpuLight::kind`]: a directional light.
pub const LIGHT_DIRECTIONAL: u32 = 3;

/// Words of the `counters` buffer (`CNT_*` in `common.glsl`).
pub mod counter {
    /// Live rays in the queue.
    pub const QUEUE: usize = 0;
    /// Camera rays generated.
    pub const PRIMARY: usize = 1;
    /// Mirror reflection rays spawned.
    pub const REFLECTION: usize = 2;
    /// Refraction rays spawned.
    pub const REFRACTION: usize = 3;
    /// Glossy reflection rays spawned.
    pub const GLOSSY: usize = 4;
    /// Occlusion queries towards lights traced.
    pub const SHADOW: usize = 5;
    /// Ambient-occlusion queries traced.
    pub const AO: usize = 6;
    /// Rays that ran out of traversal steps (counted as misses).
    pub const EXHAUSTED: usize = 7;
    /// First of 3 words: the indirect dispatch's workgroups over the queue.
    pub const ARGS_QUEUE: usize = 8;
    /// First of 3 words: the indirect dispatch's workgroups over the queue's shadow slots.
    pub const ARGS_SHADOW: usize = 11;
    /// Set to 1 when a wave's children outgrew the queue: the host redoes the sample with
    /// smaller waves.
    pub const OVERFLOW: usize = 14;
    /// Words in the buffer.
    pub const WORDS: usize = 16;
}

/// `pcg` in `common.glsl` (Jarzynski & Olano 2020).
pub fn pcg(v: u32) -> u32 {
    let state = v.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277_803_737);
    (word >> 22) ^ word
}

/// `rnd` in `common.glsl`: uniform in [0, 1) with 24 bits.
pub fn rnd(s: &mut u32) -> f32 {
    *s = pcg(*s);
    (*s >> 8) as f32 * (1.0 / 16_777_216.0)
}
