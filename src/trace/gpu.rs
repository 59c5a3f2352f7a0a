//! The GPU tracer: geometry and kd-tree uploaded once, ray batches traced by
//! `glsl/render/trace.comp` (closest or any hit, watertight or Möller–Trumbore, chosen by
//! specialization constants so each variant compiles only what it runs).

use std::sync::Arc;

use crate::accel::device::{AccelBuilder, AccelStructure};
use crate::accel::gpu_geometry::GpuGeometry;
use crate::accel::kdtree::KdTree;
use crate::accel::walk::{AccelTraversal, NodeAccess};
use crate::gpu::kernels;
use crate::gpu::{
    Buffer, BufferArg, Context, GpuError, Kernel, Profile, Recorder, Result, Spec, Traffic,
};

use super::{Hit, Query, Ray, TraceOptions};
use crate::accel::primitives::TraceGeometry;

const WORKGROUP: u32 = 64;

/// Spec constant ids shared by every kernel that includes `traverse.glsl` (for options
/// resolved by [`effective_options`]): the step cap (22); the exact variants also check the
/// driver's division (21) where it is not known to be correct.
pub fn traversal_spec(ctx: &Context, opt: &TraceOptions) -> Spec {
    let spec = Spec::new()
        .u32(1, opt.intersector.spec())
        .u32(2, (opt.query == Query::Any) as u32)
        .u32(3, opt.stack_size.max(1))
        .u32(22, opt.max_steps.unwrap_or(ctx.info().max_traversal_steps));
    if opt.exact {
        spec.u32(21, !ctx.info().ieee_division as u32)
    } else {
        spec
    }
}

/// Result of a batch.
pub struct TraceBatch {
    /// One hit per ray, in ray order (a miss has `prim == NO_HIT`).
    pub hits: Vec<Hit>,
    /// Rays that ran out of traversal steps (reported as misses).
    pub exhausted: u32,
    /// The GPU passes of the submissions, with one `trace` scope around each batch's kernel.
    pub profile: Profile,
}

/// A compiled trace kernel for one structure, walk and set of [`TraceOptions`].
#[must_use]
pub struct Tracer {
    kernel: Arc<Kernel>,
    options: TraceOptions,
    accel: AccelTraversal,
}

/// `opt` as the device can run it with `accel`: no double-precision fallback without
/// shaderFloat64 (the `exact` kernel variants also load BVH nodes as 64-bit words, so they
/// need shaderInt64 too; every device we know with one has the other), nor through the
/// driver's ray query (its intersector is its own).
pub fn effective_options(ctx: &Context, opt: &TraceOptions, accel: AccelTraversal) -> TraceOptions {
    let f = &ctx.info().features;
    let cap = ctx.info().max_traversal_steps;
    TraceOptions {
        exact: opt.exact && f.shader_float64 && f.shader_int64 && accel != AccelTraversal::RayQuery,
        max_steps: Some(opt.max_steps.map_or(cap, |m| m.clamp(1, cap))),
        ..*opt
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct TracePush {
    n: u32,
    time: f32,
}

impl Tracer {
    /// The tracer for `opt`; `opt.exact` is honoured only where the device has doubles
    /// (see [`Tracer::options`]).
    pub fn new(ctx: &Context, opt: &TraceOptions) -> Result<Self> {
        Self::for_accel(ctx, opt, AccelTraversal::KdTree)
    }

    /// The tracer for geometry holding `accel`'s structure, walked its way, reading nodes
    /// the device's way ([`NodeAccess::for_device`]).
    pub fn for_accel(ctx: &Context, opt: &TraceOptions, accel: AccelTraversal) -> Result<Self> {
        Self::for_accel_reading(ctx, opt, accel, NodeAccess::for_device(ctx))
    }

    /// [`Tracer::for_accel`], reading the nodes as `nodes` says.
    pub fn for_accel_reading(
        ctx: &Context,
        opt: &TraceOptions,
        accel: AccelTraversal,
        nodes: NodeAccess,
    ) -> Result<Self> {
        accel.require(ctx)?;
        let opt = effective_options(ctx, opt, accel);
        let spec = traversal_spec(ctx, &opt)
            .u32(20, accel.spec())
            .workgroup(WORKGROUP);
        let blob = accel.variant(
            opt.exact,
            nodes,
            [
                &kernels::RENDER_TRACE_EXACT,
                &kernels::RENDER_TRACE_FLOAT,
                &kernels::RENDER_TRACE_QUERY,
                &kernels::RENDER_TRACE_EXACT_TEXEL,
                &kernels::RENDER_TRACE_FLOAT_TEXEL,
            ],
        );
        Ok(Self {
            kernel: ctx.kernel(blob, &accel.spec_for(spec, blob))?,
            options: opt,
            accel,
        })
    }

    /// The options this tracer really runs with (its CPU twin must use the same).
    pub fn options(&self) -> TraceOptions {
        self.options
    }

    /// Records the trace of `n` rays into `hits`; the first word of `errors` counts rays that
    /// ran out of steps. Each is a range of a device buffer: vkrt's [`Buffer`]s, or ranges of
    /// the caller's own ([`RawBuffer`](crate::gpu::RawBuffer), with `STORAGE_BUFFER` usage,
    /// offsets a multiple of `minStorageBufferOffsetAlignment`), rays as [`Ray`] (32 bytes)
    /// and hits as [`Hit`]. The caller orders the writes of the inputs before. `n` above the
    /// rays or hits the ranges hold, a counter range under 4 bytes, or a structure this
    /// tracer's walk does not serve, is an error (nothing is recorded).
    ///
    /// Synchronization ([`crate::accel::sync::RecordSync::TRACE`]): compute-shader reads of
    /// the structure and rays and writes of the hits and counter, first and last, with no
    /// barrier of its own; it leaves its compute pipeline, descriptor set 0 and push
    /// constants bound at the compute bind point.
    #[allow(
        clippy::too_many_arguments,
        reason = "buffers of the dispatch, one by one"
    )]
    pub fn record(
        &self,
        rec: &mut Recorder,
        geom: &GpuGeometry,
        rays: &dyn BufferArg,
        hits: &dyn BufferArg,
        errors: &dyn BufferArg,
        n: usize,
        time: f32,
    ) -> Result<()> {
        let refuse = |reason: String| {
            Err(GpuError::Usage {
                call: "Tracer::record",
                reason,
            })
        };
        if !self.accel.walks(&geom.accel) {
            return Err(GpuError::KindMismatch {
                call: "Tracer::record",
                built: format!(
                    "{}{}",
                    geom.accel.kind().name(),
                    if geom.accel.is_wide() {
                        " with wide nodes"
                    } else {
                        ""
                    }
                ),
                expected: format!("{} tracer", self.accel.label()),
            });
        }
        geom.check_bottoms("Tracer::record")?;
        if geom.device_input.as_ref().is_some_and(|d| !d.built) {
            return Err(GpuError::NotBuilt {
                call: "Tracer::record",
            });
        }
        let ray_room = rays.range() / std::mem::size_of::<Ray>() as u64;
        let hit_room = hits.range() / std::mem::size_of::<Hit>() as u64;
        if n as u64 > ray_room || n as u64 > hit_room {
            return refuse(format!(
                "{n} rays, but the ray range holds {ray_room} and the hit range {hit_room}"
            ));
        }
        if errors.range() < 4 {
            return refuse("the error counter range holds no 32-bit word".into());
        }
        if n > u32::MAX as usize {
            return refuse(format!("{n} rays in one dispatch (at most {})", u32::MAX));
        }
        if n == 0 {
            return Ok(());
        }
        let g = geom.bindings();
        let b: [&dyn BufferArg; 10] =
            [rays, hits, g[0], g[1], g[2], g[3], g[4], g[5], g[6], errors];
        // The dispatch's own range rules (offsets, limits), checked before anything is
        // recorded rather than failing the recording.
        rec.check_bindings(&self.kernel, &b).or_else(refuse)?;
        let groups = rec.groups_1d(n as u64, WORKGROUP);
        rec.dispatch(&self.kernel, groups, &b, &TracePush { n: n as u32, time });
        rec.check()
    }

    /// Uploads `rays`, traces them at `time` and reads the hits back, in one submission. The
    /// profile has one scope, `trace`, around the kernel alone.
    pub fn trace(
        &self,
        ctx: &Context,
        geom: &GpuGeometry,
        rays: &[Ray],
        time: f32,
    ) -> Result<TraceBatch> {
        let ray_buf = Buffer::new(ctx, "trace.rays", rays.len())?;
        let hits = Buffer::<Hit>::new(ctx, "trace.hits", rays.len())?;
        let errors = Buffer::<u32>::new(ctx, "trace.errors", 1)?;
        let mut rec = Recorder::new(ctx)?;
        rec.upload(&ray_buf, rays)?;
        rec.fill(&errors, 0);
        rec.transfer_to_compute();
        rec.scope("trace", |rec| {
            self.record(rec, geom, &ray_buf, &hits, &errors, rays.len(), time)
        })?;
        rec.compute_to_transfer();
        let hits_back = rec.read_back(&hits)?;
        let errors_back = rec.read_back(&errors)?;
        rec.transfer_to_host();
        let profile = rec.submit_and_wait()?;
        Ok(TraceBatch {
            hits: hits_back.read()?,
            exhausted: errors_back.read()?[0],
            profile,
        })
    }
}

impl Tracer {
    /// The most rays one [`Tracer::trace`] call takes on this device: the ray buffer
    /// (32 bytes per ray) must fit `maxStorageBufferRange` (128 MiB = 4,194,304 rays on
    /// lavapipe).
    pub fn max_batch(ctx: &Context) -> usize {
        let limit = ctx.info().max_storage_buffer_range / std::mem::size_of::<Ray>() as u64;
        limit.min(u64::from(u32::MAX)) as usize
    }

    /// [`Tracer::trace`] over any number of rays, in batches of at most `batch` rays
    /// (`None`: [`Tracer::max_batch`]). The profile has one `trace` scope per batch; their
    /// sum (`profile.ms("trace")`) is the kernel time.
    pub fn trace_batched(
        &self,
        ctx: &Context,
        geom: &GpuGeometry,
        rays: &[Ray],
        time: f32,
        batch: Option<usize>,
    ) -> Result<TraceBatch> {
        let max = Self::max_batch(ctx).max(1);
        let batch = batch.unwrap_or(max).clamp(1, max);
        let mut out = TraceBatch {
            hits: Vec::with_capacity(rays.len()),
            exhausted: 0,
            profile: Profile::default(),
        };
        for chunk in rays.chunks(batch) {
            let b = self.trace(ctx, geom, chunk, time)?;
            out.hits.extend_from_slice(&b.hits);
            out.exhausted += b.exhausted;
            out.profile.append(b.profile);
        }
        Ok(out)
    }
}

/// Builds the kd-tree of `g` on the GPU (Kolodzey's builder over the primitives' boxes).
pub fn build_kdtree(
    ctx: &Context,
    g: &TraceGeometry,
    params: &crate::accel::kdtree::SahParams,
) -> Result<(KdTree, Profile)> {
    crate::accel::kdtree::gpu::KdTreeBuilder::new(ctx)?.build_boxes(ctx, &g.boxes, params)
}

/// What [`build_and_trace`] did.
pub struct DeviceTrace {
    /// The hits of every ray; its profile holds the build's passes too.
    pub batch: TraceBatch,
    /// The geometry and structure, still on the device.
    pub geometry: GpuGeometry,
    /// Build time: the GPU passes of a device builder (from timestamps), or the host
    /// builder's wall time.
    pub build_ms: f64,
    /// Queue submissions and bytes read back from the start of the build until the hits
    /// were on the host (the hits and the build report included).
    pub traffic: Traffic,
    /// Bytes read back between the build and the trace: 0, by construction.
    pub readback_before_trace: u64,
    /// 1, or more when a kd-tree build ran out of its reference budget and was redone with
    /// twice the budget.
    pub attempts: u32,
}

/// Uploads `g`, builds `builder`'s structure over it and traces the first batch of `rays`
/// at `time` in one submission, with nothing read back in between; further batches (at
/// most `batch` rays each) are one submission each against the structure where it lies.
pub fn build_and_trace(
    ctx: &Context,
    builder: &AccelBuilder,
    tracer: &Tracer,
    g: &TraceGeometry,
    rays: &[Ray],
    time: f32,
    batch: Option<usize>,
) -> Result<DeviceTrace> {
    let start = ctx.traffic();
    let max = Tracer::max_batch(ctx).max(1);
    let batch = batch.unwrap_or(max).clamp(1, max);
    let first = &rays[..batch.min(rays.len())];
    for grow in 0..8 {
        let mut rec = Recorder::new(ctx)?;
        let ray_buf = Buffer::new(ctx, "trace.rays", first.len())?;
        let hits = Buffer::<Hit>::new(ctx, "trace.hits", first.len())?;
        let errors = Buffer::<u32>::new(ctx, "trace.errors", 1)?;
        rec.upload(&ray_buf, first)?;
        rec.fill(&errors, 0);
        // (the upload's transfer → compute barrier covers the two writes above)
        let (geometry, recorded) = GpuGeometry::record_build(&mut rec, builder, g, grow)?;
        let readback_before_trace = ctx.traffic().readback_bytes - start.readback_bytes;
        rec.scope("trace", |rec| {
            tracer.record(rec, &geometry, &ray_buf, &hits, &errors, first.len(), time)
        })?;
        rec.compute_to_transfer();
        let built = geometry.accel.record_read_built(&mut rec)?;
        let hits_back = rec.read_back(&hits)?;
        let errors_back = rec.read_back(&errors)?;
        rec.transfer_to_host();
        let profile = rec.submit_and_wait()?;
        if let Some(b) = built {
            let b = AccelStructure::kd_built(&b.read()?);
            if b.overflow {
                continue;
            }
        }
        let build_ms = recorded.ms(&profile);
        let mut out = TraceBatch {
            hits: hits_back.read()?,
            exhausted: errors_back.read()?[0],
            profile,
        };
        if rays.len() > first.len() {
            let rest =
                tracer.trace_batched(ctx, &geometry, &rays[first.len()..], time, Some(batch))?;
            out.hits.extend_from_slice(&rest.hits);
            out.exhausted += rest.exhausted;
            out.profile.append(rest.profile);
        }
        return Ok(DeviceTrace {
            batch: out,
            geometry,
            build_ms,
            traffic: ctx.traffic() - start,
            readback_before_trace,
            attempts: grow + 1,
        });
    }
    Err(GpuError::Kernel {
        kernel: "accel.kdtree",
        reason: format!(
            "the kd-tree of {} primitives still ran out of references after 8 doublings of \
             its budget",
            g.primitive_count()
        ),
    })
}
