//! The scene model: plain data with public fields.
//!
//! Loaders and generators build it, [`validate`](super::validate) checks it,
//! and the renderer and acceleration-structure builders read it. Geometry is
//! kept in object space with a per-mesh [`Transform`] and a per-object
//! [`Motion`] (and, for meshes, optional [`Keyframe`]s);
//! [`Scene::triangles_world`](super::Scene::triangles_world) flattens it for
//! a given time, which is all an accel builder needs.

use std::sync::Arc;

use glam::{Affine3A, EulerRot, Quat, Vec3};

use super::animation::{pose_at, Keyframe};

/// Index into [`Scene::materials`](super::Scene::materials).
pub type MaterialId = u32;

/// Static placement of a mesh: scale, then rotate, then translate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform {
    /// Translation (world units).
    pub translate: Vec3,
    /// Rotation in degrees about X, then Y, then Z (fixed world axes), i.e.
    /// the matrix `Rz · Ry · Rx`.
    pub rotate: Vec3,
    /// Per-axis scale; no component may be zero.
    pub scale: Vec3,
}

impl Default for Transform {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Transform {
    /// No change.
    pub const IDENTITY: Self = Self {
        translate: Vec3::ZERO,
        rotate: Vec3::ZERO,
        scale: Vec3::ONE,
    };

    /// Whether this is the identity.
    pub fn is_identity(&self) -> bool {
        *self == Self::IDENTITY
    }

    /// The rotation part as a quaternion.
    pub fn rotation(&self) -> Quat {
        let r = self.rotate * (std::f32::consts::PI / 180.0);
        Quat::from_euler(EulerRot::ZYX, r.z, r.y, r.x)
    }

    /// Object-to-world matrix `T · R · S`.
    pub fn matrix(&self) -> Affine3A {
        Affine3A::from_scale_rotation_translation(self.scale, self.rotation(), self.translate)
    }
}

/// A circular motion: rotation about an axis through `center`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Orbit {
    /// A point on the rotation axis.
    pub center: Vec3,
    /// Rotation axis (need not be unit length; must not be zero).
    pub axis: Vec3,
    /// Angular speed, degrees per second (right-hand rule about `axis`).
    pub degrees_per_second: f32,
}

/// Rigid motion of an object over time, used both for motion blur (time
/// sampled inside the camera shutter) and for animation (one frame per
/// time). At time `t` the object is first rotated by the orbit (if any)
/// through `orbit.degrees_per_second · t`, then translated by
/// `velocity · t`. At `t = 0` the object is where the scene file puts it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Motion {
    /// Linear velocity, world units per second.
    pub velocity: Vec3,
    /// Optional rotation about an axis.
    pub orbit: Option<Orbit>,
}

impl Motion {
    /// No motion.
    pub const STATIC: Self = Self {
        velocity: Vec3::ZERO,
        orbit: None,
    };

    /// Whether the object never moves.
    pub fn is_static(&self) -> bool {
        self.velocity == Vec3::ZERO
            && self
                .orbit
                .is_none_or(|o| o.degrees_per_second == 0.0 || o.axis == Vec3::ZERO)
    }

    /// Whether the motion is a pure translation (sphere centres and vertices
    /// move on straight lines, so swept bounds are the union of the bounds
    /// at the two shutter times).
    pub fn is_linear(&self) -> bool {
        self.orbit
            .is_none_or(|o| o.degrees_per_second == 0.0 || o.axis == Vec3::ZERO)
    }

    /// The world-space rigid transform at time `t` (seconds), applied after
    /// the object's own placement.
    pub fn at(&self, t: f32) -> Affine3A {
        let mut m = Affine3A::from_translation(self.velocity * t);
        if let Some(o) = self.orbit {
            let axis = o.axis.normalize_or_zero();
            if axis != Vec3::ZERO && o.degrees_per_second != 0.0 {
                let angle = (o.degrees_per_second * t).to_radians();
                let rot = Affine3A::from_translation(o.center)
                    * Affine3A::from_quat(Quat::from_axis_angle(axis, angle))
                    * Affine3A::from_translation(-o.center);
                m *= rot;
            }
        }
        m
    }
}

/// Which material each triangle of a mesh uses.
#[derive(Clone, Debug, PartialEq)]
pub enum MeshMaterials {
    /// Every triangle uses this material.
    Single(MaterialId),
    /// One material per triangle (same length as `Mesh::indices`; shared as the
    /// geometry is).
    PerTriangle(Arc<Vec<MaterialId>>),
}

/// An indexed triangle mesh in object space.
///
/// The geometry is shared (`Arc`): a scene that names one mesh file or generator many
/// times holds its vertices and triangles once, each entry with its own placement and
/// material, as the instances it becomes. `Arc::make_mut` edits one entry's copy.
#[derive(Clone, Debug, PartialEq)]
pub struct Mesh {
    /// Name for messages (file name, OBJ object, generator).
    pub name: String,
    /// Vertex positions, object space.
    pub positions: Arc<Vec<Vec3>>,
    /// Per-vertex shading normals (same length as `positions`), or empty
    /// when the source has none (the renderer then uses face normals).
    pub normals: Arc<Vec<Vec3>>,
    /// Triangles as counter-clockwise vertex-index triples (front face by
    /// the right-hand rule).
    pub indices: Arc<Vec<[u32; 3]>>,
    /// Material per mesh or per triangle.
    pub materials: MeshMaterials,
    /// Placement.
    pub transform: Transform,
    /// Keyed placements over time, applied after `transform` (empty: none;
    /// see [`super::animation`]).
    pub keyframes: Vec<Keyframe>,
    /// Motion over time.
    pub motion: Motion,
    /// Its instance record's keys and its geometry's opaque flag (`vkrt shader-check`
    /// places it with them; nothing else reads them).
    pub instance: super::instance_keys::InstanceKeys,
}

impl Mesh {
    /// A mesh with one material, identity transform and no motion.
    pub fn new(
        name: &str,
        positions: Vec<Vec3>,
        indices: Vec<[u32; 3]>,
        material: MaterialId,
    ) -> Self {
        Self {
            name: name.to_owned(),
            positions: Arc::new(positions),
            normals: Arc::default(),
            indices: Arc::new(indices),
            materials: MeshMaterials::Single(material),
            transform: Transform::IDENTITY,
            keyframes: Vec::new(),
            motion: Motion::STATIC,
            instance: Default::default(),
        }
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len()
    }

    /// Material of triangle `tri` (which must be in range).
    pub fn material_of(&self, tri: usize) -> MaterialId {
        match &self.materials {
            MeshMaterials::Single(m) => *m,
            MeshMaterials::PerTriangle(v) => v[tri],
        }
    }

    /// Placement at time `t` before motion: the keyed pose at `t` (if the
    /// mesh has keyframes) after `transform`.
    pub fn placement(&self, t: f32) -> Affine3A {
        match pose_at(&self.keyframes, t) {
            Some(pose) => pose.matrix() * self.transform.matrix(),
            None => self.transform.matrix(),
        }
    }

    /// Object-to-world matrix at time `t`: placement, then motion.
    pub fn world_matrix(&self, t: f32) -> Affine3A {
        self.motion.at(t) * self.placement(t)
    }

    /// The shading normals at the corners of triangle `t` moved by `normal_m` (a placement's
    /// inverse transpose), unit (zero where a normal is); `None` when the mesh has none.
    pub fn corner_normals(&self, t: usize, normal_m: &glam::Mat3A) -> Option<[Vec3; 3]> {
        if self.normals.is_empty() {
            return None;
        }
        Some(self.indices[t].map(|i| (*normal_m * self.normals[i as usize]).normalize_or_zero()))
    }

    /// Object-space bounds of the vertices that triangles use.
    pub fn object_bounds(&self) -> Aabb {
        let mut b = Aabb::EMPTY;
        for tri in self.indices.iter() {
            for &i in tri {
                if let Some(p) = self.positions.get(i as usize) {
                    b.grow(*p);
                }
            }
        }
        b
    }
}

/// An analytic sphere.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    /// Centre at time 0.
    pub center: Vec3,
    /// Radius, > 0.
    pub radius: f32,
    /// Material.
    pub material: MaterialId,
    /// Motion of the centre.
    pub motion: Motion,
}

impl Sphere {
    /// A static sphere.
    pub fn new(center: Vec3, radius: f32, material: MaterialId) -> Self {
        Self {
            center,
            radius,
            material,
            motion: Motion::STATIC,
        }
    }

    /// Centre at time `t`.
    pub fn center_at(&self, t: f32) -> Vec3 {
        self.motion.at(t).transform_point3(self.center)
    }
}

/// A light source. `color · intensity` is the emitted quantity; units are
/// those of the renderer's linear radiance.
///
/// - `Point`: radiant intensity (irradiance `I·cosθ / d²`); hard shadows.
/// - `Directional`: irradiance `I·cosθ` from `direction` (it travels along
///   `direction`); hard shadows.
/// - `Sphere` and `Quad`: emitted radiance of the surface; soft shadows.
///   A quad emits from the side its normal `edge_u × edge_v` points to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Light {
    /// Point light.
    Point {
        /// Position.
        position: Vec3,
        /// Linear RGB colour.
        color: Vec3,
        /// Scale of `color`, ≥ 0.
        intensity: f32,
    },
    /// Spherical area light.
    Sphere {
        /// Centre.
        center: Vec3,
        /// Radius, > 0.
        radius: f32,
        /// Linear RGB colour.
        color: Vec3,
        /// Scale of `color`, ≥ 0.
        intensity: f32,
    },
    /// Parallelogram area light `corner + u·edge_u + v·edge_v`, u, v ∈ [0, 1].
    Quad {
        /// One corner.
        corner: Vec3,
        /// First edge from `corner`.
        edge_u: Vec3,
        /// Second edge from `corner`; not parallel to `edge_u`.
        edge_v: Vec3,
        /// Linear RGB colour.
        color: Vec3,
        /// Scale of `color`, ≥ 0.
        intensity: f32,
    },
    /// Light from infinitely far away.
    Directional {
        /// Direction the light travels (from the light towards the scene);
        /// not zero.
        direction: Vec3,
        /// Linear RGB colour.
        color: Vec3,
        /// Scale of `color`, ≥ 0.
        intensity: f32,
    },
}

impl Light {
    /// "point", "sphere", "quad" or "directional" (the TOML `type`).
    pub fn kind(&self) -> &'static str {
        match self {
            Light::Point { .. } => "point",
            Light::Sphere { .. } => "sphere",
            Light::Quad { .. } => "quad",
            Light::Directional { .. } => "directional",
        }
    }

    /// `color · intensity`.
    pub fn power(&self) -> Vec3 {
        let (color, intensity) = self.color_intensity();
        color * intensity
    }

    /// `(color, intensity)`, which every kind has.
    pub fn color_intensity(&self) -> (Vec3, f32) {
        match *self {
            Light::Point {
                color, intensity, ..
            }
            | Light::Sphere {
                color, intensity, ..
            }
            | Light::Quad {
                color, intensity, ..
            }
            | Light::Directional {
                color, intensity, ..
            } => (color, intensity),
        }
    }

    /// Whether the light has an extent (gives soft shadows).
    pub fn is_area(&self) -> bool {
        matches!(self, Light::Sphere { .. } | Light::Quad { .. })
    }
}

/// Camera: pinhole when `aperture_radius == 0`, thin lens otherwise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position (lens centre).
    pub position: Vec3,
    /// Point the camera looks at.
    pub look_at: Vec3,
    /// Up hint; must not be parallel to `look_at − position`.
    pub up: Vec3,
    /// Vertical field of view in degrees, in (0, 180).
    pub fov: f32,
    /// Lens radius (world units), ≥ 0; 0 is a pinhole (no depth of field).
    pub aperture_radius: f32,
    /// Distance from the lens to the plane in focus, > 0.
    pub focus_distance: f32,
    /// Shutter opening time, seconds.
    pub shutter_open: f32,
    /// Shutter closing time, seconds, ≥ `shutter_open`.
    pub shutter_close: f32,
}

impl Camera {
    /// A pinhole camera focused on `look_at`, shutter `[0, 0]`.
    pub fn look_at(position: Vec3, look_at: Vec3, up: Vec3, fov: f32) -> Self {
        Self {
            position,
            look_at,
            up,
            fov,
            aperture_radius: 0.0,
            focus_distance: (look_at - position).length(),
            shutter_open: 0.0,
            shutter_close: 0.0,
        }
    }

    /// Orthonormal basis `(forward, right, up)`, right-handed: `right =
    /// forward × up`. Returns zero vectors for a degenerate camera (which
    /// validation rejects).
    pub fn basis(&self) -> (Vec3, Vec3, Vec3) {
        let forward = (self.look_at - self.position).normalize_or_zero();
        let right = forward.cross(self.up).normalize_or_zero();
        let up = right.cross(forward);
        (forward, right, up)
    }
}

/// Ambient-occlusion settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AmbientOcclusion {
    /// Whether AO is computed.
    pub enabled: bool,
    /// Occlusion distance (world units), > 0.
    pub radius: f32,
    /// Rays per shading point, 1 ..= [`MAX_AO_SAMPLES`](super::MAX_AO_SAMPLES).
    pub samples: u32,
}

impl Default for AmbientOcclusion {
    fn default() -> Self {
        Self {
            enabled: false,
            radius: 1.0,
            samples: 16,
        }
    }
}

/// Image and sampling settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    /// Image width in pixels, 1 ..= [`MAX_RESOLUTION`](super::MAX_RESOLUTION).
    pub width: u32,
    /// Image height in pixels, 1 ..= [`MAX_RESOLUTION`](super::MAX_RESOLUTION).
    pub height: u32,
    /// Samples per pixel, 1 ..= [`MAX_SPP`](super::MAX_SPP).
    pub spp: u32,
    /// Bounces after the primary hit, 0 ..= [`MAX_DEPTH`](super::MAX_DEPTH)
    /// (0 = primary rays and direct light only, like Bidmon's (2010) depth 0).
    pub max_depth: u32,
    /// Colour of rays that hit nothing.
    pub background: Vec3,
    /// Jitter the samples of a pixel over its area (only meaningful with
    /// `spp > 1`).
    pub antialias: bool,
    /// Ambient occlusion.
    pub ao: AmbientOcclusion,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            width: 640,
            height: 480,
            spp: 1,
            max_depth: 5,
            background: Vec3::ZERO,
            antialias: true,
            ao: AmbientOcclusion::default(),
        }
    }
}

/// Axis-aligned bounding box; `EMPTY` has `min > max`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Lower corner.
    pub min: Vec3,
    /// Upper corner.
    pub max: Vec3,
}

impl Aabb {
    /// The empty box (identity of `union`).
    pub const EMPTY: Self = Self {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };

    /// Whether nothing was added.
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x || self.min.y > self.max.y || self.min.z > self.max.z
    }

    /// Extend to contain `p`.
    pub fn grow(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    /// Extend to contain `other`.
    pub fn union(&mut self, other: &Aabb) {
        self.min = self.min.min(other.min);
        self.max = self.max.max(other.max);
    }

    /// Centre (zero for an empty box).
    pub fn center(&self) -> Vec3 {
        if self.is_empty() {
            Vec3::ZERO
        } else {
            (self.min + self.max) * 0.5
        }
    }

    /// Length of the diagonal (zero for an empty box).
    pub fn diagonal(&self) -> f32 {
        if self.is_empty() {
            0.0
        } else {
            (self.max - self.min).length()
        }
    }
}
