//! `VK_KHR_acceleration_structure`'s objects and builds, on vkrt's builders.
//!
//! A structure lies where the application placed it: `HEADER` bytes of the layer's, then
//! vkrt's structure. The header holds, at its start, a copy of the handle vkrt's walk
//! follows (a bottom level's seven array addresses, a top level's sixteen words), so the
//! structure's device address is its buffer's address plus its offset, fixed for its life,
//! and followed directly by instance records and shaders; at `TEXEL_AT`, that address
//! again, the one texel of the uniform texel buffer a lowered shader's descriptor reads.
//! Each build writes both (constants carried by the command buffer), so a rebuild over
//! other counts, which moves vkrt's arrays, moves nothing the application holds.

use std::collections::HashSet;
use std::sync::{Arc, Mutex};

use ash::vk;
use vkrt::accel::instances::InstancePointers;
use vkrt::gpu::{DeviceRange, RawBuffer, Recorder};
use vkrt::{
    Aabbs, AccelBuilder, AccelKind, AccelSizes, BuildFlags, Geometry, GeometryShape, GpuGeometry,
    IndexType, Indices, TopLevel, TopLevelBuilder, Transform, Triangles, VertexFormat,
};

use crate::device::{served, Served};
use crate::{commands, guard, log, pfn};

/// The layer's bytes at the start of every structure.
pub const HEADER: u64 = 512;
/// Where the header keeps the structure's address, as a texel (aligned for any device's
/// `minTexelBufferOffsetAlignment`, since structures start 256-byte aligned).
const TEXEL_AT: u64 = 256;
/// Scratch the layer asks for at least, so that no build is given a null address.
const MIN_SCRATCH: u64 = 256;

/// A structure the application created.
pub struct AccelObject {
    buffer: vk::Buffer,
    offset: u64,
    size: u64,
    /// Its device address: its buffer's plus its offset.
    pub address: u64,
    /// One RGBA32UI texel over the header's copy of the address: the descriptor.
    pub view: vk::BufferView,
    built: Mutex<Option<Built>>,
}

/// What vkrt's structure in it was last created for.
enum Built {
    Bottom {
        kind: AccelKind,
        flags: BuildFlags,
        shapes: Vec<GeometryShape>,
        /// Its last build's geometries (a copy re-creates the structure over them).
        geometries: Vec<Geometry>,
        sizes: AccelSizes,
        geometry: Box<GpuGeometry>,
    },
    Top {
        kind: AccelKind,
        flags: BuildFlags,
        max: u32,
        sizes: AccelSizes,
        top: Box<TopLevel>,
    },
}

impl AccelObject {
    /// The range vkrt's structure is placed in.
    fn memory(&self) -> RawBuffer {
        // SAFETY: the structure's own range of the app's buffer, which the extension's valid
        // usage keeps alive and bound while commands using the structure execute.
        unsafe {
            RawBuffer::new(
                self.buffer,
                self.offset + HEADER,
                self.size.saturating_sub(HEADER),
            )
        }
    }

    /// The structure's header (its first 64 bytes), under the same contract.
    fn header(&self) -> RawBuffer {
        // SAFETY: as in `memory`; called by builds, which first check that the structure
        // holds HEADER bytes and its tree.
        unsafe { RawBuffer::new(self.buffer, self.offset, 64) }
    }
}

/// vkrt's builders on a device (made at the first use of each), and its live structures.
#[derive(Default)]
pub struct Builders {
    bottom: Mutex<Vec<(AccelKind, Arc<AccelBuilder>)>>,
    top: Mutex<Vec<(AccelKind, Arc<TopLevelBuilder>)>>,
    pointers: Mutex<Option<Arc<InstancePointers>>>,
    live: Mutex<HashSet<u64>>,
}

impl Builders {
    /// Makes every builder the layer may use, compiling their kernels: at device creation,
    /// on a thread of its own, so that the application's first build records with kernels
    /// ready (or waits for them) rather than compiling them while it records.
    pub fn warm(&self, ctx: &vkrt::Context) {
        for kind in [AccelKind::Lbvh, AccelKind::Ploc] {
            if let Err(e) = self.bottom(ctx, kind).and(self.top(ctx, kind)) {
                log(&format!("vkrt's {} builder: {e}", kind.name()));
            }
        }
        if let Err(e) = self.pointers(ctx) {
            log(&format!("the instance-pointer gather: {e}"));
        }
        // The geometry gather's kernels live in the context's kernel cache from now on.
        if let Err(e) = vkrt::accel::geometry::GeometryGather::new(ctx) {
            log(&format!("the geometry gather: {e}"));
        }
    }

    fn bottom(&self, ctx: &vkrt::Context, kind: AccelKind) -> vkrt::gpu::Result<Arc<AccelBuilder>> {
        let mut b = self.bottom.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, b)) = b.iter().find(|(k, _)| *k == kind) {
            return Ok(b.clone());
        }
        let new = Arc::new(AccelBuilder::new(ctx, kind)?);
        b.push((kind, new.clone()));
        Ok(new)
    }

    fn pointers(&self, ctx: &vkrt::Context) -> vkrt::gpu::Result<Arc<InstancePointers>> {
        let mut p = self.pointers.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(p) = p.as_ref() {
            return Ok(p.clone());
        }
        let new = Arc::new(InstancePointers::new(ctx)?);
        *p = Some(new.clone());
        Ok(new)
    }

    fn top(&self, ctx: &vkrt::Context, kind: AccelKind) -> vkrt::gpu::Result<Arc<TopLevelBuilder>> {
        let mut t = self.top.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, t)) = t.iter().find(|(k, _)| *k == kind) {
            return Ok(t.clone());
        }
        let new = Arc::new(TopLevelBuilder::new(ctx, kind)?);
        t.push((kind, new.clone()));
        Ok(new)
    }

    /// The structure behind `handle`, if it is one the application holds.
    pub fn object(&self, handle: vk::AccelerationStructureKHR) -> Option<&AccelObject> {
        let raw = vk::Handle::as_raw(handle);
        if !self.live.lock().ok()?.contains(&raw) {
            return None;
        }
        // SAFETY: a live handle is a pointer from Box::into_raw, freed only when it leaves
        // the set (vkDestroyAccelerationStructureKHR, which the application does not call
        // while using it).
        Some(unsafe { &*(raw as usize as *const AccelObject) })
    }

    /// Frees the structures the application left at vkDestroyDevice.
    pub fn clear(&self, fns: &ash::Device) {
        let live: Vec<u64> = self
            .live
            .lock()
            .map(|mut l| l.drain().collect())
            .unwrap_or_default();
        for raw in live {
            // SAFETY: taken out of the set: the only owner.
            let object = unsafe { Box::from_raw(raw as usize as *mut AccelObject) };
            // SAFETY: the device is idle.
            unsafe { fns.destroy_buffer_view(object.view, None) };
        }
    }
}

/// The builder a structure's flags ask for: PLOC's better trees for PREFER_FAST_TRACE,
/// the LBVH's quicker builds otherwise.
fn kind_and_flags(f: vk::BuildAccelerationStructureFlagsKHR) -> (AccelKind, BuildFlags) {
    let kind = match f.contains(vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE) {
        true => AccelKind::Ploc,
        false => AccelKind::Lbvh,
    };
    let flags = BuildFlags {
        allow_update: f.contains(vk::BuildAccelerationStructureFlagsKHR::ALLOW_UPDATE),
        ..BuildFlags::default()
    };
    (kind, flags)
}

pub fn function(name: &[u8]) -> vk::PFN_vkVoidFunction {
    match name {
        b"vkCreateAccelerationStructureKHR" => {
            pfn!(create, vk::PFN_vkCreateAccelerationStructureKHR)
        }
        b"vkDestroyAccelerationStructureKHR" => {
            pfn!(destroy, vk::PFN_vkDestroyAccelerationStructureKHR)
        }
        b"vkGetAccelerationStructureDeviceAddressKHR" => {
            pfn!(address, vk::PFN_vkGetAccelerationStructureDeviceAddressKHR)
        }
        b"vkGetAccelerationStructureBuildSizesKHR" => {
            pfn!(build_sizes, vk::PFN_vkGetAccelerationStructureBuildSizesKHR)
        }
        b"vkCmdBuildAccelerationStructuresKHR" => {
            pfn!(cmd_build, vk::PFN_vkCmdBuildAccelerationStructuresKHR)
        }
        b"vkCmdBuildAccelerationStructuresIndirectKHR" => pfn!(
            cmd_build_indirect,
            vk::PFN_vkCmdBuildAccelerationStructuresIndirectKHR
        ),
        b"vkGetDeviceAccelerationStructureCompatibilityKHR" => pfn!(
            compatibility,
            vk::PFN_vkGetDeviceAccelerationStructureCompatibilityKHR
        ),
        b"vkBuildAccelerationStructuresKHR" => {
            pfn!(host_build, vk::PFN_vkBuildAccelerationStructuresKHR)
        }
        b"vkCopyAccelerationStructureKHR" => {
            pfn!(host_copy, vk::PFN_vkCopyAccelerationStructureKHR)
        }
        b"vkCopyAccelerationStructureToMemoryKHR" => pfn!(
            host_copy_to_memory,
            vk::PFN_vkCopyAccelerationStructureToMemoryKHR
        ),
        b"vkCopyMemoryToAccelerationStructureKHR" => pfn!(
            host_copy_from_memory,
            vk::PFN_vkCopyMemoryToAccelerationStructureKHR
        ),
        b"vkWriteAccelerationStructuresPropertiesKHR" => pfn!(
            host_properties,
            vk::PFN_vkWriteAccelerationStructuresPropertiesKHR
        ),
        b"vkCmdCopyAccelerationStructureKHR" => {
            pfn!(cmd_copy, vk::PFN_vkCmdCopyAccelerationStructureKHR)
        }
        b"vkCmdCopyAccelerationStructureToMemoryKHR" => pfn!(
            cmd_copy_to_memory,
            vk::PFN_vkCmdCopyAccelerationStructureToMemoryKHR
        ),
        b"vkCmdCopyMemoryToAccelerationStructureKHR" => pfn!(
            cmd_copy_from_memory,
            vk::PFN_vkCmdCopyMemoryToAccelerationStructureKHR
        ),
        _ => None,
    }
}

unsafe extern "system" fn create(
    device: vk::Device,
    info: *const vk::AccelerationStructureCreateInfoKHR<'_>,
    _allocator: *const vk::AllocationCallbacks<'_>,
    out: *mut vk::AccelerationStructureKHR,
) -> vk::Result {
    guard(vk::Result::ERROR_OUT_OF_HOST_MEMORY, || {
        let Some(s) = served(device) else {
            return vk::Result::ERROR_DEVICE_LOST;
        };
        // SAFETY: the application's valid create info.
        let info = unsafe { &*info };
        if info
            .create_flags
            .contains(vk::AccelerationStructureCreateFlagsKHR::DEVICE_ADDRESS_CAPTURE_REPLAY)
        {
            log("vkCreateAccelerationStructureKHR: capture and replay is not supported (accelerationStructureCaptureReplay is false)");
            return vk::Result::ERROR_FEATURE_NOT_PRESENT;
        }
        let view_info = vk::BufferViewCreateInfo::default()
            .buffer(info.buffer)
            .format(vk::Format::R32G32B32A32_UINT)
            .offset(info.offset + TEXEL_AT)
            .range(16);
        // SAFETY: the application's buffer, which the layer gave texel usage; an offset
        // a multiple of 256, as the extension requires of structures.
        let view = match unsafe { s.fns.create_buffer_view(&view_info, None) } {
            Ok(v) => v,
            Err(e) => return e,
        };
        let address_info = vk::BufferDeviceAddressInfo::default().buffer(info.buffer);
        // SAFETY: the buffer is bound (the extension's rule) with device-address usage (the
        // layer's translation of ACCELERATION_STRUCTURE_STORAGE).
        let address = unsafe { s.fns.get_buffer_device_address(&address_info) } + info.offset;
        let object = Box::new(AccelObject {
            buffer: info.buffer,
            offset: info.offset,
            size: info.size,
            address,
            view,
            built: Mutex::new(None),
        });
        let raw = Box::into_raw(object) as usize as u64;
        s.accel.live.lock().map(|mut l| l.insert(raw)).ok();
        // SAFETY: the application's out pointer.
        unsafe { *out = vk::Handle::from_raw(raw) };
        vk::Result::SUCCESS
    })
}

unsafe extern "system" fn destroy(
    device: vk::Device,
    handle: vk::AccelerationStructureKHR,
    _allocator: *const vk::AllocationCallbacks<'_>,
) {
    guard((), || {
        let Some(s) = served(device) else { return };
        let raw = vk::Handle::as_raw(handle);
        if !s.accel.live.lock().is_ok_and(|mut l| l.remove(&raw)) {
            return;
        }
        // SAFETY: taken out of the live set: the only owner.
        let object = unsafe { Box::from_raw(raw as usize as *mut AccelObject) };
        // SAFETY: the application no longer uses it (the extension's rule for destroy).
        unsafe { s.fns.destroy_buffer_view(object.view, None) };
    })
}

unsafe extern "system" fn address(
    device: vk::Device,
    info: *const vk::AccelerationStructureDeviceAddressInfoKHR<'_>,
) -> vk::DeviceAddress {
    guard(0, || {
        let Some(s) = served(device) else { return 0 };
        // SAFETY: the application's valid struct.
        let handle = unsafe { (*info).acceleration_structure };
        s.accel.object(handle).map_or(0, |o| o.address)
    })
}

/// The geometries of a build info.
///
/// # Safety
/// `info` is valid.
unsafe fn geometry_list<'a>(
    info: &'a vk::AccelerationStructureBuildGeometryInfoKHR<'_>,
) -> Vec<&'a vk::AccelerationStructureGeometryKHR<'a>> {
    let n = info.geometry_count as usize;
    if n == 0 {
        return Vec::new();
    }
    if !info.p_geometries.is_null() {
        // SAFETY: the caller's contract: `n` geometries.
        unsafe { std::slice::from_raw_parts(info.p_geometries, n) }
            .iter()
            .collect()
    } else {
        // SAFETY: the caller's contract: `n` pointers to geometries.
        unsafe { std::slice::from_raw_parts(info.pp_geometries, n) }
            .iter()
            // SAFETY: as above.
            .map(|&p| unsafe { &*p })
            .collect()
    }
}

fn index_type(t: vk::IndexType) -> Result<Option<IndexType>, String> {
    match t {
        vk::IndexType::NONE_KHR => Ok(None),
        vk::IndexType::UINT16 => Ok(Some(IndexType::U16)),
        vk::IndexType::UINT32 => Ok(Some(IndexType::U32)),
        t => Err(format!(
            "index type {t:?}: vkrt reads none, UINT16 and UINT32"
        )),
    }
}

fn vertex_format(f: vk::Format) -> Result<VertexFormat, String> {
    VertexFormat::from_vk(f).ok_or_else(|| {
        format!("vertex format {f:?}: vkrt's builders read the six formats the extension requires")
    })
}

fn opaque(g: &vk::AccelerationStructureGeometryKHR<'_>) -> bool {
    g.flags.contains(vk::GeometryFlagsKHR::OPAQUE)
}

/// A bottom level's geometries without their data, at their maximum counts: what the
/// sizes come from.
fn bottom_shapes(
    geometries: &[&vk::AccelerationStructureGeometryKHR<'_>],
    counts: &[u32],
) -> Result<Vec<GeometryShape>, String> {
    geometries
        .iter()
        .zip(counts)
        .map(|(g, &count)| match g.geometry_type {
            vk::GeometryTypeKHR::TRIANGLES => {
                // SAFETY: the geometry type says which member holds.
                let t = unsafe { g.geometry.triangles };
                let index_type = index_type(t.index_type)?;
                let format = vertex_format(t.vertex_format)?;
                Ok(GeometryShape::Triangles {
                    format,
                    // Sizes come from counts, and applications ask for them before they
                    // know their strides (wgpu passes 0, which the specification allows):
                    // the least stride stands in; the build checks the real one.
                    stride: format.bytes(),
                    vertex_count: match index_type {
                        Some(_) => t.max_vertex.saturating_add(1),
                        None => count.saturating_mul(3),
                    },
                    index_type,
                    triangle_count: count,
                    opaque: opaque(g),
                })
            }
            vk::GeometryTypeKHR::AABBS => {
                // SAFETY: as above.
                Ok(GeometryShape::Aabbs {
                    // As for triangles: the build checks the stride.
                    stride: 24,
                    count,
                    opaque: opaque(g),
                })
            }
            t => Err(format!("geometry type {t:?} in a bottom level")),
        })
        .collect()
}

/// A bottom level's geometries at their addresses, as a build's ranges place them.
fn bottom_geometries(
    geometries: &[&vk::AccelerationStructureGeometryKHR<'_>],
    ranges: &[vk::AccelerationStructureBuildRangeInfoKHR],
) -> Result<Vec<Geometry>, String> {
    geometries
        .iter()
        .zip(ranges)
        .map(|(g, r)| match g.geometry_type {
            vk::GeometryTypeKHR::TRIANGLES => {
                // SAFETY: the geometry type says which member holds.
                let t = unsafe { g.geometry.triangles };
                let index_type = index_type(t.index_type)?;
                // SAFETY: device builds give device addresses.
                let (vertex_data, index_data, transform) = unsafe {
                    (
                        t.vertex_data.device_address,
                        t.index_data.device_address,
                        t.transform_data.device_address,
                    )
                };
                let stride = t.vertex_stride;
                let first = u64::from(r.first_vertex) * stride;
                let (vertices_at, vertex_count) = match index_type {
                    Some(_) => (vertex_data + first, t.max_vertex.saturating_add(1)),
                    None => (
                        vertex_data + u64::from(r.primitive_offset) + first,
                        r.primitive_count.saturating_mul(3),
                    ),
                };
                let vertex_bytes = match vertex_count {
                    0 => 0,
                    n => u64::from(n - 1) * stride + 12,
                };
                // SAFETY (the three addresses below): the app's device addresses, which the
                // build command's valid usage requires in live buffers with device-address
                // usage until the build has executed; the layer reads only what the ranges
                // and counts name.
                let indices = index_type.map(|it| Indices {
                    data: unsafe {
                        DeviceRange::new(
                            index_data + u64::from(r.primitive_offset),
                            u64::from(r.primitive_count) * 3 * it_bytes(it),
                        )
                    }
                    .into(),
                    index_type: it,
                });
                Ok(Geometry::Triangles(Triangles {
                    // SAFETY: as above.
                    vertices: unsafe { DeviceRange::new(vertices_at, vertex_bytes) }.into(),
                    format: vertex_format(t.vertex_format)?,
                    stride,
                    vertex_count,
                    indices,
                    triangle_count: r.primitive_count,
                    transform: (transform != 0)
                        // SAFETY: as above.
                        .then(|| {
                            let at = transform + u64::from(r.transform_offset);
                            Transform::at(unsafe { DeviceRange::new(at, 48) })
                        }),
                    opaque: opaque(g),
                }))
            }
            vk::GeometryTypeKHR::AABBS => {
                // SAFETY: as above.
                let a = unsafe { g.geometry.aabbs };
                // SAFETY: device builds give device addresses.
                let data = unsafe { a.data.device_address };
                let bytes = match r.primitive_count {
                    0 => 0,
                    n => u64::from(n - 1) * a.stride + 24,
                };
                Ok(Geometry::Aabbs(Aabbs {
                    // SAFETY: as for triangles.
                    data: unsafe { DeviceRange::new(data + u64::from(r.primitive_offset), bytes) }
                        .into(),
                    stride: a.stride,
                    count: r.primitive_count,
                    opaque: opaque(g),
                }))
            }
            t => Err(format!("geometry type {t:?} in a bottom level")),
        })
        .collect()
}

fn it_bytes(t: IndexType) -> u64 {
    match t {
        IndexType::U16 => 2,
        _ => 4,
    }
}

/// The sizes of a structure of `ty` over `geometries` at `counts`, the header included.
fn sizes_of(
    s: &Served,
    ty: vk::AccelerationStructureTypeKHR,
    flags: vk::BuildAccelerationStructureFlagsKHR,
    geometries: &[&vk::AccelerationStructureGeometryKHR<'_>],
    counts: &[u32],
) -> Result<AccelSizes, String> {
    let (kind, flags) = kind_and_flags(flags);
    let sizes = match ty {
        vk::AccelerationStructureTypeKHR::TOP_LEVEL => {
            let max = counts.first().copied().unwrap_or(0);
            let builder = s.accel.top(&s.ctx, kind).map_err(|e| e.to_string())?;
            // Instances given as pointers are gathered into the scratch, past the build's.
            // SAFETY: a top level's one geometry is its instances.
            let pointers = geometries.first().is_some_and(|g| unsafe {
                g.geometry_type == vk::GeometryTypeKHR::INSTANCES
                    && g.geometry.instances.array_of_pointers == vk::TRUE
            });
            builder
                .sizes_for(&s.ctx, max, 0, &flags)
                .map(|z| match pointers {
                    false => z,
                    true => {
                        let room = |w: u64| pointer_room_at(w) + 64 * u64::from(max.max(1));
                        AccelSizes {
                            build_scratch_bytes: room(z.build_scratch_bytes),
                            update_scratch_bytes: z.update_scratch_bytes.map(room),
                            ..z
                        }
                    }
                })
        }
        _ => {
            let shapes = bottom_shapes(geometries, counts)?;
            let builder = s.accel.bottom(&s.ctx, kind).map_err(|e| e.to_string())?;
            builder.sizes_for(&s.ctx, &shapes, &flags)
        }
    };
    sizes.map_err(|e| e.to_string())
}

unsafe extern "system" fn build_sizes(
    device: vk::Device,
    _build_type: vk::AccelerationStructureBuildTypeKHR,
    info: *const vk::AccelerationStructureBuildGeometryInfoKHR<'_>,
    max_counts: *const u32,
    out: *mut vk::AccelerationStructureBuildSizesInfoKHR<'_>,
) {
    guard((), || {
        let Some(s) = served(device) else { return };
        // SAFETY: the application's valid struct.
        let info = unsafe { &*info };
        // SAFETY: as above.
        let geometries = unsafe { geometry_list(info) };
        let counts: &[u32] = match geometries.len() {
            0 => &[],
            // SAFETY: one count per geometry.
            n => unsafe { std::slice::from_raw_parts(max_counts, n) },
        };
        // SAFETY: the application's out struct.
        let out = unsafe { &mut *out };
        match sizes_of(&s, info.ty, info.flags, &geometries, counts) {
            Ok(sizes) => {
                out.acceleration_structure_size = HEADER + sizes.structure_bytes;
                out.build_scratch_size = sizes.build_scratch_bytes.max(MIN_SCRATCH);
                out.update_scratch_size = sizes
                    .update_scratch_bytes
                    .unwrap_or(sizes.build_scratch_bytes)
                    .max(MIN_SCRATCH);
            }
            Err(e) => {
                log(&format!("vkGetAccelerationStructureBuildSizesKHR: {e}"));
                out.acceleration_structure_size = 0;
                out.build_scratch_size = 0;
                out.update_scratch_size = 0;
            }
        }
    })
}

unsafe extern "system" fn cmd_build(
    cb: vk::CommandBuffer,
    count: u32,
    infos: *const vk::AccelerationStructureBuildGeometryInfoKHR<'_>,
    ranges: *const *const vk::AccelerationStructureBuildRangeInfoKHR,
) {
    guard((), || {
        let Some(s) = served(cb) else { return };
        if count == 0 {
            return;
        }
        // SAFETY: the application's `count` infos and range arrays.
        let (infos, ranges) = unsafe {
            (
                std::slice::from_raw_parts(infos, count as usize),
                std::slice::from_raw_parts(ranges, count as usize),
            )
        };
        s.kernels_ready();
        let before = s.ctx.traffic();
        // SAFETY: the application's command buffer, recording, outside a render pass (the
        // extension's rules for builds); what it binds lives until the command buffer is
        // reset or freed, when the layer completes the work (`commands`); the cache's sets
        // of a buffer are freed only when the application destroys it (`memory`).
        let mut rec = match unsafe { Recorder::from_raw_with(&s.ctx, cb, &s.bindings) } {
            Ok(r) => r,
            Err(e) => return log(&format!("vkCmdBuildAccelerationStructuresKHR: {e}")),
        };
        for (i, (info, &r)) in infos.iter().zip(ranges).enumerate() {
            let r: &[vk::AccelerationStructureBuildRangeInfoKHR] = match info.geometry_count {
                0 => &[],
                // SAFETY: one range per geometry.
                n => unsafe { std::slice::from_raw_parts(r, n as usize) },
            };
            // SAFETY: the application's valid info.
            if let Err(e) = unsafe { build_one(&s, &mut rec, info, r) } {
                log(&format!(
                    "vkCmdBuildAccelerationStructuresKHR: build {i} not recorded: {e}"
                ));
            }
        }
        match rec.finish() {
            Ok(work) => commands::keep(&s, cb, work),
            Err(e) => log(&format!("vkCmdBuildAccelerationStructuresKHR: {e}")),
        }
        crate::stats("vkCmdBuildAccelerationStructuresKHR", &s.ctx, before);
        commands::restore(&s, cb);
    })
}

/// # Safety
/// `info` is valid and its geometries' addresses are the application's.
unsafe fn build_one(
    s: &Served,
    rec: &mut Recorder,
    info: &vk::AccelerationStructureBuildGeometryInfoKHR<'_>,
    ranges: &[vk::AccelerationStructureBuildRangeInfoKHR],
) -> Result<(), String> {
    let dst = s
        .accel
        .object(info.dst_acceleration_structure)
        .ok_or("the destination is not a live acceleration structure")?;
    let update = info.mode == vk::BuildAccelerationStructureModeKHR::UPDATE;
    if update && info.src_acceleration_structure != info.dst_acceleration_structure {
        // An update into another structure: the source cloned into the destination
        // (ordered before the compute work that follows), then updated there.
        copy(
            s,
            rec,
            info.src_acceleration_structure,
            info.dst_acceleration_structure,
        )
        .map_err(|e| format!("an update from another structure: {e}"))?;
    }
    let (kind, flags) = kind_and_flags(info.flags);
    // SAFETY: the caller's contract.
    let geometries = unsafe { geometry_list(info) };
    // SAFETY: device builds give device addresses.
    let scratch_at = unsafe { info.scratch_data.device_address };
    let scratch = |bytes: u64| -> Result<RawBuffer, String> {
        let bytes = bytes.max(MIN_SCRATCH);
        s.buffers
            .lock()
            .map_err(|e| e.to_string())?
            .resolve(scratch_at, bytes)
            .ok_or_else(|| format!("no buffer holds {bytes} bytes of scratch at {scratch_at:#x}"))
    };
    let too_small = |need: u64| {
        format!(
            "the structure holds {} bytes; its geometries need {}",
            dst.size,
            HEADER + need
        )
    };
    let mut built = dst.built.lock().map_err(|e| e.to_string())?;
    let e = |e: vkrt::gpu::GpuError| e.to_string();
    if info.ty == vk::AccelerationStructureTypeKHR::TOP_LEVEL {
        let [g] = geometries[..] else {
            return Err("a top level has one geometry, its instances".into());
        };
        if g.geometry_type != vk::GeometryTypeKHR::INSTANCES {
            return Err("a top level's geometry is not instances".into());
        }
        // SAFETY: the geometry type says which member holds.
        let instances = unsafe { g.geometry.instances };
        let pointers = instances.array_of_pointers == vk::TRUE;
        let r = ranges[0];
        let count = r.primitive_count;
        // SAFETY: device builds give device addresses.
        let at = unsafe { instances.data.device_address } + u64::from(r.primitive_offset);
        let builder = s.accel.top(&s.ctx, kind).map_err(e)?;
        if !update {
            let reuse = matches!(built.as_ref(), Some(Built::Top { kind: k, flags: f, max, .. })
                if *k == kind && *f == flags && count <= *max);
            if !reuse {
                let max = count.max(1);
                let sizes = builder.sizes_for(&s.ctx, max, 0, &flags).map_err(e)?;
                if HEADER + sizes.structure_bytes > dst.size {
                    return Err(too_small(sizes.structure_bytes));
                }
                let top = builder
                    .create_in(&s.ctx, &[], max, &flags, dst.memory())
                    .map_err(e)?;
                *built = Some(Built::Top {
                    kind,
                    flags,
                    max,
                    sizes,
                    top: Box::new(top),
                });
            }
        }
        let Some(Built::Top { top, sizes, .. }) = built.as_mut() else {
            return Err("an update of a top level never built".into());
        };
        let work = match update {
            true => sizes.update_scratch_bytes.unwrap_or(0),
            false => sizes.build_scratch_bytes,
        };
        let (scratch, records) = match (pointers, count) {
            (true, n @ 1..) => {
                // The records the pointers name, gathered past the build's own scratch
                // (the sizes reserve the room).
                let room_at = pointer_room_at(work);
                let whole = scratch(room_at + 64 * u64::from(n))?;
                let part = |at, size| {
                    whole
                        .slice(at, size)
                        .ok_or_else(|| format!("a scratch of {} bytes", whole.size()))
                };
                let records = part(room_at, 64 * u64::from(n))?;
                let gather = s.accel.pointers(&s.ctx).map_err(e)?;
                gather.record(rec, at, n, records).map_err(e)?;
                (part(0, room_at)?, records)
            }
            // Nothing is read: any range of the structure's own buffer serves.
            (_, 0) => (scratch(work)?, dst.header()),
            (false, n) => (
                scratch(work)?,
                s.buffers
                    .lock()
                    .map_err(|e| e.to_string())?
                    .resolve(at, 64 * u64::from(n))
                    .ok_or_else(|| format!("no buffer holds {n} instance records at {at:#x}"))?,
            ),
        };
        if update {
            return builder
                .record_update_from(rec, top, records, scratch)
                .map_err(e);
        }
        let words = top.handle_words().map_err(e)?;
        write_header(s, rec, dst, &words);
        return builder
            .record_build_from(rec, top, records, count, scratch)
            .map_err(e);
    }
    let list = bottom_geometries(&geometries, ranges)?;
    let shapes: Vec<GeometryShape> = list.iter().map(|g| g.shape()).collect();
    let builder = s.accel.bottom(&s.ctx, kind).map_err(e)?;
    if update {
        let Some(Built::Bottom {
            geometry,
            sizes,
            shapes: old,
            ..
        }) = built.as_mut()
        else {
            return Err("an update of a bottom level never built".into());
        };
        if *old != shapes {
            return Err("an update with other geometry counts than the build's".into());
        }
        let scratch = scratch(sizes.update_scratch_bytes.unwrap_or(0))?;
        return builder
            .record_update_from(rec, geometry, &list, scratch)
            .map_err(e);
    }
    let reuse = matches!(built.as_ref(), Some(Built::Bottom { kind: k, flags: f, shapes: old, .. })
        if *k == kind && *f == flags && *old == shapes);
    if !reuse {
        let sizes = builder.sizes_for(&s.ctx, &list, &flags).map_err(e)?;
        if HEADER + sizes.structure_bytes > dst.size {
            return Err(too_small(sizes.structure_bytes));
        }
        let mut geometry = builder
            .create_in(&s.ctx, &list, &flags, dst.memory())
            .map_err(e)?;
        geometry.enable_references();
        *built = Some(Built::Bottom {
            kind,
            flags,
            shapes,
            geometries: list.clone(),
            sizes,
            geometry: Box::new(geometry),
        });
    }
    let Some(Built::Bottom {
        geometry,
        sizes,
        geometries,
        ..
    }) = built.as_mut()
    else {
        unreachable!("created above")
    };
    geometries.clone_from(&list);
    let words = geometry.handle_words().map_err(e)?;
    write_header(s, rec, dst, &words);
    let scratch = scratch(sizes.build_scratch_bytes)?;
    builder
        .record_build_from(rec, geometry, &list, scratch)
        .map_err(e)
}

/// Where, in a top level's scratch, the records gathered from pointers start: past the
/// `work` bytes its build or update uses, aligned for a storage binding.
fn pointer_room_at(work: u64) -> u64 {
    work.max(MIN_SCRATCH).next_multiple_of(256)
}

/// Records the header's writes: the handle's words at the structure's address, the address
/// at `TEXEL_AT`; then a barrier to the build's compute work.
fn write_header(s: &Served, rec: &mut Recorder, dst: &AccelObject, words: &[u64]) {
    let cb = rec.command_buffer();
    let texel = [dst.address, 0];
    // SAFETY: the application's buffer, with transfer-destination usage (the layer's
    // translation), outside a render pass; the writes lie within the structure's header.
    unsafe {
        s.fns
            .cmd_update_buffer(cb, dst.buffer, dst.offset, bytemuck_bytes(words));
        s.fns.cmd_update_buffer(
            cb,
            dst.buffer,
            dst.offset + TEXEL_AT,
            bytemuck_bytes(&texel),
        );
    }
    rec.transfer_to_compute();
}

fn bytemuck_bytes(words: &[u64]) -> &[u8] {
    // SAFETY: u64s are plain bytes.
    unsafe { std::slice::from_raw_parts(words.as_ptr().cast(), std::mem::size_of_val(words)) }
}

unsafe extern "system" fn cmd_build_indirect(
    _cb: vk::CommandBuffer,
    _count: u32,
    _infos: *const vk::AccelerationStructureBuildGeometryInfoKHR<'_>,
    _addresses: *const vk::DeviceAddress,
    _strides: *const u32,
    _max_counts: *const *const u32,
) {
    log("vkCmdBuildAccelerationStructuresIndirectKHR: not supported (accelerationStructureIndirectBuild is false); nothing recorded");
}

unsafe extern "system" fn compatibility(
    _device: vk::Device,
    _version: *const vk::AccelerationStructureVersionInfoKHR<'_>,
    out: *mut vk::AccelerationStructureCompatibilityKHR,
) {
    // Serialized structures are not written, so none is compatible.
    // SAFETY: the application's out pointer.
    guard((), || unsafe {
        *out = vk::AccelerationStructureCompatibilityKHR::INCOMPATIBLE
    });
}

fn unsupported_host(call: &str) -> vk::Result {
    log(&format!(
        "{call}: host commands are not supported (accelerationStructureHostCommands is false)"
    ));
    vk::Result::ERROR_FEATURE_NOT_PRESENT
}

unsafe extern "system" fn host_build(
    _device: vk::Device,
    _op: vk::DeferredOperationKHR,
    _count: u32,
    _infos: *const vk::AccelerationStructureBuildGeometryInfoKHR<'_>,
    _ranges: *const *const vk::AccelerationStructureBuildRangeInfoKHR,
) -> vk::Result {
    unsupported_host("vkBuildAccelerationStructuresKHR")
}

unsafe extern "system" fn host_copy(
    _device: vk::Device,
    _op: vk::DeferredOperationKHR,
    _info: *const vk::CopyAccelerationStructureInfoKHR<'_>,
) -> vk::Result {
    unsupported_host("vkCopyAccelerationStructureKHR")
}

unsafe extern "system" fn host_copy_to_memory(
    _device: vk::Device,
    _op: vk::DeferredOperationKHR,
    _info: *const vk::CopyAccelerationStructureToMemoryInfoKHR<'_>,
) -> vk::Result {
    unsupported_host("vkCopyAccelerationStructureToMemoryKHR")
}

unsafe extern "system" fn host_copy_from_memory(
    _device: vk::Device,
    _op: vk::DeferredOperationKHR,
    _info: *const vk::CopyMemoryToAccelerationStructureInfoKHR<'_>,
) -> vk::Result {
    unsupported_host("vkCopyMemoryToAccelerationStructureKHR")
}

unsafe extern "system" fn host_properties(
    _device: vk::Device,
    _count: u32,
    _structures: *const vk::AccelerationStructureKHR,
    _query_type: vk::QueryType,
    _data_size: usize,
    _data: *mut std::ffi::c_void,
    _stride: usize,
) -> vk::Result {
    unsupported_host("vkWriteAccelerationStructuresPropertiesKHR")
}

unsafe extern "system" fn cmd_copy(
    cb: vk::CommandBuffer,
    info: *const vk::CopyAccelerationStructureInfoKHR<'_>,
) {
    guard((), || {
        let Some(s) = served(cb) else { return };
        // SAFETY: the application's valid struct.
        let info = unsafe { &*info };
        let call = "vkCmdCopyAccelerationStructureKHR";
        match info.mode {
            vk::CopyAccelerationStructureModeKHR::CLONE
            | vk::CopyAccelerationStructureModeKHR::COMPACT => {}
            m => {
                return log(&format!(
                    "{call}: mode {m:?} is not supported; nothing recorded"
                ))
            }
        }
        s.kernels_ready();
        let before = s.ctx.traffic();
        // SAFETY: the application's command buffer, recording, outside a render pass.
        let mut rec = match unsafe { Recorder::from_raw_with(&s.ctx, cb, &s.bindings) } {
            Ok(r) => r,
            Err(e) => return log(&format!("{call}: {e}")),
        };
        if let Err(e) = copy(&s, &mut rec, info.src, info.dst) {
            log(&format!("{call}: not recorded: {e}"));
        }
        match rec.finish() {
            Ok(work) => commands::keep(&s, cb, work),
            Err(e) => log(&format!("{call}: {e}")),
        }
        crate::stats(call, &s.ctx, before);
        commands::restore(&s, cb);
    })
}

/// The bytes a structure's copy holds: what `vkCmdWriteAccelerationStructuresPropertiesKHR`
/// reports as its compacted size. Copies do not shrink (yet): a compaction is a clone.
pub fn compacted_size(object: &AccelObject) -> Option<u64> {
    match object.built.lock().ok()?.as_ref()? {
        Built::Bottom { sizes, .. } | Built::Top { sizes, .. } => {
            Some(HEADER + sizes.structure_bytes)
        }
    }
}

/// Records a clone of `src` into `dst`: vkrt's structure created in `dst` over the same
/// geometries, counts and flags (so laid out alike), its bytes copied (vkrt's arrays refer
/// to one another by index), and `dst`'s header written with its own addresses.
fn copy(
    s: &Served,
    rec: &mut Recorder,
    src: vk::AccelerationStructureKHR,
    dst: vk::AccelerationStructureKHR,
) -> Result<(), String> {
    if src == dst {
        return Err("the source is the destination".into());
    }
    let e = |e: vkrt::gpu::GpuError| e.to_string();
    let from = s
        .accel
        .object(src)
        .ok_or("the source is not a live acceleration structure")?;
    let to = s
        .accel
        .object(dst)
        .ok_or("the destination is not a live acceleration structure")?;
    let from_built = from.built.lock().map_err(|e| e.to_string())?;
    let mut to_built = to.built.lock().map_err(|e| e.to_string())?;
    let source = from_built.as_ref().ok_or("the source was never built")?;
    let bytes = match source {
        Built::Bottom { sizes, .. } | Built::Top { sizes, .. } => sizes.structure_bytes,
    };
    if HEADER + bytes > to.size {
        return Err(format!(
            "the destination holds {} bytes; the copy needs {}",
            to.size,
            HEADER + bytes
        ));
    }
    let region = vk::BufferCopy {
        src_offset: from.offset + HEADER,
        dst_offset: to.offset + HEADER,
        size: bytes,
    };
    // SAFETY: ranges of the application's buffers (transfer usages: the layer's
    // translation) within both structures; the command buffer is recording.
    unsafe {
        s.fns
            .cmd_copy_buffer(rec.command_buffer(), from.buffer, to.buffer, &[region])
    };
    // The copy then takes the source's build state and its own handle record, so that it
    // traces and can be updated as the source could; where vkrt cannot carry the state over
    // (a kd-tree), the copy traces but an update of it is refused, logged.
    // SAFETY: the copy just recorded brought the source's bytes (built: the source has a
    // recorded build), over the same geometry and flags, into the destination's range.
    let copied = unsafe { vkrt::gpu::CopiedStructure::new() };
    match source {
        Built::Bottom {
            kind,
            flags,
            shapes,
            geometries,
            sizes,
            geometry: source,
        } => {
            let builder = s.accel.bottom(&s.ctx, *kind).map_err(e)?;
            let mut geometry = builder
                .create_in(&s.ctx, geometries, flags, to.memory())
                .map_err(e)?;
            geometry.enable_references();
            let _ = geometry.record_built_by_copy(rec, source, copied);
            let words = geometry.handle_words().map_err(e)?;
            write_header(s, rec, to, &words);
            *to_built = Some(Built::Bottom {
                kind: *kind,
                flags: *flags,
                shapes: shapes.clone(),
                geometries: geometries.clone(),
                sizes: *sizes,
                geometry: Box::new(geometry),
            });
        }
        Built::Top {
            kind,
            flags,
            max,
            sizes,
            top: source,
        } => {
            let builder = s.accel.top(&s.ctx, *kind).map_err(e)?;
            let mut top = builder
                .create_in(&s.ctx, &[], *max, flags, to.memory())
                .map_err(e)?;
            let _ = top.record_built_by_copy(rec, source, copied);
            let words = top.handle_words().map_err(e)?;
            write_header(s, rec, to, &words);
            *to_built = Some(Built::Top {
                kind: *kind,
                flags: *flags,
                max: *max,
                sizes: *sizes,
                top: Box::new(top),
            });
        }
    }
    // What follows in this command reads the copy: a trace, or an update whose refit takes
    // its dispatch arguments from the copied schedule.
    rec.transfer_to_indirect();
    Ok(())
}

unsafe extern "system" fn cmd_copy_to_memory(
    _cb: vk::CommandBuffer,
    _info: *const vk::CopyAccelerationStructureToMemoryInfoKHR<'_>,
) {
    log("vkCmdCopyAccelerationStructureToMemoryKHR: serialization is not supported; nothing recorded");
}

unsafe extern "system" fn cmd_copy_from_memory(
    _cb: vk::CommandBuffer,
    _info: *const vk::CopyMemoryToAccelerationStructureInfoKHR<'_>,
) {
    log("vkCmdCopyMemoryToAccelerationStructureKHR: deserialization is not supported; nothing recorded");
}
