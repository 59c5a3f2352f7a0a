//! The driver's structure as one of vkrt's kinds: the `nodes` binding holds its top level's
//! device address and `prim_refs` the first primitive id of each instance, for the `query`
//! variants of the kernels that trace.

use crate::accel::device_primitives::DevicePrimitives;
use crate::accel::driver::{DriverAccel, DriverInput, Prefer};
use crate::accel::primitives::{SceneInfo, TraceGeometry};
use crate::accel::sizes::AccelSizes;
use crate::gpu::{AccelGeometry, Buffer, BufferArg, Context, GpuError, Recorder, Result};
use crate::scene::Aabb;

/// The driver's structure in device memory.
pub(crate) struct DriverStorage {
    /// The driver's levels; made by the build, or placed in a caller's memory before it.
    pub(crate) levels: Option<Box<DriverAccel>>,
    /// The TLAS's device address: the `nodes` binding of the `query` kernels.
    pub(crate) address: Buffer<u64>,
    /// The `prim_refs` binding: the first primitive id of each instance.
    pub(crate) bases: Buffer<u32>,
}

/// Bytes of the driver's structure over `n` triangles (its sizes depend on the geometry:
/// [`DriverAccel::sizes`] has them exactly).
pub(crate) fn sizes(ctx: &Context, n: usize, prefer: Prefer) -> Result<AccelSizes> {
    let info = std::mem::size_of::<SceneInfo>() as u64;
    let tris = [AccelGeometry::Triangles {
        vertices: 0,
        count: n as u32,
    }];
    let s = crate::gpu::accel_build_sizes(ctx, &tris, prefer.flags(false))?;
    Ok(AccelSizes {
        structure_bytes: s.structure + info + 8,
        build_scratch_bytes: s.scratch,
        update_scratch_bytes: None,
    })
}

impl DriverStorage {
    /// The bindings, without levels yet.
    pub(crate) fn new(ctx: &Context) -> Result<Self> {
        Ok(Self {
            levels: None,
            address: Buffer::new(ctx, "accel.driver.address", 1)?,
            // Triangles and boxes at most (DriverAccel::geometries).
            bases: Buffer::new(ctx, "accel.driver.bases", 2)?,
        })
    }

    /// Records the build over `prims` (`host`: their host copy, whose bounds go into the
    /// scene constants; `None` where a gather wrote them). `given`: the caller's scratch,
    /// where its levels were placed in its memory; else the levels are made now, in vkrt's
    /// memory, with a scratch of their own.
    #[allow(clippy::too_many_arguments, reason = "the build's inputs and outputs")]
    pub(crate) fn record_build(
        &mut self,
        rec: &mut Recorder,
        prims: &DevicePrimitives,
        host: Option<&TraceGeometry>,
        prefer: Prefer,
        allow_update: bool,
        given: Option<&Buffer<u8>>,
        info: &Buffer<SceneInfo>,
    ) -> Result<()> {
        if let Some(host) = host {
            let mut bounds = Aabb::EMPTY;
            host.boxes.iter().for_each(|b| bounds.union(b));
            let constants = prims.info(&bounds, 0).walked(SceneInfo::WALK_RAY_QUERY);
            rec.upload(info, &[constants])?;
        }
        let input = DriverInput::of(prims);
        if given.is_none() || self.levels.is_none() {
            let ctx = rec.context().clone();
            let own = given.is_none();
            self.levels =
                DriverAccel::create(&ctx, &input, prefer, allow_update, own)?.map(Box::new);
        }
        let built = self.levels.as_ref().ok_or_else(|| GpuError::Usage {
            call: "AccelBuilder::record_build",
            reason: "the driver's levels were not created".into(),
        })?;
        rec.update(&self.bases, 0, &DriverAccel::instance_bases(&input)?)?;
        rec.update(&self.address, 0, &[built.tlas_address()])?;
        built.record_build(rec, given)?;
        rec.transfer_to_compute();
        Ok(())
    }

    /// Records an update of the levels built before, with their own scratch.
    pub(crate) fn record_update(&self, rec: &mut Recorder) -> Result<()> {
        let levels = self.levels.as_ref().ok_or(GpuError::NotBuilt {
            call: "AccelBuilder::record_refit",
        })?;
        levels.record_update(rec, None)
    }

    /// The `nodes` and `prim_refs` bindings.
    pub(crate) fn node_bindings(&self) -> [&dyn BufferArg; 2] {
        [&self.address, &self.bases]
    }
}
