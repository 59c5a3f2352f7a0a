//! The driver's own acceleration structures (`VK_KHR_acceleration_structure`): build sizes,
//! structures living in a [`Buffer`], and builds recorded into a [`Recorder`]. Only on
//! devices with [`super::DeviceFeatures::ray_query`]; elsewhere every entry point returns
//! [`GpuError::MissingCapability`] naming the extensions.
//!
//! Inputs (vertices, instances) and scratch are read at device addresses, so the buffers
//! holding them come from [`Buffer`] (which adds the usages these need when ray query is on).

use ash::vk;

use super::buffer::{Buffer, BufferArg};
use super::context::Context;
use super::error::{vk_err, GpuError, Result};
use super::recorder::Recorder;

/// One instance of a bottom-level structure in a top-level one: `VkAccelerationStructureInstanceKHR`
/// byte for byte (64 bytes), but `Pod`, so it can be uploaded.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct AccelInstance {
    /// Row-major 3×4 object-to-world transform.
    pub transform: [f32; 12],
    /// Custom index (low 24 bits) and visibility mask (high 8 bits).
    pub custom_index_and_mask: u32,
    /// Shader binding table offset (low 24 bits) and `VkGeometryInstanceFlagsKHR` (high 8).
    pub sbt_offset_and_flags: u32,
    /// Device address of the bottom-level structure.
    pub blas: u64,
}

impl AccelInstance {
    /// `blas` untransformed, visible to every mask, custom index 0.
    pub fn identity(blas: u64) -> Self {
        Self {
            transform: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0],
            custom_index_and_mask: 0xff << 24,
            sbt_offset_and_flags: 0,
            blas,
        }
    }
}

/// What a structure is built over.
#[derive(Clone, Copy, Debug)]
pub enum AccelGeometry {
    /// A bottom level over `count` opaque non-indexed triangles: three R32G32B32_SFLOAT
    /// vertices each (stride 12), from device address `vertices`.
    Triangles {
        /// Device address of the first vertex.
        vertices: u64,
        /// Number of triangles.
        count: u32,
    },
    /// A bottom level over `count` procedural primitives: boxes of six floats (min x, y, z,
    /// max x, y, z: `VkAabbPositionsKHR`) every `stride` bytes from device address `boxes`
    /// (both multiples of 8). Rays meet them as candidates the querying kernel intersects.
    Aabbs {
        /// Device address of the first box.
        boxes: u64,
        /// Bytes from one box to the next.
        stride: u64,
        /// Number of boxes.
        count: u32,
    },
    /// A top level over `count` [`AccelInstance`]s at device address `instances`.
    Instances {
        /// Device address of the first instance.
        instances: u64,
        /// Number of instances.
        count: u32,
    },
}

impl AccelGeometry {
    fn level(self) -> vk::AccelerationStructureTypeKHR {
        match self {
            AccelGeometry::Triangles { .. } | AccelGeometry::Aabbs { .. } => {
                vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL
            }
            AccelGeometry::Instances { .. } => vk::AccelerationStructureTypeKHR::TOP_LEVEL,
        }
    }

    fn count(self) -> u32 {
        match self {
            AccelGeometry::Triangles { count, .. }
            | AccelGeometry::Aabbs { count, .. }
            | AccelGeometry::Instances { count, .. } => count,
        }
    }

    fn vk(self) -> vk::AccelerationStructureGeometryKHR<'static> {
        match self {
            AccelGeometry::Triangles { vertices, count } => {
                let triangles = vk::AccelerationStructureGeometryTrianglesDataKHR::default()
                    .vertex_format(vk::Format::R32G32B32_SFLOAT)
                    .vertex_data(vk::DeviceOrHostAddressConstKHR {
                        device_address: vertices,
                    })
                    .vertex_stride(12)
                    .max_vertex((3 * count).saturating_sub(1))
                    .index_type(vk::IndexType::NONE_KHR);
                vk::AccelerationStructureGeometryKHR::default()
                    .geometry_type(vk::GeometryTypeKHR::TRIANGLES)
                    .geometry(vk::AccelerationStructureGeometryDataKHR { triangles })
                    .flags(vk::GeometryFlagsKHR::OPAQUE)
            }
            AccelGeometry::Aabbs { boxes, stride, .. } => {
                let aabbs = vk::AccelerationStructureGeometryAabbsDataKHR::default()
                    .data(vk::DeviceOrHostAddressConstKHR {
                        device_address: boxes,
                    })
                    .stride(stride);
                vk::AccelerationStructureGeometryKHR::default()
                    .geometry_type(vk::GeometryTypeKHR::AABBS)
                    .geometry(vk::AccelerationStructureGeometryDataKHR { aabbs })
                    .flags(vk::GeometryFlagsKHR::OPAQUE)
            }
            AccelGeometry::Instances { instances, .. } => {
                let instances = vk::AccelerationStructureGeometryInstancesDataKHR::default()
                    .array_of_pointers(false)
                    .data(vk::DeviceOrHostAddressConstKHR {
                        device_address: instances,
                    });
                vk::AccelerationStructureGeometryKHR::default()
                    .geometry_type(vk::GeometryTypeKHR::INSTANCES)
                    .geometry(vk::AccelerationStructureGeometryDataKHR { instances })
                    .flags(vk::GeometryFlagsKHR::OPAQUE)
            }
        }
    }
}

/// The level of a structure built over `geometries`: bottom (triangles and boxes; also an
/// empty list) or top (instances); a mix is a usage error.
fn level_of(geometries: &[AccelGeometry]) -> Result<vk::AccelerationStructureTypeKHR> {
    let bottom = vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL;
    let level = geometries.first().map_or(bottom, |g| g.level());
    if geometries.iter().any(|g| g.level() != level) {
        return Err(misuse(
            "instances and primitives in one acceleration structure",
        ));
    }
    Ok(level)
}

fn misuse(reason: impl Into<String>) -> GpuError {
    GpuError::Usage {
        call: "AccelerationStructure",
        reason: reason.into(),
    }
}

/// Bytes the driver's build needs (`vkGetAccelerationStructureBuildSizesKHR`): the
/// structure's storage and the scratch of a build and of an update (to be allocated with
/// [`accel_scratch`]). vkrt's own structures report theirs as `accel::AccelSizes`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DriverBuildSizes {
    /// Bytes of the structure itself (`accelerationStructureSize`).
    pub structure: u64,
    /// Bytes of scratch a build needs (`buildScratchSize`).
    pub scratch: u64,
    /// Bytes of scratch an update in place needs (`updateScratchSize`).
    pub update_scratch: u64,
}

/// The extension's functions, or the error naming what the device lacks.
fn ext(ctx: &Context) -> Result<&ash::khr::acceleration_structure::Device> {
    ctx.inner
        .accel_ext
        .as_ref()
        .ok_or_else(|| GpuError::MissingCapability {
            device: ctx.info().device.clone(),
            what: "the driver's ray tracing: VK_KHR_acceleration_structure, \
                   VK_KHR_deferred_host_operations and VK_KHR_ray_query with the \
                   accelerationStructure, rayQuery and bufferDeviceAddress features \
                   (Mesa's lavapipe has them from 25.x)"
                .into(),
        })
}

/// `Ok` where the device has the driver's ray tracing enabled, else the error naming the
/// missing extensions and features.
pub fn require_ray_query(ctx: &Context) -> Result<()> {
    ext(ctx).map(drop)
}

/// Sizes of a device build over `geometries` (one level) with `flags`.
pub fn accel_build_sizes(
    ctx: &Context,
    geometries: &[AccelGeometry],
    flags: vk::BuildAccelerationStructureFlagsKHR,
) -> Result<DriverBuildSizes> {
    let ext = ext(ctx)?;
    let level = level_of(geometries)?;
    let counts: Vec<u32> = geometries.iter().map(|g| g.count()).collect();
    let geometries: Vec<_> = geometries.iter().map(|g| g.vk()).collect();
    let info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
        .ty(level)
        .flags(flags)
        .mode(vk::BuildAccelerationStructureModeKHR::BUILD)
        .geometries(&geometries);
    let mut sizes = vk::AccelerationStructureBuildSizesInfoKHR::default();
    // SAFETY: the extension is enabled (ext() returned it); `info` points at `geometries`,
    // which lives across the call; one primitive count per geometry.
    unsafe {
        ext.get_acceleration_structure_build_sizes(
            vk::AccelerationStructureBuildTypeKHR::DEVICE,
            &info,
            &counts,
            &mut sizes,
        )
    };
    Ok(DriverBuildSizes {
        structure: sizes.acceleration_structure_size,
        scratch: sizes.build_scratch_size,
        update_scratch: sizes.update_scratch_size,
    })
}

/// `minAccelerationStructureScratchOffsetAlignment` of the device.
fn scratch_alignment(ctx: &Context) -> u64 {
    let mut props = vk::PhysicalDeviceAccelerationStructurePropertiesKHR::default();
    let mut props2 = vk::PhysicalDeviceProperties2::default().push_next(&mut props);
    // SAFETY: valid physical device; the chained struct lives across the call.
    unsafe {
        ctx.inner
            .instance
            .get_physical_device_properties2(ctx.inner.physical_device, &mut props2)
    };
    u64::from(
        props
            .min_acceleration_structure_scratch_offset_alignment
            .max(1),
    )
}

/// A scratch buffer for builds needing up to `bytes` of scratch, with room to align its
/// address to the device's scratch alignment (see [`AccelerationStructure::record_build`]).
pub fn accel_scratch(ctx: &Context, bytes: u64) -> Result<Buffer<u8>> {
    ext(ctx)?;
    Buffer::new(
        ctx,
        "accel.scratch",
        (bytes + scratch_alignment(ctx)) as usize,
    )
}

/// A driver acceleration structure on a buffer of its own.
pub struct AccelerationStructure {
    ctx: crate::gpu::teardown::Held,
    raw: vk::AccelerationStructureKHR,
    geometry_level: vk::AccelerationStructureTypeKHR,
    bytes: u64,
    address: u64,
    // Dropped after the structure (Drop destroys `raw` first).
    _storage: Buffer<u8>,
}

impl AccelerationStructure {
    /// An unbuilt structure of `bytes` (from [`accel_build_sizes`]) for `geometries`' level.
    pub fn new(
        ctx: &Context,
        name: &str,
        geometries: &[AccelGeometry],
        bytes: u64,
    ) -> Result<Self> {
        let ext = ext(ctx)?;
        let storage = Buffer::<u8>::new(ctx, name, Self::storage_bytes(bytes) as usize)?;
        let level = level_of(geometries)?;
        let offset = storage.offset().next_multiple_of(256);
        let create = vk::AccelerationStructureCreateInfoKHR::default()
            .buffer(storage.raw)
            .offset(offset)
            .size(bytes)
            .ty(level);
        // SAFETY: the extension is enabled; `storage` has ACCELERATION_STRUCTURE_STORAGE
        // usage (Buffer adds it with ray query; a caller's buffer it is placed in must have
        // it, DRIVER_BUFFER_USAGE), and `bytes` from `offset` (a multiple of 256, as Vulkan
        // requires) lie inside it; it outlives the structure (field order and Drop).
        let raw = unsafe { ext.create_acceleration_structure(&create, None) }
            .map_err(vk_err("vkCreateAccelerationStructureKHR"))?;
        ctx.inner.created(1);
        let info =
            vk::AccelerationStructureDeviceAddressInfoKHR::default().acceleration_structure(raw);
        // SAFETY: `raw` is a live structure of this device.
        let address = unsafe { ext.get_acceleration_structure_device_address(&info) };
        ctx.set_object_name(raw, name);
        Ok(Self {
            ctx: crate::gpu::teardown::Held::new(
                ctx,
                crate::gpu::teardown::Holder::DriverStructure,
            ),
            raw,
            geometry_level: level,
            bytes,
            address,
            _storage: storage,
        })
    }

    /// Counts the bytes of a structure's buffer while sizes are measured
    /// ([`super::placement::measuring`]), where no structure can be created.
    pub fn reserve(ctx: &Context, name: &str, bytes: u64) -> Result<()> {
        ext(ctx)?;
        Buffer::<u8>::new(ctx, name, Self::storage_bytes(bytes) as usize).map(drop)
    }

    /// Bytes of buffer a structure of `bytes` is created on (room to start it at a multiple
    /// of 256 wherever the buffer is placed).
    pub fn storage_bytes(bytes: u64) -> u64 {
        bytes + 255
    }

    /// Bytes of its storage.
    pub fn byte_len(&self) -> u64 {
        self.bytes
    }

    /// Its device address: what instances point at and what kernels query.
    pub fn device_address(&self) -> u64 {
        self.address
    }

    /// The Vulkan handle, for a descriptor write (valid while `self` lives).
    pub fn raw(&self) -> vk::AccelerationStructureKHR {
        self.raw
    }

    /// Records the build of this structure over `geometries` into `rec`, with scratch from
    /// `scratch` ([`accel_scratch`] of at least the size's scratch). Order the writes of
    /// the inputs before with [`Recorder::to_accel_build`], and the build before its users
    /// with [`Recorder::accel_build_to_accel_build`] or
    /// [`Recorder::accel_build_to_compute`]. `self`, the inputs and `scratch` must outlive
    /// the execution.
    pub fn record_build(
        &self,
        rec: &mut Recorder,
        geometries: &[AccelGeometry],
        flags: vk::BuildAccelerationStructureFlagsKHR,
        scratch: &Buffer<u8>,
    ) -> Result<()> {
        self.record(rec, geometries, flags, scratch, false)
    }

    /// Records an update (refit) of this structure, built before with `flags` holding
    /// `ALLOW_UPDATE`, over the same `geometries` with moved positions: the driver keeps
    /// the topology and recomputes the bounds in place. Ordering as for
    /// [`AccelerationStructure::record_build`]; `scratch` holds the update's scratch.
    pub fn record_update(
        &self,
        rec: &mut Recorder,
        geometries: &[AccelGeometry],
        flags: vk::BuildAccelerationStructureFlagsKHR,
        scratch: &Buffer<u8>,
    ) -> Result<()> {
        if !flags.contains(vk::BuildAccelerationStructureFlagsKHR::ALLOW_UPDATE) {
            return Err(misuse(
                "an update of a structure not built with ALLOW_UPDATE",
            ));
        }
        self.record(rec, geometries, flags, scratch, true)
    }

    fn record(
        &self,
        rec: &mut Recorder,
        geometries: &[AccelGeometry],
        flags: vk::BuildAccelerationStructureFlagsKHR,
        scratch: &Buffer<u8>,
        update: bool,
    ) -> Result<()> {
        let ctx = rec.context().clone();
        let ext = ext(&ctx)?;
        if level_of(geometries)? != self.geometry_level {
            return Err(misuse(
                "an acceleration structure built at another level than created",
            ));
        }
        let sizes = accel_build_sizes(&ctx, geometries, flags)?;
        if sizes.structure > self.bytes {
            return Err(misuse(format!(
                "the build needs {} bytes of structure, {} were created",
                sizes.structure, self.bytes
            )));
        }
        let needed = if update {
            sizes.update_scratch
        } else {
            sizes.scratch
        };
        let align = scratch_alignment(&ctx);
        let base = scratch.address();
        let scratch_address = base.next_multiple_of(align);
        if scratch_address - base + needed > scratch.byte_len() {
            return Err(misuse(format!(
                "`{}` holds {} bytes; the build needs {needed} of scratch aligned to {align}",
                scratch.name(),
                scratch.byte_len(),
            )));
        }
        let (mode, src) = if update {
            (vk::BuildAccelerationStructureModeKHR::UPDATE, self.raw)
        } else {
            (
                vk::BuildAccelerationStructureModeKHR::BUILD,
                vk::AccelerationStructureKHR::null(),
            )
        };
        let ranges: Vec<_> = geometries
            .iter()
            .map(|g| {
                vk::AccelerationStructureBuildRangeInfoKHR::default().primitive_count(g.count())
            })
            .collect();
        let geometries: Vec<_> = geometries.iter().map(|g| g.vk()).collect();
        let info = [vk::AccelerationStructureBuildGeometryInfoKHR::default()
            .ty(self.geometry_level)
            .flags(flags)
            .mode(mode)
            .src_acceleration_structure(src)
            .dst_acceleration_structure(self.raw)
            .geometries(&geometries)
            .scratch_data(vk::DeviceOrHostAddressKHR {
                device_address: scratch_address,
            })];
        let range_refs: [&[vk::AccelerationStructureBuildRangeInfoKHR]; 1] = [&ranges];
        // SAFETY: recording outside a render pass; the extension is enabled; `info` and
        // `ranges` point at locals living across the call, one range per geometry; the
        // destination was created for this level with the storage the sizes ask for and the
        // scratch range is inside `scratch` and aligned (both checked above); an update's
        // source is this structure, built before with ALLOW_UPDATE (the caller's contract,
        // flags checked); the caller keeps inputs, scratch and `self` alive until the work
        // executes.
        unsafe { ext.cmd_build_acceleration_structures(rec.command_buffer(), &info, &range_refs) };
        Ok(())
    }
}

impl Drop for AccelerationStructure {
    fn drop(&mut self) {
        if let Some(ext) = self.ctx.inner.accel_ext.as_ref() {
            // SAFETY: as for buffers: vkrt waits for its submissions, and work recorded into
            // a caller's command buffer must have executed before the structure is dropped.
            unsafe { ext.destroy_acceleration_structure(self.raw, None) };
        }
    }
}
