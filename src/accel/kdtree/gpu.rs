//! The GPU build of seed 001 (see [`super::seed001`] for the algorithm and its CPU twin).
//!
//! Status: Phase I runs on the GPU and equals the twin bit for bit — triangle boxes
//! (`accel.kdtree_boxes`), the scene box (min/max reductions), the per-axis event keys
//! (`accel.kdtree_event_keys`), one stable f32 radix sort per axis and the SoA event
//! records (`accel.kdtree_event_gather`). Phase II (the per-level passes) is still to come;
//! until then trees are built by the CPU twin.

use super::seed001::Events;
use super::Aabb;
use crate::gpu::{kernels, Buffer, Context, Kernel, Recorder, Result, Spec};
use crate::prims::radix_sort::{RadixScratch, RadixSort};
use crate::prims::reduce::Reduce;
use crate::prims::PrimConfig;
use glam::Vec3;
use std::sync::Arc;

/// One axis list of events on the GPU (SoA, as [`Events`]).
pub struct GpuEvents {
    pub plane: Buffer<f32>,
    /// END = 0 / START = 1, one byte each.
    pub kind: Buffer<u8>,
    pub prim: Buffer<u32>,
    pub node: Buffer<u32>,
    pub box_min: [Buffer<f32>; 3],
    pub box_max: [Buffer<f32>; 3],
}

impl GpuEvents {
    fn new(ctx: &Context, axis: usize, len: usize) -> Result<Self> {
        let name = |f: &str| format!("kdtree.events{axis}.{f}");
        let f = |f: &str| Buffer::<f32>::new(ctx, &name(f), len);
        Ok(Self {
            plane: f("plane")?,
            kind: Buffer::new(ctx, &name("kind"), len)?,
            prim: Buffer::new(ctx, &name("prim"), len)?,
            node: Buffer::new(ctx, &name("node"), len)?,
            box_min: [f("min_x")?, f("min_y")?, f("min_z")?],
            box_max: [f("max_x")?, f("max_y")?, f("max_z")?],
        })
    }

    /// Reads the list back (for tests and the twin comparison).
    pub fn download(&self) -> Result<Events> {
        Ok(Events {
            plane: self.plane.download()?,
            kind: self.kind.download()?,
            prim: self.prim.download()?,
            node: self.node.download()?,
            box_min: [
                self.box_min[0].download()?,
                self.box_min[1].download()?,
                self.box_min[2].download()?,
            ],
            box_max: [
                self.box_max[0].download()?,
                self.box_max[1].download()?,
                self.box_max[2].download()?,
            ],
        })
    }
}

/// Phase I output: the scene box and the three sorted event lists.
pub struct PhaseOne {
    /// min x, y, z, max x, y, z (one f32 each).
    pub bounds: [Buffer<f32>; 6],
    pub events: [GpuEvents; 3],
}

impl PhaseOne {
    pub fn bounds(&self) -> Result<Aabb> {
        let v = |i: usize| self.bounds[i].download().map(|b| b[0]);
        Ok(Aabb {
            min: Vec3::new(v(0)?, v(1)?, v(2)?),
            max: Vec3::new(v(3)?, v(4)?, v(5)?),
        })
    }
}

/// The kernels of the GPU build.
pub struct KdTreeBuilder {
    boxes: Arc<Kernel>,
    event_keys: Arc<Kernel>,
    event_gather: Arc<Kernel>,
    sort: RadixSort,
    reduce: Reduce,
}

/// Scratch of Phase I for up to `max_prims` triangles.
pub struct PhaseOneScratch {
    max_prims: usize,
    prim_min: [Buffer<f32>; 3],
    prim_max: [Buffer<f32>; 3],
    keys: Buffer<f32>,
    values: Buffer<u32>,
    sort: RadixScratch,
    reduce: Buffer<u32>,
}

const WORKGROUP: u32 = 256;

impl KdTreeBuilder {
    pub fn new(ctx: &Context) -> Result<Self> {
        let spec = Spec::new().workgroup(WORKGROUP);
        let cfg = PrimConfig::default_for(ctx);
        Ok(Self {
            boxes: ctx.kernel(&kernels::ACCEL_KDTREE_BOXES, &spec)?,
            event_keys: ctx.kernel(&kernels::ACCEL_KDTREE_EVENT_KEYS, &spec)?,
            event_gather: ctx.kernel(&kernels::ACCEL_KDTREE_EVENT_GATHER, &spec)?,
            sort: RadixSort::new(ctx, cfg, 8)?,
            reduce: Reduce::new(ctx, cfg)?,
        })
    }

    pub fn phase_one_scratch(&self, ctx: &Context, max_prims: usize) -> Result<PhaseOneScratch> {
        let f = |name: &str| Buffer::<f32>::new(ctx, name, max_prims);
        Ok(PhaseOneScratch {
            max_prims,
            prim_min: [
                f("kdtree.prim_min_x")?,
                f("kdtree.prim_min_y")?,
                f("kdtree.prim_min_z")?,
            ],
            prim_max: [
                f("kdtree.prim_max_x")?,
                f("kdtree.prim_max_y")?,
                f("kdtree.prim_max_z")?,
            ],
            keys: Buffer::new(ctx, "kdtree.sort_keys", 2 * max_prims)?,
            values: Buffer::new(ctx, "kdtree.sort_values", 2 * max_prims)?,
            sort: self.sort.scratch(ctx, 2 * max_prims)?,
            reduce: Buffer::new(
                ctx,
                "kdtree.reduce_scratch",
                self.reduce.scratch_len(max_prims).max(1),
            )?,
        })
    }

    /// Allocates the Phase I output for `n` triangles.
    pub fn phase_one_output(&self, ctx: &Context, n: usize) -> Result<PhaseOne> {
        let f = |name: &str| Buffer::<f32>::new(ctx, name, 1);
        Ok(PhaseOne {
            bounds: [
                f("kdtree.bounds.min_x")?,
                f("kdtree.bounds.min_y")?,
                f("kdtree.bounds.min_z")?,
                f("kdtree.bounds.max_x")?,
                f("kdtree.bounds.max_y")?,
                f("kdtree.bounds.max_z")?,
            ],
            events: [
                GpuEvents::new(ctx, 0, 2 * n)?,
                GpuEvents::new(ctx, 1, 2 * n)?,
                GpuEvents::new(ctx, 2, 2 * n)?,
            ],
        })
    }

    /// Records Phase I for the `n` triangles in `triangles` (9 floats each). The caller
    /// orders the upload of `triangles` before and the use of `out` after.
    pub fn record_phase_one(
        &self,
        rec: &mut Recorder,
        triangles: &Buffer<f32>,
        n: usize,
        scratch: &PhaseOneScratch,
        out: &PhaseOne,
    ) {
        assert!(
            n <= scratch.max_prims && 9 * n <= triangles.len(),
            "phase one of {n} triangles"
        );
        let s = scratch;
        rec.scope("kdtree.phase1", |rec| {
            rec.scope("kdtree.boxes", |rec| {
                let groups = rec.groups_1d(n as u64, WORKGROUP);
                rec.dispatch(
                    &self.boxes,
                    groups,
                    &[
                        triangles,
                        &s.prim_min[0],
                        &s.prim_min[1],
                        &s.prim_min[2],
                        &s.prim_max[0],
                        &s.prim_max[1],
                        &s.prim_max[2],
                    ],
                    &(n as u32),
                );
            });
            rec.compute_to_compute();
            rec.scope("kdtree.bounds", |rec| {
                for a in 0..3 {
                    self.reduce.record_min_f32(
                        rec,
                        &s.prim_min[a],
                        n as u32,
                        &s.reduce,
                        &out.bounds[a],
                    );
                    rec.compute_to_compute();
                    self.reduce.record_max_f32(
                        rec,
                        &s.prim_max[a],
                        n as u32,
                        &s.reduce,
                        &out.bounds[3 + a],
                    );
                    rec.compute_to_compute();
                }
            });
            for (a, ev) in out.events.iter().enumerate() {
                rec.scope("kdtree.events", |rec| {
                    let groups = rec.groups_1d(2 * n as u64, WORKGROUP);
                    rec.dispatch(
                        &self.event_keys,
                        groups,
                        &[&s.prim_min[a], &s.prim_max[a], &s.keys, &s.values],
                        &(n as u32),
                    );
                    rec.compute_to_compute();
                    self.sort
                        .record_f32(rec, &s.keys, &s.values, 2 * n, &s.sort);
                    rec.compute_to_compute();
                    let groups = rec.groups_1d((2 * n).div_ceil(4) as u64, WORKGROUP);
                    rec.dispatch(
                        &self.event_gather,
                        groups,
                        &[
                            &s.keys,
                            &s.values,
                            &s.prim_min[0],
                            &s.prim_min[1],
                            &s.prim_min[2],
                            &s.prim_max[0],
                            &s.prim_max[1],
                            &s.prim_max[2],
                            &ev.plane,
                            &ev.kind,
                            &ev.prim,
                            &ev.node,
                            &ev.box_min[0],
                            &ev.box_min[1],
                            &ev.box_min[2],
                            &ev.box_max[0],
                            &ev.box_max[1],
                            &ev.box_max[2],
                        ],
                        &(n as u32),
                    );
                    // The next axis reuses keys and values.
                    rec.compute_to_compute();
                });
            }
        });
    }

    /// Convenience: uploads `triangles`, runs Phase I and waits.
    pub fn phase_one(
        &self,
        ctx: &Context,
        triangles: &[[Vec3; 3]],
    ) -> Result<(PhaseOne, crate::gpu::Profile)> {
        let n = triangles.len();
        let flat: Vec<f32> = triangles
            .iter()
            .flat_map(|t| t.iter().flat_map(|p| p.to_array()))
            .collect();
        let tris = Buffer::from_slice(ctx, "kdtree.triangles", &flat)?;
        let scratch = self.phase_one_scratch(ctx, n)?;
        let out = self.phase_one_output(ctx, n)?;
        let mut rec = Recorder::new(ctx)?;
        self.record_phase_one(&mut rec, &tris, n, &scratch, &out);
        rec.compute_to_transfer();
        let profile = rec.submit_and_wait()?;
        Ok((out, profile))
    }
}
