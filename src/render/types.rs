//! Records shared byte for byte with `glsl/render/common.glsl` (keep in sync; sizes are
//! asserted below and the render tests exercise every field).

use bytemuck::{Pod, Zeroable};

/// A ray of the wavefront queue (64 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PathRay {
    pub o: [f32; 3],
    pub tmin: f32,
    pub d: [f32; 3],
    pub tmax: f32,
    pub weight: [f32; 3],
    pub pixel: u32,
    pub time: f32,
    pub depth: u32,
    pub seed: u32,
    pub kind: u32,
}

/// An occlusion query and the radiance it adds when unoccluded (48 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ShadowRay {
    pub o: [f32; 3],
    pub tmin: f32,
    pub d: [f32; 3],
    pub tmax: f32,
    pub contrib: [f32; 3],
    pub kind: u32,
}

/// A material (80 bytes); see `Material` in `common.glsl` for the packing.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuMaterial {
    pub diffuse: [f32; 4],
    pub specular: [f32; 4],
    pub mirror: [f32; 4],
    pub emission: [f32; 4],
    pub flags: [u32; 4],
}

/// A light (80 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuLight {
    pub kind: [u32; 4],
    pub p: [f32; 4],
    pub u: [f32; 4],
    pub v: [f32; 4],
    pub power: [f32; 4],
}

/// An instance as shading reads it, over two levels (128 bytes, `glsl/render/shade.comp`):
/// where its bottom level's primitives lie among the level primitives, its transforms, and
/// how it moves over the shutter.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Placement {
    /// Rows of the object-to-world transform.
    pub object_to_world: [[f32; 4]; 3],
    /// Rows of its inverse (normals move by its transpose).
    pub world_to_object: [[f32; 4]; 3],
    /// The bottom level's first level primitive, its triangles, its first sphere (in the
    /// level spheres), and the instance's material (`u32::MAX`: each primitive's).
    pub info: [u32; 4],
    /// As the top level's record has it ([`crate::accel::instances::InstanceRecord::motion`]):
    /// steps (1: still; the transforms above), where its steps start among the levels'
    /// steps, the first step's time and `(steps - 1) / shutter` (as bits).
    pub motion: [u32; 4],
}

/// Per-render constants (160 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct RenderParams {
    pub cam_pos: [f32; 4],
    pub cam_forward: [f32; 4],
    pub cam_right: [f32; 4],
    pub cam_up: [f32; 4],
    pub background: [f32; 4],
    pub ambient: [f32; 4],
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub max_depth: u32,
    pub n_lights: u32,
    pub ao_samples: u32,
    pub shadow_slots: u32,
    pub jitter: u32,
    pub aperture: f32,
    pub focus_distance: f32,
    pub shutter_open: f32,
    pub shutter_close: f32,
    pub ao_radius: f32,
    pub min_weight: f32,
    pub pad: [u32; 2],
}

const _: () = assert!(std::mem::size_of::<PathRay>() == 64);
const _: () = assert!(std::mem::size_of::<ShadowRay>() == 48);
const _: () = assert!(std::mem::size_of::<GpuMaterial>() == 80);
const _: () = assert!(std::mem::size_of::<GpuLight>() == 80);
const _: () = assert!(std::mem::size_of::<RenderParams>() == 160);
const _: () = assert!(std::mem::size_of::<Placement>() == 128);

pub const RAY_PRIMARY: u32 = 0;
pub const RAY_REFLECTION: u32 = 1;
pub const RAY_REFRACTION: u32 = 2;
pub const RAY_GLOSSY: u32 = 3;

pub const SHADOW_NONE: u32 = 0;
pub const SHADOW_LIGHT: u32 = 1;
pub const SHADOW_AO: u32 = 2;

pub const LIGHT_POINT: u32 = 0;
pub const LIGHT_SPHERE: u32 = 1;
pub const LIGHT_QUAD: u32 = 2;
pub const LIGHT_DIRECTIONAL: u32 = 3;

/// Words of the `counters` buffer (`CNT_*` in `common.glsl`).
pub mod counter {
    pub const QUEUE: usize = 0;
    pub const PRIMARY: usize = 1;
    pub const REFLECTION: usize = 2;
    pub const REFRACTION: usize = 3;
    pub const GLOSSY: usize = 4;
    pub const SHADOW: usize = 5;
    pub const AO: usize = 6;
    pub const EXHAUSTED: usize = 7;
    pub const ARGS_QUEUE: usize = 8;
    pub const ARGS_SHADOW: usize = 11;
    pub const OVERFLOW: usize = 14;
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
