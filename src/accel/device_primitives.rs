//! The scene's primitives in device memory: what every builder reads and every walk binds.

use crate::accel::primitives::{MotionRecord, SceneInfo, TraceGeometry};
use crate::gpu::{Buffer, Context, GpuError, Recorder, Result};
use crate::scene::Aabb;

/// The scene's primitives on the device, as the builders and the traversal read them.
pub struct DevicePrimitives {
    /// 9 floats per triangle (three vertices), then four floats of padding.
    pub tri_verts: Buffer<f32>,
    /// The spheres (centre, radius), then two per box primitive (min, 0 and max, 0).
    pub spheres: Buffer<[f32; 4]>,
    /// Motion slot per primitive (`NO_MOTION` if static); empty when nothing moves.
    pub prim_motion: Buffer<u32>,
    /// The rigid motions the slots of `prim_motion` index.
    pub motions: Buffer<MotionRecord>,
    /// Box of every primitive: min x, y, z, max x, y, z.
    pub boxes: Buffer<f32>,
    /// Triangles (ids `0..n_tris`).
    pub n_tris: usize,
    /// Spheres (ids after the triangles).
    pub n_spheres: usize,
    /// Axis-aligned box primitives (ids after the spheres).
    pub n_aabbs: usize,
    /// Whether any primitive moves (`prim_motion` is filled).
    pub has_motion: bool,
}

impl DevicePrimitives {
    /// Buffers for `g`'s primitives, filled by the uploads recorded into `rec` (followed by
    /// a transfer → compute barrier).
    pub fn record_upload(rec: &mut Recorder, g: &TraceGeometry) -> Result<Self> {
        let ctx = rec.context().clone();
        let boxes = flat_boxes(&g.boxes);
        let spheres = g.sphere_words();
        let p = Self {
            // Four floats of padding: the exact kernels read a triangle as five 64-bit words,
            // the texel walks as three 16-byte texels (up to three floats past its end).
            tri_verts: Buffer::new(&ctx, "trace.tri_verts", g.tri_verts.len() + 4)?,
            spheres: Buffer::new(&ctx, "trace.spheres", spheres.len())?,
            prim_motion: Buffer::new(&ctx, "trace.prim_motion", g.prim_motion.len())?,
            motions: Buffer::new(&ctx, "trace.motions", g.motions.len())?,
            boxes: Buffer::new(&ctx, "trace.boxes", boxes.len())?,
            n_tris: g.triangle_count(),
            n_spheres: g.spheres.len(),
            n_aabbs: g.aabbs.len(),
            has_motion: g.has_motion(),
        };
        rec.upload(&p.tri_verts, &g.tri_verts)?;
        rec.upload(&p.spheres, &spheres)?;
        rec.upload(&p.prim_motion, &g.prim_motion)?;
        rec.upload(&p.motions, &g.motions)?;
        rec.upload(&p.boxes, &boxes)?;
        rec.transfer_to_compute();
        Ok(p)
    }

    /// Records the upload of `g`'s moved primitives (vertices, spheres, motions, boxes) into
    /// these buffers, followed by a transfer → compute barrier: the same primitive counts,
    /// new positions (then refit or rebuild the structure).
    pub fn record_update(&self, rec: &mut Recorder, g: &TraceGeometry) -> Result<()> {
        if g.triangle_count() != self.n_tris
            || g.spheres.len() != self.n_spheres
            || g.aabbs.len() != self.n_aabbs
            || g.has_motion() != self.has_motion
            || g.motions.len() != self.motions.len()
        {
            return Err(GpuError::Usage {
                call: "DevicePrimitives::record_update",
                reason: format!(
                    "an update keeps the primitives: {} triangles, {} spheres and {} boxes \
                     on the device, {}, {} and {} given",
                    self.n_tris,
                    self.n_spheres,
                    self.n_aabbs,
                    g.triangle_count(),
                    g.spheres.len(),
                    g.aabbs.len()
                ),
            });
        }
        rec.compute_to_transfer();
        rec.upload(&self.tri_verts, &g.tri_verts)?;
        rec.upload(&self.spheres, &g.sphere_words())?;
        rec.upload(&self.prim_motion, &g.prim_motion)?;
        rec.upload(&self.motions, &g.motions)?;
        rec.upload(&self.boxes, &flat_boxes(&g.boxes))?;
        rec.transfer_to_compute();
        Ok(())
    }

    /// [`DevicePrimitives::record_upload`] in a submission of its own.
    pub fn upload(ctx: &Context, g: &TraceGeometry) -> Result<Self> {
        let mut rec = Recorder::new(ctx)?;
        let p = Self::record_upload(&mut rec, g)?;
        rec.submit_and_wait()?;
        Ok(p)
    }

    /// Frees the primitives' boxes (one empty box is left): after the build of a structure
    /// that is never refit or rebuilt over them (a bottom level of two), which the walks
    /// never read. 24 bytes a primitive.
    pub fn release_boxes(&mut self) -> Result<()> {
        let ctx = self.tri_verts.context().clone();
        self.boxes = Buffer::new(&ctx, "trace.boxes", 6)?;
        Ok(())
    }

    /// Primitives of every type.
    pub fn count(&self) -> usize {
        self.n_tris + self.n_spheres + self.n_aabbs
    }

    /// The scene constants of a structure with root box `bounds`.
    pub(crate) fn info(&self, bounds: &Aabb, parents_at: u32) -> SceneInfo {
        SceneInfo::new(
            bounds,
            [self.n_tris, self.n_spheres, self.n_aabbs],
            self.has_motion,
            parents_at,
        )
    }
}

/// Boxes as 6 floats each (min x, y, z, max x, y, z), as the kernels read them.
fn flat_boxes(boxes: &[Aabb]) -> Vec<f32> {
    boxes
        .iter()
        .flat_map(|b| b.min.to_array().into_iter().chain(b.max.to_array()))
        .collect()
}
