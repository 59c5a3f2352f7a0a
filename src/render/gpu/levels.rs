//! What the renderer traces: one structure over every primitive, or a scene as two levels
//! ([`TwoLevelScene`]): the bottom levels built once, the top level (an LBVH over the
//! instances) built with the first frame and, in an animation, refit or rebuilt from the
//! moved instances every frame, so that a rigid motion changes one transform, not the
//! primitives' structure. The extend and shadow passes walk the two levels
//! (`render.instances`); shading reads the bottom levels' primitives placed by the hit's
//! instance (`render.shade.levels`, [`RenderLevels`]): no flat copy of the scene is made.

use std::sync::Arc;

use crate::accel::device::{
    AccelBuilder, AccelChoice, AccelKind, AccelStructure, DevicePrimitives,
};
use crate::accel::embedded::BuildFlags;
use crate::accel::gpu_geometry::GpuGeometry;
use crate::accel::instances::{TopLevel, TopLevelBuilder};
use crate::gpu::{Buffer, BufferArg, Readback, Recorder, Result};
use crate::render::types::{BottomShading, Placement};
use crate::render::RenderLevels;

use super::Update;

/// The structures a render traces.
#[allow(
    clippy::large_enum_variant,
    reason = "one per render, made once and kept in place"
)]
pub(crate) enum Traced {
    Flat(GpuGeometry),
    Levels(Levels),
}

impl Traced {
    /// What `shade` binds after its head (bindings 5 on): flat, the primitives (triangle
    /// vertices, spheres, per-primitive motion slot, motions) and the scene constants,
    /// `traverse.glsl`'s last five bindings; over two levels the bottom levels' shading
    /// records, the placements, the hits' instances and the moving instances' steps.
    pub fn shading_bindings(&self) -> Vec<&dyn BufferArg> {
        match self {
            Traced::Flat(g) => g.bindings()[2..].to_vec(),
            Traced::Levels(l) => {
                // (the driver's levels never move: shading never reads the steps)
                let steps: &dyn BufferArg = match &l.top {
                    Top::Own { top, .. } => top.steps(),
                    Top::Driver { .. } => &l.placements,
                };
                vec![&l.bottoms, &l.placements, &l.hit_instance, steps]
            }
        }
    }

    /// Records the copies of the kd-tree builds' reports (16 bytes each; none for other
    /// kinds), read with `AccelStructure::kd_built` after the work has executed.
    pub fn record_read_built(&self, rec: &mut Recorder) -> Result<Vec<Readback<u32>>> {
        let mut out = Vec::new();
        match self {
            Traced::Flat(g) => out.extend(g.accel.record_read_built(rec)?),
            Traced::Levels(l) => {
                if let Top::Own { top, .. } = &l.top {
                    for b in top.bottoms() {
                        out.extend(b.accel.record_read_built(rec)?);
                    }
                }
            }
        }
        Ok(out)
    }

    /// Whether any of the reports [`Traced::record_read_built`] copied says a kd-tree ran
    /// out of references.
    pub fn kd_overflow(reports: Vec<Readback<u32>>) -> Result<bool> {
        for r in reports {
            if AccelStructure::kd_built(&r.read()?).overflow {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// The flat structure, if that is what is traced.
    pub fn flat(&self) -> Option<&GpuGeometry> {
        match self {
            Traced::Flat(g) => Some(g),
            Traced::Levels(_) => None,
        }
    }
}

/// The top level a render traces: vkrt's own (walked by `render.instances` through the
/// shader library), or the driver's TLAS over its BLASes (walked by the flat kernels' ray
/// query, whose hits `render.driver_hits` maps to instances).
#[allow(
    clippy::large_enum_variant,
    reason = "one per render, made once and kept in place"
)]
pub(crate) enum Top {
    Own {
        top: TopLevel,
        builder: TopLevelBuilder,
    },
    Driver {
        /// The TLAS, with the primitives of the level that holds the spheres bound (they are
        /// the kernels' to intersect), as the flat walk binds a structure.
        geom: GpuGeometry,
        /// The other levels' primitives, which the BLASes read.
        _levels: Vec<DevicePrimitives>,
        /// `InstancedIds::starts`, and how many.
        starts: Buffer<[u32; 4]>,
        n_starts: u32,
    },
}

/// A scene's two levels on the device, and what shading reads of them.
pub(crate) struct Levels {
    pub top: Top,
    /// The level materials and normals ([`RenderLevels::new`]), which shading reads at
    /// device addresses (neither is bound whole, so a scene in pieces may hold more than
    /// one binding reaches), as it reads the bottom levels' own primitives.
    #[allow(
        dead_code,
        reason = "held for shading, which reads them at their addresses"
    )]
    level_arrays: LevelArrays,
    /// Per bottom level where shading reads it (`Bottoms` in `render/shade.comp`).
    bottoms: Buffer<BottomShading>,
    placements: Buffer<Placement>,
    /// Per queued ray: the instance its closest hit is in (`render.instances` writes it).
    pub hit_instance: Buffer<u32>,
    /// Host milliseconds of the bottom levels' builds (the SAH BVH's host builder; the
    /// device builders' passes are in the profile).
    pub bottom_ms: f64,
}

impl Levels {
    /// Records into `rec` the builds of `rl`'s bottom levels with `choice`'s builder (a
    /// kd-tree's with `grow` doublings of its reference budget: read its reports with
    /// [`Traced::record_read_built`]) and of the top level, in a scope `levels`, and the
    /// upload of what shading reads (with the level `materials` and `normals`);
    /// `queue` rays per wave. With `allow_update`, the top level can be refit.
    pub fn record_build(
        rec: &mut Recorder,
        choice: AccelChoice,
        shading: (&RenderLevels, &[u32], &[f32]),
        (grow, queue): (u32, usize),
        allow_update: bool,
    ) -> Result<Self> {
        let ctx = rec.context().clone();
        let rl = shading.0;
        let two = &rl.scene;
        let arrays = level_arrays(&ctx, shading.1.len(), shading.2.len())?;
        rec.upload(&arrays.0, shading.1)?;
        rec.upload(&arrays.1, shading.2)?;
        if choice.kind == AccelKind::Driver {
            let (top, prims) = rec.scope("levels", |rec| driver_levels(rec, rl, choice))?;
            return Self::with_top(rec, (top, prims), 0.0, (rl, arrays), queue);
        }
        // Everything in one scope `levels` (nested scopes repeat names such as `build`).
        let (top, builder, bottom_ms) = rec.scope("levels", |rec| {
            let builder = AccelBuilder::for_choice(&ctx, choice)?;
            let mut bottoms = Vec::with_capacity(two.bottoms.len());
            let mut bottom_ms = 0.0;
            for g in &two.bottoms {
                let (level, recorded) = GpuGeometry::record_build(rec, &builder, g, grow)?;
                bottom_ms += recorded.host_ms.unwrap_or(0.0);
                bottoms.push(Arc::new(level));
            }
            let top_builder = TopLevelBuilder::new(&ctx, AccelKind::Lbvh)?;
            let flags = BuildFlags {
                allow_update,
                ..BuildFlags::default()
            };
            let top =
                top_builder.record_build_shared(rec, &bottoms, &rl.moving, rl.motion, &flags)?;
            Ok::<_, crate::gpu::GpuError>((top, top_builder, bottom_ms))
        })?;
        let prims = primitive_addresses(&ctx, top.bottoms().map(|b| &b.prims))?;
        let top = Top::Own { top, builder };
        Self::with_top(rec, (top, prims), bottom_ms, (rl, arrays), queue)
    }

    /// Records into `rec` the build of `rl`'s top level over bottom levels built before it,
    /// one after another, each in submissions of its own, and what shading reads, the
    /// large arrays uploaded ahead in parts (as [`Levels::record_build`], which records it
    /// all into `rec`): at no time are all the primitives held twice on the host. `rl`'s
    /// bottom levels' host geometry and the rest's primitive ids (taken:
    /// [`RenderLevels::take_bottoms`]) and the level `materials` and `normals` go as they
    /// reach the device.
    pub fn record_build_in_pieces(
        rec: &mut Recorder,
        choice: AccelChoice,
        rl: &mut RenderLevels,
        (materials, normals): (Vec<u32>, Vec<f32>),
        queue: usize,
    ) -> Result<Self> {
        let ctx = rec.context().clone();
        let arrays = level_arrays(&ctx, materials.len(), normals.len())?;
        upload_in_parts(&ctx, &arrays.1, 0, &normals)?;
        drop(normals);
        upload_in_parts(&ctx, &arrays.0, 0, &materials)?;
        drop(materials);
        let builder = AccelBuilder::for_choice(&ctx, choice)?;
        let taken = rl.take_bottoms();
        let mut bottoms = Vec::with_capacity(taken.len());
        let mut bottom_ms = 0.0;
        for g in taken {
            let (mut level, ms) = GpuGeometry::build_fitting_taking(&ctx, &builder, g)?;
            // Nothing refits a bottom level.
            level.prims.release_boxes()?;
            bottom_ms += ms;
            bottoms.push(Arc::new(level));
        }
        let (top, builder) = rec.scope("levels", |rec| {
            let top_builder = TopLevelBuilder::new(&ctx, AccelKind::Lbvh)?;
            let flags = BuildFlags::default();
            let top =
                top_builder.record_build_shared(rec, &bottoms, &rl.moving, rl.motion, &flags)?;
            Ok::<_, crate::gpu::GpuError>((top, top_builder))
        })?;
        let prims = primitive_addresses(&ctx, bottoms.iter().map(|b| &b.prims))?;
        let top = Top::Own { top, builder };
        Self::with_top(rec, (top, prims), bottom_ms, (rl, arrays), queue)
    }

    /// The levels over `top` (and, per bottom level, where its triangles' vertices and its
    /// spheres lie), with the upload of what shading reads besides the level `arrays`
    /// recorded into `rec`.
    fn with_top(
        rec: &mut Recorder,
        (top, prims): (Top, Vec<[u64; 2]>),
        bottom_ms: f64,
        (rl, arrays): (&RenderLevels, LevelArrays),
        queue: usize,
    ) -> Result<Self> {
        let ctx = rec.context().clone();
        let materials = crate::gpu::address_of(&ctx, &arrays.0)?;
        let normals = crate::gpu::address_of(&ctx, &arrays.1)?;
        let shading: Vec<BottomShading> = prims
            .iter()
            .enumerate()
            .map(|(b, &[verts, spheres])| {
                let (first_normal, first_material) = rl.shading_of(b);
                BottomShading {
                    verts,
                    spheres,
                    normals: first_normal.map_or(0, |t| normals + 36 * t as u64),
                    materials: first_material.map_or(0, |p| materials + 4 * p as u64),
                }
            })
            .collect();
        let bottoms = Buffer::new(&ctx, "render.bottoms", shading.len().max(1))?;
        let placements = Buffer::new(&ctx, "render.placements", rl.placements.len().max(1))?;
        let hit_instance = Buffer::new(&ctx, "render.hit_instance", queue.max(1))?;
        rec.upload(&bottoms, &shading)?;
        rec.upload(&placements, &rl.placements)?;
        rec.transfer_to_compute();
        Ok(Self {
            top,
            level_arrays: arrays,
            bottoms,
            placements,
            hit_instance,
            bottom_ms,
        })
    }

    /// Records the upload of `rl`'s placements (a later frame's; order it after the last
    /// frame's shading and before the next, as [`super::Renderer`]'s reset of a frame does).
    /// The moving instances' steps shading reads are the top level's, written by its update.
    pub fn record_placements(&self, rec: &mut Recorder, rl: &RenderLevels) -> Result<()> {
        rec.upload(&self.placements, &rl.placements)
    }

    /// Records the top level's update to `rl`'s instances (as many as it was built with),
    /// refit or rebuilt as `update` says (in a scope `levels`): what a later frame changes
    /// besides the placements. The bottom levels stay.
    pub fn record_update(
        &mut self,
        rec: &mut Recorder,
        rl: &RenderLevels,
        update: Update,
    ) -> Result<()> {
        let (top, b) = match &mut self.top {
            Top::Own { top, builder } => (top, builder),
            // The driver's TLAS is rebuilt over the moved instances (they never move over
            // a shutter: `Plan::levels`), its BLASes kept.
            Top::Driver { geom, .. } => {
                let driver = crate::accel::driver_levels::levels_mut(&mut geom.accel);
                let driver = driver.ok_or_else(|| crate::gpu::GpuError::Usage {
                    call: "FrameLoop::render",
                    reason: "the driver's levels were not built".into(),
                })?;
                return rec.scope("levels", |rec| {
                    driver.record_move_instances(rec, &rl.moving)
                });
            }
        };
        let instances = &rl.moving;
        if rl.motion.steps > 1 {
            top.set_time(rl.motion.time)?;
        }
        match update {
            Update::Refit => rec.scope("levels", |rec| b.record_update(rec, top, instances)),
            Update::Rebuild => rec.scope("levels", |rec| b.record_rebuild(rec, top, instances)),
        }
    }

    /// Where vkrt's top level's handle lies (`render.instances`' push constant); 0 for the
    /// driver's.
    pub fn handle(&self) -> u64 {
        match &self.top {
            Top::Own { top, .. } => top.handle_address(),
            Top::Driver { .. } => 0,
        }
    }
}

/// The level arrays shading reads besides the bottom levels' primitives: the level
/// materials and the level normals ([`RenderLevels::new`]).
type LevelArrays = (Buffer<u32>, Buffer<f32>);

/// The level arrays on the device, for `materials` and `normals` elements, their contents not
/// yet written.
fn level_arrays(
    ctx: &crate::gpu::Context,
    materials: usize,
    normals: usize,
) -> Result<LevelArrays> {
    Ok((
        Buffer::arena(ctx, "render.level_materials", materials.max(1))?,
        Buffer::arena(ctx, "render.level_normals", normals.max(1))?,
    ))
}

/// Per bottom level the device addresses of its triangles' vertices and of its spheres (0
/// where it has none), where its walk reads them.
fn primitive_addresses<'a>(
    ctx: &crate::gpu::Context,
    prims: impl Iterator<Item = &'a DevicePrimitives>,
) -> Result<Vec<[u64; 2]>> {
    prims
        .map(|p| {
            let spheres = match p.n_spheres {
                0 => 0,
                _ => crate::gpu::address_of(ctx, &p.spheres)?,
            };
            Ok([crate::gpu::address_of(ctx, &p.tri_verts)?, spheres])
        })
        .collect()
}

/// Uploads `data` into `dst` from element `at` on, in submissions of at most 64 MiB each,
/// waited for one after another (each one's staging buffer freed before the next is filled),
/// ending with a transfer → compute barrier.
fn upload_in_parts<T: bytemuck::Pod>(
    ctx: &crate::gpu::Context,
    dst: &Buffer<T>,
    at: usize,
    data: &[T],
) -> Result<()> {
    let per = ((64 << 20) / std::mem::size_of::<T>().max(1)).max(1);
    for (k, part) in data.chunks(per).enumerate() {
        let mut rec = Recorder::new(ctx)?;
        rec.upload_at(dst, at + k * per, part)?;
        rec.transfer_to_compute();
        rec.submit_and_wait()?;
    }
    Ok(())
}

/// Records the build of the driver's own levels over `rl`'s bottom levels (a BLAS per level
/// and kind of geometry, a TLAS instance per instance with its transform, custom index and
/// mask: `DriverAccel::record_instanced`); with the addresses of each level's primitives
/// ([`primitive_addresses`]).
fn driver_levels(
    rec: &mut Recorder,
    rl: &RenderLevels,
    choice: AccelChoice,
) -> Result<(Top, Vec<[u64; 2]>)> {
    let ctx = rec.context().clone();
    let two = &rl.scene;
    let mut prims = Vec::with_capacity(two.bottoms.len());
    for g in &two.bottoms {
        prims.push(DevicePrimitives::record_upload(rec, g)?);
    }
    let with_spheres: Vec<usize> = (0..two.bottoms.len())
        .filter(|&b| !two.bottoms[b].spheres.is_empty())
        .collect();
    if with_spheres.len() > 1 {
        return Err(crate::gpu::GpuError::Usage {
            call: "render over the driver's two levels",
            reason: format!(
                "the spheres lie in {} bottom levels; the driver's walk intersects one \
                 level's spheres",
                with_spheres.len()
            ),
        });
    }
    let bound = with_spheres.first().copied().unwrap_or(0);
    let addresses = primitive_addresses(&ctx, prims.iter())?;
    let refs: Vec<&DevicePrimitives> = prims.iter().collect();
    let (accel, ids) = crate::accel::driver_levels::record_instanced(
        rec,
        &refs,
        &two.instances,
        bound,
        choice.prefer,
    )?;
    let starts = ids.starts();
    let n_starts = starts.len() as u32;
    let table = Buffer::new(&ctx, "render.driver_starts", starts.len().max(1))?;
    rec.upload(&table, starts)?;
    let geom = GpuGeometry {
        prims: prims.swap_remove(bound),
        accel,
        device_input: None,
        life: Default::default(),
    };
    let top = Top::Driver {
        geom,
        _levels: prims,
        starts: table,
        n_starts,
    };
    Ok((top, addresses))
}
