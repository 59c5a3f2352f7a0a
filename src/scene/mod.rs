//! Host-side scene model, loaders, generators and validation.
//!
//! A [`Scene`] is plain data — meshes in object space with a transform, a
//! motion and optional keyframes, analytic spheres, materials, lights, a
//! camera, render settings and optionally frames ([`animation`]) — so that
//! every front end produces the same thing and every consumer reads the
//! same thing:
//!
//! - front ends: the TOML scene format ([`toml_format`], documented in
//!   `docs/scene-format.md`), Wavefront OBJ + MTL ([`obj`], parsed by `tobj`
//!   after a line-numbered pre-validation), Bidmon's (2010) plain-text format
//!   ([`scn`]) and procedural generators ([`gen`]);
//! - one validation pass ([`validate`]) that every front end runs, so "no
//!   NaN, no index out of range, no zero-size image, nothing above the
//!   documented limits" holds for every scene the renderer ever sees;
//! - consumers: [`Scene::triangles_world`] and friends flatten geometry at a
//!   time for the acceleration-structure builders; [`Scene::effects`] tells
//!   the renderer which passes the scene needs.
//!
//! Nothing here prints: warnings (dropped zero-area triangles, ignored OBJ
//! statements) are returned in [`LoadedScene::warnings`].

pub mod animation;
pub mod effects;
pub mod error;
#[cfg(feature = "scene-files")]
pub mod files;
pub mod gen;
pub mod instance_keys;
pub mod limits;
pub mod material;
pub mod model;
#[cfg(feature = "scene-files")]
pub mod obj;
#[cfg(feature = "scene-files")]
pub mod scn;
#[cfg(feature = "scene-files")]
mod toml_anim;
#[cfg(feature = "scene-files")]
mod toml_defs;
#[cfg(feature = "scene-files")]
pub mod toml_format;
#[cfg(feature = "scene-files")]
mod toml_locate;
#[cfg(feature = "scene-files")]
mod toml_write;
pub mod validate;

#[cfg(feature = "scene-files")]
use std::path::{Path, PathBuf};

use glam::Vec3;

pub use animation::{Animation, Keyframe, Pose};
pub use effects::{AnimationSummary, BoundsSummary, Effects, SceneSummary};
pub use error::{Origin, SceneError};
#[cfg(feature = "scene-files")]
pub use files::{DiskFiles, FileSource, MemoryFiles};
pub use limits::*;
pub use material::Material;
pub use model::{
    Aabb, AmbientOcclusion, Camera, Light, MaterialId, Mesh, MeshMaterials, Motion, Orbit,
    RenderSettings, Sphere, Transform,
};

/// A complete scene. Fields are public: build one by hand, load one, or
/// generate one, then call [`Scene::validate`] (loaders and generators
/// already have).
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    /// Triangle meshes.
    pub meshes: Vec<Mesh>,
    /// Analytic spheres.
    pub spheres: Vec<Sphere>,
    /// Materials, indexed by [`MaterialId`].
    pub materials: Vec<Material>,
    /// Light sources.
    pub lights: Vec<Light>,
    /// The camera.
    pub camera: Camera,
    /// Image and sampling settings.
    pub settings: RenderSettings,
    /// Ambient light colour (added as `ambient · diffuse` at every hit).
    pub ambient: Vec3,
    /// Frames, for an animated scene ([`animation`]); `None` for a still.
    pub animation: Option<Animation>,
}

#[cfg(feature = "scene-files")]
/// A scene as loaded, with the warnings loading produced (for the caller to
/// print or ignore; the library never prints).
#[derive(Clone, Debug)]
pub struct LoadedScene {
    /// The validated scene.
    pub scene: Scene,
    /// Human-readable warnings, e.g. "bunny.obj: dropped 3 zero-area
    /// triangles".
    pub warnings: Vec<String>,
}

#[cfg(feature = "scene-files")]
/// The file formats [`Scene::load`] understands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SceneFormat {
    /// `.toml`: the vkrt scene format.
    Toml,
    /// `.obj`: a Wavefront mesh (with its MTL libraries), framed by a
    /// default camera and light.
    Obj,
    /// `.scn` or `.txt`: Bidmon's (2010) plain-text format.
    Scn,
}

#[cfg(feature = "scene-files")]
impl SceneFormat {
    /// The format a path's extension names (case-insensitive).
    pub fn from_path(path: &Path) -> Result<Self, SceneError> {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        match ext.as_str() {
            "toml" => Ok(SceneFormat::Toml),
            "obj" => Ok(SceneFormat::Obj),
            "scn" | "txt" => Ok(SceneFormat::Scn),
            _ => Err(SceneError::UnsupportedFormat {
                path: path.to_owned(),
                extension: ext,
            }),
        }
    }
}

#[cfg(feature = "scene-files")]
impl Scene {
    /// Load and validate a scene file; the format is chosen by extension
    /// (see [`SceneFormat`]). Referenced files (meshes, MTL libraries) are
    /// resolved relative to the file's directory.
    pub fn load(path: &Path) -> Result<LoadedScene, SceneError> {
        Self::load_with(path, &Limits::default())
    }

    /// [`Scene::load`] with explicit size limits.
    pub fn load_with(path: &Path, limits: &Limits) -> Result<LoadedScene, SceneError> {
        let format = SceneFormat::from_path(path)?;
        let text = || files::read_file_text(path, limits.max_file_bytes);
        let base_dir = path.parent().unwrap_or(Path::new("")).to_path_buf();
        match format {
            SceneFormat::Toml => {
                toml_format::parse_toml_scene(&text()?, path, &base_dir, &DiskFiles, limits)
            }
            // (read line by line: a large mesh's text is never held whole)
            SceneFormat::Obj => obj::load_obj_scene_file(path, &DiskFiles, limits),
            SceneFormat::Scn => scn::parse_scn(&text()?, path, limits),
        }
    }

    /// Parse TOML scene text. Relative mesh paths are resolved against
    /// `base_dir` on disk; messages call the text `<base_dir>/<scene>.toml`.
    pub fn from_toml_str(text: &str, base_dir: &Path) -> Result<LoadedScene, SceneError> {
        let name: PathBuf = base_dir.join("<scene>.toml");
        toml_format::parse_toml_scene(text, &name, base_dir, &DiskFiles, &Limits::default())
    }

    /// Parse TOML scene text with referenced files read from `files` (e.g. a
    /// [`MemoryFiles`]) and explicit limits. `name` is the path used in
    /// messages; meshes resolve against its directory.
    pub fn from_toml_str_with(
        text: &str,
        name: &Path,
        files: &dyn FileSource,
        limits: &Limits,
    ) -> Result<LoadedScene, SceneError> {
        let base_dir = name.parent().unwrap_or(Path::new("")).to_path_buf();
        toml_format::parse_toml_scene(text, name, &base_dir, files, limits)
    }

    /// Serialize to the TOML scene format. Meshes are written inline
    /// (positions, normals, indices), so the output does not depend on the
    /// files the scene was loaded from; material names are made unique.
    pub fn to_toml_string(&self) -> String {
        toml_format::scene_to_toml(self)
    }
}

impl Scene {
    /// The embedded default scene: a Cornell-style box with a mirror sphere,
    /// a glass sphere and a quad area light ([`gen::cornell_box`]).
    pub fn default_scene() -> Scene {
        gen::cornell_box()
    }

    /// A scene around the given geometry, with a camera framing its bounds
    /// (front view, slightly from above, vertical fov 40°), a white point
    /// light near the camera and a little ambient light. This is what an
    /// `.obj` path loads as.
    pub fn from_geometry(
        meshes: Vec<Mesh>,
        spheres: Vec<Sphere>,
        materials: Vec<Material>,
    ) -> Scene {
        let mut scene = Scene {
            meshes,
            spheres,
            materials,
            lights: Vec::new(),
            camera: Camera::look_at(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 40.0),
            settings: RenderSettings::default(),
            ambient: Vec3::splat(0.05),
            animation: None,
        };
        scene.frame_camera();
        let (forward, right, up) = scene.camera.basis();
        let dist = scene.camera.focus_distance;
        let light_pos = scene.camera.position + (up * 0.5 - right * 0.3 - forward * 0.1) * dist;
        let to_center = (scene.camera.look_at - light_pos).length().max(1e-6);
        scene.lights.push(Light::Point {
            position: light_pos,
            color: Vec3::ONE,
            // Irradiance ≈ 1 at the centre of the bounds.
            intensity: to_center * to_center,
        });
        scene
    }

    /// Point the camera at the scene bounds (at the shutter-open time) from
    /// the front (+Z), slightly above, so that the bounding sphere fits the
    /// image. Keeps the field of view if valid, else uses 40°.
    pub fn frame_camera(&mut self) {
        let b = self.bounds();
        let center = b.center();
        let radius = (b.diagonal() * 0.5).max(1e-3);
        let fov = if self.camera.fov > 0.0 && self.camera.fov < 180.0 {
            self.camera.fov
        } else {
            40.0
        };
        let aspect = self.settings.width.max(1) as f32 / self.settings.height.max(1) as f32;
        let half_v = (fov.to_radians() * 0.5).tan();
        let half = half_v.min(half_v * aspect).atan();
        let dist = radius / half.sin() * 1.05;
        let dir = Vec3::new(0.0, 0.25, 1.0).normalize();
        self.camera = Camera {
            fov,
            ..Camera::look_at(center + dir * dist, center, Vec3::Y, fov)
        };
    }

    /// Check the scene against the documented limits (see [`validate`]),
    /// dropping zero-area triangles. Returns warnings.
    pub fn validate(&mut self) -> Result<Vec<String>, SceneError> {
        validate::validate(self, &Limits::default())
    }

    /// The meshes grouped by their object-space geometry (the same positions and
    /// triangles: a mesh file or generator named more than once with the same parameters),
    /// in order of first appearance; each group lists mesh indices in scene order. A group
    /// of more than one becomes one bottom-level structure with an instance per mesh.
    pub fn mesh_groups(&self) -> Vec<Vec<usize>> {
        use std::hash::{Hash, Hasher};
        let key = |m: &Mesh| {
            let mut h = std::collections::hash_map::DefaultHasher::new();
            for p in m.positions.iter() {
                p.to_array().map(f32::to_bits).hash(&mut h);
            }
            m.indices.hash(&mut h);
            h.finish()
        };
        let same = |a: &Mesh, b: &Mesh| {
            a.indices == b.indices
                && a.positions.len() == b.positions.len()
                && a.positions
                    .iter()
                    .zip(b.positions.iter())
                    .all(|(p, q)| p.to_array().map(f32::to_bits) == q.to_array().map(f32::to_bits))
        };
        let mut groups: Vec<Vec<usize>> = Vec::new();
        let mut by_key: std::collections::HashMap<u64, Vec<usize>> = Default::default();
        // Entries sharing their geometry (a file or generator named again) are one group
        // without a look at their contents.
        let mut by_identity: std::collections::HashMap<[usize; 2], usize> = Default::default();
        for (i, m) in self.meshes.iter().enumerate() {
            let identity = [
                std::sync::Arc::as_ptr(&m.positions) as usize,
                std::sync::Arc::as_ptr(&m.indices) as usize,
            ];
            if let Some(&g) = by_identity.get(&identity) {
                groups[g].push(i);
                continue;
            }
            let candidates = by_key.entry(key(m)).or_default();
            let g = match candidates
                .iter()
                .find(|&&g| same(&self.meshes[groups[g][0]], m))
            {
                Some(&g) => {
                    groups[g].push(i);
                    g
                }
                None => {
                    candidates.push(groups.len());
                    groups.push(vec![i]);
                    groups.len() - 1
                }
            };
            by_identity.insert(identity, g);
        }
        groups
    }

    /// Total number of triangles over all meshes.
    pub fn triangle_count(&self) -> usize {
        self.meshes.iter().map(|m| m.indices.len()).sum()
    }

    /// All triangles in world space at time `t` (transforms and motion
    /// applied), meshes in order. Pairs with [`Scene::triangle_materials`].
    pub fn triangles_world(&self, t: f32) -> Vec<[Vec3; 3]> {
        let mut out = Vec::with_capacity(self.triangle_count());
        for mesh in &self.meshes {
            let m = mesh.world_matrix(t);
            let p = &mesh.positions;
            out.extend(mesh.indices.iter().map(|&[a, b, c]| {
                [
                    m.transform_point3(p[a as usize]),
                    m.transform_point3(p[b as usize]),
                    m.transform_point3(p[c as usize]),
                ]
            }));
        }
        out
    }

    /// Material of every triangle, in the order of
    /// [`Scene::triangles_world`].
    pub fn triangle_materials(&self) -> Vec<MaterialId> {
        let mut out = Vec::with_capacity(self.triangle_count());
        for mesh in &self.meshes {
            match &mesh.materials {
                MeshMaterials::Single(id) => {
                    out.extend(std::iter::repeat_n(*id, mesh.indices.len()))
                }
                MeshMaterials::PerTriangle(ids) => out.extend_from_slice(ids),
            }
        }
        out
    }

    /// Unit shading normals at the three corners of every triangle, world
    /// space at time `t`, in the order of [`Scene::triangles_world`]. Meshes
    /// without normals get the face normal at all three corners.
    pub fn triangle_normals_world(&self, t: f32) -> Vec<[Vec3; 3]> {
        let mut out = Vec::with_capacity(self.triangle_count());
        for mesh in &self.meshes {
            let m = mesh.world_matrix(t);
            let normal_m = m.matrix3.inverse().transpose();
            let p = &mesh.positions;
            out.extend((0..mesh.indices.len()).map(|t| {
                mesh.corner_normals(t, &normal_m).unwrap_or_else(|| {
                    let [pa, pb, pc] = mesh.indices[t].map(|i| m.transform_point3(p[i as usize]));
                    let f = (pb - pa).cross(pc - pa).normalize_or_zero();
                    [f, f, f]
                })
            }));
        }
        out
    }

    /// The spheres at time `t`: centres moved by their motion, motion
    /// cleared.
    pub fn spheres_at(&self, t: f32) -> Vec<Sphere> {
        self.spheres
            .iter()
            .map(|s| Sphere {
                center: s.center_at(t),
                motion: Motion::STATIC,
                ..*s
            })
            .collect()
    }

    /// World bounds of all geometry at time `t`.
    pub fn bounds_at(&self, t: f32) -> Aabb {
        let mut b = Aabb::EMPTY;
        for mesh in &self.meshes {
            let m = mesh.world_matrix(t);
            for tri in mesh.indices.iter() {
                for &i in tri {
                    if let Some(p) = mesh.positions.get(i as usize) {
                        b.grow(m.transform_point3(*p));
                    }
                }
            }
        }
        for s in &self.spheres {
            let c = s.center_at(t);
            b.grow(c - Vec3::splat(s.radius));
            b.grow(c + Vec3::splat(s.radius));
        }
        b
    }

    /// World bounds at the shutter-open time.
    pub fn bounds(&self) -> Aabb {
        self.bounds_at(self.camera.shutter_open)
    }

    /// Conservative bounds of all geometry over the whole shutter interval
    /// `[shutter_open, shutter_close]` ([`Scene::swept_bounds_over`]).
    pub fn swept_bounds(&self) -> Aabb {
        self.swept_bounds_over(self.camera.shutter_open, self.camera.shutter_close)
    }

    /// Conservative bounds of all geometry over `[t0, t1]`: exact for
    /// linear motion; orbits are sampled every 5° at most and padded by the
    /// chord's sagitta. Meshes with keyframes are bounded over all their
    /// keys ([`animation::keyed_bounds`]), whatever the interval.
    pub fn swept_bounds_over(&self, t0: f32, t1: f32) -> Aabb {
        let mut out = Aabb::EMPTY;
        for mesh in &self.meshes {
            let ob = mesh.object_bounds();
            if ob.is_empty() {
                continue;
            }
            let placed: Vec<Vec3> = if mesh.keyframes.len() > 1 {
                let m = mesh.transform.matrix();
                let reach = box_corners(&ob)
                    .iter()
                    .map(|&c| m.transform_point3(c).length())
                    .fold(0.0f32, f32::max);
                box_corners(&animation::keyed_bounds(&mesh.keyframes, reach)).to_vec()
            } else {
                // No keys or one: the placement does not change over time.
                let m = mesh.placement(t0);
                box_corners(&ob).map(|c| m.transform_point3(c)).to_vec()
            };
            out.union(&swept_points(&placed, &mesh.motion, t0, t1));
        }
        for s in &self.spheres {
            let b = swept_points(&[s.center], &s.motion, t0, t1);
            if !b.is_empty() {
                out.grow(b.min - Vec3::splat(s.radius));
                out.grow(b.max + Vec3::splat(s.radius));
            }
        }
        out
    }
}

/// The 8 corners of a non-empty box.
fn box_corners(b: &Aabb) -> [Vec3; 8] {
    std::array::from_fn(|i| {
        Vec3::new(
            if i & 1 == 0 { b.min.x } else { b.max.x },
            if i & 2 == 0 { b.min.y } else { b.max.y },
            if i & 4 == 0 { b.min.z } else { b.max.z },
        )
    })
}

/// Bounds of `points` moved by `motion` over `[t0, t1]`.
pub fn swept_points(points: &[Vec3], motion: &Motion, t0: f32, t1: f32) -> Aabb {
    let mut b = Aabb::EMPTY;
    let mut add = |t: f32, pad: f32| {
        let m = motion.at(t);
        for &p in points {
            let q = m.transform_point3(p);
            b.grow(q - Vec3::splat(pad));
            b.grow(q + Vec3::splat(pad));
        }
    };
    if t1 <= t0 || motion.is_linear() {
        add(t0, 0.0);
        add(t1.max(t0), 0.0);
        return b;
    }
    let Some(orbit) = motion.orbit else {
        return b;
    };
    let sweep = (orbit.degrees_per_second * (t1 - t0)).abs();
    let steps = (sweep / 5.0).ceil().clamp(1.0, 72.0) as u32;
    let step_deg = (sweep / steps as f32).min(5.0);
    let axis = orbit.axis.normalize_or_zero();
    let radius = points
        .iter()
        .map(|&p| {
            let d = p - orbit.center;
            (d - axis * d.dot(axis)).length()
        })
        .fold(0.0f32, f32::max);
    let sagitta = radius * (1.0 - (step_deg.to_radians() * 0.5).cos()) * 1.01 + 1e-6 * radius;
    if sweep >= 360.0 {
        // Whole turns: every angle occurs, so bound one full turn sampled
        // from t0 and widen by the linear travel over the interval in both
        // directions (each sample's offset v·t is within |v|·(t1 − t0) of
        // any other).
        let period = 360.0 / orbit.degrees_per_second.abs();
        for k in 0..=steps {
            add(t0 + period * (k as f32 / steps as f32), sagitta);
        }
        let lin = (motion.velocity * (t1 - t0)).abs();
        b.min -= lin;
        b.max += lin;
    } else {
        for k in 0..=steps {
            add(t0 + (t1 - t0) * (k as f32 / steps as f32), sagitta);
        }
    }
    b
}
