//! What the renderer traces: one structure over every primitive, or a scene as two levels
//! ([`TwoLevelScene`]): the bottom levels built once, the top level (an LBVH over the
//! instances) built with the first frame and, in an animation, refit or rebuilt from the
//! moved instances every frame, so that a rigid motion changes one transform, not the
//! primitives' structure. The extend and shadow passes walk the two levels
//! (`render.instances`); shading reads the primitives where the flat scene has them (moved
//! each frame as before, no structure over them), so both give the same images.

use std::sync::Arc;

use crate::accel::device::{
    AccelBuilder, AccelChoice, AccelKind, AccelStructure, DevicePrimitives,
};
use crate::accel::embedded::BuildFlags;
use crate::accel::instances::{Instance, TopLevel, TopLevelBuilder};
use crate::gpu::{Buffer, BufferArg, Readback, Recorder, Result};
use crate::scene::Aabb;
use crate::trace::geometry::SceneInfo;
use crate::trace::gpu::GpuGeometry;
use crate::trace::instanced::{nonempty, TwoLevelScene};
use crate::trace::TraceGeometry;

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
    /// What `shade` binds after its head: the primitives (triangle vertices, spheres,
    /// per-primitive motion slot, motions) and the scene constants, `traverse.glsl`'s last
    /// five bindings.
    pub fn shading_bindings(&self) -> [&dyn BufferArg; 5] {
        match self {
            Traced::Flat(g) => {
                let [_, _, rest @ ..] = g.bindings();
                rest
            }
            Traced::Levels(l) => {
                let p = &l.prims;
                [
                    &p.tri_verts,
                    &p.spheres,
                    &p.prim_motion,
                    &p.motions,
                    &l.info,
                ]
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
                for b in l.top.bottoms() {
                    out.extend(b.accel.record_read_built(rec)?);
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

/// A scene's two levels on the device, and the flat primitives shading reads.
pub(crate) struct Levels {
    prims: DevicePrimitives,
    /// The flat primitives' constants (counts, motion) for shading.
    info: Buffer<SceneInfo>,
    top: TopLevel<'static>,
    top_builder: TopLevelBuilder,
    pub mesh_first: Buffer<u32>,
    pub rest_ids: Buffer<u32>,
    /// Host milliseconds of the bottom levels' builds (the SAH BVH's host builder; the
    /// device builders' passes are in the profile).
    pub bottom_ms: f64,
}

impl Levels {
    /// Records into `rec` the builds of `two`'s bottom levels with `choice`'s builder (a
    /// kd-tree's with `grow` doublings of its reference budget: read its reports with
    /// [`Traced::record_read_built`]), the upload of `flat` (the same scene, flat, for
    /// shading) and the top level's build, each in a scope `build`. With `allow_update`, the
    /// top level can be refit.
    pub fn record_build(
        rec: &mut Recorder,
        choice: AccelChoice,
        (two, flat): (&TwoLevelScene, &TraceGeometry),
        grow: u32,
        allow_update: bool,
    ) -> Result<Self> {
        let ctx = rec.context().clone();
        let builder = AccelBuilder::for_choice(&ctx, choice)?;
        let mut bottoms = Vec::with_capacity(two.bottoms.len());
        let mut bottom_ms = 0.0;
        for g in &two.bottoms {
            let (level, recorded) = GpuGeometry::record_build(rec, &builder, g, grow)?;
            bottom_ms += recorded.host_ms.unwrap_or(0.0);
            bottoms.push(Arc::new(level));
        }
        let prims = DevicePrimitives::record_upload(rec, flat)?;
        let mut bounds = Aabb::EMPTY;
        flat.boxes.iter().for_each(|b| bounds.union(b));
        let info = Buffer::new(&ctx, "render.scene_info", 1)?;
        rec.upload(&info, &[prims.info(&bounds, 0)])?;
        let (mesh_first_words, rest_words) = (nonempty(&two.mesh_first), nonempty(&two.rest_ids));
        let mesh_first = Buffer::new(&ctx, "render.mesh_first", mesh_first_words.len())?;
        let rest_ids = Buffer::new(&ctx, "render.rest_ids", rest_words.len())?;
        rec.upload(&mesh_first, &mesh_first_words)?;
        rec.upload(&rest_ids, &rest_words)?;
        rec.transfer_to_compute();
        let top_builder = TopLevelBuilder::new(&ctx, AccelKind::Lbvh)?;
        let flags = BuildFlags {
            allow_update,
            ..BuildFlags::default()
        };
        let top = rec.scope("build", |rec| {
            top_builder.record_build_shared(rec, &bottoms, &two.instances, &flags)
        })?;
        Ok(Self {
            prims,
            info,
            top,
            top_builder,
            mesh_first,
            rest_ids,
            bottom_ms,
        })
    }

    /// Records what a later frame changes: the moved primitives (for shading) and the top
    /// level over `instances` (as many as it was built with), refit or rebuilt as `update`
    /// says (in a scope `update` or `build`). The bottom levels stay.
    pub fn record_update(
        &mut self,
        rec: &mut Recorder,
        flat: &TraceGeometry,
        instances: &[Instance],
        update: Update,
    ) -> Result<()> {
        self.prims.record_update(rec, flat)?;
        let (b, top) = (&self.top_builder, &mut self.top);
        match update {
            Update::Refit => rec.scope("update", |rec| b.record_update(rec, top, instances)),
            Update::Rebuild => rec.scope("build", |rec| b.record_rebuild(rec, top, instances)),
        }
    }

    /// Where the top level's handle lies (the kernels' push constant).
    pub fn handle(&self) -> u64 {
        self.top.handle_address()
    }
}
