//! A scene split into two levels: each mesh whose geometry another mesh repeats
//! ([`Scene::mesh_groups`]) becomes one bottom-level structure, object space, with one
//! instance per mesh placed by that mesh's transform (as does a moving mesh named once); the
//! static meshes named once and the spheres stay together in one more bottom level (world
//! space, an identity instance). The walks over it are `crate::trace::instanced`'s, the
//! device's levels `crate::accel::instances`'.
//!
//! A scene whose primitives no one device buffer holds is split the same way with its rest
//! in pieces ([`TwoLevelScene::of_within`]): the rest's triangles in the order of a Morton
//! curve through their centroids, cut into bottom levels of at most what one buffer holds,
//! each under its own identity instance (custom index `REST - c` for piece `c`).

use glam::{Affine3A, Vec3, Vec4};

use crate::accel::device::AccelKind;
use crate::accel::instance::Instance;
use crate::accel::primitives::TraceGeometry;
use crate::gpu::Context;
use crate::scene::Scene;

/// The custom index of the instance of the rest (meshes named once, spheres); where the rest
/// is in pieces, piece `c`'s instance has `REST - c`.
pub const REST: u32 = 0x00ff_ffff;
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
