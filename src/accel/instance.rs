//! One instance of a bottom-level structure ([`Instance`], the layout of
//! `VkAccelerationStructureInstanceKHR`), how instances move ([`InstanceMotion`]), and the
//! record the walk reads per instance ([`InstanceRecord`]), with the transforms' arithmetic
//! the device and its CPU twin share.

use crate::gpu::{GpuError, Result};
use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// Bottom levels one top level may name (the index shares a word with the flags).
pub const MAX_BOTTOM_LEVELS: usize = 1 << 24;
/// Time steps a moving top level may give (Embree's `RTC_MAX_TIME_STEP_COUNT`).
pub const MAX_MOTION_STEPS: u32 = 129;

/// How a top level's instances move: each instance's object-to-world at `steps` evenly
/// spaced times from `time[0]` to `time[1]`, given as `steps` lists of the instances, step
/// after step (the record of instance `i` at step `s` is `s * count + i`; everything but the
/// transform is step 0's). A ray at time `t` sees the two steps around `t` interpolated row
/// by row, `(1 - f) * a + f * b`; a time outside the interval sees the first or the last
/// step (Embree clamps the same way). [`InstanceMotion::STATIC`]: one step, no motion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InstanceMotion {
    /// Transforms given per instance, 1 (no motion) to [`MAX_MOTION_STEPS`].
    pub steps: u32,
    /// The times of the first and the last step (`time[1] > time[0]` when moving).
    pub time: [f32; 2],
}

impl InstanceMotion {
    /// Instances that do not move: one record each.
    pub const STATIC: Self = Self {
        steps: 1,
        time: [0.0, 0.0],
    };

    /// `steps` evenly spaced over `[t0, t1]`.
    pub fn new(steps: u32, t0: f32, t1: f32) -> Self {
        Self {
            steps,
            time: [t0, t1],
        }
    }

    /// Whether a top level can move this way: a [`GpuError::Usage`] saying why not.
    pub fn check(&self) -> Result<()> {
        self.why_not().map_err(|reason| GpuError::Usage {
            call: "InstanceMotion::check",
            reason,
        })
    }

    /// Why a top level cannot move this way, for the calls that report it under their name.
    pub(crate) fn why_not(&self) -> std::result::Result<(), String> {
        if self.steps == 0 || self.steps > MAX_MOTION_STEPS {
            return Err(format!(
                "{} time steps: give 1 (no motion) to {MAX_MOTION_STEPS}",
                self.steps
            ));
        }
        let [t0, t1] = self.time;
        if self.steps > 1 && !(t0.is_finite() && t1.is_finite() && t1 > t0) {
            return Err(format!(
                "the time interval [{t0}, {t1}] is not finite and increasing"
            ));
        }
        if self.steps > 1 && !self.scale().is_finite() {
            return Err(format!(
                "the time interval [{t0}, {t1}] is too short for {} steps in single precision",
                self.steps
            ));
        }
        Ok(())
    }

    /// `(steps - 1) / (t1 - t0)` (0 without motion): what takes a time to a step.
    pub fn scale(&self) -> f32 {
        if self.steps < 2 {
            return 0.0;
        }
        (self.steps - 1) as f32 / (self.time[1] - self.time[0])
    }

    /// The records a top level of `count` instances reads.
    pub fn records(&self, count: u32) -> u64 {
        u64::from(self.steps.max(1)) * u64::from(count)
    }
}

/// `VkGeometryInstanceFlagBitsKHR`.
pub mod flags {
    /// `VK_GEOMETRY_INSTANCE_TRIANGLE_FACING_CULL_DISABLE_BIT_KHR`: no face culling.
    pub const TRIANGLE_FACING_CULL_DISABLE: u8 = 0x1;
    /// `VK_GEOMETRY_INSTANCE_TRIANGLE_FLIP_FACING_BIT_KHR`: front and back faces swapped.
    pub const TRIANGLE_FLIP_FACING: u8 = 0x2;
    /// `VK_GEOMETRY_INSTANCE_FORCE_OPAQUE_BIT_KHR`: every geometry treated as opaque.
    pub const FORCE_OPAQUE: u8 = 0x4;
    /// `VK_GEOMETRY_INSTANCE_FORCE_NO_OPAQUE_BIT_KHR`: every geometry treated as non-opaque.
    pub const FORCE_NO_OPAQUE: u8 = 0x8;
}

/// One instance: 64 bytes, the layout of `VkAccelerationStructureInstanceKHR`. Its
/// [`Instance::bottom`] names the bottom level as Vulkan's `accelerationStructureReference`
/// does, by the level's reference ([`GpuGeometry::reference`]: an address), or by its index
/// in the top level's list of bottom levels.
///
/// [`GpuGeometry::reference`]: crate::accel::gpu_geometry::GpuGeometry::reference
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Instance {
    /// Object to world, row-major 3×4 (`VkTransformMatrixKHR`).
    pub transform: [[f32; 4]; 3],
    /// Bits 0..24: the custom index the hit reports; bits 24..32: the mask (a ray traced
    /// with cull mask `c` sees the instance where `mask & c != 0`).
    pub custom_index_and_mask: u32,
    /// Bits 24..32: [`flags`] (bits 0..24, Vulkan's shader-binding-table offset, are kept
    /// and unused).
    pub sbt_offset_and_flags: u32,
    /// The bottom level: its reference ([`GpuGeometry::reference`], at least
    /// [`MAX_BOTTOM_LEVELS`]: the address of the level's handle), or below that its index in
    /// the list the top level was created with (0 with no list names nothing: a null
    /// reference is never hit).
    ///
    /// [`GpuGeometry::reference`]: crate::accel::gpu_geometry::GpuGeometry::reference
    pub bottom: u64,
}

impl Instance {
    /// An instance of bottom level `bottom` placed by `transform` (object to world,
    /// row-major 3×4), custom index 0, visible to every ray (mask 0xff), no flags.
    pub fn new(bottom: u32, transform: [[f32; 4]; 3]) -> Self {
        Self {
            transform,
            custom_index_and_mask: 0xff << 24,
            sbt_offset_and_flags: 0,
            bottom: u64::from(bottom),
        }
    }

    /// The identity transform.
    pub const IDENTITY: [[f32; 4]; 3] = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
    ];

    /// From glam's affine transform.
    pub fn rows_of(a: &glam::Affine3A) -> [[f32; 4]; 3] {
        let m = a.matrix3;
        let t = a.translation;
        [
            [m.x_axis.x, m.y_axis.x, m.z_axis.x, t.x],
            [m.x_axis.y, m.y_axis.y, m.z_axis.y, t.y],
            [m.x_axis.z, m.y_axis.z, m.z_axis.z, t.z],
        ]
    }

    /// The affine transform of object-to-world rows (the inverse of [`Instance::rows_of`]).
    pub fn affine_of(rows: &[[f32; 4]; 3]) -> glam::Affine3A {
        let [a, b, c] = rows;
        glam::Affine3A::from_cols_array(&[
            a[0], b[0], c[0], a[1], b[1], c[1], a[2], b[2], c[2], a[3], b[3], c[3],
        ])
    }

    /// With custom index `index` (24 bits: higher bits are an error in [`Instance::check`]).
    pub fn with_custom_index(mut self, index: u32) -> Self {
        self.custom_index_and_mask = (self.custom_index_and_mask & 0xff00_0000) | index;
        self
    }

    /// With visibility mask `mask` (a ray with cull mask `c` sees it where `mask & c != 0`).
    pub fn with_mask(mut self, mask: u8) -> Self {
        self.custom_index_and_mask =
            (self.custom_index_and_mask & 0x00ff_ffff) | (u32::from(mask) << 24);
        self
    }

    /// With [`flags`] `flags` (bits of `VkGeometryInstanceFlagBitsKHR`).
    pub fn with_flags(mut self, flags: u8) -> Self {
        self.sbt_offset_and_flags =
            (self.sbt_offset_and_flags & 0x00ff_ffff) | (u32::from(flags) << 24);
        self
    }

    /// The custom index a hit reports (24 bits).
    pub fn custom_index(&self) -> u32 {
        self.custom_index_and_mask & 0x00ff_ffff
    }

    /// The 8-bit visibility mask.
    pub fn mask(&self) -> u8 {
        (self.custom_index_and_mask >> 24) as u8
    }

    /// The [`flags`] bits.
    pub fn flags(&self) -> u8 {
        (self.sbt_offset_and_flags >> 24) as u8
    }

    /// An instance of the bottom level whose reference ([`GpuGeometry::reference`]) is
    /// `reference`, placed by `transform`, custom index 0, mask 0xff, no flags.
    ///
    /// [`GpuGeometry::reference`]: crate::accel::gpu_geometry::GpuGeometry::reference
    pub fn referencing(reference: u64, transform: [[f32; 4]; 3]) -> Self {
        Self {
            bottom: reference,
            ..Self::new(0, transform)
        }
    }

    /// The index of its bottom level among levels whose references are `references` (in
    /// the top level's order): [`Instance::bottom`] as an index, or the level it references.
    pub fn bottom_index(&self, references: &[u64]) -> Option<u32> {
        if self.bottom < MAX_BOTTOM_LEVELS as u64 {
            return (self.bottom < references.len() as u64).then_some(self.bottom as u32);
        }
        references
            .iter()
            .position(|&r| r == self.bottom)
            .map(|k| k as u32)
    }

    /// Whether the device would hit this instance of one of the levels whose references are
    /// `references`: a [`GpuError::Usage`] saying why not. The checks `accel.instance_boxes`
    /// makes.
    pub fn check(&self, references: &[u64]) -> Result<()> {
        self.why_invalid(references)
            .map_err(|reason| GpuError::Usage {
                call: "Instance::check",
                reason,
            })
    }

    /// Why the device would never hit this instance, for the calls that report it under
    /// their name.
    pub(crate) fn why_invalid(&self, references: &[u64]) -> std::result::Result<(), String> {
        if self.bottom_index(references).is_none() {
            return Err(if self.bottom < MAX_BOTTOM_LEVELS as u64 {
                format!(
                    "it names bottom level {}, but the top level has {}",
                    self.bottom,
                    references.len()
                )
            } else {
                format!(
                    "it references {:#x}, none of the top level's {} bottom levels",
                    self.bottom,
                    references.len()
                )
            });
        }
        if self.transform.iter().flatten().any(|x| !x.is_finite()) {
            return Err(format!("its transform {:?} is not finite", self.transform));
        }
        match world_to_object(&self.transform) {
            Some(_) => Ok(()),
            None => Err(format!(
                "its transform {:?} is singular (not invertible in single precision): no ray \
                 can be moved into its object space; leave the instance out",
                self.transform
            )),
        }
    }
}

/// What the walk reads per instance: 80 bytes, `InstanceRecord` in
/// `glsl/accel/instance_boxes.comp` and `VkrtInstanceRecord` in `vkrt/ray_query.glsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct InstanceRecord {
    /// World to object, row-major 3×4.
    pub world_to_object: [[f32; 4]; 3],
    /// Where the bottom level's handle lies: the top level's copy for a level of its list,
    /// else the instance's reference (0: never hit).
    pub handle: u64,
    /// The instance's custom index | mask << 24 (mask 0: never hit).
    pub custom_index_and_mask: u32,
    /// Its flags | bottom-level index << 8 ([`InstanceRecord::UNLISTED`] where the top level
    /// has no list).
    pub flags_and_bottom: u32,
    /// Its motion: steps (1: it does not move), where its steps start among the top level's,
    /// the first step's time and [`InstanceMotion::scale`] (as bits).
    pub motion: [u32; 4],
}

impl InstanceRecord {
    /// The index a record gives an instance that names its bottom level by reference in a
    /// top level without a list of them.
    pub const UNLISTED: u32 = 0x00ff_ffff;

    /// The bottom level's index in the top level's list ([`InstanceRecord::UNLISTED`]
    /// without one).
    pub fn bottom(&self) -> u32 {
        self.flags_and_bottom >> 8
    }

    /// The visibility mask (0: never hit).
    pub fn mask(&self) -> u32 {
        self.custom_index_and_mask >> 24
    }

    /// Its world-to-object rows at `time`, interpolated from `steps` (the top level's, as
    /// [`instance_boxes`](crate::accel::instances::instance_boxes) returns them) as the walk
    /// does; `None` where the transform there is not invertible (the ray misses the
    /// instance).
    pub fn world_to_object_at(&self, steps: &[[[f32; 4]; 3]], time: f32) -> Option<[[f32; 4]; 3]> {
        let [n, first, t0, scale] = self.motion;
        if n < 2 {
            return Some(self.world_to_object);
        }
        let (t0, scale) = (f32::from_bits(t0), f32::from_bits(scale));
        let u = (time - t0) * scale;
        let u = if u >= 0.0 { u.min((n - 1) as f32) } else { 0.0 };
        let k = (u as u32).min(n - 2);
        let f = u - k as f32;
        let at = (first + k) as usize;
        world_to_object(&lerp_rows(&steps[at], &steps[at + 1], f))
    }
}

const _: () = assert!(std::mem::size_of::<InstanceRecord>() == 80);

/// `(1 - f) * a + f * b`, element by element (`vkrt_lerp_rows` in `vkrt/affine.glsl`).
pub fn lerp_rows(a: &[[f32; 4]; 3], b: &[[f32; 4]; 3], f: f32) -> [[f32; 4]; 3] {
    let g = 1.0 - f;
    std::array::from_fn(|r| std::array::from_fn(|c| g * a[r][c] + f * b[r][c]))
}

fn finite(v: &[f32]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// The inverse of object-to-world `m` as the device computes it (cofactors, one division;
/// every product and sum rounded on its own, left to right), `None` where `m` is not
/// invertible or its inverse not finite.
pub fn world_to_object(m: &[[f32; 4]; 3]) -> Option<[[f32; 4]; 3]> {
    let [a, b, c] = m;
    let c00 = a_minus_b(b[1] * c[2], b[2] * c[1]);
    let c01 = a_minus_b(a[2] * c[1], a[1] * c[2]);
    let c02 = a_minus_b(a[1] * b[2], a[2] * b[1]);
    let c10 = a_minus_b(b[2] * c[0], b[0] * c[2]);
    let c11 = a_minus_b(a[0] * c[2], a[2] * c[0]);
    let c12 = a_minus_b(a[2] * b[0], a[0] * b[2]);
    let c20 = a_minus_b(b[0] * c[1], b[1] * c[0]);
    let c21 = a_minus_b(a[1] * c[0], a[0] * c[1]);
    let c22 = a_minus_b(a[0] * b[1], a[1] * b[0]);
    let det = a[0] * c00 + a[1] * c10 + a[2] * c20;
    let inv_det = 1.0 / det;
    let rows = [
        [c00 * inv_det, c01 * inv_det, c02 * inv_det],
        [c10 * inv_det, c11 * inv_det, c12 * inv_det],
        [c20 * inv_det, c21 * inv_det, c22 * inv_det],
    ];
    let t = [a[3], b[3], c[3]];
    let row = |r: [f32; 3]| [r[0], r[1], r[2], -(r[0] * t[0] + r[1] * t[1] + r[2] * t[2])];
    let out = [row(rows[0]), row(rows[1]), row(rows[2])];
    let ok = finite(m.as_flattened()) && det != 0.0 && finite(out.as_flattened());
    ok.then_some(out)
}

fn a_minus_b(a: f32, b: f32) -> f32 {
    a - b
}

/// `rows · (d, 0)`: a direction moved, each row summed left to right (as
/// [`transform_point`](crate::accel::geometry::transform_point) moves points).
pub fn transform_direction(rows: &[[f32; 4]; 3], d: Vec3) -> Vec3 {
    let row = |r: &[f32; 4]| r[0] * d.x + r[1] * d.y + r[2] * d.z;
    Vec3::new(row(&rows[0]), row(&rows[1]), row(&rows[2]))
}
