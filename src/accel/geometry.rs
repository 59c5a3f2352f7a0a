//! Geometry that lives in the caller's device buffers, described the way
//! `VkAccelerationStructureGeometryKHR` describes it: triangles (a vertex buffer with format
//! and stride, an optional `u16`/`u32` index buffer, an optional 3×4 transform), spheres
//! (centre and radius) and axis-aligned boxes (`VkAabbPositionsKHR`), several geometries per
//! structure.
//!
//! The GPU builders read these buffers where they lie: `accel.geometry_gather` copies each
//! geometry, on the device, into the structure's own primitive arrays (as a driver copies its
//! input into its own format), so nothing passes through the host and nothing is uploaded.
//! A hit reports the geometry's index in the list and the primitive's index within it.

use crate::accel::geometry_shape::{GeometryDescription, GeometryShape};
pub use crate::accel::geometry_shape::{IndexType, VertexFormat, NON_OPAQUE};
use crate::accel::primitives::SceneInfo;
use crate::accel::primitives::TraceGeometry;
use crate::gpu::{
    kernels, Buffer, BufferArg, Context, DeviceRange, GpuError, Kernel, RawBuffer, Recorder,
    Result, Spec,
};
use crate::scene::Aabb;
use glam::{Vec3, Vec4};

use crate::accel::device_primitives::DevicePrimitives;

const WORKGROUP: u32 = 64;

/// Where a geometry's data lies: a range of a buffer, or bytes at a device address.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum GeometryData {
    /// A range of the caller's buffer (bound as a storage buffer, so at most
    /// `maxStorageBufferRange` bytes from the aligned offset below its start).
    Buffer(RawBuffer),
    /// `size` bytes at a device address (`VkDeviceOrHostAddressConstKHR`), read with
    /// `GL_EXT_buffer_reference`: no binding limit; needs `bufferDeviceAddress` enabled.
    /// Made from a [`DeviceRange`], whose constructor carries the caller's promise.
    ///
    /// ```compile_fail
    /// // Not from a bare u64: any address would reach the GPU.
    /// let d = vkrt::accel::geometry::GeometryData::Address { address: 64, size: 12 };
    /// ```
    #[non_exhaustive]
    Address {
        /// The device address of the first byte.
        address: u64,
        /// Bytes from there.
        size: u64,
    },
}

impl From<DeviceRange> for GeometryData {
    fn from(r: DeviceRange) -> Self {
        GeometryData::Address {
            address: r.address(),
            size: r.size(),
        }
    }
}

impl From<RawBuffer> for GeometryData {
    fn from(r: RawBuffer) -> Self {
        GeometryData::Buffer(r)
    }
}

impl GeometryData {
    /// Bytes of the data.
    pub fn size(&self) -> u64 {
        match self {
            GeometryData::Buffer(r) => r.size,
            GeometryData::Address { size, .. } => *size,
        }
    }

    /// The offset or address of its first byte (what alignment rules apply to).
    fn start(&self) -> u64 {
        match self {
            GeometryData::Buffer(r) => r.offset,
            GeometryData::Address { address, .. } => *address,
        }
    }

    fn is_null(&self) -> bool {
        match self {
            GeometryData::Buffer(r) => r.raw == crate::gpu::vk::Buffer::null(),
            GeometryData::Address { address, .. } => *address == 0,
        }
    }

    fn is_address(&self) -> bool {
        matches!(self, GeometryData::Address { .. })
    }
}

/// An index buffer: three entries per triangle, starting at the data's first byte.
#[derive(Clone, Copy, Debug)]
pub struct Indices {
    /// The entries (offset or address a multiple of the entry size; in a buffer exactly
    /// when the vertices are).
    pub data: GeometryData,
    /// The size of each entry.
    pub index_type: IndexType,
}

/// Where a triangle geometry's object-to-structure transform comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Transform {
    /// Given by the host: three rows of a 3×4 matrix.
    Rows([[f32; 4]; 3]),
    /// A `VkTransformMatrixKHR` (twelve floats, row-major) at a 16-byte-aligned device
    /// address, read by the build where it reads the vertices: they lie at device addresses
    /// too. A non-finite entry makes the geometry's triangles invalid (never hit, counted).
    /// Made with [`Transform::at`] from a [`DeviceRange`].
    #[non_exhaustive]
    At(u64),
}

impl Transform {
    /// The matrix at the start of `range` (whose promise covers its 48 bytes).
    pub fn at(range: DeviceRange) -> Self {
        Transform::At(range.address())
    }
}

impl From<[[f32; 4]; 3]> for Transform {
    fn from(rows: [[f32; 4]; 3]) -> Self {
        Transform::Rows(rows)
    }
}

/// Triangles (`VkAccelerationStructureGeometryTrianglesDataKHR`).
#[derive(Clone, Copy, Debug)]
pub struct Triangles {
    /// The vertices; the first is at the data's first byte.
    pub vertices: GeometryData,
    /// How each vertex's position is stored.
    pub format: VertexFormat,
    /// Bytes from one vertex to the next (a multiple of 4, at least the format's bytes).
    pub stride: u64,
    /// Vertices the indices may name (`maxVertex + 1`).
    pub vertex_count: u32,
    /// `None`: vertices `3k, 3k + 1, 3k + 2` form triangle `k`.
    pub indices: Option<Indices>,
    /// Triangles to read (0: the geometry is empty).
    pub triangle_count: u32,
    /// Row-major object-to-structure transform (`VkTransformMatrixKHR`), applied as the
    /// geometry is read: given by the host, or read by the build at a device address
    /// (`transformData`). A `[[f32; 4]; 3]` converts (`.into()`).
    pub transform: Option<Transform>,
    /// `VK_GEOMETRY_OPAQUE_BIT_KHR`. A non-opaque geometry's hits are candidates a ray query
    /// returns to the shader (`vkrt/ext_ray_query.glsl`), which confirms or ignores them;
    /// vkrt's own walks (`vkrtTrace`, the renderer) take every hit as opaque. Non-opaque
    /// geometry needs a BVH (LBVH, PLOC, SAH BVH; binary or 4-wide: each primitive
    /// referenced once, so no candidate comes twice, as
    /// `VK_GEOMETRY_NO_DUPLICATE_ANY_HIT_INVOCATION_BIT_KHR` asks); the kd-tree refuses it.
    pub opaque: bool,
}

impl Triangles {
    /// Non-indexed triangles: `vertex_count / 3` of them, tightly packed `vec3`s.
    pub fn soup(vertices: impl Into<GeometryData>, vertex_count: u32) -> Self {
        Self {
            vertices: vertices.into(),
            format: VertexFormat::Rgb32Float,
            stride: 12,
            vertex_count,
            indices: None,
            triangle_count: vertex_count / 3,
            transform: None,
            opaque: true,
        }
    }

    /// Indexed triangles over tightly packed `vec3` vertices.
    pub fn indexed(
        vertices: impl Into<GeometryData>,
        vertex_count: u32,
        indices: impl Into<GeometryData>,
        index_type: IndexType,
        triangle_count: u32,
    ) -> Self {
        Self {
            indices: Some(Indices {
                data: indices.into(),
                index_type,
            }),
            triangle_count,
            ..Self::soup(vertices, vertex_count)
        }
    }
}

/// Spheres: a centre and a radius, four floats, `stride` bytes apart.
#[derive(Clone, Copy, Debug)]
pub struct Spheres {
    /// The records; the first is at the data's first byte (offset or address a multiple
    /// of 4).
    pub data: GeometryData,
    /// At least 16, a multiple of 4.
    pub stride: u64,
    /// Spheres to read.
    pub count: u32,
    /// As for [`Triangles::opaque`].
    pub opaque: bool,
}

/// Axis-aligned boxes (`VkAccelerationStructureGeometryAabbsDataKHR`): six floats each,
/// min x, y, z then max x, y, z (`VkAabbPositionsKHR`), `stride` bytes apart.
///
/// A box is hit where the ray enters it (or leaves it, from inside), unless the shader that
/// traces supplies its own intersection for boxes (`VKRT_AABB_INTERSECTION` in
/// `vkrt/ray_query.glsl`), as a ray query's procedural candidates are. A box with min > max
/// on an axis is inactive (never hit), as in Vulkan; a non-finite coordinate makes it
/// inactive too, and is counted in [`crate::accel::embedded::BuildStatus::invalid_primitives`].
/// Boxes do not move.
#[derive(Clone, Copy, Debug)]
pub struct Aabbs {
    /// The records; the first is at the data's first byte (offset or address a multiple
    /// of 4).
    pub data: GeometryData,
    /// At least 24, a multiple of 4.
    pub stride: u64,
    /// Boxes to read.
    pub count: u32,
    /// As for [`Triangles::opaque`].
    pub opaque: bool,
}

/// One geometry of a structure.
#[derive(Clone, Copy, Debug)]
#[non_exhaustive]
pub enum Geometry {
    /// Triangles, optionally indexed and transformed.
    Triangles(Triangles),
    /// Spheres (centre and radius).
    Spheres(Spheres),
    /// Axis-aligned boxes.
    Aabbs(Aabbs),
}

impl Geometry {
    /// Whether its hits are opaque (`VK_GEOMETRY_OPAQUE_BIT_KHR`).
    pub fn opaque(&self) -> bool {
        match self {
            Geometry::Triangles(t) => t.opaque,
            Geometry::Spheres(s) => s.opaque,
            Geometry::Aabbs(b) => b.opaque,
        }
    }

    /// Its word in the geometry table: geometry `index`, [`NON_OPAQUE`] where it is not.
    pub(crate) fn table_word(&self, index: usize) -> u32 {
        index as u32 | if self.opaque() { 0 } else { NON_OPAQUE }
    }

    /// Its primitives.
    pub fn primitive_count(&self) -> u32 {
        match self {
            Geometry::Triangles(t) => t.triangle_count,
            Geometry::Spheres(s) => s.count,
            Geometry::Aabbs(b) => b.count,
        }
    }
}

/// Triangles, spheres and boxes over `geometries`, and where each geometry's primitives
/// start in vkrt's ids (triangles of every geometry first, then spheres, then boxes:
/// `traverse.glsl`'s order).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GeometryLayout {
    /// Triangles of every geometry (ids `0..n_tris`).
    pub n_tris: u32,
    /// Spheres of every geometry (ids after the triangles).
    pub n_spheres: u32,
    /// Boxes of every geometry (ids after the spheres).
    pub n_aabbs: u32,
    /// Per geometry: its first primitive id.
    pub first: Vec<u32>,
    /// The table the walk searches: (first id, geometry index, with [`NON_OPAQUE`] set for
    /// a non-opaque geometry), ordered by first id, for the geometries that have primitives.
    pub table: Vec<[u32; 2]>,
}

fn usage(reason: String) -> GpuError {
    GpuError::Usage {
        call: "accel geometry",
        reason,
    }
}

impl GeometryLayout {
    /// Checks every description against the limits of `ctx`'s device and lays them out.
    pub fn of(ctx: &Context, geometries: &[Geometry]) -> Result<Self> {
        Self::of_described(ctx, geometries)
    }

    /// [`GeometryLayout::of`] geometries with their data or by their counts alone.
    pub fn of_described<G: GeometryDescription>(ctx: &Context, geometries: &[G]) -> Result<Self> {
        for (k, g) in geometries.iter().enumerate() {
            g.check(ctx, k)?;
        }
        let shapes: Vec<GeometryShape> = geometries.iter().map(|g| g.shape()).collect();
        Self::of_shapes(&shapes)
    }

    /// The layout of checked shapes.
    fn of_shapes(geometries: &[GeometryShape]) -> Result<Self> {
        // Per primitive type (triangles, spheres, boxes): its count.
        let mut n = [0u64; 3];
        for g in geometries {
            n[g.type_index()] += u64::from(g.primitive_count());
        }
        let total: u64 = n.iter().sum();
        if total > u64::from(u32::MAX / 9) {
            return Err(usage(format!(
                "{total} primitives in all: above the {} one structure holds",
                u32::MAX / 9
            )));
        }
        // Where each type's ids start, and the table's entries per type.
        let mut at = [0, n[0] as u32, (n[0] + n[1]) as u32];
        let mut first = Vec::with_capacity(geometries.len());
        let mut lists: [Vec<[u32; 2]>; 3] = Default::default();
        for (k, g) in geometries.iter().enumerate() {
            let t = g.type_index();
            first.push(at[t]);
            if g.primitive_count() > 0 {
                lists[t].push([at[t], g.table_word(k)]);
            }
            at[t] += g.primitive_count();
        }
        Ok(Self {
            n_tris: n[0] as u32,
            n_spheres: n[1] as u32,
            n_aabbs: n[2] as u32,
            first,
            table: lists.concat(),
        })
    }

    /// Primitives of every geometry.
    pub fn primitive_count(&self) -> usize {
        (self.n_tris + self.n_spheres + self.n_aabbs) as usize
    }

    /// `SceneInfo` elements (64 bytes each) holding the constants and the table.
    pub fn info_len(&self) -> usize {
        1 + self.table.len().div_ceil(8)
    }

    /// (geometry index, primitive index) of vkrt's primitive id `prim`.
    pub fn locate(&self, prim: u32) -> Option<(u32, u32)> {
        let k = self
            .table
            .partition_point(|e| e[0] <= prim)
            .checked_sub(1)?;
        let [first, geometry] = self.table[k];
        ((prim as usize) < self.primitive_count()).then_some((geometry & !NON_OPAQUE, prim - first))
    }
}

/// Checks `g` (geometry `k`) and its data against `ctx`'s device.
pub(crate) fn check(ctx: &Context, k: usize, g: &Geometry) -> Result<()> {
    let err = |what: String| Err(usage(format!("geometry {k}: {what}")));
    match g {
        Geometry::Triangles(t) => {
            if t.stride < t.format.bytes() || t.stride % 4 != 0 {
                return err(format!(
                    "vertex stride {} (a multiple of 4, at least {} for {:?})",
                    t.stride,
                    t.format.bytes(),
                    t.format
                ));
            }
            if t.vertices.start() % 4 != 0 {
                return err(format!(
                    "vertex offset (address) {} is not a multiple of 4",
                    t.vertices.start()
                ));
            }
            if let Some(ix) = &t.indices {
                if ix.data.is_address() != t.vertices.is_address() {
                    return err(
                        "vertices and indices are both in buffers or both at device \
                                addresses"
                            .into(),
                    );
                }
            }
            match t.transform {
                Some(Transform::Rows(m)) if m.iter().flatten().any(|x| !x.is_finite()) => {
                    return err("the transform has a non-finite entry".into());
                }
                Some(Transform::At(address)) => {
                    if !t.vertices.is_address() {
                        return err(
                            "a transform at a device address needs the vertices at device \
                             addresses too"
                                .into(),
                        );
                    }
                    if address == 0 || address % 16 != 0 {
                        return err(format!(
                            "the transform's address {address:#x} is not a non-null multiple of 16"
                        ));
                    }
                }
                _ => {}
            }
            if t.triangle_count == 0 {
                return Ok(());
            }
            if t.vertices.is_null() {
                return err("a null vertex buffer (address)".into());
            }
            let needed = match t.vertex_count {
                0 => return err("triangles over 0 vertices".into()),
                n => u64::from(n - 1) * t.stride + t.format.bytes(),
            };
            if needed > t.vertices.size() {
                return err(format!(
                    "{} vertices at stride {} need {needed} bytes; the range holds {}",
                    t.vertex_count,
                    t.stride,
                    t.vertices.size()
                ));
            }
            match t.indices {
                None if u64::from(t.triangle_count) * 3 > u64::from(t.vertex_count) => {
                    err(format!(
                        "{} triangles without indices need {} vertices; {} given",
                        t.triangle_count,
                        3 * u64::from(t.triangle_count),
                        t.vertex_count
                    ))
                }
                None => Ok(()),
                Some(ix) => {
                    let size = ix.index_type.bytes();
                    let needed = 3 * u64::from(t.triangle_count) * size;
                    if ix.data.is_null() {
                        err("a null index buffer (address)".into())
                    } else if ix.data.start() % size != 0 {
                        err(format!(
                            "index offset (address) {} is not a multiple of the index size \
                             {size}",
                            ix.data.start()
                        ))
                    } else if needed > ix.data.size() {
                        err(format!(
                            "{} triangles need {needed} bytes of indices; the range holds {}",
                            t.triangle_count,
                            ix.data.size()
                        ))
                    } else {
                        range_fits(ctx, k, &ix.data)
                    }
                }
            }?;
            range_fits(ctx, k, &t.vertices)
        }
        Geometry::Spheres(s) => records(ctx, k, "sphere", &s.data, s.stride, 16, s.count),
        Geometry::Aabbs(b) => records(ctx, k, "box", &b.data, b.stride, 24, b.count),
    }
}

/// Checks `count` records of `size` bytes (`what`: spheres, boxes) every `stride` bytes.
#[allow(clippy::too_many_arguments, reason = "one record array's description")]
fn records(
    ctx: &Context,
    k: usize,
    what: &str,
    data: &GeometryData,
    stride: u64,
    size: u64,
    count: u32,
) -> Result<()> {
    let err = |why: String| Err(usage(format!("geometry {k}: {why}")));
    if stride < size || stride % 4 != 0 || data.start() % 4 != 0 {
        return err(format!(
            "{what} stride {stride} and offset (address) {} (multiples of 4, stride at least \
             {size})",
            data.start()
        ));
    }
    if count == 0 {
        return Ok(());
    }
    if data.is_null() {
        return err(format!("a null {what} buffer (address)"));
    }
    let needed = u64::from(count - 1) * stride + size;
    if needed > data.size() {
        return err(format!(
            "{count} {what} records at stride {stride} need {needed} bytes; the range holds {}",
            data.size()
        ));
    }
    range_fits(ctx, k, data)
}

/// The range as bound: from the aligned offset at or below its start, within one binding.
pub(crate) fn bound(ctx: &Context, r: &RawBuffer) -> (RawBuffer, u64) {
    let align = ctx.info().min_storage_buffer_offset_alignment.max(4);
    let start = r.offset - r.offset % align;
    let skip = r.offset - start;
    (
        RawBuffer {
            raw: r.raw,
            offset: start,
            size: (r.size + skip).next_multiple_of(4),
            id: r.id,
        },
        skip,
    )
}

fn range_fits(ctx: &Context, k: usize, data: &GeometryData) -> Result<()> {
    let r = match data {
        GeometryData::Buffer(r) => r,
        GeometryData::Address { .. } => {
            let f = &ctx.info().features;
            if !(f.buffer_device_address || f.ray_query) {
                return Err(usage(format!(
                    "geometry {k}: data at a device address needs bufferDeviceAddress, which \
                     this device (or its context) does not enable"
                )));
            }
            // Words are indexed with 32 bits.
            if data.size() / 4 > u64::from(u32::MAX) {
                return Err(usage(format!(
                    "geometry {k}: {} bytes at one address",
                    data.size()
                )));
            }
            return Ok(());
        }
    };
    let (b, _) = bound(ctx, r);
    let limit = ctx.info().max_storage_buffer_range;
    if b.size > limit || b.size / 4 > u64::from(u32::MAX) {
        return Err(usage(format!(
            "geometry {k}: a range of {} bytes, above this device's maxStorageBufferRange \
             ({limit}); split the geometry",
            b.size
        )));
    }
    Ok(())
}

#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct GatherPush {
    mode: u32,
    count: u32,
    first: u32,
    out_first: u32,
    src_word: u32,
    stride_words: u32,
    index_type: u32,
    index_first: u32,
    vertex_count: u32,
    table_slot: u32,
    geometry: u32,
    has_transform: u32,
    rows: [[f32; 4]; 3],
    src_address: u64,
    idx_address: u64,
    transform_address: u64,
    vertex_format: u32,
    pad: u32,
}

/// Where the gather reads one of a geometry's inputs: a binding (buffers) or a word-aligned
/// address, and the bytes from there to the data's first byte.
#[derive(Clone, Copy)]
enum Read {
    Bound(RawBuffer, u64),
    At(u64, u64),
}

impl Read {
    fn of(ctx: &Context, data: &GeometryData) -> Self {
        match data {
            GeometryData::Buffer(r) => {
                let (b, skip) = bound(ctx, r);
                Read::Bound(b, skip)
            }
            GeometryData::Address { address, .. } => Read::At(address & !3, address & 3),
        }
    }

    fn skip(&self) -> u64 {
        match self {
            Read::Bound(_, s) | Read::At(_, s) => *s,
        }
    }

    fn address(&self) -> u64 {
        match self {
            Read::Bound(..) => 0,
            Read::At(a, _) => *a,
        }
    }
}

/// One structure's gather ([`GeometryGather::record_batch`]): its geometries, their layout,
/// and the primitive arrays and scene constants it writes (walked as `walk`, parent links at
/// `parents_at`).
pub struct GatherJob<'a> {
    /// The caller's geometries.
    pub geometries: &'a [Geometry],
    /// Their layout.
    pub layout: &'a GeometryLayout,
    /// The structure's primitive arrays.
    pub prims: &'a DevicePrimitives,
    /// The structure's scene constants.
    pub info: &'a crate::gpu::Buffer<SceneInfo>,
    /// `SceneInfo::walk`.
    pub walk: u32,
    /// Where the parent links start.
    pub parents_at: u32,
}

/// `accel.geometry_gather`: the caller's geometry into a structure's primitive arrays.
pub struct GeometryGather {
    buffers: std::sync::Arc<Kernel>,
    /// The kernel that reads at device addresses, where the device has them.
    address: Option<std::sync::Arc<Kernel>>,
}

impl GeometryGather {
    /// Compiles the gather kernels: the one that reads bound buffers, and, where the
    /// device has buffer device addresses, the one that reads at addresses.
    pub fn new(ctx: &Context) -> Result<Self> {
        let spec = Spec::new().workgroup(WORKGROUP);
        let address = match ctx.info().features.buffer_device_address {
            true => Some(ctx.kernel(&kernels::ACCEL_GEOMETRY_GATHER_ADDRESS, &spec)?),
            false => None,
        };
        Ok(Self {
            buffers: ctx.kernel(&kernels::ACCEL_GEOMETRY_GATHER_BUFFERS, &spec)?,
            address,
        })
    }

    /// Records the reads of `geometries` (laid out as `layout`) into `prims` and `info`
    /// (whose constants say: walked as `walk`, parent links at `parents_at`). The caller
    /// orders its writes of the geometry before; the recording ends with a compute →
    /// compute barrier.
    #[allow(clippy::too_many_arguments, reason = "the gather's inputs and outputs")]
    pub fn record(
        &self,
        rec: &mut Recorder,
        geometries: &[Geometry],
        layout: &GeometryLayout,
        prims: &DevicePrimitives,
        info: &crate::gpu::Buffer<SceneInfo>,
        walk: u32,
        parents_at: u32,
    ) -> Result<()> {
        let job = GatherJob {
            geometries,
            layout,
            prims,
            info,
            walk,
            parents_at,
        };
        self.record_batch(rec, &[job])
    }

    /// Records the gathers of several structures (their outputs disjoint) interleaved:
    /// every structure's header, one barrier, then each structure's `k`-th geometry with
    /// data, one barrier, and so on — as many barriers as the longest list needs, not the
    /// sum of all. Ends with a compute → compute barrier.
    pub fn record_batch(&self, rec: &mut Recorder, jobs: &[GatherJob<'_>]) -> Result<()> {
        for job in jobs {
            self.record_header(rec, job);
        }
        // Every dispatch may write every output of its structure (as synchronization
        // validation reads a binding): each is ordered after the one before.
        rec.compute_to_compute();
        let with_data = |job: &GatherJob<'_>| -> Vec<usize> {
            (0..job.geometries.len())
                .filter(|&k| job.geometries[k].primitive_count() > 0)
                .collect()
        };
        let lists: Vec<Vec<usize>> = jobs.iter().map(with_data).collect();
        let steps = lists.iter().map(Vec::len).max().unwrap_or(0);
        for step in 0..steps {
            for (job, list) in jobs.iter().zip(&lists) {
                if let Some(&k) = list.get(step) {
                    self.record_geometry(rec, job, k)?;
                }
            }
            rec.compute_to_compute();
        }
        Ok(())
    }

    /// The dispatch that writes a structure's scene constants and clears its table.
    fn record_header(&self, rec: &mut Recorder, job: &GatherJob<'_>) {
        let (layout, prims, info) = (job.layout, job.prims, job.info);
        let header = GatherPush {
            mode: 2,
            count: layout.n_tris,
            first: layout.n_spheres,
            out_first: job.parents_at,
            src_word: job.walk,
            index_first: layout.table.len() as u32,
            vertex_count: layout.n_aabbs,
            ..GatherPush::default()
        };
        let outputs: [&dyn BufferArg; 4] = [&prims.tri_verts, &prims.spheres, &prims.boxes, info];
        let [o0, o1, o2, o3] = outputs;
        rec.dispatch(
            &self.buffers,
            [1, 1, 1],
            &[info, info, o0, o1, o2, o3],
            &header,
        );
    }

    /// The dispatch that reads geometry `k` (which has primitives) of `job`.
    fn record_geometry(&self, rec: &mut Recorder, job: &GatherJob<'_>, k: usize) -> Result<()> {
        let ctx = rec.context().clone();
        let (layout, prims, info) = (job.layout, job.prims, job.info);
        let outputs: [&dyn BufferArg; 4] = [&prims.tri_verts, &prims.spheres, &prims.boxes, info];
        let [o0, o1, o2, o3] = outputs;
        let g = &job.geometries[k];
        let count = g.primitive_count();
        let first = layout.first[k];
        // The table is ordered by first id (triangles, spheres, boxes), not by `k`.
        let slot = layout
            .table
            .iter()
            .position(|e| e[1] & !NON_OPAQUE == k as u32)
            .ok_or_else(|| usage(format!("geometry {k} is not in the layout")))?
            as u32;
        let (src, indices, push) = match g {
            Geometry::Triangles(t) => {
                let src = Read::of(&ctx, &t.vertices);
                let (ix, index_type, index_first) = match &t.indices {
                    Some(i) => {
                        let ix = Read::of(&ctx, &i.data);
                        let kind = match i.index_type {
                            IndexType::U16 => 1,
                            IndexType::U32 => 2,
                        };
                        (ix, kind, (ix.skip() / i.index_type.bytes()) as u32)
                    }
                    None => (src, 0, 0),
                };
                let push = GatherPush {
                    mode: 0,
                    count,
                    first,
                    out_first: first,
                    src_word: (src.skip() / 4) as u32,
                    stride_words: (t.stride / 4) as u32,
                    index_type,
                    index_first,
                    vertex_count: t.vertex_count,
                    table_slot: slot,
                    geometry: g.table_word(k),
                    has_transform: match t.transform {
                        None => 0,
                        Some(Transform::Rows(_)) => 1,
                        Some(Transform::At(_)) => 2,
                    },
                    rows: match t.transform {
                        Some(Transform::Rows(m)) => m,
                        _ => Default::default(),
                    },
                    src_address: src.address(),
                    idx_address: ix.address(),
                    transform_address: match t.transform {
                        Some(Transform::At(a)) => a,
                        _ => 0,
                    },
                    vertex_format: t.format.code(),
                    pad: 0,
                };
                (src, ix, push)
            }
            Geometry::Spheres(s) => {
                let src = Read::of(&ctx, &s.data);
                let push = GatherPush {
                    mode: 1,
                    count,
                    first,
                    out_first: first - layout.n_tris,
                    src_word: (src.skip() / 4) as u32,
                    stride_words: (s.stride / 4) as u32,
                    table_slot: slot,
                    geometry: g.table_word(k),
                    src_address: src.address(),
                    ..GatherPush::default()
                };
                (src, src, push)
            }
            Geometry::Aabbs(b) => {
                let src = Read::of(&ctx, &b.data);
                // Two vec4s per box, after the spheres.
                let push = GatherPush {
                    mode: 3,
                    count,
                    first,
                    out_first: layout.n_spheres + 2 * (first - layout.n_tris - layout.n_spheres),
                    src_word: (src.skip() / 4) as u32,
                    stride_words: (b.stride / 4) as u32,
                    table_slot: slot,
                    geometry: g.table_word(k),
                    src_address: src.address(),
                    ..GatherPush::default()
                };
                (src, src, push)
            }
        };
        let groups = rec.groups_1d(u64::from(count), WORKGROUP);
        match (src, indices) {
            (Read::Bound(s, _), Read::Bound(i, _)) => {
                rec.dispatch(&self.buffers, groups, &[&s, &i, o0, o1, o2, o3], &push)
            }
            _ => {
                let kernel = match &self.address {
                    Some(k) => k.clone(),
                    None => ctx.kernel(
                        &kernels::ACCEL_GEOMETRY_GATHER_ADDRESS,
                        &Spec::new().workgroup(WORKGROUP),
                    )?,
                };
                rec.dispatch(&kernel, groups, &[o0, o1, o2, o3], &push)
            }
        }
        Ok(())
    }
}

/// The CPU twin of the gather: `geometries` as a [`TraceGeometry`], read from host copies
/// of their data (`read(data)` returns its bytes). Tests compare the device's
/// arrays with it.
pub fn gather_on_host(
    geometries: &[Geometry],
    read: impl Fn(&GeometryData) -> Vec<u8>,
) -> (TraceGeometry, u32) {
    let mut tris: Vec<[Vec3; 3]> = Vec::new();
    let mut spheres: Vec<Vec4> = Vec::new();
    let mut aabbs: Vec<Aabb> = Vec::new();
    let mut invalid = 0u32;
    let f32_at = |b: &[u8], at: usize| f32::from_le_bytes(b[at..at + 4].try_into().unwrap());
    for g in geometries {
        match g {
            Geometry::Triangles(t) => {
                let v = read(&t.vertices);
                let transform = t.transform.map(|m| match m {
                    Transform::Rows(m) => m,
                    Transform::At(address) => {
                        let b = read(&GeometryData::Address { address, size: 48 });
                        std::array::from_fn(|r| std::array::from_fn(|c| f32_at(&b, 16 * r + 4 * c)))
                    }
                });
                let ix = t.indices.map(|i| (read(&i.data), i.index_type));
                let index = |k: usize| -> u32 {
                    match &ix {
                        None => k as u32,
                        Some((b, IndexType::U16)) => {
                            u32::from(u16::from_le_bytes([b[2 * k], b[2 * k + 1]]))
                        }
                        Some((b, IndexType::U32)) => {
                            u32::from_le_bytes(b[4 * k..4 * k + 4].try_into().unwrap())
                        }
                    }
                };
                for k in 0..t.triangle_count as usize {
                    let corners = [0, 1, 2].map(|c| index(3 * k + c));
                    let mut ok = corners.iter().all(|&c| c < t.vertex_count);
                    let mut pts = [Vec3::ZERO; 3];
                    if ok {
                        pts = corners.map(|c| {
                            let at = c as usize * t.stride as usize;
                            let p = Vec3::from_array(t.format.decode(&v[at..]));
                            match &transform {
                                Some(m) => transform_point(m, p),
                                None => p,
                            }
                        });
                        ok = pts.iter().all(|p| p.is_finite());
                    }
                    if !ok {
                        invalid += 1;
                        pts = [Vec3::ZERO; 3];
                    }
                    tris.push(pts);
                }
            }
            Geometry::Spheres(s) => {
                let b = read(&s.data);
                for k in 0..s.count as usize {
                    let at = k * s.stride as usize;
                    let mut c = Vec4::new(
                        f32_at(&b, at),
                        f32_at(&b, at + 4),
                        f32_at(&b, at + 8),
                        f32_at(&b, at + 12),
                    );
                    if !c.is_finite() || c.w < 0.0 {
                        invalid += 1;
                        c = Vec4::ZERO;
                    }
                    spheres.push(c);
                }
            }
            Geometry::Aabbs(a) => {
                let b = read(&a.data);
                for k in 0..a.count as usize {
                    let at = k * a.stride as usize;
                    let f = |i: usize| f32_at(&b, at + 4 * i);
                    let mut bx = Aabb {
                        min: Vec3::new(f(0), f(1), f(2)),
                        max: Vec3::new(f(3), f(4), f(5)),
                    };
                    if !(bx.min.is_finite() && bx.max.is_finite()) {
                        invalid += 1;
                        bx = Aabb::EMPTY;
                    }
                    aabbs.push(bx);
                }
            }
        }
    }
    (
        TraceGeometry::from_primitives(&tris, &spheres, &aabbs),
        invalid,
    )
}

/// `m · (p, 1)`, each row summed left to right without fused multiply-add (as the gather).
pub fn transform_point(m: &[[f32; 4]; 3], p: Vec3) -> Vec3 {
    let row = |r: &[f32; 4]| {
        let mut x = r[0] * p.x;
        x += r[1] * p.y;
        x += r[2] * p.z;
        x + r[3]
    };
    Vec3::new(row(&m[0]), row(&m[1]), row(&m[2]))
}

impl DevicePrimitives {
    /// Buffers for the primitives of `layout` (static: no motion), filled on the device by
    /// `accel.geometry_gather` from the caller's buffers.
    pub fn for_layout(ctx: &Context, layout: &GeometryLayout) -> Result<Self> {
        let (n_tris, n_spheres) = (layout.n_tris as usize, layout.n_spheres as usize);
        let n_aabbs = layout.n_aabbs as usize;
        let n = layout.primitive_count();
        Ok(Self {
            // Four floats of padding, as in record_upload.
            tri_verts: Buffer::new(ctx, "trace.tri_verts", 9 * n_tris + 4)?,
            spheres: Buffer::new(ctx, "trace.spheres", n_spheres + 2 * n_aabbs)?,
            prim_motion: Buffer::new(ctx, "trace.prim_motion", 0)?,
            motions: Buffer::new(ctx, "trace.motions", 0)?,
            boxes: Buffer::new(ctx, "trace.boxes", 6 * n)?,
            n_tris,
            n_spheres,
            n_aabbs,
            has_motion: false,
        })
    }
}

impl Geometry {
    /// What it is without its data: the description sizes are asked with
    /// ([`GeometryShape`]).
    pub fn shape(&self) -> GeometryShape {
        match self {
            Geometry::Triangles(t) => GeometryShape::Triangles {
                format: t.format,
                stride: t.stride,
                vertex_count: t.vertex_count,
                index_type: t.indices.map(|i| i.index_type),
                triangle_count: t.triangle_count,
                opaque: t.opaque,
            },
            Geometry::Spheres(s) => GeometryShape::Spheres {
                stride: s.stride,
                count: s.count,
                opaque: s.opaque,
            },
            Geometry::Aabbs(b) => GeometryShape::Aabbs {
                stride: b.stride,
                count: b.count,
                opaque: b.opaque,
            },
        }
    }
}

impl GeometryDescription for Geometry {
    fn shape(&self) -> GeometryShape {
        Geometry::shape(self)
    }

    fn check(&self, ctx: &Context, k: usize) -> Result<()> {
        check(ctx, k, self)
    }
}
