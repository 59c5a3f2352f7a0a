//! A scene traced as two levels: each mesh whose geometry another mesh repeats
//! ([`Scene::mesh_groups`]) becomes one bottom-level structure, object space, with one
//! instance per mesh placed by that mesh's transform (as does a moving mesh named once); the
//! static meshes named once and the spheres stay together in one more bottom level (world
//! space, an identity instance). The top
//! level is an LBVH over the instances ([`crate::accel::instances`]); rays go through
//! `vkrt/ray_query.glsl` at device addresses (`render.trace_instances`), and hits come back
//! with the scene's primitive ids, as the flat scene's ([`TraceGeometry::at_time`]) would.
//!
//! t agrees with the flat scene's to about 1e-6 relative, not bit for bit: the flat scene's
//! vertices are moved to the world and rounded there, the two-level walk moves the ray into
//! object space and rounds there (measured within 1e-6 relative in `tests/instances.rs`).

use glam::{Vec3, Vec4};

use crate::accel::device::{AccelBuilder, AccelChoice, AccelKind};
use crate::accel::embedded::BuildFlags;
use crate::accel::instances::{Instance, TopLevel, TopLevelBuilder};
use std::sync::Arc;

use crate::gpu::{
    kernels, Buffer, BufferArg, Context, GpuError, Kernel, Recorder, Result, ShaderBlob, Spec,
};
use crate::scene::Scene;
use crate::trace::bvh_cpu::Traversal;
use crate::trace::gpu::{effective_options, AccelTraversal, GpuGeometry, TraceBatch, Tracer};
use crate::trace::{Hit, Intersector, Query, Ray, TraceGeometry, TraceOptions};

/// The custom index of the instance of the rest (meshes named once, spheres).
pub const REST: u32 = 0x00ff_ffff;
const WORKGROUP: u32 = 64;

/// A scene split into bottom levels and the instances that place them.
pub struct TwoLevelScene {
    /// Per bottom level its geometry: a repeated mesh in object space, or the rest in the
    /// world (last, when there is any).
    pub bottoms: Vec<TraceGeometry>,
    /// One per repeated mesh (custom index: the mesh's index in the scene), then the
    /// rest's identity instance (custom index 0xffffff).
    pub instances: Vec<Instance>,
    /// Per mesh: its first primitive id in the scene's flat order.
    pub mesh_first: Vec<u32>,
    /// Per primitive of the rest's bottom level: its id in the scene.
    pub rest_ids: Vec<u32>,
    /// Primitives the structures hold (every repeated mesh once).
    pub unique_primitives: usize,
}

impl TwoLevelScene {
    /// The scene at `time` as two levels, or `None` when no mesh repeats another (the flat
    /// structure is then the whole story). Meshes with motion are placed at `time`.
    pub fn of(scene: &Scene, time: f32) -> Option<Self> {
        let groups = scene.mesh_groups();
        if groups.iter().all(|g| g.len() < 2) {
            return None;
        }
        let mut mesh_first = Vec::with_capacity(scene.meshes.len());
        let mut at = 0u32;
        for m in &scene.meshes {
            mesh_first.push(at);
            at += m.indices.len() as u32;
        }
        let n_tris = at;
        let mut bottoms = Vec::new();
        let mut instances = Vec::new();
        let mut rest_tris = Vec::new();
        let mut rest_ids = Vec::new();
        for g in &groups {
            let mesh = &scene.meshes[g[0]];
            // A mesh named once stays in the world (the rest) unless it moves: then it is
            // placed by an instance too, so that its motion changes one transform.
            let moves = !mesh.motion.is_static() || !mesh.keyframes.is_empty();
            if g.len() < 2 && !moves {
                let mesh = &scene.meshes[g[0]];
                let m = mesh.world_matrix(time);
                for (k, &[a, b, c]) in mesh.indices.iter().enumerate() {
                    let p = |i: u32| m.transform_point3(mesh.positions[i as usize]);
                    rest_tris.push([p(a), p(b), p(c)]);
                    rest_ids.push(mesh_first[g[0]] + k as u32);
                }
                continue;
            }
            let mesh = &scene.meshes[g[0]];
            let tris: Vec<[Vec3; 3]> = mesh
                .indices
                .iter()
                .map(|t| t.map(|i| mesh.positions[i as usize]))
                .collect();
            let level = bottoms.len() as u32;
            bottoms.push(TraceGeometry::from_triangles(&tris));
            for &k in g {
                let rows = Instance::rows_of(&scene.meshes[k].world_matrix(time));
                instances.push(Instance::new(level, rows).with_custom_index(k as u32));
            }
        }
        // The rest: its triangles (in scene order within it), then the spheres.
        let spheres: Vec<Vec4> = scene
            .spheres_at(time)
            .iter()
            .map(|s| s.center.extend(s.radius))
            .collect();
        for k in 0..spheres.len() {
            rest_ids.push(n_tris + k as u32);
        }
        if !rest_ids.is_empty() {
            let level = bottoms.len() as u32;
            bottoms.push(TraceGeometry::from_triangles_and_spheres(
                &rest_tris, &spheres,
            ));
            instances.push(Instance::new(level, Instance::IDENTITY).with_custom_index(REST));
        }
        let unique_primitives = bottoms.iter().map(TraceGeometry::primitive_count).sum();
        Some(Self {
            bottoms,
            instances,
            mesh_first,
            rest_ids,
            unique_primitives,
        })
    }

    /// Instances of repeated meshes (the rest's identity instance not counted).
    pub fn mesh_instances(&self) -> usize {
        self.instances
            .iter()
            .filter(|i| i.custom_index() != REST)
            .count()
    }
}

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
    let opt = effective_options(ctx, opt, choice.traversal());
    let before = ctx.memory().vkrt_bytes;
    let builder = AccelBuilder::for_choice(ctx, choice)?;
    let (levels, bottom_build_ms) = build_bottoms(ctx, &builder, &s.bottoms)?;
    let bottom_bytes = ctx.memory().vkrt_bytes.saturating_sub(before);
    let refs: Vec<&GpuGeometry> = levels.iter().collect();
    let top_builder = TopLevelBuilder::new(ctx, AccelKind::Lbvh)?;
    let mut rec = Recorder::new(ctx)?;
    let top = top_builder.record_build(&mut rec, &refs, &s.instances, &BuildFlags::default())?;
    let profile = rec.submit_and_wait()?;
    let top_build_ms = profile.ms("top level").unwrap_or(0.0);

    let bitstack = choice.traversal() == AccelTraversal::Bvh(Traversal::Bitstack);
    let batch = trace_top_level(
        ctx,
        &top,
        (&s.mesh_first, &s.rest_ids),
        &opt,
        bitstack,
        rays,
        time,
    )?;
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
    use crate::accel::device::{AccelStructure, DevicePrimitives};
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
    // The kernels bind the rest's primitives (its spheres are theirs to intersect).
    let bound = s
        .instances
        .iter()
        .find(|i| i.custom_index() == REST)
        .map_or(0, |i| i.bottom as usize);
    let refs: Vec<&DevicePrimitives> = prims.iter().collect();
    let (accel, ids) =
        AccelStructure::record_driver_instanced(&mut rec, &refs, &s.instances, bound, prefer)?;
    let profile = rec.submit_and_wait()?;
    let top_bytes = accel
        .driver_levels_ref()
        .flatten()
        .map_or(0, |a| a.top_bytes());
    let bytes = ctx.memory().vkrt_bytes.saturating_sub(before);
    let geom = GpuGeometry {
        prims: prims.swap_remove(bound),
        accel,
        device_input: None,
    };
    let batch = Tracer::for_accel(ctx, &opt, walk)?.trace_batched(ctx, &geom, rays, time, None)?;
    let hits = batch
        .hits
        .iter()
        .map(|h| {
            let scene_id = |(i, p): (u32, u32)| match s.instances[i as usize].custom_index() {
                REST => s.rest_ids.get(p as usize).copied(),
                k => s.mesh_first.get(k as usize).map(|f| f + p),
            };
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
/// primitive ids: an instance's custom index `k` names the mesh whose first id is
/// `ids.0[k]`, and the instance with custom index 0xffffff maps its primitives through
/// `ids.1`. `opt` as the device runs it ([`effective_options`]); `bitstack`: binary BVH
/// bottom levels walked with the bitstack walk (else each level's own).
pub fn trace_top_level(
    ctx: &Context,
    top: &TopLevel<'_>,
    (mesh_first, rest_ids): (&[u32], &[u32]),
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
    let mesh_first = Buffer::from_slice(ctx, "trace.mesh_first", &nonempty(mesh_first))?;
    let rest_ids = Buffer::from_slice(ctx, "trace.rest_ids", &nonempty(rest_ids))?;
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
            pad: [0; 3],
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
    trace_top_level(ctx, &top, (&[0], &[]), opt, bitstack, rays, 0.0)
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
    pad: [u32; 3],
}

/// Each bottom level built (a kd-tree grown until its references fit), and the builds'
/// milliseconds.
fn build_bottoms(
    ctx: &Context,
    builder: &AccelBuilder,
    bottoms: &[TraceGeometry],
) -> Result<(Vec<GpuGeometry>, f64)> {
    let mut levels = Vec::with_capacity(bottoms.len());
    let mut ms = 0.0;
    for g in bottoms {
        let (level, build_ms) = GpuGeometry::build_fitting(ctx, builder, g)?;
        levels.push(level);
        ms += build_ms;
    }
    Ok((levels, ms))
}
