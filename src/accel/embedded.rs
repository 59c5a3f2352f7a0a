//! Structures on the renderer's terms, as `VK_KHR_acceleration_structure` has them: built from
//! geometry in the caller's device buffers ([`Geometry`]), in memory the caller allocates.
//!
//! 1. [`AccelBuilder::sizes_for`]: the structure's bytes and the build's and an update's
//!    scratch, for exactly these geometries and flags;
//! 2. [`AccelBuilder::create_in`]: the structure placed in a range of the caller's buffer;
//! 3. [`AccelBuilder::record_build_from`] / [`AccelBuilder::record_update_from`]: recorded
//!    into the caller's command buffer, with the scratch in another range of the caller's;
//!    they allocate nothing, upload nothing and submit nothing. Several structures are
//!    built by one call with [`AccelBuilder::record_builds_from`]
//!    ([`crate::accel::batch`]).
//!
//! Sizes may be asked from counts alone, before the geometry's buffers exist
//! ([`GeometryShape`](crate::accel::geometry_shape::GeometryShape)).
//!
//! The sizes are exact because they come from the same code that places the buffers, run
//! in a measuring mode ([`crate::gpu::placement`]). The caller's buffers need
//! [`REQUIRED_BUFFER_USAGE`] (and [`DRIVER_BUFFER_USAGE`] too for the driver's structure).
//!
//! Where vkrt differs from the Vulkan extension: the SAH BVH is a host builder and takes host
//! slices ([`AccelBuilder::record_build`]); the kd-tree's references per level are a
//! capacity, so its build may report that it ran out ([`BuildStatus`]), and the caller asks
//! for sizes with one more doubling and builds again — an answer the caller acts on, never
//! a hidden host round trip. The driver's own structure places its opaque levels, their
//! instance records and its scratch in the caller's ranges too (the records are written by
//! the recorded build with `vkCmdUpdateBuffer`: a few constants in the command buffer, no
//! staging).

use crate::accel::batch::BuildTarget;
use crate::accel::device::{
    AccelBuilder, AccelKind, AccelScratch, AccelSizes, DevicePrimitives, Scratch,
};
pub use crate::accel::device_input::BuildFlags;
use crate::accel::device_input::{shape, DeviceInput};
use crate::accel::driver::{DriverAccel, DriverInput};
use crate::accel::driver_levels;
use crate::accel::geometry::{Geometry, GeometryGather, GeometryLayout};
use crate::accel::geometry_shape::GeometryDescription;
use crate::accel::gpu_geometry::GpuGeometry;
use crate::accel::primitives::SceneInfo;
use crate::gpu::placement::{place, Placement};
use crate::gpu::{vk, Buffer, Context, GpuError, RawBuffer, Readback, Recorder, Result};

/// Usage the caller's structure and scratch buffers need: vkrt binds ranges of them as
/// storage buffers (and texel buffers), fills and copies within them and dispatches
/// indirectly from them.
pub const REQUIRED_BUFFER_USAGE: vk::BufferUsageFlags = vk::BufferUsageFlags::from_raw(
    vk::BufferUsageFlags::STORAGE_BUFFER.as_raw()
        | vk::BufferUsageFlags::TRANSFER_SRC.as_raw()
        | vk::BufferUsageFlags::TRANSFER_DST.as_raw()
        | vk::BufferUsageFlags::INDIRECT_BUFFER.as_raw()
        | vk::BufferUsageFlags::UNIFORM_TEXEL_BUFFER.as_raw(),
);

/// Usage a structure's buffer needs where its address is taken — a top level's instances
/// naming it by reference, [`TopLevel::handle_words`](crate::accel::instances::TopLevel::handle_words),
/// a shader finding it at a device address: [`REQUIRED_BUFFER_USAGE`] and
/// `SHADER_DEVICE_ADDRESS`, its memory allocated with [`REFERENCEABLE_MEMORY_FLAGS`].
pub const REFERENCEABLE_BUFFER_USAGE: vk::BufferUsageFlags = vk::BufferUsageFlags::from_raw(
    REQUIRED_BUFFER_USAGE.as_raw() | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS.as_raw(),
);

/// The `VkMemoryAllocateFlagsInfo` flags of memory bound to a buffer with
/// `SHADER_DEVICE_ADDRESS` usage ([`REFERENCEABLE_BUFFER_USAGE`], geometry read at device
/// addresses).
pub const REFERENCEABLE_MEMORY_FLAGS: vk::MemoryAllocateFlags =
    vk::MemoryAllocateFlags::DEVICE_ADDRESS;

/// Usage of a buffer holding geometry (vertices, indices, boxes, spheres, instance records)
/// that a build reads as a range ([`GeometryData::Buffer`](crate::accel::geometry::GeometryData)):
/// vkrt's gather binds it as a storage buffer. Data read at device addresses
/// (a [`DeviceRange`](crate::gpu::DeviceRange)) needs
/// `SHADER_DEVICE_ADDRESS` instead, with [`REFERENCEABLE_MEMORY_FLAGS`].
pub const GEOMETRY_BUFFER_USAGE: vk::BufferUsageFlags = vk::BufferUsageFlags::STORAGE_BUFFER;

/// What the driver's structure needs in addition: its inputs are read at device addresses.
pub const DRIVER_BUFFER_USAGE: vk::BufferUsageFlags = vk::BufferUsageFlags::from_raw(
    vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS.as_raw()
        | vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR.as_raw()
        | vk::BufferUsageFlags::ACCELERATION_STRUCTURE_STORAGE_KHR.as_raw(),
);

/// The driver's levels over `layout`'s primitive counts (no addresses: for sizes).
fn driver_counts(layout: &GeometryLayout) -> DriverInput {
    DriverInput {
        n_tris: layout.n_tris as usize,
        n_boxes: (layout.n_spheres + layout.n_aabbs) as usize,
        has_motion: false,
        tri_verts: 0,
        boxes: 0,
    }
}

fn usage(call: &'static str, reason: impl Into<String>) -> GpuError {
    GpuError::Usage {
        call,
        reason: reason.into(),
    }
}

/// What a build reports once it has executed ([`GpuGeometry::record_read_status`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BuildStatus {
    /// Primitives the caller's data could not give (an index past the vertex count, a
    /// non-finite coordinate, a negative radius): each became a point no ray hits.
    pub invalid_primitives: u32,
    /// The kd-tree ran out of its reference budget: the structure is empty (every ray
    /// misses). Build again with [`BuildFlags::kd_capacity_doublings`] one higher, at the
    /// sizes asked for then.
    pub kd_overflow: bool,
}

/// The copy of a build's report, read after the work has executed.
#[must_use = "read() it once the work has executed"]
pub struct StatusReadback {
    info: Readback<SceneInfo>,
    kd: Option<Readback<u32>>,
}

impl StatusReadback {
    /// The report, once the recording's work is known complete ([`Recorder::submit_and_wait`]
    /// returned, or [`crate::gpu::RecordedWork::complete`] was called): an error before.
    pub fn read(self) -> Result<BuildStatus> {
        let info = self.info.read()?;
        let kd_overflow = match self.kd {
            Some(k) => k.read()?.get(2).is_some_and(|&w| w != 0),
            None => false,
        };
        Ok(BuildStatus {
            invalid_primitives: info.first().map_or(0, |i| i.invalid),
            kd_overflow,
        })
    }
}

impl GpuGeometry {
    /// Records the copy of the build's report (80 bytes at most) into host memory: read it
    /// with [`StatusReadback::read`] after the work has executed. Order the build before
    /// with [`Recorder::compute_to_transfer`], and the copy before the host's read with
    /// [`Recorder::transfer_to_host`] ([`RecordSync::READ_STATUS`]), then wait for the
    /// caller's fence.
    ///
    /// [`RecordSync::READ_STATUS`]: crate::accel::sync::RecordSync::READ_STATUS
    pub fn record_read_status(&self, rec: &mut Recorder) -> Result<StatusReadback> {
        let ctx = rec.context().clone();
        let head = Buffer::<SceneInfo>::with_memory(
            &ctx,
            "accel.status",
            1,
            crate::gpu::Memory::Readback,
        )?;
        rec.copy(&self.accel.info, &head, 1);
        Ok(StatusReadback {
            info: Readback::from_staging(rec, head),
            kd: self.accel.record_read_built(rec)?,
        })
    }
}

impl AccelBuilder {
    /// What every call over device geometry checks first: the kind builds from device
    /// buffers, and holds `geometries`' opacity.
    fn check_device_input(
        &self,
        call: &'static str,
        geometries: &[impl GeometryDescription],
    ) -> Result<()> {
        // Non-opaque hits go back to a ray query as candidates, each once: the walk of a
        // BVH (binary or 4-wide), which references every primitive once, does that; a
        // kd-tree's walk may meet a primitive in several leaves.
        let bvh = matches!(self.kind(), AccelKind::Lbvh | AccelKind::Ploc);
        if !bvh && geometries.iter().any(|g| !g.shape().opaque()) {
            return Err(usage(
                call,
                format!(
                    "non-opaque geometry goes to ray queries as candidates through the walk of \
                     a BVH (LBVH or PLOC); a {} structure holds opaque geometry only",
                    self.kind().name()
                ),
            ));
        }
        match self.kind() {
            AccelKind::SahBvh => Err(usage(
                call,
                "the SAH BVH is a host builder: it builds from host slices (record_build \
                 with a TraceGeometry), not from device buffers",
            )),
            _ => Ok(()),
        }
    }

    /// The alignment a structure's and a scratch's offset in the caller's buffer needs on
    /// this device (`minStorageBufferOffsetAlignment` and `minTexelBufferOffsetAlignment`,
    /// at least 4): a range at another offset is refused with
    /// [`PlacementProblem::Misaligned`](crate::gpu::PlacementProblem::Misaligned).
    pub fn placement_alignment(ctx: &Context) -> u64 {
        crate::gpu::placement::alignment(ctx)
    }

    /// Bytes of the structure over `geometries` built with `flags`, of its build's scratch
    /// and of an update's scratch (`None`: this kind cannot be updated, or `flags` does not
    /// allow it), exactly as [`AccelBuilder::create_in`] and the recordings place them.
    ///
    /// `geometries` are [`Geometry`]s (their buffers checked too) or [`GeometryShape`]s,
    /// their counts alone (`vkGetAccelerationStructureBuildSizesKHR`'s `maxPrimitiveCount`
    /// and description without addresses): the sizes are the same, and depend on nothing
    /// else.
    ///
    /// [`GeometryShape`]: crate::accel::geometry_shape::GeometryShape
    pub fn sizes_for<G: GeometryDescription>(
        &self,
        ctx: &Context,
        geometries: &[G],
        flags: &BuildFlags,
    ) -> Result<AccelSizes> {
        self.check_device_input("AccelBuilder::sizes_for", geometries)?;
        let input = DeviceInput::new(ctx, geometries, *flags)?;
        let (_, structure_bytes) = place(ctx, "the structure", Placement::Measure, || {
            self.place_structure(ctx, &input)
        })?;
        let n = input.layout.primitive_count();
        let (_, build_scratch_bytes) = place(ctx, "the build scratch", Placement::Measure, || {
            self.scratch_for(ctx, &input)
        })?;
        let update_scratch_bytes = match (self.kind(), flags.allow_update) {
            (AccelKind::KdTree, _) | (_, false) => None,
            (AccelKind::Driver, _) => Some(build_scratch_bytes),
            _ => Some(
                place(ctx, "the update scratch", Placement::Measure, || {
                    self.update_scratch(ctx, n)
                })?
                .1,
            ),
        };
        Ok(AccelSizes {
            structure_bytes,
            build_scratch_bytes,
            update_scratch_bytes,
        })
    }

    /// The build scratch (and the driver's update scratch: one buffer serves both).
    pub(crate) fn scratch_for(&self, ctx: &Context, input: &DeviceInput) -> Result<AccelScratch> {
        let f = &input.flags;
        match self.kind() {
            AccelKind::Driver => Ok(AccelScratch(Scratch::Driver(Some(
                DriverAccel::create_scratch(
                    ctx,
                    &driver_counts(&input.layout),
                    f.prefer,
                    f.allow_update,
                )?,
            )))),
            _ => self.create_scratch(
                ctx,
                input.layout.primitive_count(),
                f.kd_capacity_doublings,
                f.allow_update,
            ),
        }
    }

    fn place_structure(&self, ctx: &Context, input: &DeviceInput) -> Result<GpuGeometry> {
        let l = &input.layout;
        let n = l.primitive_count();
        let prims = DevicePrimitives::for_layout(ctx, l)?;
        let mut accel = self.create_structure(ctx, n, &input.flags, l.info_len())?;
        if let Some(levels) = driver_levels::storage_mut(&mut accel).map(|d| &mut d.levels) {
            // While measuring, the primitives' buffers are placeholders without addresses.
            let driver_input = match crate::gpu::placement::measuring() {
                true => driver_counts(l),
                false => DriverInput::of(&prims),
            };
            let f = &input.flags;
            *levels = DriverAccel::create(ctx, &driver_input, f.prefer, f.allow_update, false)?
                .map(Box::new);
        }
        Ok(GpuGeometry {
            prims,
            accel,
            device_input: Some(input.clone()),
            life: Default::default(),
        })
    }

    /// The structure over `geometries` (built with `flags`), placed at the start of
    /// `memory`, a range of the caller's buffer of at least
    /// [`AccelSizes::structure_bytes`] with [`REQUIRED_BUFFER_USAGE`]. It holds no data
    /// until [`AccelBuilder::record_build_from`] has executed. The caller keeps `memory`
    /// alive as long as the structure is used.
    ///
    /// A structure over the caller's vertex buffer, in memory the caller allocates, as
    /// `vkCreateAccelerationStructureKHR` places one: the
    /// [embedding guide](crate::guide::embedding)'s section 3 has the whole of it, run as a
    /// test.
    pub fn create_in(
        &self,
        ctx: &Context,
        geometries: &[Geometry],
        flags: &BuildFlags,
        memory: RawBuffer,
    ) -> Result<GpuGeometry> {
        self.check_device_input("AccelBuilder::create_in", geometries)?;
        let input = DeviceInput::new(ctx, geometries, *flags)?;
        let (g, _) = place(ctx, "the structure", Placement::Into(memory), || {
            self.place_structure(ctx, &input)
        })?;
        Ok(g)
    }

    /// Records the read of `geometries` into `out`'s primitive arrays and scene constants.
    fn record_gather(
        &self,
        rec: &mut Recorder,
        geometries: &[Geometry],
        input: &DeviceInput,
        out: &GpuGeometry,
    ) -> Result<()> {
        // The structure's own flags: wide nodes only where its kind has them.
        let flags = out.accel.flags();
        let (walk, parents_at) = self.scene_header(&flags, input.layout.primitive_count());
        GeometryGather::new(rec.context())?.record(
            rec,
            geometries,
            &input.layout,
            &out.prims,
            &out.accel.info,
            walk,
            parents_at,
        )
    }

    /// The description of `out` that a build into it over `geometries` checks against.
    pub(crate) fn input_of<'a>(
        &self,
        call: &'static str,
        geometries: &[Geometry],
        out: &'a GpuGeometry,
    ) -> Result<&'a DeviceInput> {
        self.device_input_of(call, geometries, out, false)
    }

    /// [`AccelBuilder::input_of`] for an update, which a compacted BVH takes too (its
    /// topology is the original's, renumbered, and its refit schedule came with it).
    fn update_input_of<'a>(
        &self,
        call: &'static str,
        geometries: &[Geometry],
        out: &'a GpuGeometry,
    ) -> Result<&'a DeviceInput> {
        self.device_input_of(call, geometries, out, true)
    }

    fn device_input_of<'a>(
        &self,
        call: &'static str,
        geometries: &[Geometry],
        out: &'a GpuGeometry,
        compacted_ok: bool,
    ) -> Result<&'a DeviceInput> {
        let input = out.device_input.as_ref().ok_or_else(|| {
            usage(
                call,
                "this structure was not created over device geometry (AccelBuilder::create_in)",
            )
        })?;
        if input.compacted.is_some() && !compacted_ok {
            return Err(usage(
                call,
                "a compacted structure holds its tree's bytes only: build into the structure \
                 it was compacted from, or create one (create_in); a compacted BVH built \
                 with allow_update can be updated",
            ));
        }
        self.check_device_input(call, geometries)?;
        self.check_frozen(call, &out.accel)?;
        if shape(geometries) != input.shape {
            return Err(usage(
                call,
                "the geometries differ from those the structure was created for (their \
                 kinds or primitive counts): create a structure for them",
            ));
        }
        Ok(input)
    }

    /// Records the build of `out` over `geometries` (the ones it was created for, their
    /// buffers now holding the data: the caller orders its writes before, as compute or
    /// transfer writes) into `rec`, with its scratch in `scratch`, a range of the caller's
    /// buffer of at least [`AccelSizes::build_scratch_bytes`]. Ends with one barrier from all
    /// its work to compute-shader reads and writes, after which kernels recorded next (the
    /// caller's, through `vkrt/ray_query.glsl`) may trace it. Allocates, uploads and submits
    /// nothing.
    ///
    /// Synchronization ([`crate::accel::sync`]): the caller's barrier before it has
    /// [`RecordSync::build`]`(kind).first` as its destination — with, for a rebuild in
    /// place, every stage that read the structure before (the previous frame's fragment
    /// shader, say) in its source; its consumers other than compute shaders wait on
    /// [`RecordSync::build`]`(kind).last` (compute-shader writes). It leaves vkrt's compute
    /// pipeline, descriptor set 0 and push constants bound at the compute bind point.
    ///
    /// [`RecordSync::build`]: crate::accel::sync::RecordSync::build
    pub fn record_build_from(
        &self,
        rec: &mut Recorder,
        out: &mut GpuGeometry,
        geometries: &[Geometry],
        scratch: RawBuffer,
    ) -> Result<()> {
        let target = BuildTarget {
            geometries,
            out,
            scratch,
        };
        self.record_builds("AccelBuilder::record_build_from", rec, &mut [target])
    }

    /// Records an update (refit) of `out`, built with `allow_update`, to the positions its
    /// geometries' buffers hold now (the same geometries, moved), with its scratch in
    /// `scratch` (at least [`AccelSizes::update_scratch_bytes`]). A kd-tree cannot be
    /// updated (its split planes are fixed): rebuild it. A compacted LBVH or PLOC
    /// ([`crate::accel::compact`]) is updated as the structure it was compacted from, with
    /// that structure's update scratch. Synchronized as
    /// [`AccelBuilder::record_build_from`] is ([`RecordSync::build`]): an update in place
    /// after the previous frame's reads needs the same write-after-read barrier.
    ///
    /// [`RecordSync::build`]: crate::accel::sync::RecordSync::build
    pub fn record_update_from(
        &self,
        rec: &mut Recorder,
        out: &mut GpuGeometry,
        geometries: &[Geometry],
        scratch: RawBuffer,
    ) -> Result<()> {
        let call = "AccelBuilder::record_update_from";
        let input = self.update_input_of(call, geometries, out)?.clone();
        if self.kind() == AccelKind::KdTree {
            return Err(usage(
                call,
                "a kd-tree cannot be updated (its split planes are fixed): rebuild it",
            ));
        }
        if !input.built {
            return Err(GpuError::NotBuilt { call });
        }
        if !input.flags.allow_update {
            return Err(usage(
                call,
                "the structure was not built with allow_update: rebuild it, or create it \
                 with BuildFlags::allow_update",
            ));
        }
        let ctx = rec.context().clone();
        let n = input.layout.primitive_count();
        if self.kind() == AccelKind::Driver {
            let (scratch, _) = place(&ctx, "the update scratch", Placement::Into(scratch), || {
                self.scratch_for(&ctx, &input)
            })?;
            let (Scratch::Driver(Some(scratch)), Some(levels)) =
                (scratch.0, driver_levels::levels(&out.accel))
            else {
                return Err(usage(call, "the driver's levels were not created"));
            };
            return rec.scope("update", |rec| {
                self.record_gather(rec, geometries, &input, out)?;
                levels.record_update(rec, Some(&scratch))?;
                rec.keep_alive(scratch);
                rec.end_of_build();
                rec.check()
            });
        }
        let (visits, _) = place(&ctx, "the update scratch", Placement::Into(scratch), || {
            self.update_scratch(&ctx, n)
        })?;
        let visits = visits.ok_or_else(|| usage(call, "this kind cannot be updated"))?;
        rec.scope("update", |rec| {
            self.record_gather(rec, geometries, &input, out)?;
            self.record_refit(rec, out, &visits)
        })?;
        rec.check()
    }
}
