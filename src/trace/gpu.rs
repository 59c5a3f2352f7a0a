//! The GPU tracer: geometry and kd-tree uploaded once, ray batches traced by
//! `glsl/render/trace.comp` (closest or any hit, watertight or Möller–Trumbore, chosen by
//! specialization constants so each variant compiles only what it runs).

use std::sync::Arc;

use crate::accel::bvh::Bvh;
use crate::accel::kdtree::KdTree;
use crate::gpu::kernels;
use crate::gpu::{Buffer, BufferArg, Context, Kernel, Profile, Recorder, Result, Spec};

use super::bvh_cpu::Traversal;
use super::geometry::{MotionRecord, SceneInfo, TraceGeometry};
use super::{Hit, Query, Ray, TraceOptions};

const WORKGROUP: u32 = 64;

/// Which structure a [`GpuGeometry`] holds, and how a kernel walks it (the `ACCEL_KIND`
/// specialization constant of `traverse.glsl`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum AccelTraversal {
    #[default]
    KdTree,
    Bvh(Traversal),
}

impl AccelTraversal {
    /// The `ACCEL_KIND` specialization constant (id 20) of kernels that trace.
    pub fn spec(self) -> u32 {
        match self {
            AccelTraversal::KdTree => 0,
            AccelTraversal::Bvh(Traversal::Stack) => 1,
            AccelTraversal::Bvh(Traversal::Bitstack) => 2,
        }
    }

    fn is_bvh(self) -> bool {
        matches!(self, AccelTraversal::Bvh(_))
    }
}

/// Geometry and tree in device memory: the seven buffers `traverse.glsl` binds, in order.
/// `nodes` holds `KdNode`s or `BvhNode`s as words; a BVH's `prim_refs` are its references
/// followed by its parent links.
pub struct GpuGeometry {
    pub nodes: Buffer<u32>,
    /// Whether `nodes` is a BVH (else a kd-tree).
    pub is_bvh: bool,
    pub prim_refs: Buffer<u32>,
    pub tri_verts: Buffer<f32>,
    pub spheres: Buffer<[f32; 4]>,
    pub prim_motion: Buffer<u32>,
    pub motions: Buffer<MotionRecord>,
    pub info: Buffer<SceneInfo>,
    pub primitives: usize,
}

impl GpuGeometry {
    pub fn upload(ctx: &Context, g: &TraceGeometry, tree: &KdTree) -> Result<Self> {
        let info = g.info(&tree.bounds);
        Self::with_structure(ctx, g, words(&tree.nodes), &tree.prim_refs, info, false)
    }

    /// Geometry and a BVH built over `g`'s boxes.
    pub fn upload_bvh(ctx: &Context, g: &TraceGeometry, bvh: &Bvh) -> Result<Self> {
        let mut refs = bvh.refs.clone();
        refs.extend_from_slice(&bvh.parents);
        let info = SceneInfo {
            parents_at: bvh.refs.len() as u32,
            ..g.info(&bvh.bounds)
        };
        Self::with_structure(ctx, g, words(&bvh.nodes), &refs, info, true)
    }

    fn with_structure(
        ctx: &Context,
        g: &TraceGeometry,
        nodes: &[u32],
        refs: &[u32],
        info: SceneInfo,
        is_bvh: bool,
    ) -> Result<Self> {
        Ok(Self {
            nodes: Buffer::from_slice(ctx, "trace.nodes", nodes)?,
            is_bvh,
            prim_refs: Buffer::from_slice(ctx, "trace.prim_refs", refs)?,
            tri_verts: Buffer::from_slice(ctx, "trace.tri_verts", &g.tri_verts)?,
            spheres: Buffer::from_slice(ctx, "trace.spheres", &g.spheres)?,
            prim_motion: Buffer::from_slice(ctx, "trace.prim_motion", &g.prim_motion)?,
            motions: Buffer::from_slice(ctx, "trace.motions", &g.motions)?,
            info: Buffer::from_slice(ctx, "trace.info", &[info])?,
            primitives: g.primitive_count(),
        })
    }

    /// The seven bindings in `traverse.glsl`'s order.
    pub fn bindings(&self) -> [&dyn BufferArg; 7] {
        [
            &self.nodes,
            &self.prim_refs,
            &self.tri_verts,
            &self.spheres,
            &self.prim_motion,
            &self.motions,
            &self.info,
        ]
    }
}

/// Nodes as the 32-bit words a storage buffer of either layout binds.
fn words<T: bytemuck::Pod>(nodes: &[T]) -> &[u32] {
    bytemuck::cast_slice(nodes)
}

/// Spec constant ids shared by every kernel that includes `traverse.glsl`.
pub fn traversal_spec(opt: &TraceOptions) -> Spec {
    Spec::new()
        .u32(1, opt.intersector.spec())
        .u32(2, (opt.query == Query::Any) as u32)
        .u32(3, opt.stack_size.max(1))
}

/// Result of a batch.
pub struct TraceBatch {
    pub hits: Vec<Hit>,
    /// Rays that ran out of traversal steps (reported as misses).
    pub exhausted: u32,
    pub profile: Profile,
}

pub struct Tracer {
    kernel: Arc<Kernel>,
    options: TraceOptions,
    accel: AccelTraversal,
}

/// `opt` as the device can run it: no double-precision fallback without shaderFloat64.
pub fn effective_options(ctx: &Context, opt: &TraceOptions) -> TraceOptions {
    TraceOptions {
        exact: opt.exact && ctx.info().features.shader_float64,
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

    /// The tracer for geometry holding `accel`'s structure, walked its way.
    pub fn for_accel(ctx: &Context, opt: &TraceOptions, accel: AccelTraversal) -> Result<Self> {
        let opt = effective_options(ctx, opt);
        let spec = traversal_spec(&opt)
            .u32(20, accel.spec())
            .workgroup(WORKGROUP);
        let blob = if opt.exact {
            &kernels::RENDER_TRACE_EXACT
        } else {
            &kernels::RENDER_TRACE_FLOAT
        };
        Ok(Self {
            kernel: ctx.kernel(blob, &spec)?,
            options: opt,
            accel,
        })
    }

    /// The options this tracer really runs with (its CPU twin must use the same).
    pub fn options(&self) -> TraceOptions {
        self.options
    }

    /// Records the trace of `n` rays into `hits` (both device buffers); `errors[0]` counts
    /// rays that ran out of steps. The caller orders the writes of the inputs before.
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
    ) {
        if n == 0 {
            return;
        }
        assert_eq!(
            geom.is_bvh,
            self.accel.is_bvh(),
            "a {:?} tracer cannot walk this geometry's structure",
            self.accel
        );
        let g = geom.bindings();
        let b: [&dyn BufferArg; 10] =
            [rays, hits, g[0], g[1], g[2], g[3], g[4], g[5], g[6], errors];
        let groups = rec.groups_1d(n as u64, WORKGROUP);
        rec.dispatch(&self.kernel, groups, &b, &TracePush { n: n as u32, time });
    }

    /// Uploads `rays`, traces them at `time`, waits and reads the hits back. The profile has
    /// one scope, `trace`, around the kernel alone.
    pub fn trace(
        &self,
        ctx: &Context,
        geom: &GpuGeometry,
        rays: &[Ray],
        time: f32,
    ) -> Result<TraceBatch> {
        let ray_buf = Buffer::from_slice(ctx, "trace.rays", rays)?;
        let hits = Buffer::<Hit>::new(ctx, "trace.hits", rays.len())?;
        let errors = Buffer::<u32>::zeroed(ctx, "trace.errors", 1)?;
        let mut rec = Recorder::new(ctx)?;
        rec.scope("trace", |rec| {
            self.record(rec, geom, &ray_buf, &hits, &errors, rays.len(), time)
        });
        rec.compute_to_transfer();
        let profile = rec.submit_and_wait()?;
        Ok(TraceBatch {
            hits: hits.download()?,
            exhausted: errors.download()?[0],
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

/// Builds the kd-tree of `g` on the GPU (seed 001's builder over the primitives' boxes).
pub fn build_kdtree(
    ctx: &Context,
    g: &TraceGeometry,
    params: &crate::accel::kdtree::SahParams,
) -> Result<(KdTree, Profile)> {
    crate::accel::kdtree::gpu::KdTreeBuilder::new(ctx)?.build_boxes(ctx, &g.boxes, params)
}
