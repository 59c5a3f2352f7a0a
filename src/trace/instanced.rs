//! A scene traced as two levels: each mesh whose geometry another mesh repeats
//! ([`Scene::mesh_groups`]) becomes one bottom-level structure, object space, with one
//! instance per mesh placed by that mesh's transform (as does a moving mesh named once); the
//! static meshes named once and the spheres stay together in one more bottom level (world
//! space, an identity instance). The top
//! level is an LBVH over the instances ([`crate::accel::instances`]); rays go through
//! `vkrt/ray_query.glsl` at device addresses (`render.trace_instances`), and hits come back
//! with the scene's primitive ids, as the flat scene's ([`TraceGeometry::at_time`]) would.
//!
//! A scene whose primitives no one device buffer holds (a 10 M-triangle mesh needs 640 MB of
//! binary BVH nodes; lavapipe binds 128 MiB) is traced the same way with its rest in pieces
//! ([`TwoLevelScene::of_within`]): the rest's triangles in the order of a Morton curve
//! through their centroids, cut into bottom levels of at most what one buffer holds, each
//! under its own identity instance (custom index `REST - c` for piece `c`), so that each
//! build binds one piece while the walk reaches every piece through the top level.
//!
//! t agrees with the flat scene's to about 1e-6 relative, not bit for bit: the flat scene's
//! vertices are moved to the world and rounded there, the two-level walk moves the ray into
//! object space and rounds there (measured within 1e-6 relative in `tests/instances.rs`).

use glam::{Affine3A, Vec3, Vec4};

use crate::accel::device::{AccelBuilder, AccelChoice, AccelKind};
use crate::accel::embedded::BuildFlags;
use crate::accel::geometry::transform_point;
use crate::accel::instances::{
    transform_direction, Instance, InstanceRecord, TopLevel, TopLevelBuilder,
};
use std::sync::Arc;

use crate::accel::gpu_geometry::GpuGeometry;
use crate::accel::primitives::TraceGeometry;
use crate::accel::walk::AccelTraversal;
use crate::accel::walk::Traversal;
use crate::gpu::{
    kernels, Buffer, BufferArg, Context, GpuError, Kernel, Recorder, Result, ShaderBlob, Spec,
};
use crate::scene::Scene;
use crate::trace::gpu::{effective_options, TraceBatch, Tracer};
use crate::trace::{Hit, Intersector, Query, Ray, TraceOptions};

/// The custom index of the instance of the rest (meshes named once, spheres); where the rest
/// is in pieces, piece `c`'s instance has `REST - c`.
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
    /// Per primitive of the rest's bottom levels (piece after piece): its id in the scene.
    pub rest_ids: Vec<u32>,
    /// Per piece of the rest (the instance with custom index `REST - c` places piece `c`):
    /// where its primitives' entries start in `rest_ids`. Empty where there is no rest.
    pub rest_first: Vec<u32>,
    /// Primitives the structures hold (every repeated mesh once).
    pub unique_primitives: usize,
}

impl TwoLevelScene {
    /// The scene at `time` as two levels, or `None` when no mesh repeats another (the flat
    /// structure is then the whole story). Meshes with motion are placed at `time`.
    pub fn of(scene: &Scene, time: f32) -> Option<Self> {
        Self::of_within(scene, time, usize::MAX)
    }

    /// As [`TwoLevelScene::of`], with no bottom level of the rest above `max_per_level`
    /// primitives: a rest that is larger (where no mesh repeats too: the whole scene) is cut
    /// into pieces along a Morton curve, each its own bottom level. `None` where no mesh
    /// repeats and the scene fits one level.
    pub fn of_within(scene: &Scene, time: f32, max_per_level: usize) -> Option<Self> {
        Self::build(scene, time, max_per_level, false)
    }

    /// As [`TwoLevelScene::of_within`], for a scene whose motion is followed over time (a
    /// renderer's shutter, an animation's frames): each moving sphere too is placed by an
    /// instance of its own, of a bottom level holding one sphere of its radius at the origin
    /// (one per radius), so that its motion changes one transform. Such an instance's custom
    /// index names a piece of the rest (`REST - c`) whose one primitive is the sphere.
    pub fn of_moving(scene: &Scene, time: f32, max_per_level: usize) -> Option<Self> {
        Self::build(scene, time, max_per_level, true)
    }

    fn build(
        scene: &Scene,
        time: f32,
        max_per_level: usize,
        sphere_instances: bool,
    ) -> Option<Self> {
        let groups = scene.mesh_groups();
        let repeats = groups.iter().any(|g| g.len() >= 2);
        let total = scene.triangle_count() + scene.spheres.len();
        if !repeats && total <= max_per_level {
            return None;
        }
        let mut mesh_first = Vec::with_capacity(scene.meshes.len());
        let mut at = 0u32;
        for m in &scene.meshes {
            mesh_first.push(at);
            at += m.indices.len() as u32;
        }
        let n_tris = at;
        // A mesh named once stays in the world (the rest) unless it moves: then it is placed
        // by an instance too, so that its motion changes one transform.
        let in_rest = |g: &[usize]| {
            let mesh = &scene.meshes[g[0]];
            g.len() < 2 && mesh.motion.is_static() && mesh.keyframes.is_empty()
        };
        let rest_triangles: usize = groups
            .iter()
            .filter(|g| in_rest(g))
            .map(|g| scene.meshes[g[0]].indices.len())
            .sum();
        let mut bottoms = Vec::new();
        let mut instances = Vec::new();
        let mut rest_ids = Vec::with_capacity(rest_triangles + scene.spheres.len());
        for g in &groups {
            if in_rest(g) {
                let first = mesh_first[g[0]];
                rest_ids.extend((0..scene.meshes[g[0]].indices.len() as u32).map(|k| first + k));
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
        // The rest's triangles in the world, by scene id: made where a piece needs them (a
        // copy of the whole rest is never held).
        let matrices: Vec<Affine3A> = scene.meshes.iter().map(|m| m.world_matrix(time)).collect();
        let world = |id: u32| {
            let k = mesh_first.partition_point(|&f| f <= id) - 1;
            let mesh = &scene.meshes[k];
            let [a, b, c] = mesh.indices[(id - mesh_first[k]) as usize];
            let p = |i: u32| matrices[k].transform_point3(mesh.positions[i as usize]);
            [p(a), p(b), p(c)]
        };
        // The rest: its triangles (in scene order within it), then the spheres (the still
        // ones, where moving ones are placed by instances); in pieces where it is larger than
        // one level may be.
        let placed = scene.spheres_at(time);
        let moves = |k: usize| sphere_instances && !scene.spheres[k].motion.is_static();
        let mut spheres: Vec<Vec4> = Vec::with_capacity(placed.len());
        for (k, s) in placed.iter().enumerate().filter(|&(k, _)| !moves(k)) {
            spheres.push(s.center.extend(s.radius));
            rest_ids.push(n_tris + k as u32);
        }
        let mut rest_first = Vec::new();
        let max = max_per_level.max(1);
        if rest_ids.len() > max {
            let ids = &mut rest_ids[..rest_triangles];
            let order = morton_order(ids.len(), |k| world(ids[k]));
            let sorted: Vec<u32> = order.iter().map(|&k| ids[k as usize]).collect();
            drop(order);
            ids.copy_from_slice(&sorted);
        }
        let mut start = 0;
        while start < rest_ids.len() {
            let end = (start + max).min(rest_ids.len());
            // Triangles first, then the spheres, as in the scene's order of ids.
            let tris: Vec<[Vec3; 3]> = rest_ids[start.min(rest_triangles)..end.min(rest_triangles)]
                .iter()
                .map(|&id| world(id))
                .collect();
            let balls =
                &spheres[start.saturating_sub(rest_triangles)..end.saturating_sub(rest_triangles)];
            let level = bottoms.len() as u32;
            let piece = rest_first.len() as u32;
            bottoms.push(TraceGeometry::from_triangles_and_spheres(&tris, balls));
            instances
                .push(Instance::new(level, Instance::IDENTITY).with_custom_index(REST - piece));
            rest_first.push(start as u32);
            start = end;
        }
        // Moving spheres: one bottom level per radius, an instance per sphere at its centre.
        let mut by_radius: Vec<(u32, u32)> = Vec::new();
        for (k, s) in placed.iter().enumerate().filter(|&(k, _)| moves(k)) {
            let level = match by_radius.iter().find(|(r, _)| *r == s.radius.to_bits()) {
                Some(&(_, level)) => level,
                None => {
                    let level = bottoms.len() as u32;
                    let ball = [Vec3::ZERO.extend(s.radius)];
                    bottoms.push(TraceGeometry::from_triangles_and_spheres(&[], &ball));
                    by_radius.push((s.radius.to_bits(), level));
                    level
                }
            };
            let piece = rest_first.len() as u32;
            let rows = Instance::rows_of(&glam::Affine3A::from_translation(s.center));
            instances.push(Instance::new(level, rows).with_custom_index(REST - piece));
            rest_first.push(rest_ids.len() as u32);
            rest_ids.push(n_tris + k as u32);
        }
        let unique_primitives = bottoms.iter().map(TraceGeometry::primitive_count).sum();
        Some(Self {
            bottoms,
            instances,
            mesh_first,
            rest_ids,
            rest_first,
            unique_primitives,
        })
    }

    /// Whether an instance's custom index names a piece of the rest (else a mesh).
    pub fn is_rest(&self, custom_index: u32) -> bool {
        custom_index <= REST && ((REST - custom_index) as usize) < self.rest_first.len()
    }

    /// The scene's id of primitive `prim` of the instance whose custom index is
    /// `custom_index`.
    pub fn scene_id(&self, custom_index: u32, prim: u32) -> Option<u32> {
        if self.is_rest(custom_index) {
            let first = self.rest_first[(REST - custom_index) as usize];
            self.rest_ids.get((first + prim) as usize).copied()
        } else {
            self.mesh_first.get(custom_index as usize).map(|f| f + prim)
        }
    }

    /// How the two-level walk's hits name the scene's primitives.
    pub fn ids(&self) -> SceneIds<'_> {
        SceneIds {
            mesh_first: &self.mesh_first,
            rest_first: &self.rest_first,
            rest_ids: &self.rest_ids,
        }
    }

    /// The scene ids of the primitives of the rest's piece that the instance with
    /// `custom_index` places (`None`: it places a mesh).
    pub fn piece_ids(&self, custom_index: u32) -> Option<&[u32]> {
        if !self.is_rest(custom_index) {
            return None;
        }
        let c = (REST - custom_index) as usize;
        let first = self.rest_first[c] as usize;
        let end = self
            .rest_first
            .get(c + 1)
            .map_or(self.rest_ids.len(), |&e| e as usize);
        Some(&self.rest_ids[first..end])
    }

    /// Instances of repeated meshes (the rest's identity instances not counted).
    pub fn mesh_instances(&self) -> usize {
        self.instances
            .iter()
            .filter(|i| !self.is_rest(i.custom_index()))
            .count()
    }
}

/// The most primitives one bottom level of `kind` holds on `ctx`'s device, so that its
/// largest buffer stays within `maxStorageBufferRange`: a binary BVH's nodes (2n − 1 of 32
/// bytes, 64 bytes a primitive; 2.1 M primitives on lavapipe's 128 MiB); a kd-tree's
/// references of a level (16 bytes each, up to 2.4 per primitive measured on a random soup:
/// 128 bytes a primitive are kept).
pub fn max_level_primitives(ctx: &Context, kind: AccelKind) -> usize {
    let per_primitive = match kind {
        AccelKind::KdTree => 128,
        _ => 64,
    };
    (ctx.info().max_storage_buffer_range / per_primitive) as usize
}

/// How a two-level walk's hits name the scene's primitives: an instance's custom index `k`
/// names mesh `k` (its primitives' ids start at `mesh_first[k]`) or, as `REST - c`, piece
/// `c` of the rest (its primitives' ids are `rest_ids[rest_first[c]..]`).
#[derive(Clone, Copy, Default)]
pub struct SceneIds<'a> {
    /// Per mesh: its first primitive id in the scene.
    pub mesh_first: &'a [u32],
    /// Per piece of the rest: where its entries start in `rest_ids`.
    pub rest_first: &'a [u32],
    /// Per primitive of the rest's pieces, piece after piece: its id in the scene.
    pub rest_ids: &'a [u32],
}

/// Indices of triangles `0..n` (`tri(k)`: triangle k) ordered along a Morton curve (Z-order,
/// 10 bits per axis) through their centroids in the box of all of them, equal codes in index
/// order: consecutive runs are compact in space, so pieces cut from the order overlap little
/// (as an LBVH's leaves, Karras 2012).
fn morton_order(n: usize, tri: impl Fn(usize) -> [Vec3; 3]) -> Vec<u32> {
    let centroid = |t: &[Vec3; 3]| (t[0] + t[1] + t[2]) / 3.0;
    let (lo, hi) = (0..n).fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), k| {
            let c = centroid(&tri(k));
            (lo.min(c), hi.max(c))
        },
    );
    let scale = (hi - lo).max(Vec3::splat(f32::MIN_POSITIVE)).recip() * 1023.0;
    let spread = |v: u32| {
        let mut x = v & 0x3ff;
        x = (x | (x << 16)) & 0x0300_00ff;
        x = (x | (x << 8)) & 0x0300_f00f;
        x = (x | (x << 4)) & 0x030c_30c3;
        (x | (x << 2)) & 0x0924_9249
    };
    let code = |t: &[Vec3; 3]| {
        // (a NaN centroid, from a degenerate triangle, lands at 0)
        let q = ((centroid(t) - lo) * scale).clamp(Vec3::ZERO, Vec3::splat(1023.0));
        (spread(q.x as u32) << 2) | (spread(q.y as u32) << 1) | spread(q.z as u32)
    };
    // (code, index) pairs in one word each: sorted, the order of a stable sort by code
    let mut keyed: Vec<u64> = (0..n)
        .map(|k| (u64::from(code(&tri(k))) << 32) | k as u64)
        .collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|w| w as u32).collect()
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
    let (accel, ids) = crate::accel::driver::instanced::record_instanced(
        &mut rec,
        &refs,
        &s.instances,
        bound,
        prefer,
    )?;
    let profile = rec.submit_and_wait()?;
    let top_bytes = crate::accel::driver::instanced::levels(&accel).map_or(0, |a| a.top_bytes());
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
    top: &TopLevel<'_>,
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
/// whether it gave up. Ties in `t` go to
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
