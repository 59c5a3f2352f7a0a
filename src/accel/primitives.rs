//! The scene flattened for traversal, laid out as `glsl/include/vkrt/traverse.glsl` reads it:
//! triangle vertices (9 floats each), spheres (centre, radius), a motion slot per primitive
//! and the motions, plus every primitive's box for the kd-tree builder.
//!
//! Static geometry is placed at one time and stored in world space. When motion blur is
//! wanted, moving primitives keep their position at time 0 and a motion slot; the traversal
//! moves them to the ray's time, and their boxes are swept over the shutter interval.

use bytemuck::{Pod, Zeroable};
use glam::{Vec3, Vec4};

use crate::gpu::{Context, GpuError};
use crate::scene::{swept_points, Aabb, Motion, Scene};

/// Motion slot of a primitive that does not move.
pub const NO_MOTION: u32 = u32::MAX;

/// One rigid motion: 48 bytes, `VkrtMotionRecord` in `traverse.glsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct MotionRecord {
    /// xyz: velocity; w: angular speed in radians per second.
    pub velocity: [f32; 4],
    /// xyz: a point on the rotation axis.
    pub center: [f32; 4],
    /// xyz: unit rotation axis.
    pub axis: [f32; 4],
}

impl MotionRecord {
    /// The record of motion `m` (an orbit about a zero axis, or none, rotates nothing).
    pub fn new(m: &Motion) -> Self {
        let (center, axis, rate) = match m.orbit {
            Some(o) if o.axis.normalize_or_zero() != Vec3::ZERO => (
                o.center,
                o.axis.normalize(),
                o.degrees_per_second.to_radians(),
            ),
            _ => (Vec3::ZERO, Vec3::Z, 0.0),
        };
        Self {
            velocity: m.velocity.extend(rate).to_array(),
            center: center.extend(0.0).to_array(),
            axis: axis.extend(0.0).to_array(),
        }
    }

    /// `move_point` in `traverse.glsl`: rotate about the axis, then translate.
    pub fn move_point(&self, p: Vec3, time: f32) -> Vec3 {
        let angle = self.velocity[3] * time;
        let mut q = p;
        if angle != 0.0 {
            let k = Vec3::from_slice(&self.axis[..3]);
            let c0 = Vec3::from_slice(&self.center[..3]);
            let r = p - c0;
            let (s, c) = angle.sin_cos();
            let kr = Vec3::new(
                k.y * r.z - r.y * k.z,
                k.z * r.x - r.z * k.x,
                k.x * r.y - r.x * k.y,
            );
            let kd = k.x * r.x + k.y * r.y + k.z * r.z;
            q = r * c + kr * s + k * (kd * (1.0 - c)) + c0;
        }
        q + Vec3::from_slice(&self.velocity[..3]) * time
    }
}

/// Scene constants: 64 bytes, `SceneInfoBuf` in `traverse.glsl` (where a table of
/// `(first primitive id, geometry index)` pairs may follow, [`SceneInfo::n_geometries`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct SceneInfo {
    /// xyz: the minimum corner of the structure's root box (zeros for an empty box).
    pub bounds_min: [f32; 4],
    /// xyz: the maximum corner of the structure's root box (zeros for an empty box).
    pub bounds_max: [f32; 4],
    /// Triangles; their ids come first.
    pub n_tris: u32,
    /// Spheres, after the triangles in id order.
    pub n_spheres: u32,
    /// 1 when primitives move (the motion slots are bound), 0 otherwise.
    pub has_motion: u32,
    /// BVH: where the parent links start in the references buffer (0 for a kd-tree).
    pub parents_at: u32,
    /// How the shader library walks it (`ACCEL_*` in `traverse.glsl`): 0 kd-tree, 1 BVH,
    /// 3 the driver's ray query, 4 a BVH's wide nodes, 8 a top level over instances.
    pub walk: u32,
    /// Entries of the geometry table that follows (0: one geometry, ids are its indices).
    pub n_geometries: u32,
    /// Primitives `accel.geometry_gather` could not read from the caller's data.
    pub invalid: u32,
    /// Axis-aligned box primitives, after the spheres in id order.
    pub n_aabbs: u32,
}

impl SceneInfo {
    /// `ACCEL_*` of `traverse.glsl`: how the shader library walks a structure.
    pub const WALK_KDTREE: u32 = 0;
    /// A binary BVH, walked with a stack.
    pub const WALK_BVH: u32 = 1;
    /// The driver's structure, walked by `VK_KHR_ray_query`.
    pub const WALK_RAY_QUERY: u32 = 3;
    /// A BVH with 4-wide nodes in the nodes binding.
    pub const WALK_BVH_WIDE: u32 = 4;
    /// A top level: a BVH over instances' boxes, whose leaves name instances of bottom
    /// levels (`vkrt/instances.glsl`).
    pub const WALK_INSTANCES: u32 = 8;

    /// These constants, walked as `walk`.
    pub fn walked(self, walk: u32) -> Self {
        Self { walk, ..self }
    }

    /// The constants of a structure with root box `bounds` (an empty box is stored as zeros)
    /// over `[n_tris, n_spheres, n_aabbs]` primitives; `parents_at`: see the field.
    pub fn new(
        bounds: &Aabb,
        [n_tris, n_spheres, n_aabbs]: [usize; 3],
        has_motion: bool,
        parents_at: u32,
    ) -> Self {
        let (min, max) = if bounds.is_empty() {
            (Vec3::ZERO, Vec3::ZERO)
        } else {
            (bounds.min, bounds.max)
        };
        Self {
            bounds_min: min.extend(0.0).to_array(),
            bounds_max: max.extend(0.0).to_array(),
            n_tris: n_tris as u32,
            n_spheres: n_spheres as u32,
            has_motion: has_motion as u32,
            parents_at,
            walk: 0,
            n_geometries: 0,
            invalid: 0,
            n_aabbs: n_aabbs as u32,
        }
    }
}

/// Geometry ready to upload and trace. Primitive ids: triangles first, then spheres, then
/// axis-aligned boxes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TraceGeometry {
    /// 9 floats per triangle.
    pub tri_verts: Vec<f32>,
    /// Centre and radius per sphere.
    pub spheres: Vec<[f32; 4]>,
    /// Axis-aligned box primitives (`VK_GEOMETRY_TYPE_AABBS_KHR`): hit where the ray enters
    /// the box (or leaves it, from inside), unless a shader supplies its own intersection.
    /// They never move. One with `min > max` on an axis is never hit.
    pub aabbs: Vec<Aabb>,
    /// Motion slot per primitive ([`NO_MOTION`] if static); empty when nothing moves.
    pub prim_motion: Vec<u32>,
    /// The motions the slots of `prim_motion` index.
    pub motions: Vec<MotionRecord>,
    /// Box of every primitive (swept over the time interval when moving).
    pub boxes: Vec<Aabb>,
}

impl TraceGeometry {
    /// Static triangles. Zero-area ones (a cross product of exactly zero: collinear or
    /// repeated vertices) keep their id and box but get NaN vertices, which no intersector
    /// ever hits (the watertight test's rounding could otherwise "hit" a collinear triangle).
    pub fn from_triangles(tris: &[[Vec3; 3]]) -> Self {
        Self::from_triangles_and_spheres(tris, &[])
    }

    /// Static triangles and spheres (centre, radius).
    pub fn from_triangles_and_spheres(tris: &[[Vec3; 3]], spheres: &[Vec4]) -> Self {
        // (sized exactly: a piece of a large scene holds millions)
        let mut tri_verts = Vec::with_capacity(9 * tris.len());
        tri_verts.extend(tris.iter().flat_map(|t| {
            unhittable_if_degenerate(*t)
                .into_iter()
                .flat_map(|p| p.to_array())
        }));
        let mut boxes = Vec::with_capacity(tris.len() + spheres.len());
        boxes.extend(tris.iter().map(prim_box));
        let mut g = Self {
            tri_verts,
            spheres: Vec::with_capacity(spheres.len()),
            boxes,
            ..Self::default()
        };
        for s in spheres {
            g.spheres.push(s.to_array());
            g.boxes.push(sphere_box(s.truncate(), s.w));
        }
        g
    }

    /// Refuses, before any host work, a scene whose flattened triangles cannot fit one of
    /// `ctx`'s storage buffers (`trace.tri_verts`, 36 bytes a triangle): flattened, a mesh
    /// named many times holds every copy (a grid of 1,024 bunnies is 71 M triangles, 2.5 GB),
    /// which its two levels never do.
    pub fn check_flat_fits(ctx: &Context, scene: &Scene) -> Result<(), GpuError> {
        let bytes = 36 * scene.triangle_count() as u64;
        let limit = ctx.info().max_storage_buffer_range;
        if bytes > limit {
            return Err(GpuError::BufferTooLarge {
                name: "trace.tri_verts".into(),
                bytes,
                limit,
            });
        }
        Ok(())
    }

    /// The scene at one instant `time`, everything static.
    pub fn at_time(scene: &Scene, time: f32) -> Self {
        let spheres: Vec<Vec4> = scene
            .spheres_at(time)
            .iter()
            .map(|s| s.center.extend(s.radius))
            .collect();
        Self::from_triangles_and_spheres(&scene.triangles_world(time), &spheres)
    }

    /// The scene over the shutter interval `[t0, t1]`: static primitives placed at `t0`,
    /// moving ones at time 0 with a motion slot (the traversal moves them to the ray time).
    /// Keyframed meshes are placed by their keys at `t0` for the whole interval.
    pub fn over_interval(scene: &Scene, t0: f32, t1: f32) -> Self {
        let mut g = Self::at_time(scene, t0);
        let mut any = false;
        let n_tris = scene.triangle_count();
        let mut prim_motion = vec![NO_MOTION; n_tris + scene.spheres.len()];
        let mut first = 0usize;
        for mesh in &scene.meshes {
            let count = mesh.indices.len();
            if !mesh.motion.is_static() && count > 0 {
                any = true;
                let slot = g.motions.len() as u32;
                g.motions.push(MotionRecord::new(&mesh.motion));
                // Keyframes hold their pose at `t0` (see `scene::animation`).
                let m = mesh.placement(t0);
                for (k, tri) in mesh.indices.iter().enumerate() {
                    let i = first + k;
                    let pts = tri.map(|v| m.transform_point3(mesh.positions[v as usize]));
                    for (c, p) in unhittable_if_degenerate(pts).iter().enumerate() {
                        g.tri_verts[9 * i + 3 * c..9 * i + 3 * c + 3]
                            .copy_from_slice(&p.to_array());
                    }
                    g.boxes[i] = swept_points(&pts, &mesh.motion, t0, t1);
                    prim_motion[i] = slot;
                }
            }
            first += count;
        }
        for (k, s) in scene.spheres.iter().enumerate() {
            if !s.motion.is_static() {
                any = true;
                prim_motion[n_tris + k] = g.motions.len() as u32;
                g.motions.push(MotionRecord::new(&s.motion));
                g.spheres[k] = s.center.extend(s.radius).to_array();
                let c = swept_points(&[s.center], &s.motion, t0, t1);
                g.boxes[n_tris + k] = Aabb {
                    min: c.min - Vec3::splat(s.radius),
                    max: c.max + Vec3::splat(s.radius),
                };
            }
        }
        if any {
            g.prim_motion = prim_motion;
        }
        g
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.tri_verts.len() / 9
    }

    /// Number of primitives: triangles, spheres and boxes.
    pub fn primitive_count(&self) -> usize {
        self.triangle_count() + self.spheres.len() + self.aabbs.len()
    }

    /// [`TraceGeometry::from_triangles_and_spheres`] and axis-aligned boxes after them (an
    /// empty box — `min > max` — is stored as it is and never hit; its bounding box for the
    /// builders is the point at the origin).
    pub fn from_primitives(tris: &[[Vec3; 3]], spheres: &[Vec4], aabbs: &[Aabb]) -> Self {
        let mut g = Self::from_triangles_and_spheres(tris, spheres);
        for b in aabbs {
            g.aabbs.push(*b);
            g.boxes.push(if b.min.cmple(b.max).all() {
                *b
            } else {
                Aabb {
                    min: Vec3::ZERO,
                    max: Vec3::ZERO,
                }
            });
        }
        g
    }

    /// The spheres buffer as the walk reads it: the spheres, then two `vec4`s per
    /// axis-aligned box (min, 0 and max, 0).
    pub fn sphere_words(&self) -> Vec<[f32; 4]> {
        let mut w = self.spheres.clone();
        for b in &self.aabbs {
            w.push(b.min.extend(0.0).to_array());
            w.push(b.max.extend(0.0).to_array());
        }
        w
    }

    /// Whether any primitive moves (has a motion slot).
    pub fn has_motion(&self) -> bool {
        !self.prim_motion.is_empty()
    }

    /// The scene constants for a tree with root box `bounds`.
    pub fn info(&self, bounds: &Aabb) -> SceneInfo {
        SceneInfo::new(
            bounds,
            [self.triangle_count(), self.spheres.len(), self.aabbs.len()],
            self.has_motion(),
            0,
        )
    }

    /// Triangle `i`'s vertices at `time`.
    pub fn triangle_at(&self, i: usize, time: f32) -> [Vec3; 3] {
        let v = |c: usize| Vec3::from_slice(&self.tri_verts[9 * i + 3 * c..9 * i + 3 * c + 3]);
        let mut p = [v(0), v(1), v(2)];
        if let Some(&slot) = self.prim_motion.get(i) {
            if slot != NO_MOTION {
                let m = &self.motions[slot as usize];
                p = p.map(|q| m.move_point(q, time));
            }
        }
        p
    }

    /// Sphere `i` (centre, radius) at `time`.
    pub fn sphere_at(&self, i: usize, time: f32) -> Vec4 {
        let mut s = Vec4::from_array(self.spheres[i]);
        if let Some(&slot) = self.prim_motion.get(self.triangle_count() + i) {
            if slot != NO_MOTION {
                let c = self.motions[slot as usize].move_point(s.truncate(), time);
                s = c.extend(s.w);
            }
        }
        s
    }
}

/// NaN vertices for a triangle of zero area (see [`TraceGeometry::from_triangles`]).
pub fn unhittable_if_degenerate(t: [Vec3; 3]) -> [Vec3; 3] {
    if (t[1] - t[0]).cross(t[2] - t[0]) == Vec3::ZERO {
        [Vec3::NAN; 3]
    } else {
        t
    }
}

/// The box of a sphere, rounded outwards (`c ± r` rounds to nearest).
pub fn sphere_box(c: Vec3, r: f32) -> Aabb {
    Aabb {
        min: (c - Vec3::splat(r)).to_array().map(next_down).into(),
        max: (c + Vec3::splat(r)).to_array().map(next_up).into(),
    }
}

/// The next float towards +inf, never a subnormal: a GPU may flush subnormals to zero, so
/// rounding outwards steps over them (above zero and the subnormals is `f32::MIN_POSITIVE`,
/// above `-f32::MIN_POSITIVE` is `-0.0`). Otherwise `f32::next_up` (stable only since Rust
/// 1.86; MSRV 1.85).
pub fn next_up(x: f32) -> f32 {
    if x.is_nan() || x == f32::INFINITY {
        return x;
    }
    if x.abs() < f32::MIN_POSITIVE {
        return f32::MIN_POSITIVE;
    }
    if x == -f32::MIN_POSITIVE {
        return -0.0;
    }
    let b = x.to_bits();
    f32::from_bits(if x > 0.0 { b + 1 } else { b - 1 })
}

/// The next float towards -inf (`f32::next_down`).
pub fn next_down(x: f32) -> f32 {
    -next_up(-x)
}

/// min with -0.0 below +0.0 (`f32::min` leaves that case open); the GLSL twin is
/// `fmin_total` in `glsl/include/vkrt/kdtree.glsl`.
pub fn fmin(a: f32, b: f32) -> f32 {
    if a < b || (a == b && a.is_sign_negative()) {
        a
    } else {
        b
    }
}

/// max with -0.0 below +0.0; the GLSL twin is `fmax_total`.
pub fn fmax(a: f32, b: f32) -> f32 {
    if a > b || (a == b && b.is_sign_negative()) {
        a
    } else {
        b
    }
}

/// A triangle's box, exactly as `accel.kdtree_boxes` computes it.
pub fn prim_box(t: &[Vec3; 3]) -> Aabb {
    let f = |g: fn(f32, f32) -> f32, a: usize| g(g(t[0][a], t[1][a]), t[2][a]);
    Aabb {
        min: Vec3::new(f(fmin, 0), f(fmin, 1), f(fmin, 2)),
        max: Vec3::new(f(fmax, 0), f(fmax, 1), f(fmax, 2)),
    }
}
