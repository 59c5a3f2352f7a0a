//! A scene traced as two levels ([`TwoLevelScene`]: its repeated meshes as bottom levels
//! under one instance each, the rest in one more, or in pieces where no one device buffer
//! holds it; split in `crate::accel::two_levels`). The top level is an LBVH over the
//! instances ([`crate::accel::instances`]); rays go through `vkrt/ray_query.glsl` at device
//! addresses (`render.trace_instances`), and hits come back with the scene's primitive ids,
//! as the flat scene's ([`TraceGeometry::at_time`]) would; each build binds one piece while
//! the walk reaches every piece through the top level.
//!
//! t agrees with the flat scene's to about 1e-6 relative, not bit for bit: the flat scene's
//! vertices are moved to the world and rounded there, the two-level walk moves the ray into
//! object space and rounds there (measured within 1e-6 relative in `tests/instances.rs`).

use crate::accel::device::{AccelBuilder, AccelChoice, AccelKind};
use crate::accel::embedded::BuildFlags;
use crate::accel::geometry::transform_point;
use crate::accel::instances::{
    transform_direction, Instance, InstanceRecord, TopLevel, TopLevelBuilder,
};
use std::sync::Arc;

use crate::accel::gpu_geometry::GpuGeometry;
use crate::accel::primitives::TraceGeometry;
use crate::accel::two_levels::{SceneIds, TwoLevelScene, REST};
use crate::accel::walk::AccelTraversal;
use crate::accel::walk::Traversal;
use crate::gpu::{
    kernels, Buffer, BufferArg, Context, GpuError, Kernel, Recorder, Result, ShaderBlob, Spec,
};
use crate::trace::gpu::{effective_options, TraceBatch, Tracer};
use crate::trace::{Hit, Intersector, Query, Ray, TraceOptions};

const WORKGROUP: u32 = 64;

/// Bytes of a scene's two levels ([`level_bytes`]).
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct LevelBytes {
    /// Bottom-level structures (one per repeated mesh, plus the rest's).
    pub bottom_levels: usize,
    /// Instances of repeated meshes ([`TwoLevelScene::mesh_instances`]).
    pub instances: usize,
    /// Primitives the bottom levels hold ([`TwoLevelScene::unique_primitives`]).
    pub unique_primitives: usize,
    /// Device bytes of the bottom levels (primitives and structures).
    pub bottom_bytes: u64,
    /// Bytes of the top level ([`TopLevelBuilder::sizes_for`]).
    pub top_bytes: u64,
}

/// `s`'s bottom levels built with `choice`'s builder, and the bytes of both levels.
pub fn level_bytes(ctx: &Context, choice: AccelChoice, s: &TwoLevelScene) -> Result<LevelBytes> {
    let before = ctx.memory().vkrt_bytes;
    let builder = AccelBuilder::for_choice(ctx, choice)?;
    let (levels, _) = build_bottoms(ctx, &builder, &s.bottoms)?;
    let bottom_bytes = ctx.memory().vkrt_bytes.saturating_sub(before);
    drop(levels);
    let top = TopLevelBuilder::new(ctx, AccelKind::Lbvh)?.sizes_for(
        ctx,
        s.instances.len() as u32,
        s.bottoms.len(),
        &BuildFlags::default(),
    )?;
    Ok(LevelBytes {
        bottom_levels: s.bottoms.len(),
        instances: s.mesh_instances(),
        unique_primitives: s.unique_primitives,
        bottom_bytes,
        top_bytes: top.structure_bytes,
    })
}

/// What [`build_and_trace`] measured.
pub struct TwoLevelTrace {
    /// One hit per ray, with the scene's primitive ids.
    pub hits: Vec<Hit>,
    /// Rays whose walk ran out of steps (reported as misses).
    pub exhausted: u32,
    /// GPU ms of the bottom levels' builds (host ms for the SAH BVH's).
    pub bottom_build_ms: f64,
    /// GPU ms of the top level's build.
    pub top_build_ms: f64,
    /// GPU ms of the trace kernel.
    pub trace_ms: f64,
    /// Device bytes of the bottom levels (primitives and structures).
    pub bottom_bytes: u64,
    /// Device bytes of the top level.
    pub top_bytes: u64,
    /// The options the walk ran with (exactness as the device allows).
    pub options: TraceOptions,
}

/// Builds `s`'s bottom levels with `choice`'s builder and its top level (an LBVH), then
/// traces `rays` at `time`.
pub fn build_and_trace(
    ctx: &Context,
    choice: AccelChoice,
    opt: &TraceOptions,
    s: &TwoLevelScene,
    rays: &[Ray],
    time: f32,
) -> Result<TwoLevelTrace> {
    if choice.kind == AccelKind::Driver {
        return driver_build_and_trace(ctx, choice.prefer, opt, s, rays, time);
    }
    own_build_and_trace(ctx, choice, opt, s, &s.bottoms, rays, time)
}

/// [`build_and_trace`] of a scene it takes: each bottom level's host geometry is dropped
/// once its structure is on the device (the bottom levels are built one after another, each
/// in its own submission), so that a scene in pieces is never held twice.
pub fn build_and_trace_owned(
    ctx: &Context,
    choice: AccelChoice,
    opt: &TraceOptions,
    mut s: TwoLevelScene,
    rays: &[Ray],
    time: f32,
) -> Result<TwoLevelTrace> {
    if choice.kind == AccelKind::Driver {
        return driver_build_and_trace(ctx, choice.prefer, opt, &s, rays, time);
    }
    let bottoms = std::mem::take(&mut s.bottoms);
    own_build_and_trace(ctx, choice, opt, &s, bottoms, rays, time)
}

/// [`build_and_trace`] with vkrt's own structures, over `s`'s bottom levels `bottoms`
/// (borrowed, or taken and dropped one by one as they are built).
fn own_build_and_trace<G: std::borrow::Borrow<TraceGeometry>>(
    ctx: &Context,
    choice: AccelChoice,
    opt: &TraceOptions,
    s: &TwoLevelScene,
    bottoms: impl IntoIterator<Item = G>,
    rays: &[Ray],
    time: f32,
) -> Result<TwoLevelTrace> {
    let opt = effective_options(ctx, opt, choice.traversal());
    let before = ctx.memory().vkrt_bytes;
    let builder = AccelBuilder::for_choice(ctx, choice)?;
    let (levels, bottom_build_ms) = build_bottoms(ctx, &builder, bottoms)?;
    let bottom_bytes = ctx.memory().vkrt_bytes.saturating_sub(before);
    let refs: Vec<&GpuGeometry> = levels.iter().collect();
    let top_builder = TopLevelBuilder::new(ctx, AccelKind::Lbvh)?;
    let mut rec = Recorder::new(ctx)?;
    let top = top_builder.record_build(&mut rec, &refs, &s.instances, &BuildFlags::default())?;
    let profile = rec.submit_and_wait()?;
    let top_build_ms = profile.ms("top level").unwrap_or(0.0);

    let bitstack = choice.traversal() == AccelTraversal::Bvh(Traversal::Bitstack);
    let batch = trace_top_level(ctx, &top, s.ids(), &opt, bitstack, rays, time)?;
    Ok(TwoLevelTrace {
        trace_ms: batch.profile.ms("trace").unwrap_or(0.0),
        hits: batch.hits,
        exhausted: batch.exhausted,
        bottom_build_ms,
        top_build_ms,
        bottom_bytes,
        top_bytes: top.bytes(),
        options: opt,
    })
}

/// [`build_and_trace`] with the driver's own two levels (`VK_KHR_acceleration_structure`):
/// a bottom-level structure per level, a top-level instance per instance with its
/// transform, traced with the driver's ray query; the hits' ids mapped back to the scene's.
fn driver_build_and_trace(
    ctx: &Context,
    prefer: crate::accel::driver::Prefer,
    opt: &TraceOptions,
    s: &TwoLevelScene,
    rays: &[Ray],
    time: f32,
) -> Result<TwoLevelTrace> {
    use crate::accel::device::DevicePrimitives;
    let walk = AccelTraversal::RayQuery;
    let opt = effective_options(ctx, opt, walk);
    let before = ctx.memory().vkrt_bytes;
    if s.bottoms.is_empty() {
        return Err(GpuError::Usage {
            call: "two-level trace",
            reason: "a scene of two levels without a bottom level".into(),
        });
    }
    let mut rec = Recorder::new(ctx)?;
    let mut prims = Vec::with_capacity(s.bottoms.len());
    for g in &s.bottoms {
        prims.push(DevicePrimitives::record_upload(&mut rec, g)?);
    }
    // The kernels bind the primitives of the rest's piece that holds the spheres (they
    // are the kernels' to intersect), else of its first piece.
    let with_spheres: Vec<usize> = (0..s.bottoms.len())
        .filter(|&b| !s.bottoms[b].spheres.is_empty())
        .collect();
    if with_spheres.len() > 1 {
        return Err(GpuError::Usage {
            call: "two-level trace with the driver's structure",
            reason: format!(
                "the spheres lie in {} bottom levels; the driver's walk intersects one \
                 level's spheres",
                with_spheres.len()
            ),
        });
    }
    let bound = with_spheres.first().copied().unwrap_or_else(|| {
        s.instances
            .iter()
            .find(|i| i.custom_index() == REST)
            .map_or(0, |i| i.bottom as usize)
    });
    let refs: Vec<&DevicePrimitives> = prims.iter().collect();
    let (accel, ids) = crate::accel::driver_levels::record_instanced(
        &mut rec,
        &refs,
        &s.instances,
        bound,
        prefer,
    )?;
    let profile = rec.submit_and_wait()?;
    let top_bytes = crate::accel::driver_levels::levels(&accel).map_or(0, |a| a.top_bytes());
    let bytes = ctx.memory().vkrt_bytes.saturating_sub(before);
    let geom = GpuGeometry {
        prims: prims.swap_remove(bound),
        accel,
        device_input: None,
        life: Default::default(),
    };
    let batch = Tracer::for_accel(ctx, &opt, walk)?.trace_batched(ctx, &geom, rays, time, None)?;
    let hits = batch
        .hits
        .iter()
        .map(|h| {
            let scene_id =
                |(i, p): (u32, u32)| s.scene_id(s.instances[i as usize].custom_index(), p);
            match h.is_hit() {
                true => match ids.instance_primitive(h.prim).and_then(scene_id) {
                    Some(prim) => Hit { prim, ..*h },
                    None => Hit::MISS,
                },
                false => *h,
            }
        })
        .collect();
    Ok(TwoLevelTrace {
        trace_ms: batch.profile.ms("trace").unwrap_or(0.0),
        hits,
        exhausted: batch.exhausted,
        bottom_build_ms: profile.ms("driver_bottom_levels").unwrap_or(0.0),
        top_build_ms: profile.ms("driver_top_level").unwrap_or(0.0),
        bottom_bytes: bytes.saturating_sub(top_bytes),
        top_bytes,
        options: opt,
    })
}

/// Closest (or any, as `opt.query` says) hits of `rays` at `time` through top level `top`
/// (`render.trace_instances`, one `trace` scope per batch in the profile), with the scene's
/// primitive ids as `ids` names them. `opt` as the device runs it ([`effective_options`]);
/// `bitstack`: binary BVH bottom levels walked with the bitstack walk (else each level's
/// own).
pub fn trace_top_level(
    ctx: &Context,
    top: &TopLevel,
    ids: SceneIds<'_>,
    opt: &TraceOptions,
    bitstack: bool,
    rays: &[Ray],
    time: f32,
) -> Result<TraceBatch> {
    let variants = [
        &kernels::RENDER_TRACE_INSTANCES_MOLLER,
        &kernels::RENDER_TRACE_INSTANCES_EXACT,
        &kernels::RENDER_TRACE_INSTANCES_FLOAT,
        &kernels::RENDER_TRACE_INSTANCES_BITSTACK_MOLLER,
        &kernels::RENDER_TRACE_INSTANCES_BITSTACK_EXACT,
        &kernels::RENDER_TRACE_INSTANCES_BITSTACK_FLOAT,
    ];
    let kernel = library_kernel(ctx, opt, bitstack, variants, WORKGROUP)?;
    // The pieces' starts in `rest_ids` follow the meshes' first ids in one buffer.
    let firsts = [ids.mesh_first, ids.rest_first].concat();
    let mesh_first = Buffer::from_slice(ctx, "trace.mesh_first", &nonempty(&firsts))?;
    let rest_ids = Buffer::from_slice(ctx, "trace.rest_ids", &nonempty(ids.rest_ids))?;
    let handle = top.handle_address();
    let mut out = TraceBatch {
        hits: Vec::with_capacity(rays.len()),
        exhausted: 0,
        profile: Default::default(),
    };
    let batch = Tracer::max_batch(ctx).max(1);
    for chunk in rays.chunks(batch) {
        let ray_buf = Buffer::from_slice(ctx, "trace.rays", chunk)?;
        let hits = Buffer::<Hit>::new(ctx, "trace.hits", chunk.len())?;
        let errors = Buffer::<u32>::zeroed(ctx, "trace.errors", 1)?;
        let mut rec = Recorder::new(ctx)?;
        let push = TracePush {
            n: chunk.len() as u32,
            any_hit: u32::from(opt.query == Query::Any),
            handle,
            time,
            n_meshes: ids.mesh_first.len() as u32,
            n_pieces: ids.rest_first.len() as u32,
            pad: 0,
        };
        let groups = rec.groups_1d(chunk.len() as u64, WORKGROUP);
        let b: [&dyn BufferArg; 5] = [&ray_buf, &hits, &errors, &mesh_first, &rest_ids];
        rec.scope("trace", |rec| rec.dispatch(&kernel, groups, &b, &push));
        rec.compute_to_transfer();
        let hits_back = rec.read_back(&hits)?;
        let errors_back = rec.read_back(&errors)?;
        rec.transfer_to_host();
        out.profile.append(rec.submit_and_wait()?);
        out.hits.extend(hits_back.read()?);
        out.exhausted += errors_back.read()?[0];
    }
    Ok(out)
}

/// Closest (or any) hits of `rays` through `structure` placed by one identity instance
/// under a top level (an LBVH): the same answers as the structure traced alone, through
/// the two-level walk (the robustness suite's `under an instance` runs).
pub fn trace_under_identity(
    ctx: &Context,
    structure: &GpuGeometry,
    opt: &TraceOptions,
    bitstack: bool,
    rays: &[Ray],
) -> Result<TraceBatch> {
    let top = TopLevelBuilder::new(ctx, AccelKind::Lbvh)?.build(
        ctx,
        &[structure],
        &[Instance::new(0, Instance::IDENTITY)],
        &BuildFlags::default(),
    )?;
    let ids = SceneIds {
        mesh_first: &[0],
        ..SceneIds::default()
    };
    trace_top_level(ctx, &top, ids, opt, bitstack, rays, 0.0)
}

/// The variant of a kernel that walks two levels through `vkrt/ray_query.glsl` for `opt`
/// (as the device runs it) and the bottom levels' walk, specialized: `variants` are its
/// `moller`, `exact`, `float` variants, then their `bitstack_*` twins.
pub(crate) fn library_kernel(
    ctx: &Context,
    opt: &TraceOptions,
    bitstack: bool,
    variants: [&'static ShaderBlob; 6],
    workgroup: u32,
) -> Result<Arc<Kernel>> {
    let k = match (opt.intersector, opt.exact) {
        (Intersector::MollerTrumbore, _) => 0,
        (Intersector::Watertight, true) => 1,
        (Intersector::Watertight, false) => 2,
    };
    ctx.kernel(
        variants[k + 3 * usize::from(bitstack)],
        &library_spec(ctx, opt, workgroup),
    )
}

/// The specialization constants of a kernel that includes `vkrt/ray_query.glsl` with the
/// step cap as constant 22 and, in its exact variants, the division check as 21: `opt` as
/// the device runs it.
pub(crate) fn library_spec(ctx: &Context, opt: &TraceOptions, workgroup: u32) -> Spec {
    let cap = ctx.info().max_traversal_steps;
    let spec = Spec::new()
        .workgroup(workgroup)
        .u32(22, opt.max_steps.map_or(cap, |m| m.clamp(1, cap)));
    // (only the exact variants check the division)
    if opt.exact && opt.intersector == Intersector::Watertight {
        spec.u32(21, u32::from(!ctx.info().ieee_division))
    } else {
        spec
    }
}

fn nonempty(v: &[u32]) -> Vec<u32> {
    if v.is_empty() {
        vec![0]
    } else {
        v.to_vec()
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct TracePush {
    n: u32,
    any_hit: u32,
    handle: u64,
    time: f32,
    n_meshes: u32,
    n_pieces: u32,
    pad: u32,
}

/// Each bottom level built (a kd-tree grown until its references fit), and the builds'
/// milliseconds.
fn build_bottoms<G: std::borrow::Borrow<TraceGeometry>>(
    ctx: &Context,
    builder: &AccelBuilder,
    bottoms: impl IntoIterator<Item = G>,
) -> Result<(Vec<GpuGeometry>, f64)> {
    let mut levels = Vec::new();
    let mut ms = 0.0;
    for g in bottoms {
        // (a taken level's host geometry goes once its build is recorded)
        let (mut level, build_ms) = GpuGeometry::build_fitting_taking(ctx, builder, g)?;
        // Nothing refits a bottom level.
        level.prims.release_boxes()?;
        levels.push(level);
        ms += build_ms;
    }
    Ok((levels, ms))
}
/// The ray in an instance's object space, as the walk moves it: origin and direction by
/// `world_to_object` (the direction not renormalised, so `t` means the same), `tmin` kept,
/// `tmax` the closest hit so far.
pub fn object_ray(world_to_object: &[[f32; 4]; 3], r: &Ray, tmax: f32) -> Ray {
    let m = world_to_object;
    Ray::new(
        transform_point(m, r.o()),
        transform_direction(m, r.d()),
        r.tmin,
        tmax,
    )
}

/// A two-level query's answer: the hit (its `prim` the primitive id in the bottom level),
/// the instance hit, and whether a walk ran out of steps (the answer is then a miss).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InstanceHit {
    /// The closest hit ([`Hit::MISS`] for none); its `prim` is the bottom level's id.
    pub hit: Hit,
    /// Index of the instance hit (`None`: a miss).
    pub instance: Option<u32>,
    /// A bottom level's walk gave up: the answer is a miss.
    pub exhausted: bool,
}

/// The CPU twin of the two-level walk (`vkrt/instances.glsl`): the closest hit at `time`
/// over every instance the ray's cull mask sees (`steps`: the moving top level's, from
/// [`instance_boxes`](crate::accel::instances::instance_boxes)), each traced by
/// `bottom(level, object-space ray)` — the bottom level's own walk, returning its hit and
/// whether it gave up (`level`: [`InstanceRecord::bottom`], its index in the top level's
/// list; [`InstanceRecord::UNLISTED`] where it has none). Ties in `t` go to
/// the lowest instance index; an any-hit query returns the first hit in index order (the
/// device's may be another: any hit answers it).
pub fn trace_instances(
    records: &[InstanceRecord],
    steps: &[[[f32; 4]; 3]],
    r: &Ray,
    time: f32,
    cull_mask: u32,
    any_hit: bool,
    mut bottom: impl FnMut(u32, &Ray) -> (Hit, bool),
) -> InstanceHit {
    let mut best = InstanceHit {
        hit: Hit::MISS,
        instance: None,
        exhausted: false,
    };
    if !r.is_valid() {
        return best;
    }
    let mut best_t = r.tmax;
    for (i, rec) in records.iter().enumerate() {
        if rec.handle == 0 || rec.mask() & cull_mask == 0 {
            continue;
        }
        let Some(m) = rec.world_to_object_at(steps, time) else {
            continue;
        };
        let (h, exhausted) = bottom(rec.bottom(), &object_ray(&m, r, best_t));
        if exhausted {
            return InstanceHit {
                hit: Hit::MISS,
                instance: None,
                exhausted: true,
            };
        }
        if h.is_hit() && (best.instance.is_none() || h.t < best_t) {
            best_t = h.t;
            best.hit = h;
            best.instance = Some(i as u32);
            if any_hit {
                break;
            }
        }
    }
    best
}
