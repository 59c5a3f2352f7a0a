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
//! A scene as two levels ([`DriverAccel::record_instanced`]) maps to the driver's own: a
//! bottom-level structure per level (and kind of geometry), a top-level instance per vkrt
//! instance (and geometry of its level) with its transform, custom index, mask and flags.
//!
//! Nothing here submits or uploads: the instance records are written by the recorded build
//! (`vkCmdUpdateBuffer`), so the levels can live in a caller's memory.

pub(crate) mod storage;

use crate::gpu::{
    accel_build_sizes, accel_scratch, require_ray_query, vk, AccelGeometry, AccelInstance,
    AccelerationStructure, Buffer, Context, GpuError, Recorder, Result,
};

use crate::accel::device_primitives::DevicePrimitives;
use crate::accel::instance::Instance;
use crate::accel::sizes::AccelSizes;

/// Primitive ids of the driver's two levels ([`DriverAccel::record_instanced`]).
#[derive(Clone, Debug, Default)]
pub struct InstancedIds {
    /// Per top-level instance: the id of its first primitive (what the kernels read).
    pub bases: Vec<u32>,
    /// Per vkrt instance, by first id: (first id, primitives, instance index, 0).
    starts: Vec<[u32; 4]>,
}

impl InstancedIds {
    /// The instance and its level's primitive of the kernels' primitive id `id`.
    pub fn instance_primitive(&self, id: u32) -> Option<(u32, u32)> {
        instance_primitive_in(&self.starts, id)
    }

    /// Per vkrt instance, by first id: (first id, primitives, instance index, 0), the table
    /// `render.driver_hits` searches as [`instance_primitive_in`] does.
    pub fn starts(&self) -> &[[u32; 4]] {
        &self.starts
    }
}

/// The instance and its level's primitive of the kernels' primitive id `id`, in `starts`
/// (per instance, by first id: first id, primitives, instance index, 0; see
/// [`InstancedIds::starts`]): the CPU twin of `render.driver_hits`.
pub fn instance_primitive_in(starts: &[[u32; 4]], id: u32) -> Option<(u32, u32)> {
    let k = starts.partition_point(|s| s[0] <= id).checked_sub(1)?;
    let [start, count, instance, _] = starts[k];
    (id - start < count).then_some((instance, id - start))
}

// The driver's build preference is part of the structure's kind and choice
// ([`crate::accel::walk::AccelChoice`]); it lives there.
pub use crate::accel::walk::Prefer;

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
    /// The top level's instances (one identity instance per bottom level for a flat scene).
    records: Vec<AccelInstance>,
    /// Two levels ([`DriverAccel::record_instanced`]): per record, the instance it places
    /// (empty for a flat scene).
    placing: Vec<u32>,
    /// Two levels: the instances the top level was built over (0 for a flat scene).
    placed_instances: usize,
    tlas: AccelerationStructure,
    /// The instance records (with room to start them at a 16-byte aligned address), written
    /// by the recorded build from constants: nothing is uploaded.
    instances: Buffer<u32>,
    flags: vk::BuildAccelerationStructureFlagsKHR,
    /// Scratch of every build and update, reused after the barrier between them; `None`
    /// where the caller hands in its own with each recording.
    scratch: Option<Buffer<u8>>,
}

/// Primitive counts and where their device copies lie: what the driver's levels are built
/// over.
#[derive(Clone, Copy, Debug)]
pub struct DriverInput {
    /// Triangles: the driver's triangle geometry (when static).
    pub n_tris: usize,
    /// Spheres and box primitives: boxes the kernels intersect.
    pub n_boxes: usize,
    /// Whether any primitive moves: then every primitive is one box geometry over its
    /// swept box.
    pub has_motion: bool,
    /// Device addresses of the triangle vertices and the primitive boxes (0 to size only).
    pub tri_verts: u64,
    /// Device address of the primitive boxes (24 bytes each; 0 to size only).
    pub boxes: u64,
}

impl DriverInput {
    /// The primitives of `prims`, at their addresses.
    pub fn of(prims: &DevicePrimitives) -> Self {
        Self {
            tri_verts: prims.tri_verts.address(),
            boxes: prims.boxes.address(),
            ..Self::counts(prims)
        }
    }

    /// The primitives of `prims` without addresses: for sizes, and for buffers that are
    /// placeholders while sizes are measured.
    pub fn counts(prims: &DevicePrimitives) -> Self {
        Self {
            n_tris: prims.n_tris,
            n_boxes: prims.n_spheres + prims.n_aabbs,
            has_motion: prims.has_motion,
            tri_verts: 0,
            boxes: 0,
        }
    }
}

impl DriverAccel {
    /// The bottom levels for `input` (see the module's notes), each with the id of its first
    /// primitive (instance `i` of the top level is bottom level `i`): none for a scene
    /// without primitives.
    pub fn geometries(input: &DriverInput) -> Result<Vec<(AccelGeometry, u32)>> {
        let count = |n: usize| {
            u32::try_from(n).map_err(|_| GpuError::Kernel {
                kernel: "accel.driver",
                reason: format!("{n} primitives do not fit a u32 count"),
            })
        };
        if input.has_motion {
            let all = AccelGeometry::Aabbs {
                boxes: input.boxes,
                stride: BOX_BYTES,
                count: count(input.n_tris + input.n_boxes)?,
            };
            return Ok(vec![(all, 0)]);
        }
        let mut g = Vec::new();
        if input.n_tris > 0 {
            // `tri_verts` is 9 floats per triangle, non-indexed (its floats of padding
            // are past the count): stride-12 vertices.
            let tris = AccelGeometry::Triangles {
                vertices: input.tri_verts,
                count: count(input.n_tris)?,
            };
            g.push((tris, 0));
        }
        if input.n_boxes > 0 {
            // Spheres and box primitives: boxes the kernel intersects.
            let boxes = AccelGeometry::Aabbs {
                boxes: input.boxes + input.n_tris as u64 * BOX_BYTES,
                stride: BOX_BYTES,
                count: count(input.n_boxes)?,
            };
            g.push((boxes, count(input.n_tris)?));
        }
        Ok(g)
    }

    /// The first primitive id of each instance, as the kernels read them (at least one
    /// word: a binding is never empty).
    pub fn instance_bases(input: &DriverInput) -> Result<Vec<u32>> {
        let mut bases: Vec<u32> = Self::geometries(input)?.iter().map(|g| g.1).collect();
        bases.resize(bases.len().max(1), 0);
        Ok(bases)
    }

    /// Bytes of the structure (every level) and of a build's and an update's scratch for
    /// `input`, as the driver reports them.
    pub fn sizes(
        ctx: &Context,
        input: &DriverInput,
        prefer: Prefer,
        allow_update: bool,
    ) -> Result<AccelSizes> {
        let flags = prefer.flags(allow_update);
        let bottoms = Self::geometries(input)?;
        let top = accel_build_sizes(ctx, &[Self::top(0, bottoms.len())], flags)?;
        let (mut structure, mut scratch, mut update) = (top.structure, top.scratch, top.scratch);
        for (g, _) in &bottoms {
            let b = accel_build_sizes(ctx, &[*g], flags)?;
            structure += b.structure;
            scratch = scratch.max(b.scratch);
            update = update.max(b.update_scratch);
        }
        Ok(AccelSizes {
            structure_bytes: structure,
            build_scratch_bytes: scratch,
            update_scratch_bytes: allow_update.then_some(update),
        })
    }

    /// The scratch buffer for every build and update of a structure over `input` (created
    /// where buffers are created now: vkrt's memory, or a caller's range being placed).
    pub fn create_scratch(
        ctx: &Context,
        input: &DriverInput,
        prefer: Prefer,
        allow_update: bool,
    ) -> Result<Buffer<u8>> {
        let s = Self::sizes(ctx, input, prefer, allow_update)?;
        accel_scratch(
            ctx,
            s.build_scratch_bytes
                .max(s.update_scratch_bytes.unwrap_or(0)),
        )
    }

    fn top(instances: u64, count: usize) -> AccelGeometry {
        AccelGeometry::Instances {
            instances,
            count: count as u32,
        }
    }

    /// The levels over `input`, unbuilt, on buffers created where buffers are created now
    /// (vkrt's memory, or the caller's range being placed). While sizes are measured
    /// ([`crate::gpu::placement::measuring`]) only their bytes are counted: `None`.
    /// `own_scratch`: keep a scratch buffer of its own (else each recording brings one).
    pub fn create(
        ctx: &Context,
        input: &DriverInput,
        prefer: Prefer,
        allow_update: bool,
        own_scratch: bool,
    ) -> Result<Option<Self>> {
        require_ray_query(ctx)?;
        let measuring = crate::gpu::placement::measuring();
        let flags = prefer.flags(allow_update);
        let mut bottoms = Vec::new();
        for (geometry, _) in Self::geometries(input)? {
            let sizes = accel_build_sizes(ctx, &[geometry], flags)?;
            let name = "accel.driver.blas";
            if measuring {
                AccelerationStructure::reserve(ctx, name, sizes.structure)?;
            } else {
                let blas = AccelerationStructure::new(ctx, name, &[geometry], sizes.structure)?;
                bottoms.push(Bottom { blas, geometry });
            }
        }
        let n = Self::geometries(input)?.len();
        // 16 words per instance, and three more to reach a 16-byte aligned start.
        let instances = Buffer::<u32>::new(ctx, "accel.driver.instances", 16 * n.max(1) + 3)?;
        let top = [Self::top(0, n)];
        let top_sizes = accel_build_sizes(ctx, &top, flags)?;
        let name = "accel.driver.tlas";
        if measuring {
            AccelerationStructure::reserve(ctx, name, top_sizes.structure)?;
            if own_scratch {
                Self::create_scratch(ctx, input, prefer, allow_update)?;
            }
            return Ok(None);
        }
        let tlas = AccelerationStructure::new(ctx, name, &top, top_sizes.structure)?;
        let scratch = match own_scratch {
            true => Some(Self::create_scratch(ctx, input, prefer, allow_update)?),
            false => None,
        };
        let records = bottoms
            .iter()
            .map(|b| AccelInstance::identity(b.blas.device_address()))
            .collect();
        Ok(Some(Self {
            bottoms,
            records,
            placing: Vec::new(),
            placed_instances: 0,
            tlas,
            instances,
            flags,
            scratch,
        }))
    }

    /// Where the instance records start: the first 16-byte aligned word of `instances`.
    fn instance_word(&self) -> usize {
        let a = self.instances.address();
        ((a.next_multiple_of(16) - a) / 4) as usize
    }

    /// Records the build over the primitives (written before, into the same recorder or an
    /// earlier submission): the instance records, the levels, then the barrier that lets
    /// kernels query it. `scratch`: the caller's, where the structure keeps none. Without the
    /// driver's ray query: [`GpuError::MissingCapability`] naming the extensions.
    pub fn record_build(&self, rec: &mut Recorder, scratch: Option<&Buffer<u8>>) -> Result<()> {
        self.record_records(rec)?;
        let scratch = self.scratch_or(scratch)?;
        rec.scope("driver_build", |rec| {
            self.record_levels(rec, false, scratch)
        })
    }

    fn scratch_or<'a>(&'a self, given: Option<&'a Buffer<u8>>) -> Result<&'a Buffer<u8>> {
        given
            .or(self.scratch.as_ref())
            .ok_or_else(|| GpuError::Usage {
                call: "DriverAccel::record_build",
                reason: "the driver's structure has no scratch of its own: pass the caller's"
                    .into(),
            })
    }

    /// Records a refit of a structure built with `allow_update` to its primitives as they
    /// are now (the same primitives, moved; the caller orders their writes before): the
    /// driver updates the bottom levels in place and the top level is rebuilt.
    pub fn record_update(&self, rec: &mut Recorder, scratch: Option<&Buffer<u8>>) -> Result<()> {
        if !self
            .flags
            .contains(vk::BuildAccelerationStructureFlagsKHR::ALLOW_UPDATE)
        {
            return Err(GpuError::Usage {
                call: "AccelBuilder::record_refit",
                reason: "the driver's structure was not built to be updated; rebuild it".into(),
            });
        }
        let scratch = self.scratch_or(scratch)?;
        rec.scope("driver_update", |rec| {
            self.record_levels(rec, true, scratch)
        })
    }

    /// Records the top level of two levels ([`DriverAccel::record_instanced`]) rebuilt over
    /// `instances` moved: as many as it was built over, in the same order, of which only the
    /// transforms are read (each keeps its level, custom index, mask and flags). The instance
    /// records are rewritten, the TLAS rebuilt over the bottom levels as they are, then the
    /// barrier to the kernels: an animation's frame over the driver's levels.
    pub fn record_move_instances(
        &mut self,
        rec: &mut Recorder,
        instances: &[Instance],
    ) -> Result<()> {
        let count = self.placed_instances;
        if count == 0 || instances.len() != count {
            return Err(GpuError::Usage {
                call: "DriverAccel::record_move_instances",
                reason: format!(
                    "{} instances for a top level of {count} (a flat structure has none): build \
                     a new one",
                    instances.len()
                ),
            });
        }
        for (r, &i) in self.records.iter_mut().zip(&self.placing) {
            let rows = &instances[i as usize].transform;
            r.transform = *rows.as_flattened().first_chunk().expect("12 floats");
        }
        self.record_records(rec)?;
        rec.to_accel_build();
        self.record_top(rec, self.scratch_or(None)?)?;
        rec.accel_build_to_compute();
        Ok(())
    }

    /// Records the writes of the instance records (from constants: nothing is uploaded).
    fn record_records(&self, rec: &mut Recorder) -> Result<()> {
        for (k, chunk) in self.records.chunks(256).enumerate() {
            rec.update(
                &self.instances,
                self.instance_word() + 16 * 256 * k,
                bytemuck::cast_slice(chunk),
            )?;
        }
        Ok(())
    }

    /// Records the top level's build over the instance records.
    fn record_top(&self, rec: &mut Recorder, scratch: &Buffer<u8>) -> Result<()> {
        let at = self.instances.address() + 4 * self.instance_word() as u64;
        let top = [Self::top(at, self.records.len())];
        rec.scope("driver_top_level", |rec| {
            self.tlas.record_build(rec, &top, self.flags, scratch)
        })
    }

    /// The bottom levels (built or updated), one after the other on the one scratch, then
    /// the top level over them, then the barrier to the kernels.
    fn record_levels(&self, rec: &mut Recorder, update: bool, scratch: &Buffer<u8>) -> Result<()> {
        rec.to_accel_build();
        rec.scope("driver_bottom_levels", |rec| {
            for (i, b) in self.bottoms.iter().enumerate() {
                if i > 0 {
                    rec.accel_build_to_accel_build();
                }
                let g = [b.geometry];
                match update {
                    true => b.blas.record_update(rec, &g, self.flags, scratch)?,
                    false => b.blas.record_build(rec, &g, self.flags, scratch)?,
                }
            }
            Ok::<_, GpuError>(())
        })?;
        rec.accel_build_to_accel_build();
        self.record_top(rec, scratch)?;
        rec.accel_build_to_compute();
        Ok(())
    }

    /// Bytes of the top level's storage.
    pub fn top_bytes(&self) -> u64 {
        self.tlas.byte_len()
    }

    /// The driver's two levels for `instances` of `levels` (each level's primitives on the
    /// device, static; an instance names its level by index), recorded into `rec` and built
    /// with a scratch of their own: a bottom-level structure per level and kind of geometry,
    /// a top-level instance per instance and geometry of its level. Returns the levels and,
    /// per top-level instance, the id of its first primitive as the `query` kernels read it:
    /// the primitives of `bound` (the level whose primitives the kernels bind, placed by one
    /// identity instance; its spheres and boxes are intersected by the kernel) keep their
    /// own ids, every other instance's follow, instance after instance ([`InstancedIds`]).
    pub fn record_instanced(
        rec: &mut Recorder,
        levels: &[&DevicePrimitives],
        instances: &[Instance],
        bound: usize,
        prefer: Prefer,
    ) -> Result<(Self, InstancedIds)> {
        let ctx = rec.context().clone();
        require_ray_query(&ctx)?;
        let usage = |reason: String| GpuError::Usage {
            call: "DriverAccel::record_instanced",
            reason,
        };
        let flags = prefer.flags(false);
        let mut bottoms = Vec::new();
        // Per level: its bottom-level structures (index, first primitive) and primitives.
        let mut per_level = Vec::with_capacity(levels.len());
        let mut scratch_bytes = 0;
        for (l, prims) in levels.iter().enumerate() {
            let input = DriverInput::of(prims);
            if input.has_motion {
                return Err(usage(format!(
                    "level {l} moves: the driver's levels are static"
                )));
            }
            let mut list = Vec::new();
            for (geometry, first) in Self::geometries(&input)? {
                let sizes = accel_build_sizes(&ctx, &[geometry], flags)?;
                scratch_bytes = scratch_bytes.max(sizes.scratch);
                let blas = AccelerationStructure::new(
                    &ctx,
                    "accel.driver.blas",
                    &[geometry],
                    sizes.structure,
                )?;
                list.push((bottoms.len(), first));
                bottoms.push(Bottom { blas, geometry });
            }
            per_level.push((
                list,
                (input.n_tris + input.n_boxes) as u32,
                input.n_boxes > 0,
            ));
        }
        let mut records = Vec::new();
        let mut placing = Vec::new();
        let mut ids = InstancedIds::default();
        let mut next = per_level.get(bound).map_or(0, |l| l.1);
        let mut bound_placed = false;
        for (i, inst) in instances.iter().enumerate() {
            let level = usize::try_from(inst.bottom)
                .ok()
                .filter(|&l| l < levels.len())
                .ok_or_else(|| usage(format!("instance {i} names a missing level")))?;
            let (list, count, boxes) = &per_level[level];
            let start = if level == bound && *boxes {
                if inst.transform != Instance::IDENTITY || bound_placed {
                    return Err(usage(format!(
                        "instance {i}: the bound level's spheres and boxes are intersected in \
                         the world, so one identity instance must place it"
                    )));
                }
                bound_placed = true;
                0
            } else if *boxes {
                return Err(usage(format!(
                    "instance {i}: level {level} holds spheres or boxes, which only the bound \
                     level may"
                )));
            } else {
                let at = next;
                next = next
                    .checked_add(*count)
                    .ok_or_else(|| usage("more than 2^32 instanced primitives".into()))?;
                at
            };
            ids.starts.push([start, *count, i as u32, 0]);
            for &(b, first) in list {
                records.push(AccelInstance {
                    transform: *inst.transform.as_flattened().first_chunk().expect("12"),
                    custom_index_and_mask: inst.custom_index_and_mask,
                    sbt_offset_and_flags: inst.sbt_offset_and_flags,
                    blas: bottoms[b].blas.device_address(),
                });
                placing.push(i as u32);
                ids.bases.push(start + first);
            }
        }
        ids.starts.sort_unstable();
        let n = records.len();
        let instances_buf = Buffer::<u32>::new(&ctx, "accel.driver.instances", 16 * n.max(1) + 3)?;
        let top = [Self::top(0, n)];
        let top_sizes = accel_build_sizes(&ctx, &top, flags)?;
        scratch_bytes = scratch_bytes.max(top_sizes.scratch);
        let tlas =
            AccelerationStructure::new(&ctx, "accel.driver.tlas", &top, top_sizes.structure)?;
        let accel = Self {
            bottoms,
            records,
            placing,
            placed_instances: instances.len(),
            tlas,
            instances: instances_buf,
            flags,
            scratch: Some(accel_scratch(&ctx, scratch_bytes)?),
        };
        accel.record_build(rec, None)?;
        ids.bases.resize(ids.bases.len().max(1), 0);
        Ok((accel, ids))
    }

    /// The top-level structure, for a descriptor of a shader that queries it.
    pub fn tlas(&self) -> &AccelerationStructure {
        &self.tlas
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
