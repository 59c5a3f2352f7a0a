//! Several structures over the caller's geometry built by one record call, as
//! `vkCmdBuildAccelerationStructuresKHR` takes `infoCount` builds, sharing their barriers:
//! the gathers interleaved (every structure's `k`-th geometry between the same two
//! barriers), then the builders' passes interleaved (pass `k` of every structure, one
//! barrier, pass `k + 1` of every structure: [`crate::gpu`]'s capture), and one barrier at
//! the end for all of them. Separate calls pay every barrier per structure; a batch of
//! builds of one size pays those of one build. The structures' memory (and their scratch)
//! is disjoint, so passes of different structures need no order among themselves. The
//! driver's builds, recorded straight into the command buffer by its extension, follow one
//! another.

use crate::accel::device::{AccelBuilder, AccelKind};
use crate::accel::geometry::{GatherJob, Geometry, GeometryGather};
use crate::accel::gpu_geometry::GpuGeometry;
use crate::gpu::placement::{place, Placement};
use crate::gpu::{GpuError, RawBuffer, Recorder, Result};

/// One structure of [`AccelBuilder::record_builds_from`]: what
/// [`AccelBuilder::record_build_from`] takes for one.
pub struct BuildTarget<'a> {
    /// The geometries `out` was created over, their buffers holding the data.
    pub geometries: &'a [Geometry],
    /// The structure ([`AccelBuilder::create_in`]).
    pub out: &'a mut GpuGeometry,
    /// Its build scratch: at least [`AccelSizes::build_scratch_bytes`], overlapping no
    /// other target's.
    ///
    /// [`AccelSizes::build_scratch_bytes`]: crate::accel::device::AccelSizes::build_scratch_bytes
    pub scratch: RawBuffer,
}

/// Whether two ranges of `bytes` from their offsets share a byte.
fn overlap(a: (&RawBuffer, u64), b: (&RawBuffer, u64)) -> bool {
    a.0.raw == b.0.raw && a.0.offset < b.0.offset + b.1 && b.0.offset < a.0.offset + a.1
}

impl AccelBuilder {
    /// Records the builds of every target, as [`AccelBuilder::record_build_from`] records
    /// one and with the same results, in one sequence: the gathers of all targets
    /// interleaved, the builders' passes interleaved (the driver's builds one after
    /// another), and one barrier at the end
    /// ([`RecordSync::build`], as the single call). Every target is checked before anything
    /// is recorded; an error names the target's index. Scratch ranges must not overlap
    /// (each build writes its own while the others run). No target records nothing.
    ///
    /// [`RecordSync::build`]: crate::accel::sync::RecordSync::build
    pub fn record_builds_from(
        &self,
        rec: &mut Recorder,
        targets: &mut [BuildTarget<'_>],
    ) -> Result<()> {
        self.record_builds("AccelBuilder::record_builds_from", rec, targets)
    }

    /// [`AccelBuilder::record_builds_from`] for `call` (a single target's errors name no
    /// index).
    pub(crate) fn record_builds(
        &self,
        call: &'static str,
        rec: &mut Recorder,
        targets: &mut [BuildTarget<'_>],
    ) -> Result<()> {
        if targets.is_empty() {
            return Ok(());
        }
        let ctx = rec.context().clone();
        let single = targets.len() == 1;
        let entry = |i: usize, e: GpuError| match e {
            GpuError::Usage { reason, .. } if single => GpuError::Usage { call, reason },
            GpuError::Usage { reason, .. } => GpuError::Usage {
                call,
                reason: format!("target {i}: {reason}"),
            },
            GpuError::Placement { what, problem } if !single => GpuError::Placement {
                what: format!("target {i}: {what}"),
                problem,
            },
            e @ (GpuError::NotBuilt { .. }
            | GpuError::KindMismatch { .. }
            | GpuError::FrozenSetting { .. })
                if !single =>
            {
                GpuError::Target {
                    index: i,
                    error: Box::new(e),
                }
            }
            e => e,
        };
        let mut placed = Vec::with_capacity(targets.len());
        for (i, t) in targets.iter().enumerate() {
            let input = self
                .input_of(call, t.geometries, t.out)
                .map_err(|e| entry(i, e))?
                .clone();
            let (scratch, bytes) = place(
                &ctx,
                "the build scratch",
                Placement::Into(t.scratch),
                || self.scratch_for(&ctx, &input),
            )
            .map_err(|e| entry(i, e))?;
            for (j, (_, _, other)) in placed.iter().enumerate() {
                if bytes > 0 && overlap((&t.scratch, bytes), (&targets[j].scratch, *other)) {
                    return Err(entry(
                        i,
                        GpuError::Usage {
                            call,
                            reason: format!("its scratch overlaps target {j}'s"),
                        },
                    ));
                }
            }
            placed.push((input, scratch, bytes));
        }
        let gather = GeometryGather::new(&ctx)?;
        rec.scope("build", |rec| -> Result<()> {
            rec.scope("gather", |rec| {
                let headers: Vec<(u32, u32)> = targets
                    .iter()
                    .zip(&placed)
                    .map(|(t, (input, _, _))| {
                        self.scene_header(&t.out.accel.flags(), input.layout.primitive_count())
                    })
                    .collect();
                let jobs: Vec<GatherJob<'_>> = targets
                    .iter()
                    .zip(&placed)
                    .zip(&headers)
                    .map(|((t, (input, _, _)), &(walk, parents_at))| GatherJob {
                        geometries: t.geometries,
                        layout: &input.layout,
                        prims: &t.out.prims,
                        info: &t.out.accel.info,
                        walk,
                        parents_at,
                    })
                    .collect();
                gather.record_batch(rec, &jobs)
            })?;
            // vkrt's builders are recorded pass by pass across the targets; the driver's
            // builds (recorded straight into the command buffer) one after another.
            let interleave = !single && self.kind() != AccelKind::Driver;
            let mut lists = Vec::with_capacity(targets.len());
            for (t, (_, scratch, _)) in targets.iter_mut().zip(&placed) {
                let out = &mut *t.out;
                if interleave {
                    rec.begin_capture();
                }
                let built = self.record_build_inner(rec, &out.prims, None, scratch, &mut out.accel);
                if interleave {
                    lists.push(rec.end_capture());
                }
                built?;
            }
            rec.record_interleaved(lists);
            Ok(())
        })?;
        rec.end_of_build();
        rec.check()?;
        for t in targets.iter_mut() {
            if let Some(d) = t.out.device_input.as_mut() {
                d.built = true;
            }
        }
        Ok(())
    }
}
