//! A scene prepared to render as two levels ([`TwoLevelScene`]): what shading reads in place
//! of the flat primitives. A hit names its instance and the primitive in that instance's
//! bottom level (its triangles, then its spheres); the instance's [`Placement`] names its
//! bottom level and says how it is placed. Shading reads the vertices and spheres where the
//! bottom levels hold them for their walk, and keeps of its own only what they lack: the
//! shading normals of the bottom levels with a mesh that has some, and per primitive the
//! materials of those whose primitives differ in material (one shared material is the
//! placement's). Repeated and moving meshes are stored once, in object space; the rest
//! (meshes named once, spheres) in the world, as its identity instance places it.
//!
//! With motion blur, each moving mesh's instance moves over the shutter in time steps
//! ([`InstanceMotion`]): its transform at evenly spaced times, interpolated at each ray's
//! time by the walk and by shading alike; enough steps that no step turns more than
//! [`MAX_STEP_DEGREES`].

use glam::{Mat3A, Vec3};

use crate::accel::instances::{world_to_object, Instance, InstanceMotion, MAX_MOTION_STEPS};
use crate::accel::two_levels::{TwoLevelScene, REST};
use crate::scene::{Mesh, MeshMaterials, Scene};

use super::types::Placement;

/// What shading reads of one bottom level besides its own primitives (which it reads where
/// the bottom level holds them, on the device).
#[derive(Clone, Copy, Debug)]
struct Span {
    triangles: u32,
    /// Where its shading normals start among the level normals, in triangles ([`NONE`]:
    /// none of its meshes has shading normals).
    first_normal: u32,
    /// Where its materials start among the level materials ([`NONE`]: its primitives share
    /// one, `material`).
    first_material: u32,
    /// The material its primitives share ([`PER_PRIMITIVE`]: they do not).
    material: u32,
}

/// An array a bottom level has no part of.
const NONE: u32 = u32::MAX;

/// The most a moving instance turns from one time step to the next, in degrees: the
/// interpolated transform follows the chord of the arc, at most r·(1 − cos 0.5°) ≈ 4·10⁻⁵ r
/// inside it.
pub const MAX_STEP_DEGREES: f32 = 1.0;

/// The shading data of a scene as two levels.
pub struct RenderLevels {
    /// The structures' scene: bottom levels and instances (at shutter open).
    pub scene: TwoLevelScene,
    /// How the instances move over the shutter (one step: they do not).
    pub motion: InstanceMotion,
    /// The instances at every step, step after step: what the top level is built from.
    pub moving: Vec<Instance>,
    /// Per instance, in the top level's order.
    pub placements: Vec<Placement>,
    /// Per bottom level, what shading reads of it besides its primitives.
    spans: Vec<Span>,
}

/// The instance's material where it has one (`u32::MAX`: each primitive's).
const PER_PRIMITIVE: u32 = u32::MAX;

impl RenderLevels {
    /// `two` (made of `scene` at `time`) with its shading data, its moving meshes' instances
    /// moving over `shutter` (`None`: no motion blur); and the level materials and level
    /// normals: per primitive of each bottom level whose primitives differ in material its
    /// material, per triangle of each bottom level with a mesh that has shading normals its
    /// three (9 floats, zeros for a triangle of a mesh without), bottom level after bottom
    /// level. Shading reads the vertices and spheres where the bottom levels hold them.
    pub fn new(
        scene: &Scene,
        two: TwoLevelScene,
        time: f32,
        shutter: Option<[f32; 2]>,
    ) -> (Self, Vec<u32>, Vec<f32>) {
        let (mut normals, mut materials) = (Vec::new(), Vec::new());
        let mut spans = Vec::with_capacity(two.bottoms.len());
        let world_spheres = scene.spheres_at(time);
        let n_tris = scene.triangle_count() as u32;
        for (b, g) in two.bottoms.iter().enumerate() {
            let mut gather = Gather::new(&mut materials, &mut normals);
            let mut triangle = |mesh: &Mesh, t: usize, normal_m: &Mat3A| {
                let material = match &mesh.materials {
                    MeshMaterials::Single(m) => *m,
                    MeshMaterials::PerTriangle(ids) => ids[t],
                };
                gather.triangle(mesh.corner_normals(t, normal_m), material);
            };
            let instance = two.instances.iter().find(|i| i.bottom == b as u64);
            let k = instance.map_or(REST, Instance::custom_index);
            if let Some(ids) = two.piece_ids(k) {
                // The rest (or its piece `REST - k`, or a moving sphere's level): its
                // triangles in the world, then its spheres, as the bottom level holds them.
                let mut placed: Option<(usize, Mat3A)> = None;
                for &id in ids.iter().filter(|&&id| id < n_tris) {
                    let k = two.mesh_first.partition_point(|&f| f <= id) - 1;
                    let mesh = &scene.meshes[k];
                    let normal_m = match placed {
                        Some((at, m)) if at == k => m,
                        _ => {
                            let m = mesh.world_matrix(time).matrix3.inverse().transpose();
                            placed = Some((k, m));
                            m
                        }
                    };
                    triangle(mesh, (id - two.mesh_first[k]) as usize, &normal_m);
                }
                for &id in ids.iter().filter(|&&id| id >= n_tris) {
                    gather.sphere(world_spheres[(id - n_tris) as usize].material);
                }
            } else {
                // A repeated or moving mesh, in object space.
                let mesh = &scene.meshes[k as usize];
                for t in 0..mesh.indices.len() {
                    triangle(mesh, t, &Mat3A::IDENTITY);
                }
            }
            spans.push(gather.span(g.triangle_count() as u32));
        }
        materials.shrink_to_fit();
        normals.shrink_to_fit();
        let motion = match shutter {
            Some([t0, t1]) if t1 > t0 => {
                InstanceMotion::new(steps_for(scene, &two, t1 - t0), t0, t1)
            }
            _ => InstanceMotion::STATIC,
        };
        let mut levels = Self {
            scene: two,
            motion,
            moving: Vec::new(),
            placements: Vec::new(),
            spans,
        };
        levels.place(scene);
        (levels, materials, normals)
    }

    /// Where bottom level `b`'s shading normals start among the level normals, in
    /// triangles (`None`: it has none), and where its materials start among the level
    /// materials (`None`: its primitives share one, which its instances' placements hold).
    pub(crate) fn shading_of(&self, b: usize) -> (Option<usize>, Option<usize>) {
        let s = self.spans[b];
        let at = |first: u32| (first != NONE).then_some(first as usize);
        (at(s.first_normal), at(s.first_material))
    }

    /// Takes the bottom levels' host geometry to build them, and lets go of the rest's
    /// primitive ids (4 bytes a primitive): a render that builds its levels this
    /// way reads only the placements made already, and is never moved
    /// ([`RenderLevels::move_to`] needs the ids).
    pub(crate) fn take_bottoms(&mut self) -> Vec<crate::accel::primitives::TraceGeometry> {
        self.scene.rest_ids = Vec::new();
        std::mem::take(&mut self.scene.bottoms)
    }

    /// The instances and placements of `scene` (this one's scene, its meshes moved) at
    /// `shutter[0]`, moving over `shutter` in as many steps as before: what an animation's
    /// later frame changes. The bottom levels and the rest stay.
    pub fn move_to(&mut self, scene: &Scene, shutter: [f32; 2]) {
        let two = &mut self.scene;
        for i in 0..two.instances.len() {
            if let Some(placed) = placed_at(scene, two, &two.instances[i], shutter[0]) {
                two.instances[i].transform = placed;
            }
        }
        if self.motion.steps > 1 {
            self.motion.time = shutter;
        }
        self.place(scene);
    }

    /// The instances at every step and their placements (shading reads the steps the top
    /// level's build keeps, instance after instance: `TopLevel::steps`).
    fn place(&mut self, scene: &Scene) {
        let two = &self.scene;
        let instances = &two.instances;
        let motion = self.motion;
        let n = motion.steps as usize;
        self.moving = if n < 2 {
            instances.clone()
        } else {
            let [t0, t1] = motion.time;
            (0..n)
                .flat_map(|s| {
                    let t = t0 + (t1 - t0) * (s as f32 / (n - 1) as f32);
                    instances
                        .iter()
                        .map(move |inst| match moving(scene, two, inst) {
                            Some(p) => Instance {
                                transform: rows_at(scene, p, t),
                                ..*inst
                            },
                            None => *inst,
                        })
                })
                .collect()
        };
        self.placements = placements(scene, two, &self.spans);
        for (i, p) in self.placements.iter_mut().enumerate() {
            if n > 1 && moving(scene, two, &instances[i]).is_some() {
                p.motion = [
                    n as u32,
                    (i * n) as u32,
                    motion.time[0].to_bits(),
                    motion.scale().to_bits(),
                ];
            }
        }
    }
}

/// What an instance places, where that can move: a mesh, or a moving sphere (an instance of
/// its own over a bottom level of one sphere at the origin: [`TwoLevelScene::of_moving`]).
#[derive(Clone, Copy)]
enum Placed {
    Mesh(usize),
    Sphere(usize),
}

/// What `inst` places (`None`: the rest, or a piece of it, in the world).
fn placed(scene: &Scene, two: &TwoLevelScene, inst: &Instance) -> Option<Placed> {
    let k = inst.custom_index();
    // (the scene's triangle count, without a pass over its meshes per instance)
    let n_tris = match (two.mesh_first.last(), scene.meshes.last()) {
        (Some(&first), Some(mesh)) => first + mesh.indices.len() as u32,
        _ => 0,
    };
    match two.piece_ids(k) {
        None => Some(Placed::Mesh(k as usize)),
        Some(&[id]) if id >= n_tris && two.bottoms[inst.bottom as usize].triangle_count() == 0 => {
            let s = (id - n_tris) as usize;
            // (a still sphere in a piece of its own stays in the world)
            (!scene.spheres[s].motion.is_static()).then_some(Placed::Sphere(s))
        }
        Some(_) => None,
    }
}

/// What `inst` places where it moves over a shutter (velocity or orbit; keyframes are held
/// at shutter open).
fn moving(scene: &Scene, two: &TwoLevelScene, inst: &Instance) -> Option<Placed> {
    placed(scene, two, inst).filter(|&p| !motion_of(scene, p).is_static())
}

fn motion_of(scene: &Scene, p: Placed) -> &crate::scene::Motion {
    match p {
        Placed::Mesh(k) => &scene.meshes[k].motion,
        Placed::Sphere(s) => &scene.spheres[s].motion,
    }
}

/// `inst`'s object-to-world rows at `t` (`None`: it places the rest, which stays).
fn placed_at(scene: &Scene, two: &TwoLevelScene, inst: &Instance, t: f32) -> Option<[[f32; 4]; 3]> {
    placed(scene, two, inst).map(|p| rows_at(scene, p, t))
}

/// The object-to-world rows at `t` of what `p` names.
fn rows_at(scene: &Scene, p: Placed, t: f32) -> [[f32; 4]; 3] {
    match p {
        Placed::Mesh(k) => Instance::rows_of(&scene.meshes[k].world_matrix(t)),
        Placed::Sphere(s) => Instance::rows_of(&glam::Affine3A::from_translation(
            scene.spheres[s].center_at(t),
        )),
    }
}

/// Time steps for `instances` of `scene` moving over `shutter` seconds: two where they move
/// on straight lines, more where they turn ([`MAX_STEP_DEGREES`] per step at most), one
/// where nothing moves.
fn steps_for(scene: &Scene, two: &TwoLevelScene, shutter: f32) -> u32 {
    let mut segments = 0u32;
    for inst in &two.instances {
        if let Some(p) = moving(scene, two, inst) {
            let turn = motion_of(scene, p)
                .orbit
                .map_or(0.0, |o| (o.degrees_per_second * shutter).abs());
            // (a shutter's length rounds differently at each frame's time: a turn a few ulps
            // past a whole number of degrees keeps the frames' step count)
            let need = (turn / MAX_STEP_DEGREES * (1.0 - 1e-5)).ceil().max(1.0);
            segments = segments.max(need.min((MAX_MOTION_STEPS - 1) as f32) as u32);
        }
    }
    segments + 1
}

/// Per instance its placement: its bottom level, its transforms, its material (a mesh with
/// one material: the instance's own mesh's, so copies may differ; else its bottom level's
/// where its primitives share one).
fn placements(scene: &Scene, two: &TwoLevelScene, spans: &[Span]) -> Vec<Placement> {
    two.instances
        .iter()
        .map(|inst| {
            let span = spans[inst.bottom as usize];
            // (the levels of moving spheres are shared by radius: each its own material)
            let material = match placed(scene, two, inst) {
                Some(Placed::Mesh(k)) => match &scene.meshes[k].materials {
                    MeshMaterials::Single(id) => *id,
                    MeshMaterials::PerTriangle(_) => span.material,
                },
                Some(Placed::Sphere(s)) => scene.spheres[s].material,
                None => span.material,
            };
            Placement {
                object_to_world: inst.transform,
                // (a singular transform is never hit: its instance is inactive)
                world_to_object: world_to_object(&inst.transform).unwrap_or_default(),
                info: [inst.bottom as u32, span.triangles, 0, material],
                motion: [1, 0, 0, 0],
            }
        })
        .collect()
}

/// One bottom level's materials and shading normals as they are gathered, primitive after
/// primitive (its triangles, then its spheres), into the level arrays: its materials only
/// once two differ, its normals only once a triangle has some (zeros for those before).
struct Gather<'a> {
    materials: &'a mut Vec<u32>,
    normals: &'a mut Vec<f32>,
    first_material: usize,
    first_normal: usize,
    /// The first primitive's material, and whether another differs from it.
    shared: Option<u32>,
    mixed: bool,
    has_normals: bool,
    primitives: usize,
    triangles: usize,
}

impl<'a> Gather<'a> {
    fn new(materials: &'a mut Vec<u32>, normals: &'a mut Vec<f32>) -> Self {
        Self {
            first_material: materials.len(),
            first_normal: normals.len(),
            materials,
            normals,
            shared: None,
            mixed: false,
            has_normals: false,
            primitives: 0,
            triangles: 0,
        }
    }

    fn triangle(&mut self, corners: Option<[Vec3; 3]>, material: u32) {
        match corners {
            Some(n) => {
                if !self.has_normals {
                    let start = self.first_normal + 9 * self.triangles;
                    self.normals.resize(start, 0.0);
                    self.has_normals = true;
                }
                self.normals.extend(n.iter().flat_map(|v| v.to_array()));
            }
            None if self.has_normals => self.normals.extend([0.0; 9]),
            None => {}
        }
        self.triangles += 1;
        self.material(material);
    }

    fn sphere(&mut self, material: u32) {
        self.material(material);
    }

    fn material(&mut self, m: u32) {
        match self.shared {
            None => self.shared = Some(m),
            Some(first) if !self.mixed && first != m => {
                self.materials
                    .resize(self.first_material + self.primitives, first);
                self.mixed = true;
            }
            Some(_) => {}
        }
        if self.mixed {
            self.materials.push(m);
        }
        self.primitives += 1;
    }

    /// The bottom level's span (`triangles` of its primitives are triangles).
    fn span(self, triangles: u32) -> Span {
        debug_assert_eq!(self.triangles, triangles as usize);
        Span {
            triangles,
            first_normal: if self.has_normals {
                (self.first_normal / 9) as u32
            } else {
                NONE
            },
            first_material: if self.mixed {
                self.first_material as u32
            } else {
                NONE
            },
            material: match (self.mixed, self.shared) {
                (false, Some(m)) => m,
                _ => PER_PRIMITIVE,
            },
        }
    }
}
