//! The driver's own ray tracing as a structure kind (`--accel driver`): a
//! bottom-level structure over the device primitives and one identity instance of it in a
//! top-level structure, both built by the driver (`VK_KHR_acceleration_structure`) into the
//! caller's [`Recorder`], and queried with `VK_KHR_ray_query` by the `query` variants of the
//! kernels that trace (`trace_ray_query` in `glsl/include/vkrt/traverse.glsl`).
//!
//! Geometry ([`DriverAccel::geometries`]): static triangles are the driver's triangle
//! geometry, tested by its own intersector; spheres and box primitives are boxes the kernel
//! intersects. A
//! scene with motion is one box geometry over every primitive's swept box, each intersected
//! by the kernel at the ray's time — the driver's structures hold one position per vertex.
//!
//! Nothing here submits.

use crate::gpu::{
    accel_build_sizes, accel_scratch, require_ray_query, vk, AccelGeometry, AccelInstance,
    AccelerationStructure, Buffer, Context, GpuError, Recorder, Result,
};

use super::device::DevicePrimitives;

/// What the driver's builder optimises for (`VkBuildAccelerationStructureFlagsKHR`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Prefer {
    /// A slower build of a structure that traces faster.
    #[default]
    FastTrace,
    /// A quicker build, for structures rebuilt often.
    FastBuild,
}

impl Prefer {
    /// The build flags, with `ALLOW_UPDATE` where the structure will be refit.
    pub(crate) fn flags(self, allow_update: bool) -> vk::BuildAccelerationStructureFlagsKHR {
        let prefer = match self {
            Prefer::FastTrace => vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE,
            Prefer::FastBuild => vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_BUILD,
        };
        if allow_update {
            prefer | vk::BuildAccelerationStructureFlagsKHR::ALLOW_UPDATE
        } else {
            prefer
        }
    }

    /// `fast-trace` or `fast-build`.
    pub fn name(self) -> &'static str {
        match self {
            Prefer::FastTrace => "fast-trace",
            Prefer::FastBuild => "fast-build",
        }
    }
}

/// Bytes of a box in `DevicePrimitives::boxes` (six floats, `VkAabbPositionsKHR`).
const BOX_BYTES: u64 = 24;

/// One bottom-level structure (one kind of geometry: Vulkan takes no mix in one) and the id
/// of its first primitive, which the kernels read from the `prim_refs` binding by instance.
struct Bottom {
    blas: AccelerationStructure,
    geometry: AccelGeometry,
}

/// The driver's two-level structure over a scene's primitives. Keep it (and the
/// primitives) alive until the recorded build and every trace of it have executed.
pub struct DriverAccel {
    bottoms: Vec<Bottom>,
    tlas: AccelerationStructure,
    // The TLAS build reads it.
    instances: Buffer<AccelInstance>,
    flags: vk::BuildAccelerationStructureFlagsKHR,
    /// Scratch of every build and update, reused after the barrier between them.
    scratch: Buffer<u8>,
}

impl DriverAccel {
    /// The bottom levels for `prims` (see the module's notes), each with the id of its first
    /// primitive (instance `i` of the top level is bottom level `i`): none for a scene
    /// without primitives.
    pub fn geometries(prims: &DevicePrimitives) -> Result<Vec<(AccelGeometry, u32)>> {
        let count = |n: usize| {
            u32::try_from(n).map_err(|_| GpuError::Kernel {
                kernel: "accel.driver",
                reason: format!("{n} primitives do not fit a u32 count"),
            })
        };
        let boxes = prims.boxes.device_address();
        if prims.has_motion {
            let all = AccelGeometry::Aabbs {
                boxes,
                stride: BOX_BYTES,
                count: count(prims.count())?,
            };
            return Ok(vec![(all, 0)]);
        }
        let mut g = Vec::new();
        if prims.n_tris > 0 {
            // `tri_verts` is 9 floats per triangle, non-indexed (its two floats of padding
            // are past the count): stride-12 vertices.
            let tris = AccelGeometry::Triangles {
                vertices: prims.tri_verts.device_address(),
                count: count(prims.n_tris)?,
            };
            g.push((tris, 0));
        }
        if prims.n_spheres + prims.n_aabbs > 0 {
            // Spheres and box primitives: boxes the kernel intersects.
            let spheres = AccelGeometry::Aabbs {
                boxes: boxes + prims.n_tris as u64 * BOX_BYTES,
                stride: BOX_BYTES,
                count: count(prims.n_spheres + prims.n_aabbs)?,
            };
            g.push((spheres, count(prims.n_tris)?));
        }
        Ok(g)
    }

    /// The first primitive id of each instance, as the kernels read them (at least one
    /// word: a binding is never empty).
    pub fn instance_bases(prims: &DevicePrimitives) -> Result<Vec<u32>> {
        let mut bases: Vec<u32> = Self::geometries(prims)?.iter().map(|g| g.1).collect();
        bases.resize(bases.len().max(1), 0);
        Ok(bases)
    }

    /// Bytes of the structure (every level) and of a build's and an update's scratch for
    /// `prims`, as the driver reports them.
    pub fn sizes(
        ctx: &Context,
        prims: &DevicePrimitives,
        prefer: Prefer,
        allow_update: bool,
    ) -> Result<crate::accel::device::AccelSizes> {
        let flags = prefer.flags(allow_update);
        let bottoms = Self::geometries(prims)?;
        let top = accel_build_sizes(ctx, &[Self::top(0, bottoms.len())], flags)?;
        let (mut structure, mut scratch, mut update) = (top.structure, top.scratch, top.scratch);
        for (g, _) in &bottoms {
            let b = accel_build_sizes(ctx, &[*g], flags)?;
            structure += b.structure;
            scratch = scratch.max(b.scratch);
            update = update.max(b.update_scratch);
        }
        Ok(crate::accel::device::AccelSizes {
            structure_bytes: structure,
            build_scratch_bytes: scratch,
            update_scratch_bytes: allow_update.then_some(update),
        })
    }

    fn top(instances: u64, count: usize) -> AccelGeometry {
        AccelGeometry::Instances {
            instances,
            count: count as u32,
        }
    }

    /// Records the build over `prims` (uploaded before, into the same recorder or an earlier
    /// submission) into `rec`, ending with the barrier that lets kernels query it.
    /// `allow_update`: built so that [`DriverAccel::record_update`] may refit it. Without the
    /// driver's ray query: [`GpuError::MissingCapability`] naming the extensions.
    pub fn record_build(
        rec: &mut Recorder,
        prims: &DevicePrimitives,
        prefer: Prefer,
        allow_update: bool,
    ) -> Result<Self> {
        let ctx = rec.context().clone();
        require_ray_query(&ctx)?;
        let flags = prefer.flags(allow_update);
        let mut bottoms = Vec::new();
        let mut scratch_bytes = 0;
        for (geometry, _) in Self::geometries(prims)? {
            let sizes = accel_build_sizes(&ctx, &[geometry], flags)?;
            scratch_bytes = scratch_bytes.max(sizes.scratch.max(sizes.update_scratch));
            let name = "accel.driver.blas";
            let blas = AccelerationStructure::new(&ctx, name, &[geometry], sizes.structure)?;
            bottoms.push(Bottom { blas, geometry });
        }
        let n = bottoms.len();
        let instances = Buffer::<AccelInstance>::new(&ctx, "accel.driver.instances", n.max(1))?;
        let list: Vec<AccelInstance> = bottoms
            .iter()
            .map(|b| AccelInstance::identity(b.blas.device_address()))
            .collect();
        rec.upload(&instances, &list)?;
        let top = [Self::top(instances.device_address(), n)];
        let top_sizes = accel_build_sizes(&ctx, &top, flags)?;
        let tlas =
            AccelerationStructure::new(&ctx, "accel.driver.tlas", &top, top_sizes.structure)?;
        let scratch = accel_scratch(&ctx, scratch_bytes.max(top_sizes.scratch))?;
        let accel = Self {
            bottoms,
            tlas,
            instances,
            flags,
            scratch,
        };
        rec.scope("driver_build", |rec| accel.record_levels(rec, false))?;
        Ok(accel)
    }

    /// Records a refit of a structure built with `allow_update` to its primitives as they
    /// are now (the same primitives, moved; the caller orders their writes before): the
    /// driver updates the bottom levels in place and the top level is rebuilt.
    pub fn record_update(&self, rec: &mut Recorder) -> Result<()> {
        if !self
            .flags
            .contains(vk::BuildAccelerationStructureFlagsKHR::ALLOW_UPDATE)
        {
            return Err(GpuError::Kernel {
                kernel: "accel.driver",
                reason: "the driver's structure was not built to be updated; rebuild it".into(),
            });
        }
        rec.scope("driver_update", |rec| self.record_levels(rec, true))
    }

    /// The bottom levels (built or updated), one after the other on the one scratch, then
    /// the top level over them, then the barrier to the kernels.
    fn record_levels(&self, rec: &mut Recorder, update: bool) -> Result<()> {
        rec.to_accel_build();
        for (i, b) in self.bottoms.iter().enumerate() {
            if i > 0 {
                rec.accel_build_to_accel_build();
            }
            let g = [b.geometry];
            match update {
                true => b.blas.record_update(rec, &g, self.flags, &self.scratch)?,
                false => b.blas.record_build(rec, &g, self.flags, &self.scratch)?,
            }
        }
        rec.accel_build_to_accel_build();
        let top = [Self::top(
            self.instances.device_address(),
            self.bottoms.len(),
        )];
        self.tlas
            .record_build(rec, &top, self.flags, &self.scratch)?;
        rec.accel_build_to_compute();
        Ok(())
    }

    /// The TLAS's device address, which the `query` kernels read from the nodes binding.
    pub fn tlas_address(&self) -> u64 {
        self.tlas.device_address()
    }

    /// Bytes of every level's storage.
    pub fn structure_bytes(&self) -> u64 {
        self.tlas.byte_len() + self.bottoms.iter().map(|b| b.blas.byte_len()).sum::<u64>()
    }
}
