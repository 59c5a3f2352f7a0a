//! The GPU tracer: geometry and kd-tree uploaded once, ray batches traced by
//! `glsl/render/trace.comp` (closest or any hit, watertight or Möller–Trumbore, chosen by
//! specialization constants so each variant compiles only what it runs).

use std::sync::Arc;

use crate::accel::bvh::Bvh;
use crate::accel::device::{
    upload_structure, AccelBuilder, AccelStructure, DevicePrimitives, HostRef, RecordedBuild,
};
use crate::accel::kdtree::KdTree;
use crate::gpu::{kernels, ShaderBlob};
use crate::gpu::{
    Buffer, BufferArg, Context, GpuError, Kernel, Profile, Recorder, Result, Spec, Traffic,
};

use super::bvh_cpu::Traversal;
use super::geometry::TraceGeometry;
use super::{Hit, Query, Ray, TraceOptions};

const WORKGROUP: u32 = 64;

/// Which structure a [`GpuGeometry`] holds, and how a kernel walks it (the `ACCEL_KIND`
/// specialization constant of `traverse.glsl`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum AccelTraversal {
    /// A kd-tree (`ACCEL_KIND` 0).
    #[default]
    KdTree,
    /// A BVH, walked as the [`Traversal`] says.
    Bvh(Traversal),
    /// The driver's structure, through its ray query (the `query` kernel variants).
    RayQuery,
}

impl AccelTraversal {
    /// The `ACCEL_KIND` specialization constant (id 20) of kernels that trace.
    pub fn spec(self) -> u32 {
        match self {
            AccelTraversal::KdTree => 0,
            AccelTraversal::Bvh(Traversal::Stack) => 1,
            AccelTraversal::Bvh(Traversal::Bitstack) => 2,
            AccelTraversal::RayQuery => 3,
            AccelTraversal::Bvh(Traversal::Wide) => 4,
        }
    }

    /// Every structure and walk, for suites and benchmarks.
    pub const ALL: [AccelTraversal; 4] = [
        AccelTraversal::KdTree,
        AccelTraversal::Bvh(Traversal::Stack),
        AccelTraversal::Bvh(Traversal::Bitstack),
        AccelTraversal::Bvh(Traversal::Wide),
    ];

    /// `kdtree`, `sah-bvh/stack`, `sah-bvh/bitstack` or `sah-bvh/wide`.
    pub fn label(self) -> &'static str {
        match self {
            AccelTraversal::KdTree => "kdtree",
            AccelTraversal::Bvh(Traversal::Stack) => "sah-bvh/stack",
            AccelTraversal::Bvh(Traversal::Bitstack) => "sah-bvh/bitstack",
            AccelTraversal::Bvh(Traversal::Wide) => "sah-bvh/wide",
            AccelTraversal::RayQuery => "driver",
        }
    }

    /// `Ok` where the device can run this walk: the driver's needs its ray query (else the
    /// error naming the extensions; its kernels cannot even be created without it).
    pub fn require(self, ctx: &Context) -> Result<()> {
        match self {
            AccelTraversal::RayQuery => crate::gpu::require_ray_query(ctx),
            _ => Ok(()),
        }
    }

    /// Whether this walk serves `s`: its kind's family, and the wide walk exactly the
    /// structures built with wide nodes (they bind those in place of the binary ones).
    pub fn walks(self, s: &AccelStructure) -> bool {
        s.kind().walked(Traversal::default()).family() == self.family()
            && (self == AccelTraversal::Bvh(Traversal::Wide)) == s.is_wide()
    }

    fn family(self) -> u32 {
        match self {
            AccelTraversal::KdTree => 0,
            AccelTraversal::Bvh(_) => 1,
            AccelTraversal::RayQuery => 2,
        }
    }

    /// The kernel variant (of `render.trace`, `render.extend`, `render.shadow`: `[exact,
    /// float, query, exact_texel, float_texel]`) this walk runs: `query` for the driver's,
    /// else `exact` or `float`, reading nodes as `nodes` says.
    pub fn variant(
        self,
        exact: bool,
        nodes: NodeAccess,
        [exact_blob, float, query, exact_texel, float_texel]: [&'static ShaderBlob; 5],
    ) -> &'static ShaderBlob {
        match (self, exact, nodes) {
            (AccelTraversal::RayQuery, _, _) => query,
            (_, true, NodeAccess::Storage) => exact_blob,
            (_, false, NodeAccess::Storage) => float,
            (_, true, NodeAccess::Texel) => exact_texel,
            (_, false, NodeAccess::Texel) => float_texel,
        }
    }

    /// `spec` for `blob`, this walk's variant: the `query` variants take fewer constants.
    pub fn spec_for(self, spec: Spec, blob: &ShaderBlob) -> Spec {
        match self {
            AccelTraversal::RayQuery => spec.declared_in(blob),
            _ => spec,
        }
    }
}

/// How the walks read the structure's nodes: both give the same hits bit for bit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum NodeAccess {
    /// As a storage buffer (on Mesa < 25.1's lavapipe: a loop over the lanes with a bounds
    /// check each, for every load at a divergent offset).
    Storage,
    /// Through a uniform texel buffer (RGBA32UI texels), the sampler path: on lavapipe a
    /// branch-free gather.
    Texel,
}

impl NodeAccess {
    /// The device's: texel buffers wherever a view holds as many bytes as a storage binding
    /// (`maxTexelBufferElements` × 16 ≥ `maxStorageBufferRange`, so every structure that
    /// can be bound can be viewed), else storage buffers. `VKRT_NODE_ACCESS=storage` or
    /// `texel` overrides it (for measuring one against the other).
    pub fn for_device(ctx: &Context) -> Self {
        match std::env::var("VKRT_NODE_ACCESS").as_deref() {
            Ok("storage") => return NodeAccess::Storage,
            Ok("texel") => return NodeAccess::Texel,
            _ => {}
        }
        let info = ctx.info();
        if u64::from(info.max_texel_buffer_elements) * 16 >= info.max_storage_buffer_range {
            NodeAccess::Texel
        } else {
            NodeAccess::Storage
        }
    }

    /// `storage` or `texel`.
    pub fn name(self) -> &'static str {
        match self {
            NodeAccess::Storage => "storage",
            NodeAccess::Texel => "texel",
        }
    }
}

/// Primitives and a structure over them in device memory: the seven buffers
/// `traverse.glsl` binds.
pub struct GpuGeometry {
    /// The primitives on the device.
    pub prims: DevicePrimitives,
    /// The structure over them on the device.
    pub accel: AccelStructure,
    /// For a structure over the caller's device geometry
    /// ([`AccelBuilder::create_in`](crate::accel::device::AccelBuilder::create_in)): its
    /// layout and build flags, which every build and update into it must match.
    pub(crate) device_input: Option<crate::accel::embedded::DeviceInput>,
}

impl GpuGeometry {
    /// Geometry and a kd-tree built on the host (or downloaded).
    pub fn upload(ctx: &Context, g: &TraceGeometry, tree: &KdTree) -> Result<Self> {
        Self::with_host(ctx, g, HostRef::KdTree(tree))
    }

    /// Geometry and a BVH built over `g`'s boxes on the host.
    pub fn upload_bvh(ctx: &Context, g: &TraceGeometry, bvh: &Bvh) -> Result<Self> {
        Self::with_host(ctx, g, HostRef::Bvh(bvh))
    }

    /// [`GpuGeometry::upload_bvh`] with the BVH's wide nodes, for the wide walk.
    pub fn upload_wide_bvh(ctx: &Context, g: &TraceGeometry, bvh: &Bvh) -> Result<Self> {
        Self::with_host(ctx, g, HostRef::WideBvh(bvh))
    }

    /// Records the upload of `g` and the build of `builder`'s structure over it into `rec`
    /// (in a profiler scope named `build`), ending with the barrier that lets the next
    /// kernels trace it. `grow`: see [`AccelBuilder::sizes`]. Keep the returned geometry
    /// until the work has executed: its buffers are the ones the recorded commands write.
    pub fn record_build(
        rec: &mut Recorder,
        builder: &AccelBuilder,
        g: &TraceGeometry,
        grow: u32,
    ) -> Result<(Self, RecordedBuild)> {
        let prims = DevicePrimitives::record_upload(rec, g)?;
        let (mut accel, scratch) = builder.create(rec.context(), prims.count(), grow)?;
        let recorded = rec.scope("build", |rec| {
            builder.record_build(rec, &prims, g, &scratch, &mut accel)
        })?;
        // The scratch is freed when this returns, before the work runs: keep it alive.
        rec.keep_alive(scratch);
        Ok((
            Self {
                prims,
                accel,
                device_input: None,
            },
            recorded,
        ))
    }

    /// One build of `builder`'s structure over `g`, submitted and waited for, redone with
    /// twice the kd-tree's reference budget while it runs out (as `vkrt trace` does); the
    /// successful build's milliseconds ([`RecordedBuild::ms`]).
    pub fn build_fitting(
        ctx: &Context,
        builder: &AccelBuilder,
        g: &TraceGeometry,
    ) -> Result<(Self, f64)> {
        for grow in 0..8 {
            let mut rec = Recorder::new(ctx)?;
            let (geom, recorded) = Self::record_build(&mut rec, builder, g, grow)?;
            rec.compute_to_transfer();
            let built = geom.accel.record_read_built(&mut rec)?;
            rec.transfer_to_host();
            let profile = rec.submit_and_wait()?;
            if let Some(b) = built {
                if AccelStructure::kd_built(&b.read()?).overflow {
                    continue;
                }
            }
            return Ok((geom, recorded.ms(&profile)));
        }
        Err(GpuError::Kernel {
            kernel: "accel.kdtree",
            reason: format!(
                "the kd-tree of {} primitives still ran out of references after 8 doublings \
                 of its budget",
                g.primitive_count()
            ),
        })
    }

    fn with_host(ctx: &Context, g: &TraceGeometry, host: HostRef<'_>) -> Result<Self> {
        let prims = DevicePrimitives::upload(ctx, g)?;
        let accel = upload_structure(ctx, &prims, host)?;
        Ok(Self {
            prims,
            accel,
            device_input: None,
        })
    }

    /// The structure's handle for a shader that reads it at device addresses
    /// (`VKRT_DEVICE_ADDRESS` in `vkrt/ray_query.glsl`): the addresses of its seven arrays,
    /// in the bindings' order, 56 bytes the caller writes where the shader reads them and
    /// passes to `vkrtUseStructure`. An error where the context has no
    /// `bufferDeviceAddress`.
    pub fn address_handle(&self) -> Result<[u64; 7]> {
        let ctx = self.prims.tri_verts.context();
        let b = self.bindings();
        let mut out = [0u64; 7];
        for (o, b) in out.iter_mut().zip(b) {
            *o = crate::gpu::address_of(ctx, b)?;
        }
        Ok(out)
    }

    /// The seven bindings in `traverse.glsl`'s order.
    pub fn bindings(&self) -> [&dyn BufferArg; 7] {
        let [nodes, refs] = self.accel.node_bindings();
        let p = &self.prims;
        [
            nodes,
            refs,
            &p.tri_verts,
            &p.spheres,
            &p.prim_motion,
            &p.motions,
            &self.accel.info,
        ]
    }
}

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

    /// Records the trace of `n` rays into `hits` (both device buffers); `errors[0]` counts
    /// rays that ran out of steps. The caller orders the writes of the inputs before. `n`
    /// above the rays or hits the buffers hold, or a structure this tracer's walk does not
    /// serve, is an error (nothing is recorded).
    #[allow(
        clippy::too_many_arguments,
        reason = "buffers of the dispatch, one by one"
    )]
    pub fn record(
        &self,
        rec: &mut Recorder,
        geom: &GpuGeometry,
        rays: &Buffer<Ray>,
        hits: &Buffer<Hit>,
        errors: &Buffer<u32>,
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
            return refuse(format!(
                "a {} tracer cannot walk a {} structure{}",
                self.accel.label(),
                geom.accel.kind().name(),
                if geom.accel.is_wide() {
                    " built with wide nodes"
                } else {
                    ""
                }
            ));
        }
        if geom.device_input.as_ref().is_some_and(|d| !d.built) {
            return refuse("the structure has not been built: record its build first".into());
        }
        if n > rays.len() || n > hits.len() {
            return refuse(format!(
                "{n} rays, but the ray buffer holds {} and the hit buffer {}",
                rays.len(),
                hits.len()
            ));
        }
        if errors.is_empty() {
            return refuse("the error counter buffer is empty".into());
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
