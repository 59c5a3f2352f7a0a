//! A scene as the two levels `vkrt shader-check` traces, the same on both paths: each
//! `[[meshes]]` entry is one instance (its id: the entry's place among them) of a bottom level
//! holding its triangles as geometry 0 (entries with the same geometry and opaque flag share
//! one); all spheres are one more instance, the last, with the identity transform, of a
//! bottom level holding one box geometry (primitive `i`: sphere `i`'s box, centre ± radius).

use std::sync::Arc;

use glam::Vec3;

use crate::accel::device::{AccelBuilder, AccelChoice, AccelKind};
use crate::accel::device_primitives::DevicePrimitives;
use crate::accel::driver::{DriverAccel, Prefer};
use crate::accel::embedded::BuildFlags;
use crate::accel::geometry::{Aabbs, Geometry, IndexType, Triangles};
use crate::accel::gpu_geometry::GpuGeometry;
use crate::accel::instance::{flags, Instance};
use crate::accel::instances::{TopLevel, TopLevelBuilder};
use crate::accel::primitives::TraceGeometry;
use crate::gpu::{Buffer, GpuError, Recorder, Result};
use crate::scene::{Aabb, Scene};

/// What one bottom level holds.
pub enum BottomSource {
    /// Mesh `mesh`'s object-space triangles, with the geometry's opaque flag.
    Mesh {
        /// The first entry naming this geometry.
        mesh: usize,
        /// The geometry's opaque flag.
        opaque: bool,
    },
    /// The spheres' boxes.
    Spheres,
}

/// The scene's two levels, described (nothing built yet).
pub struct SceneLevels {
    /// The bottom levels, by index.
    pub bottoms: Vec<BottomSource>,
    /// The instances: one per mesh entry, then the spheres' (where there are spheres).
    pub instances: Vec<Instance>,
    /// Per sphere its box (min x, y, z, max x, y, z).
    pub sphere_boxes: Vec<[f32; 6]>,
    /// Per sphere its centre and radius.
    spheres: Vec<[f32; 4]>,
    /// Object-space triangles and indices per mesh, shared with the scene.
    meshes: Vec<MeshArrays>,
}

/// A mesh's positions and triangles, shared with the scene.
type MeshArrays = (Arc<Vec<Vec3>>, Arc<Vec<[u32; 3]>>);

impl SceneLevels {
    /// The levels of `scene` at time `time` (meshes placed, spheres moved there).
    pub fn of(scene: &Scene, time: f32) -> Self {
        let groups = scene.mesh_groups();
        let mut group_of = vec![0; scene.meshes.len()];
        for (g, members) in groups.iter().enumerate() {
            for &m in members {
                group_of[m] = g;
            }
        }
        let mut bottoms = Vec::new();
        // (group, opaque) -> bottom level
        let mut level_of: Vec<((usize, bool), u32)> = Vec::new();
        let mut instances = Vec::with_capacity(scene.meshes.len() + 1);
        for (i, m) in scene.meshes.iter().enumerate() {
            let keys = m.instance;
            let key = (group_of[i], keys.opaque);
            let level = match level_of.iter().find(|(k, _)| *k == key) {
                Some(&(_, l)) => l,
                None => {
                    let l = bottoms.len() as u32;
                    bottoms.push(BottomSource::Mesh {
                        mesh: i,
                        opaque: keys.opaque,
                    });
                    level_of.push((key, l));
                    l
                }
            };
            let rows = Instance::rows_of(&m.world_matrix(time));
            let mut inst = Instance::new(level, rows)
                .with_custom_index(keys.custom_index.unwrap_or(i as u32))
                .with_mask(keys.mask)
                .with_flags(keys.flags);
            inst.sbt_offset_and_flags |= keys.sbt_offset;
            instances.push(inst);
        }
        let placed = scene.spheres_at(time);
        let sphere_boxes: Vec<[f32; 6]> = placed
            .iter()
            .map(|s| {
                let (lo, hi) = (s.center - s.radius, s.center + s.radius);
                [lo.x, lo.y, lo.z, hi.x, hi.y, hi.z]
            })
            .collect();
        let spheres = placed
            .iter()
            .map(|s| s.center.extend(s.radius).to_array())
            .collect();
        if !sphere_boxes.is_empty() {
            let level = bottoms.len() as u32;
            bottoms.push(BottomSource::Spheres);
            let id = instances.len() as u32;
            instances.push(Instance::new(level, Instance::IDENTITY).with_custom_index(id));
        }
        let meshes = scene
            .meshes
            .iter()
            .map(|m| (m.positions.clone(), m.indices.clone()))
            .collect();
        Self {
            bottoms,
            instances,
            sphere_boxes,
            spheres,
            meshes,
        }
    }

    /// One opaque mesh of `tris` as the only instance (id and custom index 0, the identity
    /// transform): what a scene of one `[[meshes]]` entry holding them gives.
    pub fn of_triangles(tris: &[[Vec3; 3]]) -> Self {
        let positions: Vec<Vec3> = tris.iter().flatten().copied().collect();
        let indices: Vec<[u32; 3]> = (0..tris.len() as u32)
            .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect();
        Self {
            bottoms: vec![BottomSource::Mesh {
                mesh: 0,
                opaque: true,
            }],
            instances: vec![Instance::new(0, Instance::IDENTITY).with_custom_index(0)],
            sphere_boxes: Vec::new(),
            spheres: Vec::new(),
            meshes: vec![(Arc::new(positions), Arc::new(indices))],
        }
    }

    /// Bottom level `b`'s primitives as host arrays (object-space triangles, or boxes).
    fn host_geometry(&self, b: &BottomSource) -> TraceGeometry {
        match *b {
            BottomSource::Mesh { mesh, .. } => {
                let (p, idx) = &self.meshes[mesh];
                let tris: Vec<[Vec3; 3]> = idx.iter().map(|t| t.map(|v| p[v as usize])).collect();
                TraceGeometry::from_triangles(&tris)
            }
            BottomSource::Spheres => {
                let boxes: Vec<Aabb> = self
                    .sphere_boxes
                    .iter()
                    .map(|b| Aabb {
                        min: Vec3::new(b[0], b[1], b[2]),
                        max: Vec3::new(b[3], b[4], b[5]),
                    })
                    .collect();
                TraceGeometry::from_primitives(&[], &[], &boxes)
            }
        }
    }

    /// Why vkrt's bottom levels cannot be `kind` trees for these levels: the SAH BVH, built
    /// from host arrays that carry no opaque flag, only where every geometry is opaque; the
    /// kd-tree (which may hold a primitive in several leaves) only over opaque triangles.
    pub fn check_kind(&self, kind: AccelKind) -> std::result::Result<(), String> {
        match kind {
            AccelKind::Lbvh | AccelKind::Ploc => Ok(()),
            AccelKind::KdTree
                if self
                    .bottoms
                    .iter()
                    .any(|b| !matches!(b, BottomSource::Mesh { opaque: true, .. })) =>
            {
                Err(
                    "the kd-tree may hold a primitive in several leaves, so the ray queries \
                     walk it over opaque triangles only: choose a BVH (LBVH, PLOC, SAH BVH) \
                     for a scene with spheres or `opaque = false`"
                        .into(),
                )
            }
            AccelKind::KdTree => Ok(()),
            AccelKind::SahBvh
                if self
                    .bottoms
                    .iter()
                    .any(|b| matches!(b, BottomSource::Mesh { opaque: false, .. })) =>
            {
                Err(
                    "the SAH BVH is built from host arrays, which carry no opaque flag: \
                     choose the LBVH or PLOC for a scene with `opaque = false`"
                        .into(),
                )
            }
            AccelKind::SahBvh => Ok(()),
            other => Err(format!(
                "{} bottom levels: the ray queries walk vkrt's structures (kd-tree, LBVH, \
                 PLOC, SAH BVH)",
                other.name()
            )),
        }
    }

    /// vkrt's two levels, recorded into `rec`: bottom levels of `choice`'s kind (LBVH or
    /// PLOC from the geometry on the device, with its opaque flag; the SAH BVH from host
    /// arrays, which carry none, so only where every geometry is opaque), with 4-wide nodes
    /// where its walk is the wide one, and an LBVH top level over the instance records. Keep
    /// the result until the work has executed.
    pub fn record_vkrt(&self, rec: &mut Recorder, choice: AccelChoice) -> Result<VkrtLevels> {
        let ctx = rec.context().clone();
        let kind = choice.kind;
        let builder = AccelBuilder::for_choice(&ctx, choice)?;
        let mut bottoms = Vec::with_capacity(self.bottoms.len());
        let mut keep: Vec<Buffer<u8>> = Vec::new();
        let mut inputs: Vec<Buffer<[f32; 3]>> = Vec::new();
        let mut indices: Vec<Buffer<[u32; 3]>> = Vec::new();
        let mut boxes: Vec<Buffer<[f32; 6]>> = Vec::new();
        let flags = BuildFlags::for_choice(choice);
        if let Err(reason) = self.check_kind(kind) {
            return Err(GpuError::Usage {
                call: "shader-check",
                reason,
            });
        }
        for b in &self.bottoms {
            if kind == AccelKind::KdTree {
                // Built in a submission of its own, redone while its reference budget runs
                // out: a recorded kd-tree build cannot grow its budget.
                let (g, _) = GpuGeometry::build_fitting(&ctx, &builder, &self.host_geometry(b))?;
                bottoms.push(g);
                continue;
            }
            if kind == AccelKind::SahBvh {
                let (g, _) = GpuGeometry::record_build(rec, &builder, &self.host_geometry(b), 0)?;
                bottoms.push(g);
                continue;
            }
            let geometry = match *b {
                BottomSource::Mesh { mesh, opaque } => {
                    let (p, idx) = &self.meshes[mesh];
                    let verts: Vec<[f32; 3]> = p.iter().map(|v| v.to_array()).collect();
                    let vb = Buffer::new(&ctx, "shader_check.vertices", verts.len())?;
                    let ib = Buffer::new(&ctx, "shader_check.indices", idx.len())?;
                    rec.upload(&vb, &verts)?;
                    rec.upload(&ib, idx.as_slice())?;
                    let mut t = Triangles::indexed(
                        vb.own_range(),
                        verts.len() as u32,
                        ib.own_range(),
                        IndexType::U32,
                        idx.len() as u32,
                    );
                    t.opaque = opaque;
                    inputs.push(vb);
                    indices.push(ib);
                    Geometry::Triangles(t)
                }
                BottomSource::Spheres => {
                    let bb = Buffer::new(&ctx, "shader_check.boxes", self.sphere_boxes.len())?;
                    rec.upload(&bb, &self.sphere_boxes)?;
                    let g = Geometry::Aabbs(Aabbs {
                        data: bb.own_range().into(),
                        stride: 24,
                        count: self.sphere_boxes.len() as u32,
                        opaque: true,
                    });
                    boxes.push(bb);
                    g
                }
            };
            let geometries = [geometry];
            let sizes = builder.sizes_for(&ctx, &geometries, &flags)?;
            let memory =
                Buffer::<u8>::arena(&ctx, "shader_check.bottom", sizes.structure_bytes as usize)?;
            let scratch = Buffer::<u8>::arena(
                &ctx,
                "shader_check.scratch",
                sizes.build_scratch_bytes as usize,
            )?;
            let mut g = builder.create_in(&ctx, &geometries, &flags, memory.own_range())?;
            rec.transfer_to_compute();
            builder.record_build_from(rec, &mut g, &geometries, scratch.own_range())?;
            bottoms.push(g);
            keep.push(memory);
            keep.push(scratch);
        }
        let bottoms: Vec<Arc<GpuGeometry>> = bottoms.into_iter().map(Arc::new).collect();
        let top = TopLevelBuilder::new(&ctx, AccelKind::Lbvh)?.record_build_shared(
            rec,
            &bottoms,
            &self.instances,
            crate::accel::instance::InstanceMotion::STATIC,
            &flags,
        )?;
        rec.compute_to_compute();
        Ok(VkrtLevels {
            top,
            _buffers: InputBuffers {
                _levels: keep,
                _vertices: inputs,
                _indices: indices,
                _boxes: boxes,
            },
        })
    }

    /// The driver's two levels, recorded into `rec`: a bottom-level structure per bottom
    /// level (triangles, or boxes) and a top-level instance per instance, with the same
    /// records. The driver's triangle geometry is opaque: a mesh whose `opaque` is false and
    /// whose instance forces neither way gets the force-no-opaque instance flag instead,
    /// which the specification gives the same effect. Keep the result until the work has
    /// executed.
    pub fn record_driver(&self, rec: &mut Recorder) -> Result<DriverLevels> {
        let mut prims = Vec::with_capacity(self.bottoms.len());
        for b in &self.bottoms {
            prims.push(DevicePrimitives::record_upload(
                rec,
                &self.host_geometry(b),
            )?);
        }
        rec.transfer_to_compute();
        let either = flags::FORCE_OPAQUE | flags::FORCE_NO_OPAQUE;
        let instances: Vec<Instance> = self
            .instances
            .iter()
            .map(|inst| {
                let non_opaque = matches!(
                    self.bottoms.get(inst.bottom as usize),
                    Some(BottomSource::Mesh { opaque: false, .. })
                );
                match non_opaque && inst.flags() & either == 0 {
                    true => inst.with_flags(inst.flags() | flags::FORCE_NO_OPAQUE),
                    false => *inst,
                }
            })
            .collect();
        let levels: Vec<&DevicePrimitives> = prims.iter().collect();
        // The spheres' level, where there is one, is the level whose boxes the driver's
        // structure places in the world by one identity instance.
        let bound = self
            .bottoms
            .iter()
            .position(|b| matches!(b, BottomSource::Spheres))
            .unwrap_or(self.bottoms.len());
        let (accel, _) =
            DriverAccel::record_instanced(rec, &levels, &instances, bound, Prefer::FastTrace)?;
        Ok(DriverLevels {
            accel,
            _prims: prims,
        })
    }
}

/// The scene's instance data as a shader reads it at device addresses: one 32-byte record
/// per instance, in instance order (`InstanceData` in the command's interface).
pub struct InstanceData {
    /// The records.
    pub records: Buffer<InstanceRecord>,
    _positions: Vec<Buffer<[f32; 3]>>,
    _triangles: Vec<Buffer<[u32; 3]>>,
    _spheres: Option<Buffer<[f32; 4]>>,
}

/// One instance's record: a mesh's object-space positions (three floats a vertex) and
/// triangles (three u32 indices a triangle) at device addresses, with their counts; the
/// spheres' instance: the spheres (centre, radius: four floats each) and their count, no
/// triangles.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct InstanceRecord {
    /// The positions' (or spheres') device address.
    pub positions: u64,
    /// The triangles' device address (0 for the spheres).
    pub triangles: u64,
    /// Triangles (0 for the spheres).
    pub triangle_count: u32,
    /// Vertices (spheres for the spheres' instance).
    pub vertex_count: u32,
    /// Zero.
    pub reserved: [u32; 2],
}

impl SceneLevels {
    /// The instance records and the arrays they point at, uploaded in `rec` (a buffer per
    /// bottom level, shared by its instances). Keep the result until the work has
    /// executed; the uploads need a transfer-to-compute barrier before a shader reads them.
    pub fn record_instance_data(&self, rec: &mut Recorder) -> Result<InstanceData> {
        let ctx = rec.context().clone();
        let mut positions = Vec::new();
        let mut triangles = Vec::new();
        let mut spheres = None;
        let mut per_bottom = Vec::with_capacity(self.bottoms.len());
        for b in &self.bottoms {
            let record = match *b {
                BottomSource::Mesh { mesh, .. } => {
                    let (p, idx) = &self.meshes[mesh];
                    let verts: Vec<[f32; 3]> = p.iter().map(|v| v.to_array()).collect();
                    // A buffer of at least one element, so that an empty mesh has an address.
                    let vb =
                        Buffer::new(&ctx, "shader_check.instance_positions", verts.len().max(1))?;
                    let ib =
                        Buffer::new(&ctx, "shader_check.instance_triangles", idx.len().max(1))?;
                    rec.upload(&vb, &verts)?;
                    rec.upload(&ib, idx.as_slice())?;
                    let record = InstanceRecord {
                        positions: vb.device_address()?,
                        triangles: ib.device_address()?,
                        triangle_count: idx.len() as u32,
                        vertex_count: verts.len() as u32,
                        reserved: [0; 2],
                    };
                    positions.push(vb);
                    triangles.push(ib);
                    record
                }
                BottomSource::Spheres => {
                    let sb = Buffer::new(
                        &ctx,
                        "shader_check.instance_spheres",
                        self.spheres.len().max(1),
                    )?;
                    rec.upload(&sb, &self.spheres)?;
                    let record = InstanceRecord {
                        positions: sb.device_address()?,
                        vertex_count: self.spheres.len() as u32,
                        ..InstanceRecord::default()
                    };
                    spheres = Some(sb);
                    record
                }
            };
            per_bottom.push(record);
        }
        let records: Vec<InstanceRecord> = self
            .instances
            .iter()
            .map(|inst| per_bottom[inst.bottom as usize])
            .collect();
        let buffer = Buffer::new(&ctx, "shader_check.instance_data", records.len().max(1))?;
        rec.upload(&buffer, &records)?;
        Ok(InstanceData {
            records: buffer,
            _positions: positions,
            _triangles: triangles,
            _spheres: spheres,
        })
    }
}

/// vkrt's levels and the buffers they were built from.
pub struct VkrtLevels {
    /// The top level (it keeps its bottom levels).
    pub top: TopLevel,
    _buffers: InputBuffers,
}

/// What vkrt's levels were built in and from, alive until the work has executed.
struct InputBuffers {
    _levels: Vec<Buffer<u8>>,
    _vertices: Vec<Buffer<[f32; 3]>>,
    _indices: Vec<Buffer<[u32; 3]>>,
    _boxes: Vec<Buffer<[f32; 6]>>,
}

/// The driver's levels and the primitives they were built from.
pub struct DriverLevels {
    /// The driver's structures.
    pub accel: DriverAccel,
    _prims: Vec<DevicePrimitives>,
}
