//! Two levels, as `VK_KHR_acceleration_structure`, Embree and OptiX organise a scene:
//! bottom-level structures (any vkrt kind over geometries, [`GpuGeometry`]) and a top level
//! over *instances* of them, each with an object-to-world transform, a custom index, an
//! 8-bit visibility mask and flags ([`Instance`], the layout of
//! `VkAccelerationStructureInstanceKHR`).
//!
//! The top level is a BVH (LBVH or PLOC) over the instances' world boxes, built on the
//! device in memory the caller allocates and recorded into the caller's command buffer, as
//! every build: [`TopLevelBuilder::sizes_for`], [`TopLevelBuilder::create_in`],
//! [`TopLevelBuilder::record_build_from`], and [`TopLevelBuilder::record_update_from`] for
//! instances that moved (a refit of the same tree). `accel.instance_boxes` (CPU twin
//! [`instance_boxes`], bit for bit) turns the caller's records into world boxes and
//! world-to-object transforms first. [`TopLevelBuilder::build`] does all of it from host
//! records, checking each one first.
//!
//! Shaders trace it through `vkrt/ray_query.glsl` with `VKRT_DEVICE_ADDRESS`, passing
//! [`TopLevel::handle_address`] to `vkrtUseStructure`: at an instance the walk moves the ray
//! into the instance's object space (the direction is not renormalised, so `t` keeps its
//! meaning) and walks its bottom level with that level's own walk; hits name the instance
//! and its custom index (the CPU twin:
//! [`trace_instances`](crate::trace::instanced::trace_instances)).
//!
//! Instances move as Embree's motion-blurred instances do ([`InstanceMotion`]; two steps
//! are `VK_NV_ray_tracing_motion_blur`'s matrix motion): each instance's object-to-world is
//! given at `steps` evenly spaced times, and a ray at time `t` sees the two steps around `t`
//! interpolated row by row (linearly: a rotation is followed by its chords, so give as many
//! steps as the rotation needs). The top level boxes the union of an instance's steps, and
//! the walk inverts the interpolated transform per ray.
//!
//! As in Vulkan, a top level is created for a maximum number of instances
//! (`maxPrimitiveCount` of `vkGetAccelerationStructureBuildSizesKHR`) and each build reads
//! as many as it is given, up to that (`primitiveCount`); an update keeps its build's count,
//! as Vulkan requires. An instance names its bottom level as
//! `accelerationStructureReference` does, by reference ([`GpuGeometry::reference`]: an
//! address the device reads the level through), so that a top level needs no list of its
//! bottom levels and borrows none: the caller keeps every level its instances reference
//! alive, and built, for as long as the top level is built or traced, as Vulkan requires.
//! A top level may also be given a list of bottom levels: its instances may then name them
//! by index, and a reference must be one of them (a check the device makes); the top level
//! keeps copies of their handles, which those instances walk.
//!
//! An instance with an index out of range (0 included, when there is no list), a reference
//! not in the list, or a transform that is not finite or not invertible, is never hit and is
//! counted in [`BuildStatus::invalid_primitives`] ([`TopLevel::record_read_status`]);
//! [`TopLevelBuilder::build`] refuses it with an error. Without a list, a reference is
//! followed as given: one to no live bottom level is undefined, as in Vulkan (the device
//! reads whatever lies there). vkrt's walks treat every primitive as opaque and cull no
//! faces, so the flags change nothing in them; they are kept for the driver's structures.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::accel::device::{AccelBuilder, AccelKind, AccelSizes};
use crate::accel::embedded::{BuildFlags, BuildStatus};
use crate::accel::geometry::{bound, transform_point, Aabbs, Geometry, GeometryData};
use crate::accel::gpu_geometry::GpuGeometry;
pub use crate::accel::instance::{
    flags, lerp_rows, transform_direction, world_to_object, Instance, InstanceMotion,
    InstanceRecord, MAX_BOTTOM_LEVELS, MAX_MOTION_STEPS,
};
use crate::accel::primitives::SceneInfo;
use crate::gpu::placement::{place, Placement};
use crate::gpu::{
    kernels, vk, Buffer, BufferArg, Context, GpuError, Kernel, PlacementProblem, RawBuffer,
    Readback, Recorder, Result, Spec,
};

const WORKGROUP: u32 = 64;
/// `accel.instance_boxes`: its exact variant (the inverse's division rounded correctly in
/// doubles where the driver's is not, so that the records equal [`instance_boxes`]' on every
/// device) wherever the device has doubles.
fn instance_boxes_kernel(ctx: &Context) -> Result<Arc<Kernel>> {
    let spec = Spec::new().workgroup(WORKGROUP);
    if ctx.info().features.shader_float64 {
        let refine = !ctx.info().ieee_division;
        ctx.kernel(
            &kernels::ACCEL_INSTANCE_BOXES_EXACT,
            &spec.u32(21, u32::from(refine)),
        )
    } else {
        ctx.kernel(&kernels::ACCEL_INSTANCE_BOXES_FLOAT, &spec)
    }
}

/// `accel.instance_pointers`: instance records given as an array of pointers
/// (`arrayOfPointers` in `VkAccelerationStructureGeometryInstancesDataKHR`) gathered into one
/// array, which a top level's build then reads as it reads the caller's records.
pub struct InstancePointers {
    kernel: Arc<Kernel>,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct PointersPush {
    pointers: u64,
    count: u32,
    first: u32,
}

impl InstancePointers {
    /// Compiles the gather (the context needs `bufferDeviceAddress`).
    pub fn new(ctx: &Context) -> Result<Self> {
        if !ctx.info().features.buffer_device_address {
            return Err(usage(
                "InstancePointers::new",
                "instance pointers are device addresses: the context needs bufferDeviceAddress",
            ));
        }
        let kernel = ctx.kernel(
            &kernels::ACCEL_INSTANCE_POINTERS,
            &Spec::new().workgroup(WORKGROUP),
        )?;
        Ok(Self { kernel })
    }

    /// Records the gather of the `count` records the pointers at `pointers` (device
    /// addresses, 8 bytes each, each 16-byte aligned or null) point to into `out` (at least
    /// `64 * count` bytes, offset a multiple of 16), in their order. A null pointer gives a
    /// record of zeros. Ends with a compute → compute barrier; allocates nothing.
    pub fn record(
        &self,
        rec: &mut Recorder,
        pointers: u64,
        count: u32,
        out: RawBuffer,
    ) -> Result<()> {
        let call = "InstancePointers::record";
        if count == 0 {
            return Ok(());
        }
        if pointers == 0 || pointers % 8 != 0 {
            return Err(usage(
                call,
                format!("the pointers' address {pointers:#x} is not a non-null multiple of 8"),
            ));
        }
        if out.size < 64 * u64::from(count) || out.offset % 16 != 0 {
            return Err(usage(
                call,
                format!(
                    "{count} records need 64 bytes each at an offset a multiple of 16; the range \
                     holds {} at {}",
                    out.size, out.offset
                ),
            ));
        }
        let ctx = rec.context().clone();
        let (bound_out, skip) = bound(&ctx, &out);
        let push = PointersPush {
            pointers,
            count,
            first: (skip / 16) as u32,
        };
        let groups = rec.groups_1d(u64::from(count), WORKGROUP);
        rec.dispatch(&self.kernel, groups, &[&bound_out], &push);
        rec.compute_to_compute();
        rec.check()
    }
}

/// [`InstancePointers::record`] on the host: the records `read` gives at each pointer (a null
/// one: zeros), in order.
pub fn instance_pointers_on_host(
    pointers: &[u64],
    read: impl Fn(u64) -> [u8; 64],
) -> Vec<[u8; 64]> {
    pointers
        .iter()
        .map(|&p| match p {
            0 => [0; 64],
            p => read(p),
        })
        .collect()
}

/// What [`instance_boxes`] makes of a top level's instances.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct InstanceBoxes {
    /// Per instance its world box (min x, y, z, max x, y, z; an inactive one has min 1 > max
    /// 0): over all its steps when it moves.
    pub boxes: Vec<[f32; 6]>,
    /// Per instance what the walk reads.
    pub records: Vec<InstanceRecord>,
    /// A moving top level's object-to-world rows, `steps` per instance (empty without
    /// motion).
    pub steps: Vec<[[f32; 4]; 3]>,
    /// Instances that are never hit for an error (counted in the build's status).
    pub invalid: u32,
}

/// The CPU twin of `accel.instance_boxes`, bit for bit: the top level's boxes, records and
/// steps for `instances` moving by `motion` (`motion.steps` lists of them, step after step),
/// given bottom levels' scene constants and references ([`GpuGeometry::reference`]). With
/// `handles_at` (where the top level keeps its copies of their handles, 64 bytes apart:
/// [`TopLevel::bottom_handles_address`]), `bottoms` is the top level's list (instances name
/// its levels by index or by reference); without, the levels alive on the device, which
/// instances name by reference (there, a reference to none of them is undefined; the twin
/// counts it invalid).
pub fn instance_boxes(
    instances: &[Instance],
    motion: InstanceMotion,
    bottoms: &[(SceneInfo, u64)],
    handles_at: Option<u64>,
) -> InstanceBoxes {
    let listed = handles_at.is_some();
    let references: Vec<u64> = bottoms.iter().map(|b| b.1).collect();
    let n_steps = motion.steps.max(1) as usize;
    let count = instances.len() / n_steps;
    let mut out = InstanceBoxes::default();
    if n_steps > 1 {
        out.steps = (0..count * n_steps)
            .map(|k| instances[(k % n_steps) * count + k / n_steps].transform)
            .collect();
    }
    // An instance whose steps are all the same is recorded as still.
    let motion_words = |i: usize| {
        let rows = |s: usize| bytemuck::cast::<_, [u32; 12]>(instances[s * count + i].transform);
        let still = (1..n_steps).all(|s| rows(s) == rows(0));
        [
            if still { 1 } else { n_steps as u32 },
            (i * n_steps) as u32,
            motion.time[0].to_bits(),
            motion.scale().to_bits(),
        ]
    };
    let inactive_box = [1.0, 1.0, 1.0, 0.0, 0.0, 0.0];
    for (i, inst) in instances[..count].iter().enumerate() {
        // (the level's place among `bottoms`, and its index in the record)
        let found = match listed {
            true => inst.bottom_index(&references).map(|k| (k, k)),
            false if inst.bottom < MAX_BOTTOM_LEVELS as u64 => None,
            false => inst
                .bottom_index(&references)
                .map(|k| (k, InstanceRecord::UNLISTED)),
        };
        let bottom_ok = found.is_some();
        let (at, bottom) = found.unwrap_or((0, 0));
        let meta_w = u32::from(inst.flags()) | (bottom << 8);
        let inactive = InstanceRecord {
            world_to_object: [[0.0; 4]; 3],
            handle: 0,
            custom_index_and_mask: 0,
            flags_and_bottom: meta_w,
            motion: [1, 0, 0, 0],
        };
        let step = |s: usize| &instances[s * count + i].transform;
        let inv = world_to_object(step(0)).filter(|_| bottom_ok);
        let Some(inv) = inv.filter(|_| (1..n_steps).all(|s| world_to_object(step(s)).is_some()))
        else {
            out.invalid += 1;
            out.boxes.push(inactive_box);
            out.records.push(inactive);
            continue;
        };
        let b = &bottoms[at as usize].0;
        let handle = match handles_at {
            Some(h) => h + 64 * u64::from(at),
            None => bottoms[at as usize].1,
        };
        if b.n_tris + b.n_spheres + b.n_aabbs == 0 || inst.mask() == 0 {
            out.boxes.push(inactive_box);
            out.records.push(inactive);
            continue;
        }
        let (bmin, bmax) = (
            Vec3::from_slice(&b.bounds_min),
            Vec3::from_slice(&b.bounds_max),
        );
        let mut box_lo = Vec3::INFINITY;
        let mut box_hi = Vec3::NEG_INFINITY;
        for s in 0..n_steps {
            let m = step(s);
            let (lo, hi) = placed_box(m, bmin, bmax);
            box_lo = box_lo.min(lo);
            box_hi = box_hi.max(hi);
        }
        out.boxes
            .push([box_lo.x, box_lo.y, box_lo.z, box_hi.x, box_hi.y, box_hi.z]);
        out.records.push(InstanceRecord {
            world_to_object: inv,
            handle,
            custom_index_and_mask: inst.custom_index_and_mask,
            flags_and_bottom: meta_w,
            motion: motion_words(i),
        });
    }
    out
}

/// The box of `[bmin, bmax]` placed by `m`: its eight corners moved, padded by 2^-20 of
/// their terms' magnitudes (each coordinate is a sum of four rounded terms: that bounds its
/// error, and the object-space ray's, with room to spare).
fn placed_box(m: &[[f32; 4]; 3], bmin: Vec3, bmax: Vec3) -> (Vec3, Vec3) {
    let mut lo = Vec3::INFINITY;
    let mut hi = Vec3::NEG_INFINITY;
    for k in 0..8 {
        let p = Vec3::new(
            if k & 1 != 0 { bmax.x } else { bmin.x },
            if k & 2 != 0 { bmax.y } else { bmin.y },
            if k & 4 != 0 { bmax.z } else { bmin.z },
        );
        let q = transform_point(m, p);
        lo = lo.min(q);
        hi = hi.max(q);
    }
    let e = bmin.abs().max(bmax.abs());
    let pad_row = |r: &[f32; 4]| {
        (r[0].abs() * e.x + r[1].abs() * e.y + r[2].abs() * e.z + r[3].abs())
            * f32::from_bits(0x3580_0000)
    };
    let pad = Vec3::new(pad_row(&m[0]), pad_row(&m[1]), pad_row(&m[2]));
    (lo - pad, hi + pad)
}

/// A top level's list of bottom levels, copied: per level its reference (where
/// [`GpuGeometry::reference`] points, the key instances may name it by) and its handle.
fn copy_list<'a>(bottoms: impl IntoIterator<Item = &'a GpuGeometry>) -> Result<Listed> {
    let mut out = Listed::default();
    for b in bottoms {
        out.alive.push(Arc::downgrade(&b.life.token));
        out.references.push(b.reference_address()?);
        let mut handle = [0u64; 8];
        handle[..7].copy_from_slice(&b.handle_words()?);
        out.handles.push(handle);
    }
    Ok(out)
}

/// A top level's copy of its list of bottom levels ([`copy_list`]).
#[derive(Default)]
struct Listed {
    references: Vec<u64>,
    handles: Vec<[u64; 8]>,
    /// Whether each is alive: the tree refuses to be built or traced once one is dropped.
    alive: Vec<std::sync::Weak<()>>,
}

/// The table `accel.instance_boxes` searches for an instance's reference: (reference low,
/// high word, bottom index, 0) per bottom level, ordered by reference.
fn reference_table(references: &[u64]) -> Vec<[u32; 4]> {
    let mut table: Vec<[u32; 4]> = references
        .iter()
        .enumerate()
        .map(|(k, &r)| [r as u32, (r >> 32) as u32, k as u32, 0])
        .collect();
    table.sort_unstable_by_key(|e| (u64::from(e[1]) << 32) | u64::from(e[0]));
    table
}

fn usage(call: &'static str, reason: impl Into<String>) -> GpuError {
    GpuError::Usage {
        call,
        reason: reason.into(),
    }
}

/// Builds top levels of one kind (an LBVH or PLOC over the instances' boxes).
///
/// Two instances of one bottom level, the second moved 3 units along x; a shader walks the
/// result from [`TopLevel::handle_address`] (`vkrtUseStructure` in `vkrt/ray_query.glsl`):
///
/// ```
/// use vkrt::accel::instances::{Instance, TopLevelBuilder};
/// use vkrt::glam::{Affine3A, Vec3};
/// use vkrt::{AccelBuilder, AccelKind, BuildFlags, Context, ContextOptions, GpuGeometry};
/// use vkrt::{Recorder, TraceGeometry};
///
/// # fn main() -> Result<(), Box<dyn std::error::Error>> {
/// # /*
/// let ctx = Context::new(&ContextOptions::default())?;
/// # */
/// # let ctx = Context::new(&ContextOptions::for_tests())?; // validation as the tests run it
/// let triangle = [Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, -1.0, 0.0), Vec3::Y];
/// let mut rec = Recorder::new(&ctx)?;
/// let builder = AccelBuilder::new(&ctx, AccelKind::Lbvh)?;
/// let geometry = TraceGeometry::from_triangles(&[triangle]);
/// let (bottom, _) = GpuGeometry::record_build(&mut rec, &builder, &geometry, 0)?;
/// rec.submit_and_wait()?;
///
/// let moved = Instance::rows_of(&Affine3A::from_translation(Vec3::new(3.0, 0.0, 0.0)));
/// let instances = [
///     Instance::new(0, Instance::IDENTITY),
///     Instance::new(0, moved).with_custom_index(7),
/// ];
/// let top = TopLevelBuilder::new(&ctx, AccelKind::Lbvh)?.build(
///     &ctx,
///     &[&bottom],
///     &instances,
///     &BuildFlags::default(),
/// )?;
/// assert_ne!(top.handle_address(), 0);
/// let (boxes, _) = top.download()?;
/// // World boxes (min xyz, max xyz), rounded outwards by a few ulps.
/// assert!((boxes[1][0] - 2.0).abs() < 1e-5 && (boxes[1][3] - 4.0).abs() < 1e-5);
/// # let messages = ctx.take_validation_messages();
/// # assert!(messages.is_empty(), "validation: {messages:?}");
/// # Ok(())
/// # }
/// ```
pub struct TopLevelBuilder {
    tree: AccelBuilder,
    boxes: Arc<Kernel>,
}

/// The top level's own arrays (before its tree in the caller's memory).
struct Parts {
    boxes: Buffer<[f32; 6]>,
    records: Buffer<InstanceRecord>,
    /// A moving top level's object-to-world rows per instance and step.
    steps: Buffer<[[f32; 4]; 3]>,
    /// The copies of its list's handles, 64 bytes apart (an instance naming a level of the
    /// list walks the copy).
    handles: Buffer<[u64; 8]>,
    /// The caller's records as given (step 0's): what a ray query reports of an instance
    /// (object-to-world, SBT record offset).
    originals: Buffer<Instance>,
    /// The bottom levels by reference ([`reference_table`]).
    references: Buffer<[u32; 4]>,
    /// The top level's handle: its tree's seven arrays, its records, its steps, its
    /// originals.
    handle: Buffer<[u64; 8]>,
    status: Buffer<u32>,
}

impl Parts {
    fn create(ctx: &Context, slots: u32, n_bottoms: usize, motion: InstanceMotion) -> Result<Self> {
        let n = (slots as usize).max(1);
        let b = n_bottoms.max(1);
        let steps = if motion.steps > 1 {
            motion.records(slots).max(1) as usize
        } else {
            1
        };
        Ok(Self {
            boxes: Buffer::new(ctx, "accel.instance_boxes", n)?,
            records: Buffer::new(ctx, "accel.instance_records", n)?,
            steps: Buffer::new(ctx, "accel.instance_steps", steps)?,
            handles: Buffer::new(ctx, "accel.bottom_handles", b)?,
            originals: Buffer::new(ctx, "accel.instance_originals", n)?,
            references: Buffer::new(ctx, "accel.bottom_references", b)?,
            handle: Buffer::new(ctx, "accel.top_handle", 2)?,
            status: Buffer::new(ctx, "accel.instance_status", 1)?,
        })
    }
}

/// A top level over instances of bottom levels, in the caller's memory or its own. It
/// borrows nothing: its instances reference their bottom levels as Vulkan's do, and the
/// caller keeps those alive (and built) while the top level is built, updated or traced
/// (but for the ones it keeps: [`TopLevelBuilder::record_build_shared`]). Once a bottom
/// level it lists is dropped, its builds, updates, traces and handle are errors, not reads
/// of freed memory; instances in the caller's buffer that name levels by reference alone
/// are the caller's promise ([`RawBuffer::new`]).
pub struct TopLevel {
    /// The BVH over the instances' world boxes (box primitive `i` is instance `i`), over
    /// every slot of the maximum it was created for.
    pub(crate) tree: GpuGeometry,
    parts: Parts,
    /// Its list of bottom levels, copied (instances name these by index or by reference).
    listed: Listed,
    /// The bottom levels it keeps alive ([`TopLevelBuilder::record_build_shared`]).
    kept: Vec<Arc<GpuGeometry>>,
    /// Instances it has room for (its instance slots).
    max: u32,
    /// Instances its last build read (the maximum before one): its updates read as many.
    count: u32,
    motion: InstanceMotion,
    /// What [`TopLevelBuilder::build`] allocated (none for [`TopLevelBuilder::create_in`]).
    own: Option<Own>,
    /// Bytes of its memory ([`AccelSizes::structure_bytes`]).
    bytes: u64,
}

/// The memory of a top level vkrt allocated: the structure, the scratch of its builds and
/// updates, and the buffer the host's instance records are uploaded to (kept, so that an
/// update allocates nothing).
struct Own {
    _memory: Buffer<u8>,
    scratch: Buffer<u8>,
    records: Buffer<Instance>,
}

/// `flags` for a top level's tree: its own nodes binary whatever `wide` says, since the
/// instance walk (`vkrt/instances.glsl`) reads binary nodes; the bottom levels' walks are
/// theirs.
fn binary_nodes(flags: &BuildFlags) -> BuildFlags {
    BuildFlags {
        wide: false,
        ..*flags
    }
}

/// The top level's part of the caller's memory, rounded up so that its tree starts aligned.
fn parts_bytes(ctx: &Context, slots: u32, n_bottoms: usize, motion: InstanceMotion) -> Result<u64> {
    let (_, bytes) = place(ctx, "the instances", Placement::Measure, || {
        Parts::create(ctx, slots, n_bottoms, motion)
    })?;
    Ok(bytes.next_multiple_of(256))
}

/// The tree's geometry: one box per instance.
fn boxes_geometry(data: GeometryData, count: u32) -> Geometry {
    Geometry::Aabbs(Aabbs {
        data,
        stride: 24,
        count,
        opaque: true,
    })
}

/// A stand-in for the boxes while measuring (sizes depend on the count alone).
fn measured_boxes(count: u32) -> Geometry {
    use vk::Handle;
    let raw = RawBuffer {
        raw: vk::Buffer::from_raw(1),
        offset: 0,
        size: 24 * u64::from(count.max(1)),
        id: crate::gpu::BufferId::Caller(vk::Buffer::from_raw(1)),
    };
    boxes_geometry(GeometryData::Buffer(raw), count)
}

impl TopLevelBuilder {
    /// A builder of top levels that are `kind` trees ([`AccelKind::Lbvh`] or
    /// [`AccelKind::Ploc`]: builders over boxes on the device, with refit).
    pub fn new(ctx: &Context, kind: AccelKind) -> Result<Self> {
        if !matches!(kind, AccelKind::Lbvh | AccelKind::Ploc) {
            return Err(usage(
                "TopLevelBuilder::new",
                format!(
                    "a top level is an LBVH or a PLOC tree over the instances' boxes, not a {}",
                    kind.name()
                ),
            ));
        }
        let f = &ctx.info().features;
        if !(f.buffer_device_address || f.ray_query) {
            return Err(GpuError::MissingCapability {
                device: ctx.info().device.clone(),
                what: "bufferDeviceAddress (a top level reaches its bottom levels at device \
                       addresses)"
                    .into(),
            });
        }
        if !f.shader_int64 {
            return Err(GpuError::MissingCapability {
                device: ctx.info().device.clone(),
                what: "shaderInt64 (the two-level walk reads 64-bit addresses)".into(),
            });
        }
        let mut tree = AccelBuilder::new(ctx, kind)?;
        tree.top_level = true;
        Ok(Self {
            tree,
            boxes: instance_boxes_kernel(ctx)?,
        })
    }

    /// The kind of the top level's tree ([`AccelKind::Lbvh`] or [`AccelKind::Ploc`]).
    pub fn kind(&self) -> AccelKind {
        self.tree.kind()
    }

    /// Bytes of a top level of at most `max_instances` instances (Vulkan's
    /// `maxPrimitiveCount`) with a list of `n_bottoms` bottom levels (0: its instances name
    /// them by reference only), of its build's scratch and of an update's (with
    /// `flags.allow_update`).
    pub fn sizes_for(
        &self,
        ctx: &Context,
        max_instances: u32,
        n_bottoms: usize,
        flags: &BuildFlags,
    ) -> Result<AccelSizes> {
        self.sizes_for_motion(ctx, max_instances, n_bottoms, InstanceMotion::STATIC, flags)
    }

    /// [`TopLevelBuilder::sizes_for`] a top level whose instances move by `motion`.
    pub fn sizes_for_motion(
        &self,
        ctx: &Context,
        max_instances: u32,
        n_bottoms: usize,
        motion: InstanceMotion,
        flags: &BuildFlags,
    ) -> Result<AccelSizes> {
        motion
            .why_not()
            .map_err(|why| usage("TopLevelBuilder::sizes_for_motion", why))?;
        let own = parts_bytes(ctx, max_instances, n_bottoms, motion)?;
        let tree =
            self.tree
                .sizes_for(ctx, &[measured_boxes(max_instances)], &binary_nodes(flags))?;
        Ok(AccelSizes {
            structure_bytes: own + tree.structure_bytes,
            ..tree
        })
    }

    /// A top level of at most `max_instances` instances, placed at the start of `memory`, a
    /// range of the caller's buffer of at least [`AccelSizes::structure_bytes`] with
    /// [`crate::accel::embedded::REQUIRED_BUFFER_USAGE`] and `SHADER_DEVICE_ADDRESS`.
    /// `bottoms` is its list of bottom levels, which its instances may name by index (their
    /// references are copied: the list is not borrowed); give none where every instance
    /// names its level by reference, as Vulkan's do. Each level an instance names must be
    /// built before the top level's build executes, and kept alive while it is used.
    pub fn create_in(
        &self,
        ctx: &Context,
        bottoms: &[&GpuGeometry],
        max_instances: u32,
        flags: &BuildFlags,
        memory: RawBuffer,
    ) -> Result<TopLevel> {
        let listed = copy_list(bottoms.iter().copied())?;
        self.create_in_listed(
            ctx,
            listed,
            max_instances,
            InstanceMotion::STATIC,
            flags,
            memory,
        )
    }

    /// [`TopLevelBuilder::create_in`] a top level whose instances move by `motion`: its
    /// builds read `motion.steps` records per instance ([`InstanceMotion`]), and `memory`
    /// holds at least [`TopLevelBuilder::sizes_for_motion`]'s bytes.
    pub fn create_moving_in(
        &self,
        ctx: &Context,
        bottoms: &[&GpuGeometry],
        max_instances: u32,
        motion: InstanceMotion,
        flags: &BuildFlags,
        memory: RawBuffer,
    ) -> Result<TopLevel> {
        let listed = copy_list(bottoms.iter().copied())?;
        self.create_in_listed(ctx, listed, max_instances, motion, flags, memory)
    }

    fn create_in_listed(
        &self,
        ctx: &Context,
        listed: Listed,
        max: u32,
        motion: InstanceMotion,
        flags: &BuildFlags,
        memory: RawBuffer,
    ) -> Result<TopLevel> {
        let call = "TopLevelBuilder::create_in";
        motion.why_not().map_err(|why| usage(call, why))?;
        let n_bottoms = listed.references.len();
        if n_bottoms > MAX_BOTTOM_LEVELS {
            return Err(usage(
                call,
                format!("{n_bottoms} bottom levels: at most {MAX_BOTTOM_LEVELS}"),
            ));
        }
        let own = parts_bytes(ctx, max, n_bottoms, motion)?;
        if memory.size < own {
            return Err(GpuError::Placement {
                what: format!("{call}: the top level's arrays (TopLevelBuilder::sizes_for)"),
                problem: PlacementProblem::TooSmall {
                    needed: own,
                    given: memory.size,
                },
            });
        }
        let (parts, _) = place(ctx, "the instances", Placement::Into(memory), || {
            Parts::create(ctx, max, n_bottoms, motion)
        })?;
        let rest = RawBuffer {
            raw: memory.raw,
            offset: memory.offset + own,
            size: memory.size - own,
            id: memory.id,
        };
        let geometry = boxes_geometry(GeometryData::Buffer(parts.boxes.own_range()), max);
        let flags = &binary_nodes(flags);
        let mut tree = self.tree.create_in(ctx, &[geometry], flags, rest)?;
        tree.life.bottoms = listed.alive.clone();
        let bytes = own
            + self
                .tree
                .sizes_for(ctx, &[measured_boxes(max)], flags)?
                .structure_bytes;
        Ok(TopLevel {
            tree,
            parts,
            listed,
            kept: Vec::new(),
            max,
            count: max,
            motion,
            own: None,
            bytes,
        })
    }

    /// Records what a build and an update share: at a build the list's references and the
    /// top level's handle, then `accel.instance_boxes` over the `count` instances of the
    /// caller's `instances` (every slot past them inactive).
    fn record_instances(
        &self,
        rec: &mut Recorder,
        call: &'static str,
        instances: RawBuffer,
        count: u32,
        top: &TopLevel,
        build: bool,
    ) -> Result<()> {
        let ctx = rec.context().clone();
        let need = 64 * top.motion.records(count);
        if instances.size < need {
            return Err(usage(
                call,
                format!(
                    "{count} instances at {} time steps need {need} bytes; the range holds {}",
                    top.motion.steps, instances.size
                ),
            ));
        }
        if instances.offset % 4 != 0 {
            return Err(usage(call, "the instances' offset is not a multiple of 4"));
        }
        let p = &top.parts;
        // The copies of the list's handles, its references' ordered table and the top level's
        // own handle (the tree's seven arrays, then the records, steps and originals):
        // written by a build only, constants carried in the command buffer.
        let mut handle = [[0u64; 8]; 2];
        let mut table = Vec::new();
        if build {
            table = reference_table(&top.listed.references);
            handle[0][..7].copy_from_slice(&top.tree.handle_words()?);
            handle[0][7] = p.records.address();
            handle[1][0] = p.steps.address();
            handle[1][1] = p.originals.address();
        }
        rec.scope("instances", |rec| {
            // (the last build's or update's kernel wrote the status)
            rec.compute_to_transfer();
            rec.fill(&p.status, 0);
            if build {
                for (k, chunk) in top.listed.handles.chunks(1024).enumerate() {
                    rec.update(&p.handles, k * 1024, chunk)?;
                }
                for (k, chunk) in table.chunks(4096).enumerate() {
                    rec.update(&p.references, k * 4096, chunk)?;
                }
                rec.update(&p.handle, 0, &handle)?;
            }
            rec.transfer_to_compute();
            if top.max > 0 {
                let (bound_instances, skip) = bound(&ctx, &instances);
                let push = BoxesPush {
                    n: count,
                    slots: top.max,
                    first_word: (skip / 4) as u32,
                    n_bottoms: top.listed.references.len() as u32,
                    steps: top.motion.steps,
                    pad: 0,
                    handles_at: p.handles.address(),
                    t0: top.motion.time[0],
                    scale: top.motion.scale(),
                };
                let groups = rec.groups_1d(u64::from(top.max), WORKGROUP);
                let b: [&dyn BufferArg; 8] = [
                    &bound_instances,
                    &p.handles,
                    &p.boxes,
                    &p.records,
                    &p.status,
                    &p.steps,
                    &p.originals,
                    &p.references,
                ];
                rec.dispatch(&self.boxes, groups, &b, &push);
            }
            rec.compute_to_compute();
            Ok(())
        })
    }

    /// Records the build of `top` from the first `count` instance records in `instances` (a
    /// range of the caller's buffer, [`Instance`]'s layout, written before as compute or
    /// transfer writes by the caller's host or shaders; the bottom levels' builds recorded
    /// or executed before too), with its scratch in `scratch`
    /// ([`AccelSizes::build_scratch_bytes`]). `count` is Vulkan's `primitiveCount`, at most
    /// the maximum `top` was created for (an error otherwise); a moving top level reads
    /// `motion.steps` lists of `count` records. Reads the instances where they lie:
    /// stages, allocates and submits nothing. Ends with a compute → compute barrier, after
    /// which the caller's kernels may trace it.
    pub fn record_build_from(
        &self,
        rec: &mut Recorder,
        top: &mut TopLevel,
        instances: RawBuffer,
        count: u32,
        scratch: RawBuffer,
    ) -> Result<()> {
        let call = "TopLevelBuilder::record_build_from";
        self.check_kind(call, top)?;
        top.tree.check_bottoms(call)?;
        if count > top.max {
            return Err(usage(
                call,
                format!(
                    "{count} instances; the top level was created for at most {} \
                     (TopLevelBuilder::create_in)",
                    top.max
                ),
            ));
        }
        rec.scope("top level", |rec| {
            self.record_instances(rec, call, instances, count, top, true)?;
            top.count = count;
            let geometry = top.geometry();
            self.tree
                .record_build_from(rec, &mut top.tree, &[geometry], scratch)
        })
    }

    /// Records an update of `top` (built with `allow_update`) to the records `instances`
    /// holds now: new transforms, masks and bottom levels of as many instances as its last
    /// build read (Vulkan's update keeps the build's `primitiveCount`: build again for
    /// another count). A refit of the same tree: fast, and as good as the tree was while
    /// the instances move together; rebuild when they have rearranged. Stages, allocates
    /// and submits nothing.
    pub fn record_update_from(
        &self,
        rec: &mut Recorder,
        top: &mut TopLevel,
        instances: RawBuffer,
        scratch: RawBuffer,
    ) -> Result<()> {
        let call = "TopLevelBuilder::record_update_from";
        self.check_kind(call, top)?;
        top.tree.check_bottoms(call)?;
        rec.scope("top level update", |rec| {
            self.record_instances(rec, call, instances, top.count, top, false)?;
            let geometry = top.geometry();
            self.tree
                .record_update_from(rec, &mut top.tree, &[geometry], scratch)
        })
    }

    fn check_kind(&self, call: &'static str, top: &TopLevel) -> Result<()> {
        if top.tree.accel.kind() != self.kind() {
            return Err(usage(
                call,
                format!(
                    "a {} top-level builder cannot build a {} top level",
                    self.kind().name(),
                    top.tree.accel.kind().name()
                ),
            ));
        }
        Ok(())
    }

    /// A top level over `instances` of `bottoms`, built and waited for: each instance is
    /// checked first ([`Instance::check`]: it names one of `bottoms`, by index or by
    /// reference), and one that the device would never hit is an error naming it. Allocates
    /// its memory (kept by the result) and submits once. The caller keeps `bottoms` alive
    /// while the result is used.
    pub fn build(
        &self,
        ctx: &Context,
        bottoms: &[&GpuGeometry],
        instances: &[Instance],
        flags: &BuildFlags,
    ) -> Result<TopLevel> {
        let mut rec = Recorder::new(ctx)?;
        let top = self.record_build(&mut rec, bottoms, instances, flags)?;
        rec.submit_and_wait()?;
        Ok(top)
    }

    /// [`TopLevelBuilder::build`] recorded into `rec` (in a scope `top level`), not
    /// submitted: the upload of `instances` and the build, in memory the result keeps.
    pub fn record_build(
        &self,
        rec: &mut Recorder,
        bottoms: &[&GpuGeometry],
        instances: &[Instance],
        flags: &BuildFlags,
    ) -> Result<TopLevel> {
        let listed = copy_list(bottoms.iter().copied())?;
        let motion = InstanceMotion::STATIC;
        self.record_build_listed(rec, listed, instances, motion, flags)
    }

    /// [`TopLevelBuilder::build`] of a top level whose instances move by `motion`:
    /// `instances` holds `motion.steps` lists of them, step after step ([`InstanceMotion`]).
    /// Beyond each step's checks, an instance must name the same bottom level, custom
    /// index, mask and flags at every step, and keep its handedness (a transform whose
    /// determinant changes sign passes through a singular one between the steps).
    pub fn build_moving(
        &self,
        ctx: &Context,
        bottoms: &[&GpuGeometry],
        instances: &[Instance],
        motion: InstanceMotion,
        flags: &BuildFlags,
    ) -> Result<TopLevel> {
        let mut rec = Recorder::new(ctx)?;
        let listed = copy_list(bottoms.iter().copied())?;
        let top = self.record_build_listed(&mut rec, listed, instances, motion, flags)?;
        rec.submit_and_wait()?;
        Ok(top)
    }

    /// [`TopLevelBuilder::record_build`] (moving by `motion`, as
    /// [`TopLevelBuilder::build_moving`]; [`InstanceMotion::STATIC`] for none) of a top level
    /// that keeps its bottom levels alive (shared with the caller,
    /// [`TopLevel::bottoms`]): a top level that can be stored beside them, as a renderer
    /// keeps its scene from frame to frame.
    pub fn record_build_shared(
        &self,
        rec: &mut Recorder,
        bottoms: &[Arc<GpuGeometry>],
        instances: &[Instance],
        motion: InstanceMotion,
        flags: &BuildFlags,
    ) -> Result<TopLevel> {
        let listed = copy_list(bottoms.iter().map(|b| &**b))?;
        let mut top = self.record_build_listed(rec, listed, instances, motion, flags)?;
        top.kept = bottoms.to_vec();
        Ok(top)
    }

    fn record_build_listed(
        &self,
        rec: &mut Recorder,
        listed: Listed,
        instances: &[Instance],
        motion: InstanceMotion,
        flags: &BuildFlags,
    ) -> Result<TopLevel> {
        let call = "TopLevelBuilder::build";
        let count = check_instances(call, instances, motion, &listed.references)?;
        let ctx = rec.context().clone();
        let n_bottoms = listed.references.len();
        let sizes = self.sizes_for_motion(&ctx, count, n_bottoms, motion, flags)?;
        let memory = Buffer::<u8>::arena(&ctx, "accel.top_level", sizes.structure_bytes as usize)?;
        let scratch_bytes = sizes
            .build_scratch_bytes
            .max(sizes.update_scratch_bytes.unwrap_or(0));
        let scratch = Buffer::<u8>::arena(&ctx, "accel.top_scratch", scratch_bytes as usize)?;
        let records = Buffer::<Instance>::new(&ctx, "accel.instances", instances.len().max(1))?;
        let mut top =
            self.create_in_listed(&ctx, listed, count, motion, flags, memory.own_range())?;
        rec.upload(&records, instances)?;
        rec.transfer_to_compute();
        self.record_build_from(
            rec,
            &mut top,
            records.own_range(),
            count,
            scratch.own_range(),
        )?;
        top.own = Some(Own {
            _memory: memory,
            scratch,
            records,
        });
        top.bytes = sizes.structure_bytes;
        Ok(top)
    }

    /// The update of a top level [`TopLevelBuilder::build`] made (with `allow_update`) to
    /// `instances` (as many as its last build read, each checked), waited for.
    pub fn update(&self, ctx: &Context, top: &mut TopLevel, instances: &[Instance]) -> Result<()> {
        let mut rec = Recorder::new(ctx)?;
        self.record_update(&mut rec, top, instances)?;
        rec.submit_and_wait()?;
        Ok(())
    }

    /// [`TopLevelBuilder::update`] recorded into `rec` (in a scope `top level update`), not
    /// submitted: the upload of `instances` and the refit, in the memory and scratch the
    /// build allocated. Ends with a compute → compute barrier.
    pub fn record_update(
        &self,
        rec: &mut Recorder,
        top: &mut TopLevel,
        instances: &[Instance],
    ) -> Result<()> {
        let call = "TopLevelBuilder::update";
        let want = top.motion.records(top.count);
        if instances.len() as u64 != want {
            let held = match top.motion.steps {
                1 => format!("{} instances", top.count),
                s => format!("{} instances at {s} time steps, {want} records", top.count),
            };
            return Err(usage(
                call,
                format!(
                    "{} instance records; the top level holds {held} (its last build's \
                     count, which an update keeps): build it again",
                    instances.len()
                ),
            ));
        }
        let (records, scratch) = self.host_records(rec, call, top, instances)?;
        self.record_update_from(rec, top, records, scratch)
    }

    /// A new build of a top level [`TopLevelBuilder::build`] made, over `instances` (each
    /// checked; as many as its first build's, or fewer), recorded into `rec` in the memory
    /// and scratch the first build allocated: the rebuild twin of
    /// [`TopLevelBuilder::record_update`].
    pub fn record_rebuild(
        &self,
        rec: &mut Recorder,
        top: &mut TopLevel,
        instances: &[Instance],
    ) -> Result<()> {
        let call = "TopLevelBuilder::record_rebuild";
        let steps = u64::from(top.motion.steps);
        let fits = instances.len() as u64 % steps == 0
            && instances.len() as u64 / steps <= u64::from(top.max);
        if !fits {
            return Err(usage(
                call,
                format!(
                    "{} instance records; the top level holds at most {} instances at {steps} \
                     time steps: build a new one",
                    instances.len(),
                    top.max
                ),
            ));
        }
        let (records, scratch) = self.host_records(rec, call, top, instances)?;
        let count = (instances.len() as u64 / steps) as u32;
        self.record_build_from(rec, top, records, count, scratch)
    }

    /// `instances`, checked against `top`, uploaded by `rec` where `top`'s own build keeps
    /// them; and the scratch that build allocated.
    fn host_records(
        &self,
        rec: &mut Recorder,
        call: &'static str,
        top: &TopLevel,
        instances: &[Instance],
    ) -> Result<(RawBuffer, RawBuffer)> {
        check_instances(call, instances, top.motion, &top.listed.references)?;
        let Some(Own {
            scratch, records, ..
        }) = &top.own
        else {
            return Err(usage(
                call,
                "this top level lies in the caller's memory: record_update_from or \
                 record_build_from",
            ));
        };
        // (the last build or update read the records)
        rec.compute_to_transfer();
        rec.upload_at(records, 0, instances)?;
        rec.transfer_to_compute();
        Ok((records.own_range(), scratch.own_range()))
    }
}

/// The number of instances in `instances` moving by `motion`, after checking each (and,
/// when it moves, that its steps agree); an error names the first that fails.
fn check_instances(
    call: &'static str,
    instances: &[Instance],
    motion: InstanceMotion,
    references: &[u64],
) -> Result<u32> {
    motion.why_not().map_err(|why| usage(call, why))?;
    let steps = motion.steps as usize;
    if instances.len() % steps != 0 {
        return Err(usage(
            call,
            format!(
                "{} instance records are not {steps} time steps of the same instances",
                instances.len()
            ),
        ));
    }
    let count = instances.len() / steps;
    let count = u32::try_from(count).map_err(|_| usage(call, "more than 2^32 instances"))?;
    for (k, inst) in instances.iter().enumerate() {
        let (i, s) = (k % count as usize, k / count as usize);
        let at = if steps > 1 {
            format!("instance {i} at step {s}")
        } else {
            format!("instance {i}")
        };
        inst.why_invalid(references)
            .map_err(|why| usage(call, format!("{at}: {why}")))?;
        let first = &instances[i];
        if s > 0 {
            if (
                inst.bottom,
                inst.custom_index_and_mask,
                inst.sbt_offset_and_flags,
            ) != (
                first.bottom,
                first.custom_index_and_mask,
                first.sbt_offset_and_flags,
            ) {
                return Err(usage(
                    call,
                    format!(
                        "{at}: its bottom level, custom index, mask or flags differ from step \
                         0's (only the transform moves)"
                    ),
                ));
            }
            if (determinant(&inst.transform) > 0.0) != (determinant(&first.transform) > 0.0) {
                return Err(usage(
                    call,
                    format!(
                        "{at}: its transform mirrors where step 0's does not (or the other \
                         way): between them it passes through a singular transform"
                    ),
                ));
            }
        }
    }
    Ok(count)
}

fn determinant(m: &[[f32; 4]; 3]) -> f32 {
    let [a, b, c] = m;
    a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
        + a[2] * (b[0] * c[1] - b[1] * c[0])
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct BoxesPush {
    n: u32,
    slots: u32,
    first_word: u32,
    n_bottoms: u32,
    steps: u32,
    pad: u32,
    handles_at: u64,
    t0: f32,
    scale: f32,
}

impl TopLevel {
    /// The BVH over the instances' world boxes (box primitive `i` is instance `i`).
    pub fn tree(&self) -> &GpuGeometry {
        &self.tree
    }

    /// The tree's geometry: a box per slot.
    fn geometry(&self) -> Geometry {
        boxes_geometry(GeometryData::Buffer(self.parts.boxes.own_range()), self.max)
    }

    /// Instances its last build read (the maximum before one); its updates read as many.
    pub fn instance_count(&self) -> u32 {
        self.count
    }

    /// The most instances a build may read: what it was created for (Vulkan's
    /// `maxPrimitiveCount`).
    pub fn max_instances(&self) -> u32 {
        self.max
    }

    /// The references of its list of bottom levels, in order (what instances naming a level
    /// by index name; empty where they name theirs by reference only).
    pub fn listed_references(&self) -> &[u64] {
        &self.listed.references
    }

    /// Where it keeps the copies of its list's handles, 64 bytes apart (in the records of
    /// instances that name a level of the list: [`InstanceRecord::handle`]).
    pub fn bottom_handles_address(&self) -> u64 {
        self.parts.handles.address()
    }

    /// The bottom levels it keeps alive, in its list's order
    /// ([`TopLevelBuilder::record_build_shared`]; none otherwise: the caller keeps them).
    pub fn bottoms(&self) -> impl ExactSizeIterator<Item = &GpuGeometry> {
        self.kept.iter().map(|b| &**b)
    }

    /// Where the top level's handle lies: what a shader passes to `vkrtUseStructure`
    /// (`VKRT_DEVICE_ADDRESS` in `vkrt/ray_query.glsl`), written by the build.
    pub fn handle_address(&self) -> u64 {
        self.parts.handle.address()
    }

    /// Records what makes this top level a built copy of `from`, once the caller has
    /// recorded a byte copy of `from`'s placed range into this one's (`copy`: the caller's
    /// word for it), as [`GpuGeometry::record_built_by_copy`] does for a bottom level: its
    /// own handle (at [`TopLevel::handle_address`]) written anew, and `from`'s build state
    /// taken, so that it traces and can be updated as `from` could. Both were created for the
    /// same maximum of instances with the same flags; `Err` otherwise, or where `from` has no
    /// recorded build. Ends with transfer writes.
    pub fn record_built_by_copy(
        &mut self,
        rec: &mut Recorder,
        from: &TopLevel,
        copy: crate::gpu::CopiedStructure,
    ) -> Result<()> {
        if self.max != from.max || self.bytes != from.bytes {
            return Err(usage(
                "TopLevel::record_built_by_copy",
                "the source was created for another maximum of instances",
            ));
        }
        self.tree.record_built_by_copy(rec, &from.tree, copy)?;
        let words = self.handle_words()?;
        let handle: [[u64; 8]; 2] = bytemuck::cast(words);
        rec.update(&self.parts.handle, 0, &handle)?;
        self.count = from.count;
        Ok(())
    }

    /// The sixteen words a build writes at [`TopLevel::handle_address`]: the tree's seven
    /// arrays, then the addresses of its records, steps and originals. They depend on where
    /// the top level lies only, so a copy of them elsewhere (where a caller's shaders look
    /// for a structure whose place in memory must not move) is walked as the top level.
    pub fn handle_words(&self) -> Result<[u64; 16]> {
        let p = &self.parts;
        let mut words = [0u64; 16];
        words[..7].copy_from_slice(&self.tree.handle_words()?);
        words[7] = p.records.address();
        words[8] = p.steps.address();
        words[9] = p.originals.address();
        Ok(words)
    }

    /// Records the copy of the build's report: invalid instances (never hit) in
    /// [`BuildStatus::invalid_primitives`]. Order the build before with
    /// [`Recorder::compute_to_transfer`].
    pub fn record_read_status(&self, rec: &mut Recorder) -> Result<InstanceStatus> {
        Ok(InstanceStatus(rec.read_back(&self.parts.status)?))
    }

    /// Records the copy of the build's report (one word: the invalid instances, never hit)
    /// into the start of `dst`, a range of the caller's buffer, for the renderer's own
    /// read-back (as `vkCmdCopyQueryPoolResults` writes a query's result). Synchronized as
    /// [`Recorder::copy_into`].
    pub fn record_copy_status_into(
        &self,
        rec: &mut Recorder,
        dst: &dyn crate::gpu::BufferArg,
    ) -> Result<()> {
        rec.copy_into(&self.parts.status, dst);
        rec.check()
    }

    /// A moving top level's object-to-world rows, `steps` per instance, instance after
    /// instance, as its last build or update wrote them (one unused entry when it does not
    /// move): what a renderer's shading reads to place a hit as the walk placed the ray.
    pub fn steps(&self) -> &Buffer<[[f32; 4]; 3]> {
        &self.parts.steps
    }

    /// How its instances move.
    pub fn motion(&self) -> InstanceMotion {
        self.motion
    }

    /// Moves a moving top level's time interval to `time` (as `rtcSetGeometryTimeRange`), for
    /// its next build or update (the steps' count stays): an animation's next frame opens
    /// its shutter later.
    pub fn set_time(&mut self, time: [f32; 2]) -> Result<()> {
        let motion = InstanceMotion {
            time,
            ..self.motion
        };
        if self.motion.steps < 2 {
            return Err(usage(
                "TopLevel::set_time",
                "this top level does not move (built with one time step)",
            ));
        }
        motion
            .why_not()
            .map_err(|why| usage("TopLevel::set_time", why))?;
        self.motion = motion;
        Ok(())
    }

    /// A moving top level's steps as its build wrote them, `steps` per instance (empty when
    /// it does not move).
    pub fn download_steps(&self) -> Result<Vec<[[f32; 4]; 3]>> {
        if self.motion.steps < 2 {
            return Ok(Vec::new());
        }
        let mut steps = self.parts.steps.download()?;
        steps.truncate(self.motion.records(self.count) as usize);
        Ok(steps)
    }

    /// The world boxes and records the build wrote (tests and tools).
    pub fn download(&self) -> Result<(Vec<[f32; 6]>, Vec<InstanceRecord>)> {
        let n = self.count as usize;
        let mut boxes = self.parts.boxes.download()?;
        let mut records = self.parts.records.download()?;
        boxes.truncate(n);
        records.truncate(n);
        Ok((boxes, records))
    }

    /// Bytes of the top level: its instances' arrays and its tree (as
    /// [`TopLevelBuilder::sizes_for`] reports them).
    pub fn bytes(&self) -> u64 {
        self.bytes
    }
}

/// The copy of a top level's report, read after the work has executed.
#[must_use = "read() it once the work has executed"]
pub struct InstanceStatus(Readback<u32>);

impl InstanceStatus {
    /// The build's status: the instances counted invalid (never hit) in
    /// `invalid_primitives`.
    pub fn read(self) -> Result<BuildStatus> {
        let words = self.0.read()?;
        Ok(BuildStatus {
            invalid_primitives: words.first().copied().unwrap_or(0),
            kd_overflow: false,
        })
    }
}
