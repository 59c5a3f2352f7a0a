//! Primitives and a structure over them in device memory, as the tracing kernels bind them.

use crate::accel::bvh::Bvh;
use crate::accel::device::{
    address_handle, bindings, handle_record, referenceable, AccelBuilder, AccelKind,
    AccelStructure, DevicePrimitives, RecordedBuild,
};
use crate::accel::host::{upload_structure, HostRef};
use crate::accel::kdtree::KdTree;
use crate::accel::primitives::TraceGeometry;
use crate::gpu::{Buffer, BufferArg, Context, GpuError, Recorder, Result};

/// Primitives and a structure over them in device memory: the seven buffers
/// `traverse.glsl` binds.
pub struct GpuGeometry {
    /// The primitives on the device.
    pub(crate) prims: DevicePrimitives,
    /// The structure over them on the device.
    pub(crate) accel: AccelStructure,
    /// For a structure over the caller's device geometry
    /// ([`AccelBuilder::create_in`](crate::accel::device::AccelBuilder::create_in)): its
    /// layout and build flags, which every build and update into it must match.
    pub(crate) device_input: Option<crate::accel::device_input::DeviceInput>,
    /// Whether it, and the bottom levels a top level's tree lists, are alive.
    pub(crate) life: Life,
}

/// A structure's liveness, as a top level over it sees it: a top level that borrows its
/// bottom levels (listed by [`TopLevelBuilder::create_in`] or
/// [`TopLevelBuilder::build`], not kept) refuses to be built, updated or traced once one is
/// dropped, rather than let the device read freed memory.
///
/// [`TopLevelBuilder::create_in`]: crate::accel::instances::TopLevelBuilder::create_in
/// [`TopLevelBuilder::build`]: crate::accel::instances::TopLevelBuilder::build
#[derive(Default)]
pub(crate) struct Life {
    /// Dropped with the structure.
    pub(crate) token: std::sync::Arc<()>,
    /// The listed bottom levels' tokens (a top level's tree; empty otherwise).
    pub(crate) bottoms: Vec<std::sync::Weak<()>>,
}

impl GpuGeometry {
    /// `Err` where a bottom level this top level's tree lists was dropped.
    pub(crate) fn check_bottoms(&self, call: &'static str) -> Result<()> {
        match self.life.bottoms.iter().position(|b| b.strong_count() == 0) {
            None => Ok(()),
            Some(k) => Err(crate::gpu::GpuError::Usage {
                call,
                reason: format!(
                    "bottom level {k} of this top level was dropped: a top level reads its \
                     bottom levels whenever it is built, updated or traced (keep them alive, or \
                     build with TopLevelBuilder::record_build_shared, which keeps them)"
                ),
            }),
        }
    }
}

impl GpuGeometry {
    /// The primitives on the device (what [`DevicePrimitives::record_update`] moves before
    /// a refit).
    pub fn primitives(&self) -> &DevicePrimitives {
        &self.prims
    }

    /// The structure over them on the device.
    pub fn structure(&self) -> &AccelStructure {
        &self.accel
    }

    /// Geometry and a kd-tree built on the host (or downloaded).
    pub fn upload(ctx: &Context, g: &TraceGeometry, tree: &KdTree) -> Result<Self> {
        Self::with_host(ctx, g, HostRef::KdTree(tree))
    }

    /// Geometry and a BVH built over `g`'s boxes on the host.
    pub fn upload_bvh(ctx: &Context, g: &TraceGeometry, bvh: &Bvh) -> Result<Self> {
        Self::with_host(ctx, g, HostRef::Bvh(bvh))
    }

    /// [`GpuGeometry::upload_bvh`] with the BVH's wide nodes, for the wide walk.
    pub fn upload_wide_bvh(ctx: &Context, g: &TraceGeometry, bvh: &Bvh) -> Result<Self> {
        Self::with_host(ctx, g, HostRef::WideBvh(bvh))
    }

    /// Records the upload of `g` and the build of `builder`'s structure over it into `rec`
    /// (in a profiler scope named `build`), ending with the barrier that lets the next
    /// kernels trace it. `grow`: see [`AccelBuilder::sizes`]. Keep the returned geometry
    /// until the work has executed: its buffers are the ones the recorded commands write.
    pub fn record_build(
        rec: &mut Recorder,
        builder: &AccelBuilder,
        g: &TraceGeometry,
        grow: u32,
    ) -> Result<(Self, RecordedBuild)> {
        let prims = DevicePrimitives::record_upload(rec, g)?;
        Self::record_build_over(rec, builder, prims, g, grow)
    }

    /// [`GpuGeometry::record_build`] over primitives `prims` already uploaded from `g`.
    fn record_build_over(
        rec: &mut Recorder,
        builder: &AccelBuilder,
        prims: DevicePrimitives,
        g: &TraceGeometry,
        grow: u32,
    ) -> Result<(Self, RecordedBuild)> {
        let (mut accel, scratch) = builder.create(rec.context(), prims.count(), grow)?;
        let recorded = rec.scope("build", |rec| {
            builder.record_build(rec, &mut accel, &prims, g, &scratch)
        })?;
        // The scratch is freed when this returns, before the work runs: keep it alive.
        rec.keep_alive(scratch);
        Ok((
            Self {
                prims,
                accel,
                device_input: None,
                life: Default::default(),
            },
            recorded,
        ))
    }

    /// One build of `builder`'s structure over `g`, submitted and waited for, redone with
    /// twice the kd-tree's reference budget while it runs out (as `vkrt trace` does); the
    /// successful build's milliseconds ([`RecordedBuild::ms`]).
    pub fn build_fitting(
        ctx: &Context,
        builder: &AccelBuilder,
        g: &TraceGeometry,
    ) -> Result<(Self, f64)> {
        for grow in 0..8 {
            let mut rec = Recorder::new(ctx)?;
            let (geom, recorded) = Self::record_build(&mut rec, builder, g, grow)?;
            rec.compute_to_transfer();
            let built = geom.accel.record_read_built(&mut rec)?;
            rec.transfer_to_host();
            let profile = rec.submit_and_wait()?;
            if let Some(b) = built {
                if AccelStructure::kd_built(&b.read()?).overflow {
                    continue;
                }
            }
            return Ok((geom, recorded.ms(&profile)));
        }
        Err(GpuError::Kernel {
            kernel: "accel.kdtree",
            reason: format!(
                "the kd-tree of {} primitives still ran out of references after 8 doublings \
                 of its budget",
                g.primitive_count()
            ),
        })
    }

    /// [`GpuGeometry::build_fitting`] of a geometry it takes (or borrows), with the least
    /// memory at once: the primitives uploaded in a submission of their own (its staging
    /// buffers freed before the build's scratch is used), `g` dropped once the build is
    /// recorded, before it runs (a kd-tree's kept until its build fits).
    pub fn build_fitting_taking<G: std::borrow::Borrow<TraceGeometry>>(
        ctx: &Context,
        builder: &AccelBuilder,
        g: G,
    ) -> Result<(Self, f64)> {
        if builder.kind() == AccelKind::KdTree {
            return Self::build_fitting(ctx, builder, g.borrow());
        }
        let prims = DevicePrimitives::upload(ctx, g.borrow())?;
        let mut rec = Recorder::new(ctx)?;
        let (geom, recorded) = Self::record_build_over(&mut rec, builder, prims, g.borrow(), 0)?;
        drop(g);
        let profile = rec.submit_and_wait()?;
        Ok((geom, recorded.ms(&profile)))
    }

    fn with_host(ctx: &Context, g: &TraceGeometry, host: HostRef<'_>) -> Result<Self> {
        let prims = DevicePrimitives::upload(ctx, g)?;
        let accel = upload_structure(ctx, &prims, host)?;
        if let Some(record) = handle_record(ctx, &prims, &accel)? {
            let mut rec = Recorder::new(ctx)?;
            rec.update(&accel.info, accel.info.len() - 1, &[record])?;
            rec.submit_and_wait()?;
        }
        Ok(Self {
            prims,
            accel,
            device_input: None,
            life: Default::default(),
        })
    }

    /// The structure's handle for a shader that reads it at device addresses
    /// (`VKRT_DEVICE_ADDRESS` in `vkrt/ray_query.glsl`): the addresses of its seven arrays,
    /// in the bindings' order, 56 bytes the caller writes where the shader reads them and
    /// passes to `vkrtUseStructure`. An error where the context has no
    /// `bufferDeviceAddress`.
    pub fn handle_words(&self) -> Result<[u64; 7]> {
        self.check_bottoms("GpuGeometry::handle_words")?;
        address_handle(self.prims.tri_verts.context(), &self.prims, &self.accel)
    }

    /// How an instance names this bottom level in a top level's instance records
    /// ([`Instance::bottom`](crate::accel::instance::Instance::bottom)), as
    /// `VkAccelerationStructureInstanceKHR::accelerationStructureReference` holds a BLAS's
    /// device address: the device address of the level's own handle
    /// ([`GpuGeometry::handle_words`], whose seventh address is its scene constants), which
    /// each of its builds writes after its scene constants. Fixed for as long as the level
    /// lives (rebuilds into it keep it); valid in a top level's build once a build of this
    /// level has executed before it. At least
    /// [`MAX_BOTTOM_LEVELS`](crate::accel::instance::MAX_BOTTOM_LEVELS), so that it never
    /// reads as an index.
    pub fn reference(&self) -> Result<u64> {
        let info = &self.accel.info;
        if info.len() < 2 {
            return Err(crate::gpu::GpuError::Usage {
                call: "GpuGeometry::reference",
                reason: "this structure keeps no handle of its own (the driver's two levels): \
                         it cannot be a bottom level"
                    .into(),
            });
        }
        if !referenceable(&self.accel) {
            return Err(crate::gpu::GpuError::Usage {
                call: "GpuGeometry::reference",
                reason: "this structure lies in the caller's memory: give that memory \
                         SHADER_DEVICE_ADDRESS usage and call GpuGeometry::enable_references \
                         before its builds"
                    .into(),
            });
        }
        self.reference_address()
    }

    /// Where [`GpuGeometry::reference`] points, whether or not its builds write a handle
    /// there (a top level's list keys its levels by it).
    pub(crate) fn reference_address(&self) -> Result<u64> {
        let info = &self.accel.info;
        let ctx = self.prims.tri_verts.context();
        let address = crate::gpu::address_of(ctx, info)? + 64 * (info.len() as u64 - 1);
        if address < crate::accel::instance::MAX_BOTTOM_LEVELS as u64 {
            return Err(crate::gpu::GpuError::Usage {
                call: "GpuGeometry::reference",
                reason: format!(
                    "the device placed the structure at address {address:#x}, below the \
                     indices instances may use"
                ),
            });
        }
        Ok(address)
    }

    /// Lets instances reference this structure where it lies in the caller's memory
    /// ([`AccelBuilder::create_in`](crate::accel::device::AccelBuilder::create_in)): its
    /// builds then write its handle where [`GpuGeometry::reference`] points, which needs the
    /// caller's buffer to have `SHADER_DEVICE_ADDRESS` usage (as Vulkan's acceleration
    /// structures need theirs to be referenced). Call it before the builds top levels read.
    /// A structure in vkrt's own memory is referenceable from the start.
    pub fn enable_references(&mut self) {
        self.accel.references_enabled = true;
    }

    /// Records what makes this structure a built copy of `from`, once the caller has recorded
    /// a byte copy of `from`'s placed range into this one's (`copy`: the caller's word for
    /// it): the copy's own handle record (the addresses of its arrays, which the byte copy
    /// brought as `from`'s), after a transfer → transfer barrier; and it takes `from`'s build
    /// state, so that the copy traces and can be updated
    /// ([`AccelBuilder::record_update_from`](crate::accel::device::AccelBuilder::record_update_from))
    /// as `from` could. What an API layer's clone (`vkCmdCopyAccelerationStructureKHR`)
    /// records. Ends with transfer writes: order them before readers
    /// ([`Recorder::transfer_to_indirect`] before an update, whose refit reads dispatch
    /// arguments there). Both are BVHs over geometry of one description, with one kind and
    /// one set of flags; `Err` otherwise, or where `from` has no recorded build.
    pub fn record_built_by_copy(
        &mut self,
        rec: &mut Recorder,
        from: &GpuGeometry,
        copy: crate::gpu::CopiedStructure,
    ) -> Result<()> {
        let _ = copy;
        let call = "GpuGeometry::record_built_by_copy";
        let (Some(d), Some(f)) = (self.device_input.as_ref(), from.device_input.as_ref()) else {
            return Err(GpuError::Usage {
                call,
                reason: "both must be structures over the caller's geometry (create_in)".into(),
            });
        };
        if !f.built {
            return Err(GpuError::NotBuilt { call });
        }
        if d.layout != f.layout || d.shape != f.shape || d.flags != f.flags {
            return Err(GpuError::Usage {
                call,
                reason: "the source was made for other geometry or flags".into(),
            });
        }
        self.accel.adopt_build_state(&from.accel)?;
        rec.transfer_to_transfer();
        if let Some(record) = handle_record(rec.context(), &self.prims, &self.accel)? {
            let last = self.accel.info.len() - 1;
            rec.update(&self.accel.info, last, &[record])?;
        }
        if let Some(d) = self.device_input.as_mut() {
            d.built = true;
        }
        Ok(())
    }

    /// The seven bindings in `traverse.glsl`'s order.
    pub fn bindings(&self) -> [&dyn BufferArg; 7] {
        bindings(&self.prims, &self.accel)
    }
}

// A refit of a structure held with its primitives lives with them, above the builder's
// dispatch (`device`), which knows structures only.
impl AccelBuilder {
    /// Records a refit of `out` (a BVH this builder built) to its primitives' boxes as they
    /// are now (after [`DevicePrimitives::record_update`] on [`GpuGeometry::primitives`]):
    /// every box recomputed bottom-up, the topology kept, the root box rewritten. The caller
    /// orders the writes of the moved geometry before; the recording ends with the barrier
    /// of [`crate::accel::sync::RecordSync::build`]. A kd-tree cannot be refit (its split
    /// planes are fixed): that is a [`GpuError::Usage`].
    pub fn record_refit(
        &self,
        rec: &mut Recorder,
        out: &mut GpuGeometry,
        scratch: &Buffer<u32>,
    ) -> Result<()> {
        self.record_refit_parts(rec, &mut out.accel, &out.prims, scratch)
    }
}
