//! The driver's own ray tracing as a backend (issue 16): a bottom-level structure over the
//! device triangles, one identity instance of it in a top-level structure, both built by
//! the driver (`VK_KHR_acceleration_structure`), and `glsl/trace/ray_query.comp` tracing
//! rays through it with `VK_KHR_ray_query`. Triangles only for now; spheres (AABB geometry
//! with an intersection step in the kernel) come next.
//!
//! Everything is recorded into the caller's [`Recorder`]: nothing here submits.

use std::sync::Arc;

use crate::gpu::{
    accel_build_sizes, accel_scratch, kernels, require_ray_query, vk, AccelGeometry, AccelInstance,
    AccelerationStructure, Buffer, Context, GpuError, Kernel, Recorder, Result, Spec,
};
use crate::trace::{Hit, Query, Ray};

use super::device::DevicePrimitives;

/// What the driver's builder optimises for (`VkBuildAccelerationStructureFlagsKHR`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Prefer {
    /// A slower build of a structure that traces faster.
    #[default]
    FastTrace,
    /// A quicker build, for structures rebuilt often.
    FastBuild,
}

impl Prefer {
    fn flags(self) -> vk::BuildAccelerationStructureFlagsKHR {
        match self {
            Prefer::FastTrace => vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE,
            Prefer::FastBuild => vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_BUILD,
        }
    }
}

/// The driver's two-level structure over a scene's triangles. Keep it (and the
/// primitives) alive until the recorded build and every trace of it have executed.
pub struct DriverAccel {
    blas: AccelerationStructure,
    tlas: AccelerationStructure,
    // The TLAS build reads it; traces do not, but it is small and lives with the TLAS.
    _instances: Buffer<AccelInstance>,
    triangles: u32,
}

impl DriverAccel {
    /// Records the build over `prims`' triangles (uploaded before into the same recorder or
    /// an earlier submission) into `rec`, ending with the barrier that lets kernels query
    /// it. Without the driver's ray query: [`GpuError::MissingCapability`] naming the
    /// extensions.
    pub fn record_build(
        rec: &mut Recorder,
        prims: &DevicePrimitives,
        prefer: Prefer,
    ) -> Result<Self> {
        let ctx = rec.context().clone();
        require_ray_query(&ctx)?;
        if prims.n_spheres > 0 {
            return Err(GpuError::Kernel {
                kernel: "accel.driver",
                reason: format!(
                    "the driver backend takes triangles only for now; {} spheres given",
                    prims.n_spheres
                ),
            });
        }
        let triangles = u32::try_from(prims.n_tris).map_err(|_| GpuError::Kernel {
            kernel: "accel.driver",
            reason: format!("{} triangles do not fit a u32 count", prims.n_tris),
        })?;
        let flags = prefer.flags();
        // `tri_verts` is 9 floats per triangle, non-indexed, with two floats of padding at
        // the end that the count leaves out: exactly stride-12 vertices.
        let bottom = AccelGeometry::Triangles {
            vertices: prims.tri_verts.device_address(),
            count: triangles,
        };
        let bottom_sizes = accel_build_sizes(&ctx, bottom, flags)?;
        let blas =
            AccelerationStructure::new(&ctx, "accel.driver.blas", bottom, bottom_sizes.structure)?;
        let instances = Buffer::<AccelInstance>::new(&ctx, "accel.driver.instances", 1)?;
        rec.upload(
            &instances,
            &[AccelInstance::identity(blas.device_address())],
        )?;
        let top = AccelGeometry::Instances {
            instances: instances.device_address(),
            count: 1,
        };
        let top_sizes = accel_build_sizes(&ctx, top, flags)?;
        let tlas = AccelerationStructure::new(&ctx, "accel.driver.tlas", top, top_sizes.structure)?;
        // One scratch for both builds, reused after the barrier between them.
        let scratch = accel_scratch(&ctx, bottom_sizes.scratch.max(top_sizes.scratch))?;
        rec.scope("driver_build", |rec| -> Result<()> {
            rec.to_accel_build();
            blas.record_build(rec, bottom, flags, &scratch)?;
            rec.accel_build_to_accel_build();
            tlas.record_build(rec, top, flags, &scratch)?;
            rec.accel_build_to_compute();
            Ok(())
        })?;
        rec.keep_alive(scratch);
        Ok(Self {
            blas,
            tlas,
            _instances: instances,
            triangles,
        })
    }

    /// The TLAS's device address, which `trace/ray_query.comp` queries.
    pub fn tlas_address(&self) -> u64 {
        self.tlas.device_address()
    }

    /// The BLAS's device address (the instance's reference).
    pub fn blas_address(&self) -> u64 {
        self.blas.device_address()
    }

    pub fn triangle_count(&self) -> u32 {
        self.triangles
    }
}

const WORKGROUP: u32 = 64;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct RayQueryPush {
    tlas: u64,
    n: u32,
    _pad: u32,
}

/// Traces rays through a [`DriverAccel`] with `glsl/trace/ray_query.comp`.
pub struct RayQueryTracer {
    kernel: Arc<Kernel>,
}

impl RayQueryTracer {
    /// The tracer for closest or any hit; its pipeline exists only on devices with the
    /// driver's ray query (elsewhere: the error naming the extensions).
    pub fn new(ctx: &Context, query: Query) -> Result<Self> {
        require_ray_query(ctx)?;
        let spec = Spec::new()
            .u32(2, (query == Query::Any) as u32)
            .workgroup(WORKGROUP);
        Ok(Self {
            kernel: ctx.kernel(&kernels::TRACE_RAY_QUERY, &spec)?,
        })
    }

    /// Records the trace of `n` rays into `hits`. The caller orders the writes of `rays`
    /// and the build of `accel` before.
    pub fn record(
        &self,
        rec: &mut Recorder,
        accel: &DriverAccel,
        rays: &Buffer<Ray>,
        hits: &Buffer<Hit>,
        n: usize,
    ) {
        if n == 0 {
            return;
        }
        let push = RayQueryPush {
            tlas: accel.tlas_address(),
            n: n as u32,
            _pad: 0,
        };
        let groups = rec.groups_1d(n as u64, WORKGROUP);
        rec.dispatch(&self.kernel, groups, &[rays, hits], &push);
    }

    /// Uploads `rays`, traces them and reads the hits back, in one submission.
    pub fn trace(&self, ctx: &Context, accel: &DriverAccel, rays: &[Ray]) -> Result<Vec<Hit>> {
        if rays.is_empty() {
            return Ok(Vec::new());
        }
        let ray_buf = Buffer::new(ctx, "trace.rays", rays.len())?;
        let hits = Buffer::<Hit>::new(ctx, "trace.hits", rays.len())?;
        let mut rec = Recorder::new(ctx)?;
        rec.upload(&ray_buf, rays)?;
        rec.transfer_to_compute();
        rec.scope("trace", |rec| {
            self.record(rec, accel, &ray_buf, &hits, rays.len())
        });
        rec.compute_to_transfer();
        let back = rec.read_back(&hits)?;
        rec.transfer_to_host();
        rec.submit_and_wait()?;
        back.read()
    }
}
